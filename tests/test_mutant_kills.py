"""Tests written for what `make mutants` found the fast tests let through
(docs/mutants.md lists each survivor and the test here that now kills it).

Small and fast, no Ray: each names the promise the mutant broke.
"""

from __future__ import annotations

import errno
import os

import pytest

from storage import atomic

# ----------------------------------------------------------------- storage/atomic ----


def test_exclusive_write_without_hard_links_creates_the_file_once(monkeypatch, tmp_path):
    """Where hard links are unsupported (EPERM on some network file systems),
    exclusive_write falls back to O_EXCL on the name itself: still exclusive,
    the whole content written, no temp file left; another errno is an error."""
    def no_link(src, dst):
        raise OSError(errno.EPERM, "links not supported")

    monkeypatch.setattr(os, "link", no_link)
    target = tmp_path / "d" / "lease.json"
    assert atomic.exclusive_write(str(target), b"first") is True
    assert target.read_bytes() == b"first"
    assert atomic.exclusive_write(str(target), b"second") is False
    assert target.read_bytes() == b"first"
    assert os.listdir(target.parent) == ["lease.json"]

    def broken_link(src, dst):
        raise OSError(errno.EIO, "disk error")

    monkeypatch.setattr(os, "link", broken_link)
    with pytest.raises(OSError) as raised:
        atomic.exclusive_write(str(tmp_path / "d" / "other.json"), b"x")
    assert raised.value.errno == errno.EIO
    assert os.listdir(target.parent) == ["lease.json"]  # nor a temp file, nor a partial one


def test_a_failed_rename_leaves_no_temp_file_and_raises_its_own_error(monkeypatch, tmp_path):
    """atomic_write removes its temp file when the rename fails (a folder in
    the way), and when the temp file is already gone (a cleaner raced it) the
    rename's own error reaches the caller, not one from the clean-up."""
    blocked = tmp_path / "part.parquet"
    (blocked / "inside").mkdir(parents=True)
    with pytest.raises(OSError):
        atomic.atomic_write(str(blocked), b"rows")
    assert sorted(os.listdir(tmp_path)) == ["part.parquet"]

    def replace_after_a_cleaner(src, dst):
        os.unlink(src)
        raise OSError(errno.EIO, "disk error")

    monkeypatch.setattr(os, "replace", replace_after_a_cleaner)
    with pytest.raises(OSError) as raised:
        atomic.atomic_write(str(tmp_path / "run.json"), b"{}")
    assert raised.value.errno == errno.EIO
    assert sorted(os.listdir(tmp_path)) == ["part.parquet"]


@pytest.mark.parametrize("how", ["atomic_write", "exclusive_write"])
def test_written_files_get_the_usual_mode_never_executable(tmp_path, how):
    """Frames, parts and run.json are created 0o666 less the umask (0o644 here),
    as any file a user makes: not executable, not writable by others."""
    old = os.umask(0o022)
    try:
        getattr(atomic, how)(str(tmp_path / "f.png"), b"png")
    finally:
        os.umask(old)
    assert (tmp_path / "f.png").stat().st_mode & 0o777 == 0o644
