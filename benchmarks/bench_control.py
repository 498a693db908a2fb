"""The control plane at full scale: the 1,006,800-frame plan through the real driver, no rendering.

``pipeline.driver.produce`` runs the full plan (``--domains all --scale 1``,
14,355 episodes) on a local Ray cluster, with ``standin_episode`` in place of
the renderer: per frame it builds the real manifest row (all pixels sky, no
image files) and reports to the progress path, then writes the episode's real
manifest part. What is left is what the driver, Ray and the progress actor
cost: dispatch rate, driver and progress-actor memory over the run (a PNG
plot of both), and the progress path's CPU per frame, timed inside the tasks.

The stress: the same plan with ``flood_episode``, tasks calling the
progress path CALLS_PER_FRAME times per frame, paced to ``STRESS_FPS``
calls/s in all (10,000 by default), writing nothing: the progress path at
its busiest; memory must stay flat. It runs the plan at ``BENCH_CONTROL_STRESS_SCALE``
(0.02 by default): the rate, not the plan's length, is what it stresses.

``BENCH_CONTROL_DOMAINS`` / ``BENCH_CONTROL_SCALE`` shrink the plan for a quick look.
"""

from __future__ import annotations

import json
import logging
import os
import socket
import statistics
import tempfile
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from domains.catalog import INSTANCE_LABELS, LABELS, weather
from domains.conditions import frame_conditions
from outputs.geometry import HFOV_DEG, flat, intrinsics
from manifests.schema import STATS_DIR
from manifests.writer import frame_row
from pipeline.episode_job import EpisodeResult, commit_part

log = logging.getLogger("bench")

DOMAINS = os.environ.get("BENCH_CONTROL_DOMAINS", "all")
SCALE = float(os.environ.get("BENCH_CONTROL_SCALE", "1"))
# The stress run's plan: 1,006,800 frames x CALLS_PER_FRAME calls at STRESS_FPS would take 50 minutes
# for the same figure (memory flat under that rate); a 2% plan keeps it at the rate for about 90 s.
STRESS_SCALE = float(os.environ.get("BENCH_CONTROL_STRESS_SCALE", "0.02"))
STRESS_FPS = float(os.environ.get("BENCH_CONTROL_STRESS_FPS", "10000"))
SAMPLE_S = 0.5  # memory sampling period
CALLS_PER_FRAME = int(os.environ.get("BENCH_CONTROL_CALLS_PER_FRAME", "30"))  # the stress: progress calls per planned frame
SKY = next(label.id for label in LABELS if label.name == "sky")


def _standin_frame(spec, index: int) -> SimpleNamespace:
    """A frame as the renderer returns it, minus images: every pixel sky, no objects."""
    counts = np.zeros(len(LABELS), dtype=np.int64)
    counts[SKY] = spec.width * spec.height
    return SimpleNamespace(
        index=index, sim_time_s=3.0 * index, outputs={}, class_counts=counts,
        object_counts={label.object_column: 0 for label in INSTANCE_LABELS},
        camera_height_m=1.5, hood_fraction=0.0, ego_speed_mps=0.0, n_vehicles=20, n_pedestrians=0,
        K=flat(intrinsics(spec.width, spec.height, HFOV_DEG)), cam_to_world=flat(np.eye(4)),
        ego_to_world=flat(np.eye(4)), cam_to_ego=flat(np.eye(4)),
        conditions=frame_conditions(weather(spec.weather)),
    )


def _result(spec, frames: int, seconds: float) -> EpisodeResult:
    return EpisodeResult(spec.scenario, spec.episode, frames, seconds, socket.gethostname(), os.getpid())


def standin_episode(spec, storage, world: str = "test", on_frame=None, fence=None) -> EpisodeResult:
    """``run_episode`` without the renderer: real manifest rows and part, no image files.

    Writes the seconds spent in ``on_frame`` (the progress path) to the episode's stats file."""
    start = time.perf_counter()
    rows, progress_s = [], 0.0
    for index in range(spec.frames):
        rows.append(frame_row(spec, _standin_frame(spec, index), {}))
        if on_frame is not None:
            t = time.perf_counter()
            on_frame(len(rows))
            progress_s += time.perf_counter() - t
    storage.write_bytes(f"{STATS_DIR}/{spec.scenario}_e{spec.episode:04d}.json",
                        json.dumps({"frames": len(rows), "progress_s": progress_s}).encode())
    commit_part(storage, spec, rows, fence)  # the real, fenced part commit
    return _result(spec, len(rows), time.perf_counter() - start)


def flood_episode(spec, storage, world: str = "test", on_frame=None, fence=None) -> EpisodeResult:
    """Call ``on_frame`` CALLS_PER_FRAME times per frame, paced to BENCH_CONTROL_TASK_FPS calls
    per second in this task (``main`` sets it to STRESS_FPS over the cluster's CPUs); writes
    nothing. Long tasks, so the progress path, not dispatch, sets the pace."""
    rate = float(os.environ.get("BENCH_CONTROL_TASK_FPS", "5000"))
    start, calls = time.perf_counter(), 0
    for n in range(1, spec.frames + 1):
        for _ in range(CALLS_PER_FRAME):
            calls += 1
            due = start + calls / rate
            while time.perf_counter() < due:
                pass  # a busy task, as a fast renderer would be
            if on_frame is not None:
                on_frame(n)
    return _result(spec, spec.frames, time.perf_counter() - start)


def _rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return 0.0


class MemorySampler:
    """Samples (/proc) the RSS of this process (the driver), of the progress actor and
    of the largest other Ray worker, every SAMPLE_S."""

    def __init__(self) -> None:
        self.samples: list[tuple[float, float, float, float]] = []  # (t, driver MB, actor MB, largest worker MB)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._t0 = time.perf_counter()

    def __enter__(self) -> "MemorySampler":
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()

    def _ray_processes(self) -> tuple[float, float]:
        from pipeline.reaper import _proc_table, descendants

        actor, workers = 0.0, [0.0]
        for pid in descendants(os.getpid(), _proc_table()):
            try:
                with open(f"/proc/{pid}/cmdline", "rb") as f:
                    title = f.read().replace(b"\0", b" ").decode(errors="replace")
                rss = _rss_mb(pid)
            except OSError:
                continue
            if "FrameCounter" in title:
                actor = max(actor, rss)
            elif title.startswith("ray::"):
                workers.append(rss)
        return actor, max(workers)

    def _run(self) -> None:
        while not self._stop.wait(SAMPLE_S):
            actor, worker = self._ray_processes()
            self.samples.append((time.perf_counter() - self._t0, _rss_mb(os.getpid()), actor, worker))


def _run(root: str, episode_fn, scale: float, progress_interval_s: float = 1.0) -> dict:
    from pipeline.settings import ProduceConfig
    from pipeline.driver import produce
    from pipeline.planner import PlanConfig
    from pipeline.settings import RunConfig

    plan = PlanConfig(domains=DOMAINS, scale=scale)
    config = ProduceConfig(run=RunConfig(plan=plan, world="test"), out=root, progress_interval_s=progress_interval_s)
    updates = []
    load = [os.getloadavg()[0]]
    import ray

    from pipeline.cluster import shutdown, start_local_cluster

    with MemorySampler() as sampler:
        start = time.perf_counter()
        # Started here, not by produce(): a cluster produce() did not start gets the progress path of a
        # cluster of machines (the actor), the one that has to scale; a run's own local cluster counts
        # through files instead (pipeline.ray_task.FileCounts).
        start_local_cluster(ray)
        try:
            report = produce(config, progress=lambda p: updates.append(p.frames_done), episode_fn=episode_fn)
        finally:
            shutdown(ray)
        seconds = time.perf_counter() - start
    load.append(os.getloadavg()[0])
    if not report.ok:
        raise RuntimeError(f"control run failed: {report.failed[:3]}")
    return {"report": report, "seconds": seconds, "samples": sampler.samples, "updates": updates, "load": load}


def _memory_figures(samples) -> dict:
    """Median and peak of each series, and the drift of the driver's (median of the last
    quarter minus median of the second quarter: warm-up excluded)."""
    cols = [list(c) for c in zip(*samples)] if samples else [[0.0]] * 4
    cols[2] = [mb for mb in cols[2] if mb > 0] or [0.0]  # the actor: samples where it was found
    quarter = max(1, len(samples) // 4)
    driver = [s[1] for s in samples]
    drift = statistics.median(driver[-quarter:]) - statistics.median(driver[quarter:2 * quarter] or driver) if driver else 0.0
    return {
        "driver_mb_median": round(statistics.median(cols[1]), 1), "driver_mb_peak": round(max(cols[1]), 1),
        "driver_mb_drift": round(drift, 1),
        "actor_mb_median": round(statistics.median(cols[2]), 1), "actor_mb_peak": round(max(cols[2]), 1),
        "worker_mb_peak": round(max(cols[3]), 1),
    }


def _plot(runs: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4))
    for name, run in runs.items():
        t = [s[0] for s in run["samples"]]
        ax.plot(t, [s[1] for s in run["samples"]], label=f"{name}: driver")
        ax.plot(t, [s[2] for s in run["samples"]], linestyle="--", label=f"{name}: progress actor")
    ax.set_xlabel("seconds into the run")
    ax.set_ylabel("RSS (MiB)")
    ax.set_ylim(bottom=0)
    ax.set_title("Control plane memory, full plan (stand-in episodes)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(out_dir: str = "docs") -> dict:

    from storage import Storage

    out = Path(out_dir)
    slots = os.cpu_count() or 1
    runs, figures = {}, {}
    with tempfile.TemporaryDirectory(prefix="bench-control-") as tmp:
        log.info("   full plan, stand-in episodes (parts written, no images)")
        run = _run(str(Path(tmp) / "full"), standin_episode, SCALE)
        storage = Storage.from_uri(str(Path(tmp) / "full"))
        stats = [json.loads(storage.read_bytes(p)) for p in storage.list_files(f"{STATS_DIR}/", suffix=".json") if "_e" in p]
        per_frame_us = [1e6 * s["progress_s"] / s["frames"] for s in stats]
        report = run["report"]
        runs["full plan"] = run
        figures["full"] = {
            "episodes": report.rendered_episodes, "frames": report.rendered_frames, "seconds": round(run["seconds"], 1),
            "episodes_per_s": round(report.rendered_episodes / run["seconds"], 1),
            "frames_per_s": round(report.rendered_frames / run["seconds"], 0),
            "progress_us_per_frame_median": round(statistics.median(per_frame_us), 2),
            "progress_us_per_frame_p99": round(float(np.percentile(per_frame_us, 99)), 2),
            "progress_updates": len(run["updates"]), "cpus": slots, "load_average": run["load"],
            **_memory_figures(run["samples"]),
        }
        log.info("   %s", figures["full"])
        task_fps = STRESS_FPS / slots
        os.environ["BENCH_CONTROL_TASK_FPS"] = str(task_fps)  # the local cluster's workers inherit it
        log.info("   stress: progress reports at %.0f frames/s", STRESS_FPS)
        run = _run(str(Path(tmp) / "stress"), flood_episode, STRESS_SCALE)
        report = run["report"]
        runs["stress"] = run
        figures["stress"] = {
            "target_frames_per_s": STRESS_FPS, "frames": report.rendered_frames, "seconds": round(run["seconds"], 1),
            "frames_per_s": round(CALLS_PER_FRAME * report.rendered_frames / run["seconds"], 0), "cpus": slots,
            **_memory_figures(run["samples"]),
        }
        log.info("   %s", figures["stress"])
    _plot(runs, out / "bench_control.png")
    (out / "bench_control.json").write_text(json.dumps(figures, indent=2) + "\n")
    (out / "bench_control.md").write_text(_markdown(figures))
    return figures


def _markdown(f: dict) -> str:
    full, stress = f["full"], f["stress"]
    return f"""# Control plane at full scale

`BENCH=control make bench` (benchmarks/bench_control.py): the plan of `--domains {DOMAINS} --scale {SCALE:g}`
({full['episodes']:,} episodes, {full['frames']:,} frames) through `pipeline.driver.produce` on a local Ray cluster of
{full['cpus']} CPUs, with a stand-in episode function (real manifest rows and parts, no rendering, no image files).
The benchmark starts that cluster itself, so `produce` reports progress as on a cluster of machines, through
the progress actor (a run that starts its own local cluster counts frames through files instead).
Memory sampled every {SAMPLE_S} s (RSS; driver = the benchmark's process).

| run | seconds | episodes/s | frames/s accounted | driver MiB median / peak / drift | progress actor MiB median / peak | largest worker MiB |
|---|---:|---:|---:|---:|---:|---:|
| full plan, stand-in | {full['seconds']} | {full['episodes_per_s']} | {full['frames_per_s']:,.0f} | {full['driver_mb_median']} / {full['driver_mb_peak']} / {full['driver_mb_drift']:+} | {full['actor_mb_median']} / {full['actor_mb_peak']} | {full['worker_mb_peak']} |
| stress (`--scale {STRESS_SCALE:g}`), {stress['target_frames_per_s']:,.0f} frames/s of reports asked | {stress['seconds']} | | {stress['frames_per_s']:,.0f} (`on_frame` calls/s reached) | {stress['driver_mb_median']} / {stress['driver_mb_peak']} / {stress['driver_mb_drift']:+} | {stress['actor_mb_median']} / {stress['actor_mb_peak']} | {stress['worker_mb_peak']} |

Progress path CPU per frame, timed inside the tasks around `on_frame`: median {full['progress_us_per_frame_median']} us
(p99 {full['progress_us_per_frame_p99']} us) per episode. Each task sends at most one report per second and never has
more than one un-acknowledged; the driver redrew progress {full['progress_updates']:,} times.

Drift: median of the last quarter of the samples minus that of the second quarter. The machine's 1-minute load
average at the start and the end of the full-plan run: {full.get('load_average', ['?', '?'])[0]} and
{full.get('load_average', ['?', '?'])[-1]} on {full['cpus']} CPUs (other jobs shared it where these exceed the CPUs).

![driver and progress actor memory](bench_control.png)
"""
