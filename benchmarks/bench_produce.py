"""Orchestration overhead and scaling: the same episodes rendered in a plain
loop and through Ray, and through Ray with one and two workers."""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from render_workers.episode import DEFAULT_WORLD

WIDTH, HEIGHT = 960, 540
DOMAINS = "towns=T01,T02 weathers=CN viewpoints=A,B"
FRAMES = 12  # per scenario: 4 episodes x 12 frames
WORLD = os.environ.get("BENCH_WORLD", DEFAULT_WORLD)

_PLAIN = """
import sys, time
from pipeline.episode_job import run_episode
from pipeline.planner import PlanConfig, make_plan
from storage import Storage
plan = make_plan(PlanConfig(domains=sys.argv[1], frames_per_scenario=int(sys.argv[2]), width=int(sys.argv[3]), height=int(sys.argv[4])))
storage = Storage.from_uri(sys.argv[5])
start = time.perf_counter()
for spec in plan.episodes:
    run_episode(spec, storage, world=sys.argv[6])
print(time.perf_counter() - start)
"""

_RAY = """
import sys, time
import ray
from pipeline.driver import ProduceConfig, produce
from pipeline.planner import PlanConfig
from pipeline.runmeta import RunConfig
workers = int(sys.argv[7])
t0 = time.perf_counter()
ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False)

@ray.remote(num_cpus=1)
def warm():
    # The plain loop imports these before its clock starts; so do the workers.
    import pipeline.episode_job, render_workers.episode  # noqa: F401
    time.sleep(1.0)  # hold this worker so the next warm-up lands on another

ray.get([warm.remote() for _ in range(workers)])
startup = time.perf_counter() - t0
plan = PlanConfig(domains=sys.argv[1], frames_per_scenario=int(sys.argv[2]), width=int(sys.argv[3]), height=int(sys.argv[4]))
start = time.perf_counter()
report = produce(ProduceConfig(run=RunConfig(plan=plan, world=sys.argv[6]), out=sys.argv[5], workers=workers))
assert report.ok, report.failed
print(time.perf_counter() - start, startup)
"""


def _run(script: str, out: Path, workers: int | None = None) -> list[float]:
    args = [sys.executable, "-c", script, DOMAINS, str(FRAMES), str(WIDTH), str(HEIGHT), str(out), WORLD]
    if workers is not None:
        args.append(str(workers))
    result = subprocess.run(args, capture_output=True, text=True, check=True)
    return [float(x) for x in result.stdout.split()]


def main(out_dir: str = "docs", repeats: int = 3) -> dict:
    frames = 4 * FRAMES
    plain, ray1, ray2, startup = [], [], [], []
    with tempfile.TemporaryDirectory(prefix="idda-bench-") as tmp:
        for i in range(repeats):
            plain.append(_run(_PLAIN, Path(tmp) / f"plain{i}")[0])
            t, s = _run(_RAY, Path(tmp) / f"ray1_{i}", workers=1)
            ray1.append(t)
            startup.append(s)
            ray2.append(_run(_RAY, Path(tmp) / f"ray2_{i}", workers=2)[0])
    med = {k: statistics.median(v) for k, v in (("plain", plain), ("ray1", ray1), ("ray2", ray2), ("startup", startup))}
    result = {
        "command": "BENCH=produce make bench",
        "world": WORLD,
        "resolution": f"{WIDTH}x{HEIGHT}",
        "episodes": 4,
        "frames": frames,
        "repeats": repeats,
        "plain_s": plain,
        "ray_1_worker_s": ray1,
        "ray_2_workers_s": ray2,
        "ray_startup_s": startup,
        "overhead_ratio": med["ray1"] / med["plain"],
        "scaling_2_over_1": med["ray1"] / med["ray2"],
        "fps": {"plain": frames / med["plain"], "ray1": frames / med["ray1"], "ray2": frames / med["ray2"]},
        "cpus": os.cpu_count(),
    }
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench_produce.json").write_text(json.dumps(result, indent=2) + "\n")
    (out / "bench_produce.md").write_text(
        "\n".join(
            [
                "# Production benchmark: Ray overhead and scaling",
                "",
                f"`{result['command']}` on a {result['cpus']}-core machine, {WORLD} world, {WIDTH}x{HEIGHT}, "
                f"{frames} frames in 4 episodes (all six outputs encoded and written), median of {repeats} runs.",
                "Each run is a fresh process, so every variant pays for its world builds and shader",
                "compiles inside the timing. Module imports are outside it in both: the plain loop",
                "imports before its clock starts, and Ray's workers are warmed up (imports only)",
                "before `produce` is timed; that start-up is reported apart.",
                "",
                "| variant | median wall time (s) | frames/s |",
                "|---|---:|---:|",
                f"| plain loop, one process | {med['plain']:.1f} | {result['fps']['plain']:.2f} |",
                f"| Ray, 1 worker | {med['ray1']:.1f} | {result['fps']['ray1']:.2f} |",
                f"| Ray, 2 workers | {med['ray2']:.1f} | {result['fps']['ray2']:.2f} |",
                "",
                f"* Orchestration overhead, Ray 1 worker / plain loop: **{result['overhead_ratio']:.3f}** (target <= 1.05).",
                f"* Scaling, 2 workers over 1: **{result['scaling_2_over_1']:.2f}x** on 2 cores.",
                f"* Ray start-up and worker warm-up (not included above): median {med['startup']:.1f} s.",
                "* Two workers on two cores also share them with the driver and Ray's own processes, and",
                "  each worker builds every town it meets once, so scaling stays below 2x on short runs.",
            ]
        )
        + "\n"
    )
    return result


if __name__ == "__main__":
    main()
