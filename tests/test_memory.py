"""A rendering process keeps the memory it frees (render_workers.render.memory).

Measured in fresh processes, with numpy's huge pages off so that a fault is one 4 KB
page: a frame-like loop that allocates four 25 MB float images and a larger one and frees
them takes each page from the kernel again every round under glibc's defaults, and none
once ``keep_freed_memory`` has run; ``render_episode`` runs it.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from tests.faultkit import REPO

_PROBE = """
import json, resource, sys
import numpy as np
from render_workers.render.memory import keep_freed_memory

took = keep_freed_memory() if sys.argv[1] == "keep" else None  # before any large block, as in a worker

def once():  # a frame's float images, and one larger than any before it (a new high for glibc's own threshold)
    images = [np.ones((1080, 1920, 3), np.float32) for _ in range(4)] + [np.ones((1280, 2048, 3), np.float32)]
    del images

once()  # the first round takes its pages in any case
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(4):
    once()
print(json.dumps({"faults": (resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before) / 4, "took": took,
                  "again": keep_freed_memory() if took else None}))
"""


def _faults_per_round(mode: str) -> dict:
    env = dict(os.environ, NUMPY_MADVISE_HUGEPAGE="0", PYTHONPATH=str(REPO))
    for name in ("MALLOC_TRIM_THRESHOLD_", "MALLOC_TOP_PAD_", "MALLOC_MMAP_THRESHOLD_"):
        env.pop(name, None)
    out = subprocess.run([sys.executable, "-c", _PROBE, mode], env=env, capture_output=True, text=True, timeout=120,
                         check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_freed_frame_buffers_are_reused_without_page_faults():
    """Two fresh processes: glibc's defaults give the blocks back and take their pages again every round;
    after ``keep_freed_memory`` (its 32 MB mmap threshold: without it the larger block is mapped afresh
    each round) none. Trimming off and the 256 MB top pad each keep a single thread's heap on their own:
    both are set, as measured (docs/bench_render.md)."""
    pages = (4 * 1080 * 1920 + 1280 * 2048) * 3 * 4 // 4096  # the round's 4 KB pages: ~38,000
    default, kept = _faults_per_round("default"), _faults_per_round("keep")
    assert default["faults"] > pages / 2, default
    assert kept["took"] is True and kept["again"] is True
    assert kept["faults"] < pages / 50, kept


def test_a_renderer_process_keeps_freed_memory(monkeypatch):
    """render_episode asks for it before it renders (the call is cached: once per process)."""
    import render_workers.render.episode as ep

    calls = []
    monkeypatch.setattr(ep, "keep_freed_memory", lambda: calls.append(1) or True)

    class Stop(Exception):
        pass

    def no_renderer():
        raise Stop

    monkeypatch.setattr(ep, "process_renderer", no_renderer)
    with pytest.raises(Stop):
        ep.render_episode(None, lambda frame: None)
    assert calls == [1]


def test_the_loaded_scene_is_frozen_while_frames_render_and_only_then():
    """Frames render with the episode's objects out of the cyclic collector's walks (frozen), and the
    episode ends with them back in it, an error included; a process that froze objects itself keeps
    them frozen, and nothing more is frozen for it."""
    import gc

    from render_workers.render import episode as ep
    from render_workers.render.renderer import Renderer
    from roots.episode_spec import EpisodeSpec

    assert gc.get_freeze_count() == 0
    frozen = []
    spec = EpisodeSpec("T01_CN_A", 0, 1, 2, 64, 36, "train", 0).drawing
    with Renderer() as renderer:
        ep.render_episode(spec, lambda frame: frozen.append(gc.get_freeze_count()), world="test", renderer=renderer)
        assert len(frozen) == 2 and min(frozen) > 1000  # the world, traffic and scene
        assert gc.get_freeze_count() == 0

        def fail(frame):
            raise RuntimeError("sink down")

        with pytest.raises(RuntimeError, match="sink down"):
            ep.render_episode(spec, fail, world="test", renderer=renderer)
        assert gc.get_freeze_count() == 0
        gc.freeze()  # the process's own (as before forking workers)
        try:
            mine = gc.get_freeze_count()
            seen = []
            ep.render_episode(spec, lambda frame: seen.append(gc.get_freeze_count()), world="test", renderer=renderer)
            # nothing more frozen (objects frozen and then freed leave the count), nothing unfrozen
            assert len(seen) == 2 and max(seen) <= mine and gc.get_freeze_count() > mine // 2
        finally:
            gc.unfreeze()
