"""Atomic local-file writes: temp file in the same directory, fsync, then rename or link."""

from __future__ import annotations

import contextlib
import errno
import os
import re
import uuid

from storage.checksum import CHUNK

# Temp names look like ".<name>.<32 hex>.tmp"; the leading dot also hides them
# from pyarrow.dataset discovery.
TEMP_RE = re.compile(r"^\..+\.[0-9a-f]{32}\.tmp$")
# errnos for which os.link is unsupported rather than a real failure
_NO_LINK = {errno.EPERM, errno.EXDEV, errno.EMLINK, errno.ENOTSUP, errno.EOPNOTSUPP}
_FLAGS = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0)


def temp_path(path: str) -> str:
    """A fresh temp-file name next to ``path``."""
    head, tail = os.path.split(path)
    return os.path.join(head, f".{tail}.{uuid.uuid4().hex}.tmp")


def is_temp_name(name: str) -> bool:
    return bool(TEMP_RE.match(name))


def _unlink_quietly(path: str) -> None:
    with contextlib.suppress(FileNotFoundError):
        os.unlink(path)


def _write_new(path: str, data: bytes) -> None:
    """Create ``path`` (must not exist), write all of ``data``, fsync; remove it on failure."""
    fd = os.open(path, _FLAGS, 0o666)
    try:
        try:
            view = memoryview(data).cast("B")
            offset = 0
            while offset < len(view):
                offset += os.write(fd, view[offset : offset + CHUNK])
            os.fsync(fd)
        finally:
            os.close(fd)
    except BaseException:
        _unlink_quietly(path)
        raise


def atomic_write(path: str, data: bytes) -> None:
    """Write ``data`` to ``path`` so readers see the old file or the whole new one."""
    os.makedirs(os.path.dirname(path), exist_ok=True)
    tmp = temp_path(path)
    _write_new(tmp, data)
    try:
        os.replace(tmp, path)
    except BaseException:
        _unlink_quietly(tmp)
        raise


def exclusive_write(path: str, data: bytes) -> bool:
    """Create ``path`` with ``data`` only if it does not exist; True if this call created it.

    The content is written to a temp file and hard-linked into place, so the file
    appears complete or not at all. Where hard links are unsupported it falls back
    to O_CREAT|O_EXCL on ``path`` itself (still exclusive, briefly partial).
    """
    os.makedirs(os.path.dirname(path), exist_ok=True)
    tmp = temp_path(path)
    _write_new(tmp, data)
    try:
        os.link(tmp, path)
        return True
    except FileExistsError:
        return False
    except OSError as exc:
        if exc.errno not in _NO_LINK:
            raise
    finally:
        _unlink_quietly(tmp)
    try:
        _write_new(path, data)
    except FileExistsError:
        return False
    return True
