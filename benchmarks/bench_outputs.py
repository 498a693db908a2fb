"""What the opt-in outputs cost per frame at 1920x1080, and the default outputs before and after issue 24.

Each probe is this file run with ``--probe`` in a fresh process, inside the
tree it measures. After a warm-up run of the measured episode (world
build, shader compile, uploads), it renders episodes of ``FRAMES`` frames
of ``SCENARIO`` through ``render_episode`` with a sink that encodes every
output (``pipeline.episode_job.frame_files``) and writes the files, as
production does. Per frame it
reports wall seconds, process CPU seconds (all threads), the ``outputs``
stage (objects, normals and flow computed from the buffers) and the sink
(encoding and writing), and the bytes written per output.

* "after" probes (this tree) render one episode per output set: the default
  outputs (the paper's six, instance and objects), each opt-in output added
  alone (``semantic_trainid``, ``normals``, ``flow``), and all three added;
* "before" probes run the same loop with the default outputs on the
  baseline revision (``BENCH_OUTPUTS_BASELINE``, default :data:`BASELINE`:
  main just before issue 24's first commit, 5045587), whose default set
  is the same eight outputs.

Before and after probes alternate, ``BENCH_ROUNDS`` pairs (default 3), and
every figure is a median over the rounds. Per-frame figures are the
difference between an episode of ``FRAMES`` frames and one of a single
frame, over ``FRAMES - 1`` (:func:`per_frame`): the set-up (world, traffic,
scene upload) drops out, and so does the last frame, the only one that
writes an all-invalid flow image without computing flow.
"""

from __future__ import annotations

import contextlib
import importlib
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

BASELINE = "5045587~1"  # main before issue 24 (poses, flow, normals, trainIds)
WIDTH, HEIGHT = 1920, 1080
SCENARIO = "T01_CN_A"
FRAMES = 5  # frames per measured episode
OPT_IN = ("semantic_trainid", "normals", "flow")
ISAL_SET = "default-isal"  # the default outputs deflated by ISA-L, as before issue 21.11 (the baseline's deflater)
SETS = ("default", *(f"+{name}" for name in OPT_IN), "+all", ISAL_SET)
MEASURES = ("frame", "frame_cpu", "outputs", "sink")
LIMIT = 0.05  # the default outputs may be at most this much slower than before


def tree_module(new: str, old: str):
    """As ``bench_render.tree_module`` (a probe cannot import this checkout's benchmarks): ``new`` of the tree
    measured, ``old`` in a tree from before issue 36's moves, None where it has neither."""
    import manifests  # deferred: the measured tree's (first on sys.path), found in the probe's process

    base = Path(manifests.__file__).resolve().parent.parent
    name = old if (base / "manifests" / "catalog.py").exists() else new
    return importlib.import_module(name) if base.joinpath(*name.split(".")).with_suffix(".py").exists() else None


def _outputs(set_name: str) -> tuple[str, ...]:
    extra = OPT_IN if set_name == "+all" else () if set_name in ("default", ISAL_SET) else (set_name[1:],)
    return tuple(tree_module("outputs.table", "manifests.outputs").DEFAULT_OUTPUTS) + extra  # house: old name


def _deflating(deflater: str | None):
    """The PNG deflater ``deflater`` in force (None: the tree's own; older trees know no other)."""
    if deflater is None:
        return contextlib.nullcontext()
    return tree_module("outputs.deflaters", "manifests.deflaters").deflating_with(deflater)  # house: old name


def _episode(renderer, world: str, outputs: tuple[str, ...], frames: int, width: int, height: int,
             seed: int, out: Path, deflater: str | None = None) -> dict:
    """One episode through production's loop: its totals (wall, CPU, stages) and bytes per output."""
    EpisodeSpec = tree_module("roots.episode_spec", "manifests.spec").EpisodeSpec  # noqa: N806; house: old name
    from pipeline.episode_job import frame_files
    from render_workers.render.episode import render_episode

    spec = EpisodeSpec(SCENARIO, 0, seed, frames, width, height, "train", 0, outputs=outputs)
    written: dict[str, int] = {}

    def sink(frame) -> None:
        with _deflating(deflater):
            files = frame_files(spec, frame)
        for name, data in files.items():
            (out / f"{frame.index:04d}_{name}").write_bytes(data)
            written[name] = written.get(name, 0) + len(data)

    cpu, start = time.process_time(), time.perf_counter()
    info = render_episode(getattr(spec, "drawing", spec), sink, world=world, renderer=renderer)  # older trees: the spec
    return {"frame": time.perf_counter() - start, "frame_cpu": time.process_time() - cpu,
            "outputs": info.timings.get("outputs", 0.0), "sink": info.timings.get("sink", 0.0),
            "bytes": {name: n // frames for name, n in written.items()}}


def per_frame(long: dict, short: dict, frames: int) -> dict:
    """Per-frame figures from an episode of ``frames`` frames and one of a single frame (same set):
    their difference over ``frames - 1``, so the episode's set-up and the loop's first and last
    frames (nothing to overlap with) drop out, and every counted frame computes its flow."""
    out = {m: (long[m] - short[m]) / (frames - 1) for m in MEASURES}
    out["bytes"] = long["bytes"]
    return out


def probe(world: str, sets: list[str], frames: int, width: int, height: int) -> dict:
    """Figures of each output set, in this process's tree (whichever is first on sys.path)."""
    from render_workers.render.renderer import Renderer

    result = {}
    with Renderer() as renderer, tempfile.TemporaryDirectory() as tmp:
        # warm-up: the measured episode itself, so shaders, uploads and caches for everything it shows are
        # ready before the first set is timed (a shorter one left the first set paying for them)
        _episode(renderer, world, _outputs("default"), frames, width, height, 1, Path(tmp))
        for name in sets:
            deflater = "isal" if name == ISAL_SET else None
            episode = [_episode(renderer, world, _outputs(name), n, width, height, 1, Path(tmp), deflater)
                       for n in (1, frames)]
            result[name] = per_frame(episode[1], episode[0], frames)
    return {"sets": result, "load_average": os.getloadavg()[0]}


def _run_probe(tree: Path | None, world: str, sets: tuple[str, ...], frames: int, width: int, height: int,
               cache: str) -> dict:
    from benchmarks.baseline import tree_env

    here = Path(__file__).resolve()
    cwd = tree if tree is not None else here.parent.parent
    env = tree_env(tree) if tree is not None else dict(os.environ)
    env["IDDA_WORLD_CACHE"] = cache  # one warm cache per tree: world builds are not what is measured
    command = [sys.executable, str(here), "--probe", world, ",".join(sets), str(frames), str(width), str(height)]
    result = subprocess.run(command, cwd=cwd, env=env, capture_output=True, text=True, check=False)
    if result.returncode != 0:
        raise RuntimeError(f"outputs probe failed in {cwd}:\n{result.stderr[-3000:]}")
    return json.loads(result.stdout.strip().splitlines()[-1])


def _medians(runs: list[dict]) -> dict:
    out = {}
    for name in runs[0]["sets"]:
        rows = [run["sets"][name] for run in runs]
        out[name] = {m: statistics.median(r[m] for r in rows) for m in MEASURES}
        out[name]["bytes"] = rows[0]["bytes"]
        out[name]["rounds"] = [r["frame"] for r in rows]
        out[name]["rounds_cpu"] = [r["frame_cpu"] for r in rows]
    return out


def measure(world: str, frames: int = FRAMES, width: int = WIDTH, height: int = HEIGHT,
            rounds: int | None = None) -> dict:
    """Alternating before / after probes; medians per output set."""
    from benchmarks import baseline

    rounds = baseline.rounds(3) if rounds is None else rounds
    ref = os.environ.get("BENCH_OUTPUTS_BASELINE", BASELINE)
    before, after = [], []
    saved = os.environ.get("BENCH_BASELINE")
    os.environ["BENCH_BASELINE"] = ref
    try:
        with baseline.baseline_tree() as (_, tree, reason), tempfile.TemporaryDirectory() as caches:
            for _ in range(rounds):
                if tree is not None:
                    before.append(_run_probe(tree, world, ("default",), frames, width, height, caches + "/before"))
                after.append(_run_probe(None, world, SETS, frames, width, height, caches + "/after"))
    finally:
        if saved is None:
            os.environ.pop("BENCH_BASELINE", None)
        else:
            os.environ["BENCH_BASELINE"] = saved
    return {"baseline": ref, "before_missing": reason, "rounds": rounds, "frames": frames,
            "resolution": [width, height], "world": world,
            "before": _medians(before)["default"] if before else None, "after": _medians(after),
            "load_average": [r["load_average"] for r in before + after]}


def verdict(result: dict) -> dict:
    """The default set's after / before ratios per frame: of the medians, and the median of each
    round's ratio (a before and an after probe run back to back, so under similar load). The
    verdict is on process CPU's paired ratio: on a shared machine wall time swings with other jobs.
    Issue 24's question is judged with the baseline's deflater (ISA-L) on both sides; ``deflater_cpu``
    is what new roots' deflater (libdeflate from issue 21.11, zlib-ng from issue 35) adds per frame."""
    before, after = result["before"], result["after"].get(ISAL_SET, result["after"]["default"])
    if before is None:
        return {"measured": False}
    paired = {key: statistics.median(a / b for a, b in zip(after[key], before[key])) for key in ("rounds", "rounds_cpu")}
    cpu = paired["rounds_cpu"]
    return {"measured": True, "wall_ratio": after["frame"] / before["frame"],
            "cpu_ratio": after["frame_cpu"] / before["frame_cpu"], "paired_wall_ratio": paired["rounds"],
            "paired_cpu_ratio": cpu, "within": cpu <= 1 + LIMIT,
            "deflater_cpu": added_by(result["after"]["default"], after, "rounds_cpu") if ISAL_SET in result["after"] else None}


def main(out_dir: str = "docs", frames: int = FRAMES, width: int = WIDTH, height: int = HEIGHT,
         rounds: int | None = None, world: str | None = None) -> dict:
    from render_workers.render.episode import DEFAULT_WORLD

    world = world or os.environ.get("BENCH_WORLD", DEFAULT_WORLD)
    result = {"command": "BENCH=outputs make bench (benchmarks/bench_outputs.py)", "scenario": SCENARIO,
              "machine": {"cpus": os.cpu_count(), "platform": platform.platform(),
                          "load_average_at_start": os.getloadavg()[0]}}
    result.update(measure(world, frames, width, height, rounds))
    result["verdict"] = verdict(result)
    result["machine"]["load_average_at_end"] = os.getloadavg()[0]
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench_outputs.json").write_text(json.dumps(result, indent=2) + "\n")
    (out / "bench_outputs.md").write_text(markdown(result))
    return result


def added_by(row: dict, base: dict, key: str) -> float:
    """Median over rounds of ``row``'s per-frame figure minus ``base``'s from the same probe."""
    return statistics.median(a - b for a, b in zip(row[key], base[key]))


def markdown(result: dict) -> str:
    m, after, before = result["machine"], result["after"], result["before"]
    w, h = result["resolution"]
    base = after["default"]
    same = after.get(ISAL_SET, base)  # the default outputs with the baseline's deflater
    lines = [
        "# Opt-in outputs benchmark",
        "",
        f"`{result['command']}` at {w}x{h}, {result['world']} world, {result['scenario']}, episodes of "
        f"{result['frames']} frames through `render_episode` with a sink that encodes and writes every output, "
        f"as production does; medians over {result['rounds']} rounds, each probe a fresh process, before and after "
        f"alternating. {m['cpus']} CPU cores ({m['platform']}); load average at start / end "
        f"{m['load_average_at_start']:.1f} / {m['load_average_at_end']:.1f} (other jobs inflate wall times; "
        "process CPU moves less).",
        "",
        "## What each opt-in output adds (this tree)",
        "",
        "Seconds per frame (medians); *added*: the median over rounds of the set's figure minus the default",
        "set's in the same probe (one process, back to back). `outputs`: the stage that computes objects,",
        "normals and flow from the buffers; `sink`: encoding and writing the files (both on the episode's",
        "second thread, overlapping the next frame's GL passes, so they add to the frame's wall time only",
        "where they outlast the drawing).",
        "",
        "| outputs | frame (wall) | added | process CPU | added | outputs stage | sink | KB written |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for name, row in after.items():
        kb = sum(row["bytes"].values()) / 1024
        added = "" if name == "default" else f"{added_by(row, base, 'rounds'):+.3f}"
        added_cpu = "" if name == "default" else f"{added_by(row, base, 'rounds_cpu'):+.3f}"
        label = {"default": "default (paper's six, instance, objects)",
                 ISAL_SET: "default, PNGs deflated by ISA-L (roots before issue 21.11)"}.get(name, name)
        lines.append(f"| {label} | {row['frame']:.3f} | {added} | {row['frame_cpu']:.3f} | {added_cpu} | "
                     f"{row['outputs']:.3f} | {row['sink']:.3f} | {kb:,.0f} |")
    lines += ["", f"Per frame: (an episode of {result['frames']} frames - one of 1 frame) / {result['frames'] - 1}, so the "
              "set-up drops out and every counted frame computes its flow.", "",
              "## The default outputs before and after issue 24", ""]
    v = result["verdict"]
    if not v["measured"]:
        lines += [f"Not measured: {result['before_missing']}.", ""]
        return "\n".join(lines)
    lines += [
        f"Before: revision `{result['baseline']}` (`BENCH_OUTPUTS_BASELINE`), main just before issue 24's first "
        "commit; after: this tree. Same outputs (the paper's six, instance, objects), same loop, and the same PNG "
        "deflater (ISA-L, the baseline's; new roots deflate with their own, libdeflate from issue 21.11 and "
        f"zlib-ng from issue 35, which adds {v['deflater_cpu']:+.3f} CPU-s per frame: the *default* row above "
        "against the ISA-L row).",
        "",
        "| per frame | before | after | after/before |",
        "|---|---:|---:|---:|",
        f"| wall s | {before['frame']:.3f} | {same['frame']:.3f} | {v['wall_ratio']:.3f} |",
        f"| process CPU s | {before['frame_cpu']:.3f} | {same['frame_cpu']:.3f} | {v['cpu_ratio']:.3f} |",
        f"| outputs stage s | {before['outputs']:.3f} | {same['outputs']:.3f} | |",
        f"| sink s | {before['sink']:.3f} | {same['sink']:.3f} | |",
        f"| median of each round's after/before, wall | | | {v['paired_wall_ratio']:.3f} |",
        f"| median of each round's after/before, process CPU | | | {v['paired_cpu_ratio']:.3f} |",
        "",
        f"Per round, wall seconds per frame before: {', '.join(f'{x:.3f}' for x in before['rounds'])}; "
        f"after: {', '.join(f'{x:.3f}' for x in same['rounds'])}. CPU seconds before: "
        f"{', '.join(f'{x:.3f}' for x in before['rounds_cpu'])}; after: {', '.join(f'{x:.3f}' for x in same['rounds_cpu'])}.",
        "",
        f"Within {LIMIT:.0%} (the median of each round's process-CPU ratio at most {1 + LIMIT:.2f}; wall time on this "
        f"shared machine swings with other jobs' load, see the rounds): **{'yes' if v['within'] else 'no'}**.",
        "",
    ]
    return "\n".join(lines)


if __name__ == "__main__":
    if sys.argv[1:2] == ["--probe"]:
        world, sets, frames, width, height = sys.argv[2:7]
        print(json.dumps(probe(world, sets.split(","), int(frames), int(width), int(height))))
    else:
        main()
