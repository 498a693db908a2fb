"""The on-disk world cache: built once, loaded after; keyed by code; damage and 'off' handled."""

from __future__ import annotations

import numpy as np
import pytest

from render_workers.worlds import testworld, worldcache


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv(worldcache.CACHE_ENV, str(tmp_path))
    return tmp_path


def counting_build(calls: list):
    def build(town_code: str, seed: int):
        calls.append((town_code, seed))
        return testworld.build_world(town_code, seed)
    return build


def test_a_world_is_built_once_then_loaded_equal(cache):
    calls: list = []
    first = worldcache.load_or_build("test", "T01", 5, counting_build(calls))
    again = worldcache.load_or_build("test", "T01", 5, counting_build(calls))
    assert calls == [("T01", 5)]
    assert again is not first and len(again.static) == len(first.static)
    for a, b in zip(first.static, again.static):
        assert a.class_id == b.class_id and np.array_equal(a.mesh.vertices, b.mesh.vertices)
    worldcache.load_or_build("test", "T01", 6, counting_build(calls))  # another seed is another entry
    assert calls[-1] == ("T01", 6) and len(list(cache.glob("*.pickle"))) == 2


def test_unused_entries_are_dropped_and_damaged_ones_rebuilt(cache):
    import os
    import time

    stale, recent = cache / "test_T01_5_0123456789abcdef.pickle", cache / "test_T01_5_fedcba9876543210.pickle"
    stale.write_bytes(b"a world nobody loaded for a month")
    recent.write_bytes(b"another checkout's world")
    month_ago = time.time() - 30 * 86400
    os.utime(stale, (month_ago, month_ago))
    calls: list = []
    worldcache.load_or_build("test", "T01", 5, counting_build(calls))
    assert not stale.exists() and recent.exists()
    worldcache.entry_path(cache, "test", "T01", 5).write_bytes(b"\x80truncated")
    worldcache.load_or_build("test", "T01", 5, counting_build(calls))
    assert len(calls) == 2


def test_off_builds_every_time_and_writes_nothing(tmp_path, monkeypatch):
    monkeypatch.setenv(worldcache.CACHE_ENV, "off")
    calls: list = []
    for _ in range(2):
        worldcache.load_or_build("test", "T01", 5, counting_build(calls))
    assert len(calls) == 2 and worldcache.cache_dir() is None
