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


def test_the_cache_keeps_to_its_size_bound_least_recently_used_first(cache, monkeypatch):
    """Issue 21.9d: the cache had no bound. With IDDA_WORLD_CACHE_MAX it keeps the
    entries used last, never the one just written, never a write in progress."""
    import os
    import time

    def build(town_code: str, seed: int):
        return bytes(4000)  # every entry pickles to a little over 4000 bytes

    monkeypatch.setenv(worldcache.MAX_ENV, "10K")
    assert worldcache.max_bytes() == 10 * 1024
    paths, base = [], time.time_ns() - 10**9
    for i, town in enumerate(("T01", "T02")):
        worldcache.load_or_build("test", town, 1, build)
        paths.append(worldcache.entry_path(cache, "test", town, 1))
        os.utime(paths[-1], ns=(base + i, base + i))  # T01 used first, then T02
    writing = cache / f"{worldcache.entry_path(cache, 'test', 'T04', 1).name}abc.tmp"
    writing.write_bytes(bytes(20000))  # another process is writing an entry right now
    assert worldcache.load_or_build("test", "T01", 1, build) == bytes(4000)  # a load: T01 is now the newest
    worldcache.load_or_build("test", "T03", 1, build)  # a third entry: over 10K, T02 (least recent) goes
    assert [p.exists() for p in paths] == [True, False]
    assert worldcache.entry_path(cache, "test", "T03", 1).exists() and writing.exists()
    assert sum(p.stat().st_size for p in cache.glob("*.pickle")) <= 10 * 1024
    monkeypatch.setenv(worldcache.MAX_ENV, "1")  # smaller than one entry: only the new one stays
    worldcache.load_or_build("test", "T05", 1, build)
    assert [p.name for p in cache.glob("*.pickle")] == [worldcache.entry_path(cache, "test", "T05", 1).name]
    assert writing.exists()
    hour_ago = time.time() - 2 * worldcache.STALE_TEMP_S
    os.utime(writing, (hour_ago, hour_ago))  # a writer killed long ago left its temp file
    worldcache.load_or_build("test", "T06", 1, build)
    assert not writing.exists()


@pytest.mark.parametrize("text, expected", [("2G", 2 * 1024**3), ("512M", 512 * 1024**2), ("1.5k", 1536),
                                            ("1000", 1000), ("3GiB", 3 * 1024**3), ("lots", 2 * 1024**3), ("", 2 * 1024**3)])
def test_size_bound_parsing(monkeypatch, text, expected):
    monkeypatch.setenv(worldcache.MAX_ENV, text)
    assert worldcache.max_bytes() == expected
