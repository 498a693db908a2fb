"""Atomic local-file writes: temp file in the same directory, fsync, then rename or link,
then (unless asked not to) fsync the directory, so the new name survives a power loss."""

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
# errnos with which a file system refuses to fsync a directory, or to open one for it (EACCES: a
# directory one may write into but not list): nothing to sync there
_NO_DIR_SYNC = {errno.EINVAL, errno.EBADF, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EACCES}
_DIR_FLAGS = os.O_RDONLY | getattr(os, "O_DIRECTORY", 0) | getattr(os, "O_CLOEXEC", 0)


def temp_path(path: str) -> str:
    """A fresh temp-file name next to ``path``."""
    head, tail = os.path.split(path)
    return os.path.join(head, f".{tail}.{uuid.uuid4().hex}.tmp")


def is_temp_name(name: str) -> bool:
    return bool(TEMP_RE.match(name))


def _unlink_quietly(path: str) -> None:
    with contextlib.suppress(FileNotFoundError):
        os.unlink(path)


def sync_dir(path: str) -> None:
    """fsync the directory ``path``: the names created, renamed or removed in it are on disk after this.

    A file system that cannot (EINVAL, EBADF, ENOTSUP: some network and FUSE file
    systems) is skipped: it gives no such promise to keep."""
    try:
        fd = os.open(path, _DIR_FLAGS)
    except OSError as exc:
        if exc.errno in _NO_DIR_SYNC:
            return
        raise
    try:
        os.fsync(fd)
    except OSError as exc:
        if exc.errno not in _NO_DIR_SYNC:
            raise
    finally:
        os.close(fd)


def make_dirs(path: str) -> None:
    """``os.makedirs(path, exist_ok=True)``, each directory it creates synced into its parent."""
    missing = []
    head = path
    while head and not os.path.isdir(head):
        missing.append(head)
        head, tail = os.path.split(head)
        if not tail:
            break
    if not missing:
        return
    os.makedirs(path, exist_ok=True)
    for created in reversed(missing):  # top-down: a parent's entry before its child's
        sync_dir(os.path.dirname(created) or ".")


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


def atomic_write(path: str, data: bytes, durable: bool = True) -> None:
    """Write ``data`` to ``path`` so readers see the old file or the whole new one.

    ``durable``: fsync the directory after the rename, so the new file is there after a
    power loss. Frame files pass False: a producer syncs each frame folder once, before
    the episode's part (the commit point) is written (``sync_dir``)."""
    make_dirs(os.path.dirname(path))
    tmp = temp_path(path)
    _write_new(tmp, data)
    try:
        os.replace(tmp, path)
    except BaseException:
        _unlink_quietly(tmp)
        raise
    if durable:
        sync_dir(os.path.dirname(path))


def exclusive_write(path: str, data: bytes) -> bool:
    """Create ``path`` with ``data`` only if it does not exist; True if this call created it.

    The content is written to a temp file and hard-linked into place, so the file
    appears complete or not at all. Where hard links are unsupported it falls back
    to O_CREAT|O_EXCL on ``path`` itself (still exclusive, briefly partial).
    """
    make_dirs(os.path.dirname(path))
    tmp = temp_path(path)
    _write_new(tmp, data)
    try:
        os.link(tmp, path)
        linked = True
    except FileExistsError:
        return False
    except OSError as exc:
        if exc.errno not in _NO_LINK:
            raise
        linked = False
    finally:
        _unlink_quietly(tmp)
    if not linked:
        try:
            _write_new(path, data)
        except FileExistsError:
            return False
    sync_dir(os.path.dirname(path))  # the new name (and the temp name's removal) on disk
    return True
