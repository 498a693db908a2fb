"""Frame rendering at 1920x1080: per-stage cost, the PNG floor, and 1- vs 2-worker throughput.

Stages per frame (median over measured frames, after a warm-up frame that
compiles shaders): scene update, colour pass (incl. sky), class pass (SEG +
depth), post effects, outputs (the six encoders), PNG encoding, writing to a
temp dir. Throughput runs whole frames (render + encode + write) in 1 and 2
worker processes (multiprocessing, spawn), each with its own Renderer, timed
from a shared start barrier; the 2-worker run is also tried with
``LP_NUM_THREADS=1`` (one llvmpipe thread per worker instead of one per core).
"""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import platform
import statistics
import tempfile
import time
from pathlib import Path

WIDTH, HEIGHT = 1920, 1080
SCENARIOS = ("T01_CN_A", "T01_HRN_A", "T01_CS_M")  # clear, worst-case effects, low sun
FRAMES = 3  # measured frames per scenario (after one warm-up frame)
THROUGHPUT_FRAMES = 4  # frames per worker in the throughput runs
STAGES = ("scene_update", "color_pass", "class_pass", "post_fx", "outputs", "png_encode", "write")


def _spec(code: str, frames: int, seed: int = 1):
    from manifests.spec import EpisodeSpec

    return EpisodeSpec(code, 0, seed, frames, WIDTH, HEIGHT, "train", 0)


def _write(frame, data: dict, out: Path) -> None:
    for name, png in data.items():
        (out / f"{frame.index:04d}_{name}.png").write_bytes(png)


def _stage_times(world: str) -> dict:
    """Median seconds per stage over FRAMES frames of each scenario, plus the PNG floor."""
    from manifests.encoding import encode_png
    from render_workers.episode import load_episode, render_frame
    from render_workers.renderer import Renderer

    per_stage: dict[str, list[float]] = {s: [] for s in STAGES}
    png_floor, totals = [], []
    with Renderer() as renderer, tempfile.TemporaryDirectory() as tmp:
        for code in SCENARIOS:
            spec = _spec(code, FRAMES + 1)
            scene, _ = load_episode(spec, renderer, world)
            render_frame(renderer, scene, spec, 0)  # warm-up: shader compile, uploads
            for index in range(1, FRAMES + 1):
                start = time.perf_counter()
                frame, timings = render_frame(renderer, scene, spec, index)
                t0 = time.perf_counter()
                data = {name: encode_png(img, name) for name, img in frame.images.items()}
                timings["png_encode"] = time.perf_counter() - t0
                t0 = time.perf_counter()
                _write(frame, data, Path(tmp))
                timings["write"] = time.perf_counter() - t0
                totals.append(time.perf_counter() - start)
                png_floor.append(timings["png_encode"])
                for stage in STAGES:
                    per_stage[stage].append(timings[stage])
    return {
        "median_s": {s: statistics.median(v) for s, v in per_stage.items()},
        "frame_median_s": statistics.median(totals),
        "png_floor_s": statistics.median(png_floor),
    }


def _worker(world: str, code: str, seed: int, barrier, lp_threads: str | None, queue) -> None:
    if lp_threads is not None:
        os.environ["LP_NUM_THREADS"] = lp_threads
    from render_workers.episode import encode_frame, load_episode, render_frame
    from render_workers.renderer import Renderer

    spec = _spec(code, THROUGHPUT_FRAMES + 1, seed)
    with Renderer() as renderer, tempfile.TemporaryDirectory() as tmp:
        scene, _ = load_episode(spec, renderer, world)
        render_frame(renderer, scene, spec, 0)  # warm-up outside the timed window
        barrier.wait()
        start = time.monotonic()
        for index in range(1, THROUGHPUT_FRAMES + 1):
            frame, _ = render_frame(renderer, scene, spec, index)
            _write(frame, encode_frame(frame), Path(tmp))
        queue.put((start, time.monotonic()))


def _throughput(world: str, workers: int, lp_threads: str | None = None) -> dict:
    ctx = mp.get_context("spawn")
    barrier, queue = ctx.Barrier(workers), ctx.Queue()
    procs = [ctx.Process(target=_worker, args=(world, "T01_HRN_A", 1 + k, barrier, lp_threads, queue))
             for k in range(workers)]
    for p in procs:
        p.start()
    spans = [queue.get(timeout=900) for _ in procs]
    for p in procs:
        p.join()
        if p.exitcode != 0:
            raise RuntimeError(f"benchmark worker exited with code {p.exitcode}")
    wall = max(end for _, end in spans) - min(start for start, _ in spans)
    frames = workers * THROUGHPUT_FRAMES
    return {"workers": workers, "lp_num_threads": lp_threads or "default", "frames": frames,
            "wall_s": wall, "frames_per_s": frames / wall}


def main(out_dir: str = "docs") -> dict:
    from render_workers.episode import DEFAULT_WORLD

    worlds = ["test", DEFAULT_WORLD]
    result = {
        "command": "make bench BENCH=render (benchmarks/bench_render.py)",
        "resolution": [WIDTH, HEIGHT],
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform(),
                    "load_average_at_start": os.getloadavg(),
                    "pyopengl_platform": os.environ.get("PYOPENGL_PLATFORM", "egl (default)")},
        "worlds": {},
    }
    for world in worlds:
        stages = _stage_times(world)
        runs = [_throughput(world, 1), _throughput(world, 2), _throughput(world, 2, "1")]
        result["worlds"][world] = {"stages": stages, "throughput": runs}
    result["machine"]["load_average_at_end"] = os.getloadavg()

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench_render.json").write_text(json.dumps(result, indent=2) + "\n")
    (out / "bench_render.md").write_text(_markdown(result))
    return result


def _markdown(result: dict) -> str:
    m = result["machine"]
    lines = [
        "# Rendering benchmark",
        "",
        f"`{result['command']}` at {WIDTH}x{HEIGHT}, all six outputs, on {m['cpus']} CPU cores",
        f"({m['platform']}, PyOpenGL platform {m['pyopengl_platform']}, Mesa llvmpipe when there is no GPU).",
        f"Load average at start / end: {m['load_average_at_start'][0]:.1f} / {m['load_average_at_end'][0]:.1f}"
        " (other jobs on the machine inflate wall times).",
        "",
        f"Stages: median seconds per frame over {FRAMES} frames each of {', '.join(SCENARIOS)}, after a",
        "warm-up frame (the first render in a process compiles shaders, ~1.5 s).",
        "",
    ]
    for world, data in result["worlds"].items():
        st = data["stages"]
        lines += [f"## World `{world}`", "", "| stage | median s/frame |", "|---|---:|"]
        lines += [f"| {s} | {st['median_s'][s]:.3f} |" for s in STAGES]
        lines += [
            f"| **whole frame (one process)** | **{st['frame_median_s']:.3f}** |",
            "",
            f"PNG-encoding-only floor: {st['png_floor_s']:.3f} s per frame (six PNGs, zlib level 1), i.e. at most "
            f"{1 / st['png_floor_s']:.1f} frames/s per core even if rendering were free.",
            "",
            "| workers | LP_NUM_THREADS | frames | wall s | frames/s |",
            "|---:|---|---:|---:|---:|",
        ]
        lines += [f"| {r['workers']} | {r['lp_num_threads']} | {r['frames']} | {r['wall_s']:.2f} | "
                  f"{r['frames_per_s']:.2f} |" for r in data["throughput"]]
        lines.append("")
    lines += [
        "What bounds it: on a CPU-only machine every stage competes for the same cores, so two",
        "workers give about the per-frame CPU time divided by two cores. The colour pass (llvmpipe",
        "rasterising and shading 1920x1080, no multisampling: pyrender's hard-coded 4x MSAA cost",
        "about half of this pass, and edges are anti-aliased in post instead), the post effects and",
        "the PNG encoding of six full-HD images are each about a quarter of a frame; the class pass",
        "and the output encoders take the rest. The PNG floor alone caps a core at about 4 frames/s.",
        "Sun shadows (a 2048 shadow map fitted around the view) are part of the colour pass for CN",
        "and CS; HRN skips them.",
        "",
        "For scale: the IDDA paper made 1,006,800 frames in about two weeks on two GPU workstations,",
        "about 0.42 frames/s per workstation, at the same resolution.",
        "",
    ]
    return "\n".join(lines)


if __name__ == "__main__":
    main()
