"""Per-frame CPU of each built-in rig (issue 37), beside ``front``: one process, one renderer.

For each rig, one episode of FRAMES frames of SCENARIO is rendered by ``render_episode`` with a sink
that encodes every sensor's outputs into file bytes (``pipeline.episode_job.frame_files``: what
production writes, not written); the process CPU seconds (llvmpipe's threads included) and wall
seconds between the ends of consecutive frames are taken, the first WARM frames left out (the
first: world load, shader compilation; the second: 0.3-0.4 CPU-s of one-off costs more than the
frames after it, in every rig, which made two measured frames read high). BENCH_RIGS=front,lidar64 picks rigs (default: every built-in one; front first). The LiDAR sweep's wall time per frame comes from the episode's own
``lidar`` stage, its CPU from ``lidar_cpu`` (the drawing thread's; llvmpipe's own threads add about a tenth). Size: BENCH_RIGS_SIZE=WxH (default 1920x1080).
"""

from __future__ import annotations

import os
import platform
import statistics
import time
from dataclasses import replace
from pathlib import Path

from domains.rigs import builtin_rigs
from pipeline.episode_job import frame_files
from pipeline.planner import PlanConfig, make_plan
from render_workers.render.episode import render_episode

SCENARIO = "T01_CN_A"
FRAMES = 4
WARM = 2  # frames left out: measured are the FRAMES - WARM after them


def _size() -> tuple[int, int]:
    w, h = os.environ.get("BENCH_RIGS_SIZE", "1920x1080").lower().split("x")
    return int(w), int(h)


def measure(rig: str, width: int, height: int, frames: int = FRAMES, world: str = "procedural") -> dict:
    spec = make_plan(PlanConfig(domains=SCENARIO, frames_per_scenario=frames, width=width, height=height,
                                rig=rig)).episodes[0]
    spec = replace(spec, frames=frames)
    last = spec.sensors[-1]
    ends: list[tuple[float, float]] = []

    def sink(frame) -> None:
        frame_files(spec, frame)
        if frame.sensor == last:
            ends.append((time.process_time(), time.perf_counter()))

    info = render_episode(spec.drawing, sink, world=world)  # what a worker draws from
    cpu = [b[0] - a[0] for a, b in zip(ends[WARM - 1:], ends[WARM:])]
    wall = [b[1] - a[1] for a, b in zip(ends[WARM - 1:], ends[WARM:])]
    return {"rig": rig, "sensors": len(spec.sensors), "cpu_s": statistics.mean(cpu), "wall_s": statistics.mean(wall),
            "lidar_wall_s": info.timings.get("lidar", 0.0) / frames,
            "lidar_cpu_s": info.timings.get("lidar_cpu", 0.0) / frames}


def main(out_dir: str = "docs") -> None:
    width, height = _size()
    rows = [measure(rig, width, height) for rig in os.environ.get("BENCH_RIGS", ",".join(builtin_rigs())).split(",")]
    front = rows[0]["cpu_s"]
    lines = [
        "# Benchmark: per-frame cost of each sensor rig",
        "",
        f"`python -m benchmarks.bench_rigs` (`make bench BENCH=rigs`): {SCENARIO}, {width}x{height}, one process, "
        f"{FRAMES - WARM} frames measured after {WARM} left out, every sensor's outputs encoded (not written); "
        f"{platform.machine()}, {os.cpu_count()} cores, llvmpipe, a machine shared with other jobs. "
        "CPU is the process's (all threads), per frame of the rig (every sensor).",
        "",
        "| rig | sensors | CPU s / frame | x front | wall s / frame | LiDAR sweep wall s | LiDAR sweep CPU s |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        sweep = f"{r['lidar_wall_s']:.2f} | {r['lidar_cpu_s']:.2f}" if r["lidar_wall_s"] else "- | -"
        lines.append(f"| {r['rig']} | {r['sensors']} | {r['cpu_s']:.2f} | {r['cpu_s'] / front:.2f} | {r['wall_s']:.2f} | "
                     f"{sweep} |")
    Path(out_dir, "bench_rigs.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
