"""Local footers read in child processes (manifests.footer_pool): the same summaries,
in order, as reading them here; a child's failure falls back to reading here; and a
user's script without a ``__main__`` guard is not run again by the children."""

from __future__ import annotations

import logging
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

import manifests.footer_pool as footer_pool
from manifests.reader import part_summary, scan
from tests.test_control_plane import MANY, synthetic_root

REPO = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    return synthetic_root(str(tmp_path_factory.mktemp("footers") / "root"), MANY)


def _items(storage) -> list[tuple[str, int]]:
    return [item for episodes in scan(storage).parts.values() for item in episodes.values()]


def test_processes_read_the_same_summaries_in_order(root):
    items = _items(root)
    assert len(items) == 26
    here = [part_summary(root, rel, size) for rel, size in items]
    there = footer_pool.read_in_processes(root, part_summary, items, processes=3)
    assert there == here
    assert all(s is not None and s.rows > 0 for s in there)


def test_a_scan_of_many_local_parts_uses_processes(root, monkeypatch):
    used = []
    real = footer_pool.read_in_processes

    def spy(storage, read, items, processes):
        used.append((len(items), processes))
        return real(storage, read, items, processes)

    monkeypatch.setattr(footer_pool, "read_in_processes", spy)
    monkeypatch.setattr(footer_pool, "MIN_PARTS_PER_PROCESS", 10)
    monkeypatch.setattr(footer_pool.os, "sched_getaffinity", lambda pid: {0, 1, 2, 3}, raising=False)
    found = scan(root).summaries(root)
    assert used == [(26, 2)]  # 26 parts, 10 per process at least: two processes
    monkeypatch.setattr(footer_pool, "MIN_PARTS_PER_PROCESS", 1000)
    assert scan(root).summaries(root) == found and len(used) == 1  # too few parts: read here


def _fails(storage, rel, size):
    raise RuntimeError("a reader that fails in the child")


def test_a_failing_child_leaves_the_reads_to_the_caller(root, caplog):
    with caplog.at_level(logging.INFO, logger="manifests.footer_pool"):
        assert footer_pool.read_in_processes(root, _fails, _items(root), processes=2) is None
    assert "a reading process failed" in caplog.text and "a reader that fails in the child" in caplog.text


def test_remote_storage_and_one_cpu_read_here(root, monkeypatch):
    class Remote:
        is_local = False

    assert footer_pool.processes_for(Remote(), 100_000) == 0
    monkeypatch.setattr(footer_pool.os, "sched_getaffinity", lambda pid: {0}, raising=False)
    assert footer_pool.processes_for(root, 100_000) == 0


def test_a_script_without_a_main_guard_runs_once(root, tmp_path):
    marker = tmp_path / "runs.txt"
    script = tmp_path / "unguarded.py"
    script.write_text(textwrap.dedent(f"""
        import sys
        sys.path.insert(0, {str(REPO)!r})
        with open({str(marker)!r}, "a") as f:
            f.write("ran\\n")
        import manifests.footer_pool as footer_pool
        footer_pool.MIN_PARTS_PER_PROCESS = 1
        footer_pool.os.sched_getaffinity = lambda pid: {{0, 1}}
        real = footer_pool.read_in_processes
        def spy(*args):
            done = real(*args)
            print("processes read", len(done))  # None (a failed pool) would raise here
            return done
        footer_pool.read_in_processes = spy
        from manifests.reader import part_summaries
        print(sum(s.rows for s in part_summaries({root.uri!r}).values()))
    """))
    proc = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    read, total = proc.stdout.strip().splitlines()
    assert read == "processes read 26"
    assert int(total) == sum(e.frames for e in __import__("pipeline.planner").planner.make_plan(MANY).episodes)
    assert marker.read_text() == "ran\n"
