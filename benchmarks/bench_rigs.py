"""Per-frame CPU of each built-in rig (issue 37), beside ``front``: one process, one renderer.

For each rig, episodes of SCENARIO are rendered by ``render_episode`` with a sink that encodes every
sensor's outputs into file bytes (``pipeline.episode_job.frame_files``: what production writes, not
written). A frame's cost is taken by difference: the process CPU seconds (llvmpipe's threads included)
and wall seconds of an episode of FRAMES frames less those of one of WARM frames, over FRAMES - WARM,
both after a warm-up episode of WARM frames (world load, shader compilation, one-off costs). So what
every episode pays once (its load, filling and draining the sink thread) cancels, and every frame
counted is counted whole: its draws on this thread and its finishing and encoding on the sink thread.

Not a window between the ends of two frames' sinks, as this bench measured before: the drawing thread
runs up to SINK_AHEAD sensor frames ahead of the sink thread, so such a window held none of front's
draws and two of stereo's four (``render_workers.render.episode``), which read as a cost of each
extra sensor (docs/bench_rigs.md). BENCH_RIGS=front,lidar64 picks rigs (default: every built-in one;
front first); BENCH_RIGS_ROUNDS=N (default 3) rounds, the rigs alternating, medians reported. The
LiDAR sweep's wall time per frame comes from the episode's own ``lidar`` stage, its CPU from
``lidar_cpu`` (the drawing thread's; llvmpipe's own threads add about a tenth): their means over the
long episode's sweeps (each sweep is timed alone, so no difference is needed). Size: BENCH_RIGS_SIZE=WxH (default 1920x1080).
"""

from __future__ import annotations

import gc
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
FRAMES = 6
NOTES = "## Reading"  # docs/bench_rigs.md from this heading on is written by hand; a new run keeps it
WARM = 2  # frames of the episode whose cost is taken from FRAMES': measured are FRAMES - WARM frames


def _size() -> tuple[int, int]:
    w, h = os.environ.get("BENCH_RIGS_SIZE", "1920x1080").lower().split("x")
    return int(w), int(h)


def _episode(spec, frames: int, world: str) -> dict:
    """Process CPU and wall seconds of rendering and encoding an episode of ``frames`` frames of ``spec``,
    with its LiDAR stages."""
    spec = replace(spec, frames=frames)
    gc.collect()  # a collection of what came before is not this episode's cost: none runs while it is timed
    gc.disable()
    try:
        cpu, wall = time.process_time(), time.perf_counter()
        info = render_episode(spec.drawing, lambda frame: frame_files(spec, frame), world=world)  # what a worker draws
        cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
    finally:
        gc.enable()
    return {"cpu_s": cpu, "wall_s": wall,
            "lidar_wall_s": info.timings.get("lidar", 0.0), "lidar_cpu_s": info.timings.get("lidar_cpu", 0.0)}


def measure(rig: str, width: int, height: int, frames: int = FRAMES, world: str = "procedural") -> dict:
    """Per-frame figures of ``rig``: an episode of ``frames`` less one of WARM, after a warm-up one."""
    if frames <= WARM:
        raise ValueError(f"measure needs more than {WARM} frames, got {frames}")
    spec = make_plan(PlanConfig(domains=SCENARIO, frames_per_scenario=frames, width=width, height=height,
                                rig=rig)).episodes[0]
    _episode(spec, WARM, world)
    short, long = _episode(spec, WARM, world), _episode(spec, frames, world)
    row = {key: (long[key] - short[key]) / (frames - WARM) for key in ("cpu_s", "wall_s")}
    # a sweep is timed on its own, so its mean over the long episode's sweeps needs no difference (which,
    # at a test's size, noise can make negative)
    row.update({key: long[key] / frames for key in ("lidar_wall_s", "lidar_cpu_s")})
    return {"rig": rig, "sensors": len(spec.sensors), **row}


def main(out_dir: str = "docs") -> None:
    width, height = _size()
    rigs = os.environ.get("BENCH_RIGS", ",".join(builtin_rigs())).split(",")
    rounds = int(os.environ.get("BENCH_RIGS_ROUNDS", "3"))
    write_doc([[measure(rig, width, height) for rig in rigs] for _ in range(rounds)], width, height, out_dir)


def write_doc(runs: list[list[dict]], width: int, height: int, out_dir: str = "docs") -> None:
    """docs/bench_rigs.md from rounds of ``measure`` rows (the same rigs in each, front first): their medians."""
    rounds = len(runs)
    rows = [{**runs[0][i], **{key: statistics.median(run[i][key] for run in runs)
                              for key in ("cpu_s", "wall_s", "lidar_wall_s", "lidar_cpu_s")}}
            for i in range(len(runs[0]))]
    front = rows[0]["cpu_s"]
    load = os.getloadavg()[0]
    lines = [
        "# Benchmark: per-frame cost of each sensor rig",
        "",
        f"`python -m benchmarks.bench_rigs` (`make bench BENCH=rigs`): {SCENARIO}, {width}x{height}, one process, "
        f"per frame: an episode of {FRAMES} frames less one of {WARM}, after a warm-up episode; every sensor's "
        f"outputs encoded (not written); medians of {rounds} rounds, rigs alternating; {platform.machine()}, "
        f"{os.cpu_count()} cores, llvmpipe, a machine shared with other jobs (load average {load:.1f} at the end). "
        "CPU is the process's (all threads), per frame of the rig (every sensor).",
        "",
        "| rig | sensors | CPU s / frame | x front | wall s / frame | LiDAR sweep wall s | LiDAR sweep CPU s |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        sweep = f"{r['lidar_wall_s']:.2f} | {r['lidar_cpu_s']:.2f}" if r["lidar_wall_s"] else "- | -"
        lines.append(f"| {r['rig']} | {r['sensors']} | {r['cpu_s']:.2f} | {r['cpu_s'] / front:.2f} | {r['wall_s']:.2f} | "
                     f"{sweep} |")
    path = Path(out_dir, "bench_rigs.md")
    notes = path.read_text().partition(NOTES)[1:] if path.exists() else ()  # the hand-written reading, kept
    path.write_text("\n".join(lines) + "\n" + ("\n" + "".join(notes) if notes and notes[0] else ""))


if __name__ == "__main__":
    main()
