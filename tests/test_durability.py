"""Durability: a name a write creates survives a power loss once the write returns.

An fsync of a file makes its bytes durable, not its name: the rename (or link)
that publishes it is on disk only once its directory is fsynced. The control
files and parts sync their directory after each rename; frame files are synced
once per frame folder, before the episode's part (the commit point) is written.
These tests record the fsyncs and renames a write makes, in order, with real files.
"""

from __future__ import annotations

import errno
import os
import stat

import pytest

from storage import Storage, atomic
from storage.errors import StorageError


class Calls:
    """Every fsync (of a file or a directory, by path), rename, replace and link, in order."""

    def __init__(self, monkeypatch):
        self.events: list[tuple[str, str]] = []
        real = {name: getattr(os, name) for name in ("fsync", "replace", "rename", "link")}

        def fsync(fd):
            kind = "dirsync" if stat.S_ISDIR(os.fstat(fd).st_mode) else "filesync"
            self.events.append((kind, os.readlink(f"/proc/self/fd/{fd}")))
            return real["fsync"](fd)

        def moved(name):
            def call(src, dst, *args, **kwargs):
                result = real[name](src, dst, *args, **kwargs)
                self.events.append(("publish", os.path.abspath(dst)))
                return result
            return call

        monkeypatch.setattr(os, "fsync", fsync)
        for name in ("replace", "rename", "link"):
            monkeypatch.setattr(os, name, moved(name))

    def index(self, kind: str, path, after: int = -1) -> int | None:
        """The first event ``(kind, path)`` after position ``after``, or None."""
        for i, event in enumerate(self.events):
            if i > after and event == (kind, str(path)):
                return i
        return None

    def synced_after_publish(self, path) -> bool:
        """Whether ``path``'s directory was fsynced after ``path`` was last published."""
        published = [i for i, event in enumerate(self.events) if event == ("publish", str(path))]
        return bool(published) and self.index("dirsync", os.path.dirname(str(path)), published[-1]) is not None


@pytest.fixture
def calls(monkeypatch):
    return Calls(monkeypatch)


def test_atomic_write_syncs_the_directory_after_the_rename(tmp_path, calls):
    target = tmp_path / "run.json"
    atomic.atomic_write(str(target), b"{}")
    assert target.read_bytes() == b"{}"
    kinds = [kind for kind, _ in calls.events]
    assert kinds == ["filesync", "publish", "dirsync"]  # the bytes, the name, the name on disk
    assert calls.events[1:] == [("publish", str(target)), ("dirsync", str(tmp_path))]


def test_a_frame_write_leaves_its_directory_to_be_synced_once(tmp_path, calls):
    atomic.atomic_write(str(tmp_path / "0000_000.png"), b"png", durable=False)
    assert [kind for kind, _ in calls.events] == ["filesync", "publish"]


def test_exclusive_write_syncs_the_directory_after_the_link(tmp_path, calls):
    target = tmp_path / "idda-root.json"
    assert atomic.exclusive_write(str(target), b"root") is True
    assert calls.synced_after_publish(target)
    assert os.listdir(tmp_path) == ["idda-root.json"]  # the temp name's removal is synced with it
    calls.events.clear()
    assert atomic.exclusive_write(str(target), b"other") is False
    assert calls.index("dirsync", tmp_path) is None  # nothing new to sync


def test_exclusive_write_without_hard_links_syncs_the_directory_too(tmp_path, calls, monkeypatch):
    def no_link(src, dst):
        raise OSError(errno.EPERM, "links not supported")

    monkeypatch.setattr(os, "link", no_link)
    target = tmp_path / "lease.json"
    assert atomic.exclusive_write(str(target), b"lease") is True
    created = calls.index("filesync", target)
    assert created is not None and calls.index("dirsync", tmp_path, created) is not None


def test_new_folders_are_synced_into_their_parents(tmp_path, calls):
    target = tmp_path / "manifest" / "town=T01" / "part.parquet"
    atomic.atomic_write(str(target), b"rows")
    for folder in (tmp_path / "manifest", tmp_path / "manifest" / "town=T01"):
        assert calls.index("dirsync", folder.parent) is not None, folder
    assert calls.synced_after_publish(target)
    calls.events.clear()
    atomic.atomic_write(str(tmp_path / "manifest" / "town=T01" / "other.parquet"), b"rows")
    assert [kind for kind, _ in calls.events] == ["filesync", "publish", "dirsync"]  # no folder made, none synced


@pytest.mark.parametrize("code", [errno.EINVAL, errno.EBADF, errno.ENOTSUP, errno.EACCES])
@pytest.mark.parametrize("where", ["open", "fsync"])
def test_a_file_system_that_refuses_to_sync_a_directory_is_skipped(tmp_path, monkeypatch, code, where):
    """Some file systems (network, FUSE) refuse to fsync a directory, or to open one
    for it: they promise nothing there, and the write goes on. Any other error is one."""
    real_open, real_fsync = os.open, os.fsync

    def refuse(error):
        def open_(path, flags, *args):
            if where == "open" and flags & os.O_DIRECTORY:
                raise OSError(error, os.strerror(error))
            return real_open(path, flags, *args)

        def fsync(fd):
            if where == "fsync" and stat.S_ISDIR(os.fstat(fd).st_mode):
                raise OSError(error, os.strerror(error))
            return real_fsync(fd)

        monkeypatch.setattr(os, "open", open_)
        monkeypatch.setattr(os, "fsync", fsync)

    refuse(code)
    atomic.atomic_write(str(tmp_path / "new" / "run.json"), b"{}")
    assert atomic.exclusive_write(str(tmp_path / "new" / "lease.json"), b"lease") is True
    assert sorted(os.listdir(tmp_path / "new")) == ["lease.json", "run.json"]
    refuse(errno.EIO)
    with pytest.raises(StorageError, match=r"cannot write .*run\.json: .*Input/output error"):
        Storage.from_uri(str(tmp_path)).write_bytes("new/run.json", b"{}")


def test_a_produced_episode_syncs_its_frame_folders_once_before_its_part(tmp_path, calls):
    """Every control file, part and index has its directory synced after its rename;
    each frame folder is synced once, after its last frame and before the part."""
    from outputs.table import DEFAULT_OUTPUTS
    from manifests.reader import index_path
    from roots.contract import ROOT_MARKER
    from pipeline.settings import PlanConfig
    from pipeline.provenance import RUN_FILE
    from pipeline.settings import RunConfig
    from tests.roots import part_of, render_root

    root = tmp_path / "root"
    plan = PlanConfig(domains="T01_CN_A", frames_per_scenario=3, width=64, height=36, seed=5)
    render_root(root, RunConfig(plan=plan, world="test"), compact=True)
    part = root / part_of(root, "T01_CN_A", 0)
    published = {path for kind, path in calls.events if kind == "publish" and path.startswith(str(root) + "/")}
    frames = {path for path in published if path.startswith(str(root / "T01_CN_A" / "e0000") + "/")}
    assert len(frames) == 3 * len(DEFAULT_OUTPUTS)
    others = published - frames
    assert {str(root / ROOT_MARKER), str(root / RUN_FILE), str(part), str(root / index_path("T01_CN_A"))} <= others
    for path in others:
        assert calls.synced_after_publish(path), path

    committed = calls.index("publish", part)
    folders = {os.path.dirname(path) for path in frames}
    assert len(folders) == len(DEFAULT_OUTPUTS)  # T01_CN_A/e0000/<output>/
    for folder in folders:
        syncs = [i for i, event in enumerate(calls.events) if event == ("dirsync", folder)]
        assert len(syncs) == 1, (folder, syncs)  # once an episode, not once a frame
        last_frame = max(i for i, (kind, path) in enumerate(calls.events)
                         if kind == "publish" and os.path.dirname(path) == folder)
        assert last_frame < syncs[0] < committed, folder


def test_leases_and_the_generation_are_synced(tmp_path, calls):
    from roots.lease import GENERATION, acquire_exclusive, bump_generation, register_producer

    storage = Storage.from_uri(str(tmp_path))
    with acquire_exclusive(storage, "repair") as lease:
        assert calls.synced_after_publish(tmp_path / lease.rel)
        bump_generation(storage)
        assert calls.synced_after_publish(tmp_path / GENERATION)
    producer = register_producer(storage)
    try:
        assert calls.synced_after_publish(tmp_path / producer.rel)
    finally:
        producer.release()


@pytest.mark.parametrize("replacing", [False, True])
def test_an_export_commit_is_synced_into_the_targets_folder(tmp_path, monkeypatch, replacing):
    from exports import export as ex
    from pipeline.settings import PlanConfig, RunConfig
    from tests.roots import render_root

    root = tmp_path / "root"
    plan = PlanConfig(domains="T01_CN_A", frames_per_scenario=2, width=64, height=36, seed=5)
    render_root(root, RunConfig(plan=plan, world="test"), compact=True)
    target = tmp_path / "out" / "cs"
    if replacing:
        ex.export(ex.ExportConfig(root=str(root), to=str(target), format="cityscapes"))
    calls = Calls(monkeypatch)
    ex.export(ex.ExportConfig(root=str(root), to=str(target), format="cityscapes", force=replacing))
    assert calls.synced_after_publish(target)
    assert (target / ex.MARKER).is_file()


def test_a_folder_made_meanwhile_by_another_writer_is_no_error(tmp_path, calls, monkeypatch):
    """Two workers write the first files of one new folder: the one that finds it
    missing, then sees it made by the other, goes on; a relative path syncs '.'."""
    made_meanwhile = tmp_path / "T01_CN_A"
    made_meanwhile.mkdir()
    real_isdir, asked = os.path.isdir, []

    def isdir(path):  # missing when make_dirs looks, there when makedirs does
        if path == str(made_meanwhile) and not asked:
            asked.append(path)
            return False
        return real_isdir(path)

    monkeypatch.setattr(os.path, "isdir", isdir)
    atomic.make_dirs(str(made_meanwhile))
    assert calls.index("dirsync", tmp_path) is not None
    monkeypatch.chdir(tmp_path)
    calls.events.clear()
    atomic.make_dirs("relative")
    assert calls.events == [("dirsync", str(tmp_path))] and (tmp_path / "relative").is_dir()
