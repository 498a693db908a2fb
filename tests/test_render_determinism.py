"""Issue 21.11: one episode rendered in several fresh processes gives the same
bytes, every output, every frame. Each process renders as a production worker
does (the render thread draws frame i + 1 while the sink thread finishes and
encodes frame i); they differ in what could leak into the bytes: the world
built or loaded from the cache, another episode rendered first by the same
renderer, llvmpipe's thread count, Python's hash seed, and a slow or a fast
sink (so the two threads overlap fully, or hardly). The runs go two at a time,
so the world that the later pair loads from the cache is one that the first
pair built and wrote (run side by side, every process would build its own)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow
REPO = Path(__file__).resolve().parents[1]

CHILD = r"""
import hashlib, json, os, sys, time
from pipeline.planner import make_plan
from pipeline.settings import PlanConfig
from pipeline.episode_job import frame_files
from render_workers.render.episode import render_episode

plan = make_plan(PlanConfig(domains="T01_CN_A,T01_HRN_A", frames_per_scenario=3, width=64, height=36, seed=7))
delay = float(os.environ["SINK_DELAY_S"])
digests = {}
for spec in plan.episodes:
    if spec.scenario not in sys.argv[1:]:
        continue

    def sink(frame, scenario=spec.scenario, spec=spec):
        time.sleep(delay)
        for name, data in frame_files(spec, frame).items():
            digests[f"{scenario}/{frame.index}/{name}"] = hashlib.sha256(data).hexdigest()

    render_episode(spec.drawing, sink, world="test")
print(json.dumps({k: v for k, v in digests.items() if k.startswith(sys.argv[-1] + "/")}, sort_keys=True))
"""

# (scenarios rendered by the process, the last one compared; environment)
RUNS = [
    (["T01_HRN_A"], {"IDDA_WORLD_CACHE": "off", "LP_NUM_THREADS": "0", "PYTHONHASHSEED": "1", "SINK_DELAY_S": "0"}),
    (["T01_HRN_A"], {"LP_NUM_THREADS": "2", "PYTHONHASHSEED": "2", "SINK_DELAY_S": "0.2"}),
    (["T01_CN_A", "T01_HRN_A"], {"LP_NUM_THREADS": "2", "PYTHONHASHSEED": "3", "SINK_DELAY_S": "0"}),
    (["T01_CN_A", "T01_HRN_A"], {"IDDA_WORLD_CACHE": "off", "LP_NUM_THREADS": "1", "PYTHONHASHSEED": "4",
                                 "SINK_DELAY_S": "0.2"}),
]


def _digests(runs, cache: Path) -> list[dict]:
    """Run ``runs`` side by side; each one's digests."""
    procs = []
    for scenarios, env in runs:
        environ = {**os.environ, "PYTHONPATH": str(REPO), "IDDA_WORLD_CACHE": str(cache), **env}
        procs.append(subprocess.Popen([sys.executable, "-c", CHILD, *scenarios], env=environ, cwd=str(REPO),
                                      stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True))
    digests = []
    for proc in procs:
        out, err = proc.communicate(timeout=600)
        assert proc.returncode == 0, err[-3000:]
        digests.append(json.loads(out.strip().splitlines()[-1]))
    return digests


def test_one_episode_gives_the_same_bytes_in_fresh_processes(tmp_path):
    cache = tmp_path / "worlds"
    # two at a time: the second pair's cached world is one the first pair built and wrote
    digests = _digests(RUNS[:2], cache)
    assert list(cache.glob("*")), "the first pair wrote no world cache entry"
    digests += _digests(RUNS[2:], cache)
    first = digests[0]
    assert len(first) == 3 * 8 and any("/instance" in k for k in first)  # 3 frames x every output
    for (scenarios, env), other in zip(RUNS[1:], digests[1:]):
        differ = sorted(k for k in first if other.get(k) != first[k])
        assert not differ and set(other) == set(first), (scenarios, env, differ)
