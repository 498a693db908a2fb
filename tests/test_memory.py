"""A rendering process keeps the memory it frees (render_workers.render.memory).

Measured in a fresh process, with numpy's huge pages off so that a fault is one 4 KB
page: a frame-like loop that allocates four 25 MB float images and frees them takes
each page from the kernel again every time under glibc's defaults, and none once
``keep_freed_memory`` has run; ``render_episode`` runs it.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from tests.faultkit import REPO

_PROBE = """
import json, resource
import numpy as np
from render_workers.render.memory import keep_freed_memory

def faults_per_round(rounds=4):
    def once():
        images = [np.ones((1080, 1920, 3), np.float32) for _ in range(4)]  # a frame's float images
        del images
    once()  # the first round takes its pages in any case
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(rounds):
        once()
    return (resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before) / rounds

default = faults_per_round()
took = keep_freed_memory()
kept = faults_per_round()
print(json.dumps({"default": default, "took": took, "kept": kept, "again": keep_freed_memory()}))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_freed_frame_buffers_are_reused_without_page_faults():
    env = dict(os.environ, NUMPY_MADVISE_HUGEPAGE="0", PYTHONPATH=str(REPO))
    for name in ("MALLOC_TRIM_THRESHOLD_", "MALLOC_TOP_PAD_", "MALLOC_MMAP_THRESHOLD_"):
        env.pop(name, None)
    out = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True, text=True, timeout=120, check=True)
    figures = json.loads(out.stdout.strip().splitlines()[-1])
    pages = 4 * 1080 * 1920 * 3 * 4 // 4096  # four images' 4 KB pages: ~24,300
    assert figures["took"] is True and figures["again"] is True
    assert figures["default"] > pages / 2, figures  # glibc gave them back and took them again
    assert figures["kept"] < pages / 50, figures  # reused


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
