"""StorageError and the one-line messages it carries, with secrets redacted."""

from __future__ import annotations

import errno
import os
import re

# Environment variables whose values must never appear in a message.
_SECRET_ENV = ("AWS_SECRET_ACCESS_KEY", "AWS_SESSION_TOKEN", "AWS_ACCESS_KEY_ID")
# "scheme://user:pass@host" -> "scheme://***@host"
_USERINFO_RE = re.compile(r"(?P<scheme>[A-Za-z][A-Za-z0-9+.-]*://)[^/@\s]*@")

# errno -> human cause; anything else falls back to the exception's own text.
_ERRNO_CAUSES = {
    errno.ENOSPC: "no space left on device",
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
    errno.EROFS: "read-only file system",
    errno.ENOTDIR: "a path component is not a directory",
    errno.EISDIR: "a folder is in the way (EISDIR); move it out of the root",
    errno.ENOENT: "no such file or directory",
    errno.EEXIST: "the path already exists",
}
if hasattr(errno, "EDQUOT"):  # not on every platform
    _ERRNO_CAUSES[errno.EDQUOT] = "disk quota exceeded"
# Not transient: retrying cannot help, so a run stops at the first one.
FATAL_ERRNOS = {errno.ENOSPC, errno.EROFS, errno.EACCES, errno.EPERM, errno.EISDIR, errno.ENOTDIR} | (
    {errno.EDQUOT} if hasattr(errno, "EDQUOT") else set()
)

# Substrings of pyarrow's S3 error texts -> human cause.
_S3_CAUSES = {
    "NO_SUCH_BUCKET": "the bucket does not exist",
    "ACCESS_DENIED": "access denied (check the AWS credentials in the environment)",
    "INVALID_ACCESS_KEY_ID": "the access key id is not valid",
    "SIGNATURE_DOES_NOT_MATCH": "the secret access key is not valid",
    "NETWORK_CONNECTION": "cannot reach the S3 endpoint",
}


class StorageError(Exception):
    """An output root cannot be used: bad URI, permissions, full disk, missing bucket.

    ``cause`` is the short reason alone (e.g. "no space left on device (ENOSPC)");
    ``fatal`` says retrying cannot help (full disk, read-only, permissions).
    """

    def __init__(self, message: str, *, cause: str | None = None, fatal: bool = False) -> None:
        super().__init__(message)
        self.cause = cause or message
        self.fatal = fatal

    def __reduce__(self):  # keeps cause and fatal across processes (Ray workers)
        return (_rebuild, (str(self), self.cause, self.fatal))


def _rebuild(message: str, cause: str, fatal: bool) -> StorageError:
    return StorageError(message, cause=cause, fatal=fatal)


def redact(text: str) -> str:
    """``text`` with URI user-info and credential values from the environment masked."""
    text = _USERINFO_RE.sub(r"\g<scheme>***@", text)
    for name in _SECRET_ENV:
        value = os.environ.get(name, "")
        if len(value) >= 4:
            text = text.replace(value, "***")
    return text


def describe(exc: BaseException) -> str:
    """A short, single-line, redacted cause for ``exc``."""
    code = getattr(exc, "errno", None)
    if code in _ERRNO_CAUSES:
        cause = _ERRNO_CAUSES[code]
        return cause if errno.errorcode[code] in cause else f"{cause} ({errno.errorcode[code]})"
    text = str(exc)
    for needle, cause in _S3_CAUSES.items():
        if needle in text:
            return cause
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    return redact(lines[0] if lines else type(exc).__name__)


def storage_error(action: str, target: str, exc: BaseException) -> StorageError:
    """``StorageError("cannot <action> <target>: <cause>")``; raise it ``from exc``."""
    cause = describe(exc)
    fatal = getattr(exc, "errno", None) in FATAL_ERRNOS
    return StorageError(f"cannot {action} {redact(target)}: {cause}", cause=cause, fatal=fatal)
