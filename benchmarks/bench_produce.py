"""Production: the user's 120-frame full-HD run before and after, Ray overhead and scaling.

End to end: ``idda produce --domains T01_CN_A,T03_CS_M --frames-per-scenario 60
--width 1920 --height 1080`` as a subprocess, on the baseline revision
("before", ``benchmarks.baseline``) and on this tree ("after"), alternately,
``BENCH_ROUNDS`` pairs; the figure is the rate the command reports (world
builds, shader compiles and Ray start-up included). After runs start with an
empty world cache (a first run); one more after run reuses the cache a
previous run filled. Per-stage seconds per frame come from the episodes'
``_stats`` files of the same runs.

Overhead and scaling (this tree): the same episodes rendered in a plain loop
and through Ray, and through Ray with one and two workers.
"""

from __future__ import annotations

import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from manifests.schema import STATS_DIR, STATS_RE
from outputs.table import SEED_OUTPUTS  # the paper's six
from render_workers.render.episode import DEFAULT_WORLD

WIDTH, HEIGHT = 960, 540
DOMAINS = "towns=T01,T02 weathers=CN viewpoints=A,B"
FRAMES = 12  # per scenario: 4 episodes x 12 frames
WORLD = os.environ.get("BENCH_WORLD", DEFAULT_WORLD)

# The modules both sides import before their clocks start: the plain loop in its
# process, Ray in each worker (a warm-up task), so the timings compare rendering
# and orchestration, not imports. (pyarrow imports pandas at its first table.)
_IMPORTS = "import pipeline.episode_job, pipeline.planner, render_workers.render.episode, storage, pandas"

_PLAIN = _IMPORTS + """
import sys, time
from pipeline.episode_job import run_episode
from outputs.table import SEED_OUTPUTS  # the paper's six, as docs/bench_produce.md reports
from pipeline.planner import PlanConfig, make_plan
from storage import Storage
plan = make_plan(PlanConfig(domains=sys.argv[1], frames_per_scenario=int(sys.argv[2]), width=int(sys.argv[3]), height=int(sys.argv[4]), outputs=SEED_OUTPUTS))
storage = Storage.from_uri(sys.argv[5])
start = time.perf_counter()
inside = sum(run_episode(spec, storage, world=sys.argv[6]).seconds for spec in plan.episodes)
print(time.perf_counter() - start, inside)
"""

_RAY = """
import os, sys, time
import ray
from pipeline.settings import ProduceConfig
from pipeline.driver import produce, start_local_cluster
from outputs.table import SEED_OUTPUTS
from pipeline.planner import PlanConfig
from pipeline.settings import RunConfig
workers = int(sys.argv[7])
t0 = time.perf_counter()
start_local_cluster(ray, workers)  # the cluster produce() starts for itself

@ray.remote(num_cpus=1)
def warm():
    """ + _IMPORTS + """
    time.sleep(1.0)  # hold this worker so the next warm-up lands on another

# produce() hands tasks the variables it forwards (IDDA_WORLD_CACHE here) as a runtime_env on a
# cluster it did not start; Ray keeps workers per runtime_env, so warm those.
from pipeline.driver import _FORWARDED_ENV
env = {k: os.environ[k] for k in _FORWARDED_ENV if k in os.environ}
options = {"runtime_env": {"env_vars": env}} if env else {}
ray.get([warm.options(**options).remote() for _ in range(workers)])
startup = time.perf_counter() - t0
plan = PlanConfig(domains=sys.argv[1], frames_per_scenario=int(sys.argv[2]), width=int(sys.argv[3]), height=int(sys.argv[4]), outputs=SEED_OUTPUTS)
start = time.perf_counter()
report = produce(ProduceConfig(run=RunConfig(plan=plan, world=sys.argv[6]), out=sys.argv[5], workers=workers))
assert report.ok, report.failed
wall = time.perf_counter() - start
print(wall, sum(row["seconds"] for row in report.per_scenario.values()), startup)
"""


E2E_DOMAINS = "T01_CN_A,T03_CS_M"
E2E_FRAMES, E2E_WIDTH, E2E_HEIGHT = 60, 1920, 1080
E2E_ARGS = ["--domains", E2E_DOMAINS, "--frames-per-scenario", str(E2E_FRAMES),
            "--width", str(E2E_WIDTH), "--height", str(E2E_HEIGHT)]
E2E_COMMAND = "idda produce " + " ".join(E2E_ARGS)
LONG_FRAMES = 300  # per scenario in one more after run: a longer run, where the start weighs less
STAGES = ("world", "populate", "load", "scene_update", "color_pass", "class_pass", "resolve", "post_fx", "outputs",
          "sink", "sink_wait")


def machine_busy_s() -> float | None:
    """CPU seconds this machine has spent busy since boot (user, nice, system, irq, softirq: not idle,
    iowait or steal), from /proc/stat; None where there is none. Over one run it counts every process
    the run starts (Ray's workers included), and moves far less with a noisy host than wall time."""
    try:
        with open("/proc/stat") as f:
            fields = f.readline().split()[1:8]
    except OSError:
        return None
    user, nice, system, _idle, _iowait, irq, softirq = map(int, fields)
    return (user + nice + system + irq + softirq) / os.sysconf("SC_CLK_TCK")


def frame_timeline(root: Path, since: float) -> dict:
    """When a run's frames were stored: the rgb files' modification times in seconds after ``since``
    (the command's start, epoch seconds), sorted; the first and the last; and the steady rate, the
    frames between the 10% and the 90% marks over the seconds between them (both workers rendering,
    start and tail left out). Empty where the root holds no rgb files."""
    times = sorted(p.stat().st_mtime - since for p in root.rglob("*")
                   if p.suffix in (".png", ".jpg") and "rgb" in p.relative_to(root).parts[:-1])
    if not times:
        return {"times_s": [], "first_s": None, "last_s": None, "steady_fps": None}
    lo, hi = len(times) // 10, len(times) - 1 - len(times) // 10
    steady = (hi - lo) / (times[hi] - times[lo]) if hi > lo and times[hi] > times[lo] else None
    return {"times_s": [round(t, 3) for t in times], "first_s": times[0], "last_s": times[-1], "steady_fps": steady}


def _end_to_end(tree: Path | None, out: Path, cache: str, extra: tuple[str, ...] = (),
                frames_per_scenario: int = E2E_FRAMES) -> dict:
    """One run of the user's command; the rate it reports, its wall time, the machine's busy CPU
    seconds per frame, per-stage s/frame and when its frames were stored (:func:`frame_timeline`)."""
    from benchmarks.baseline import tree_env

    cwd = tree if tree is not None else Path(__file__).resolve().parent.parent
    env = tree_env(tree) if tree is not None else dict(os.environ)
    env["IDDA_WORLD_CACHE"] = cache
    idda = Path(sys.executable).with_name("idda")
    args = [*E2E_ARGS, *extra]
    args[args.index("--frames-per-scenario") + 1] = str(frames_per_scenario)
    since, start, busy = time.time(), time.perf_counter(), machine_busy_s()
    result = subprocess.run([str(idda), "produce", *args, "--out", str(out)], cwd=cwd, env=env,
                            capture_output=True, text=True, check=False)
    wall, busy = time.perf_counter() - start, (None if busy is None else machine_busy_s() - busy)
    if result.returncode != 0:
        raise RuntimeError(f"{E2E_COMMAND} failed in {cwd}:\n{result.stderr[-3000:]}")
    stats = out / "_stats"
    reported = json.loads((stats / "driver.json").read_text())["frames_per_s"]
    totals: dict[str, float] = {}
    frames = 0
    for path in (p for p in stats.glob("*.json") if STATS_RE.match(f"{STATS_DIR}/{p.name}")):  # not driver.json
        data = json.loads(path.read_text())
        frames += data["frames"]
        for stage, seconds in data["stages"].items():
            totals[stage] = totals.get(stage, 0.0) + seconds
    return {"reported_fps": reported, "command_wall_s": wall, "frames": frames, "load_average": os.getloadavg()[0],
            "machine_cpu_s_per_frame": None if busy is None else busy / frames,
            "stage_s_per_frame": {k: v / frames for k, v in totals.items()}, "timeline": frame_timeline(out, since)}


def end_to_end() -> dict:
    from benchmarks.baseline import baseline_tree, rounds

    before, after = [], []
    with baseline_tree() as (ref, tree, reason), tempfile.TemporaryDirectory(prefix="idda-bench-e2e-") as tmp:
        for i in range(rounds()):
            if tree is not None:
                before.append(_end_to_end(tree, Path(tmp) / f"before{i}", "off"))
                shutil.rmtree(Path(tmp) / f"before{i}")
            cold = Path(tmp) / f"worlds{i}"
            after.append(_end_to_end(None, Path(tmp) / f"after{i}", str(cold)))
            shutil.rmtree(Path(tmp) / f"after{i}")
        warm = _end_to_end(None, Path(tmp) / "warm", str(cold))  # the last after run filled this cache
        six = _end_to_end(None, Path(tmp) / "six", str(cold), ("--outputs", ",".join(SEED_OUTPUTS)))
        jpg = _end_to_end(None, Path(tmp) / "jpg", str(cold), ("--rgb-format", "jpg"))
        long = _end_to_end(None, Path(tmp) / "long", str(Path(tmp) / "worlds_long"), frames_per_scenario=LONG_FRAMES)
    return {"baseline": ref, "before_missing": reason, "before": before, "after": after, "after_warm": warm,
            "after_six_warm": six, "after_jpg_warm": jpg, "after_long": long, "long_frames_per_scenario": LONG_FRAMES,
            "command": E2E_COMMAND, "rounds": rounds()}


# What Ray sets in a worker that runs a num_cpus=1 task (OpenBLAS and OpenMP read it); the plain
# loop gets it too, so the two sides differ by orchestration only, not by thread settings.
RAY_WORKER_ENV = {"OMP_NUM_THREADS": "1"}


def _run(script: str, out: Path, workers: int | None = None) -> list[float]:
    args = [sys.executable, "-c", script, DOMAINS, str(FRAMES), str(WIDTH), str(HEIGHT), str(out), WORLD]
    if workers is not None:
        args.append(str(workers))
    env = dict(os.environ, IDDA_WORLD_CACHE="off")  # every variant builds its worlds
    if workers is None:
        env.update(RAY_WORKER_ENV)
    result = subprocess.run(args, capture_output=True, text=True, check=True, env=env)
    return [float(x) for x in result.stdout.split()]


def main(out_dir: str = "docs", repeats: int = 5) -> dict:
    frames = 4 * FRAMES
    plain, ray1, ray2, startup = [], [], [], []
    outside = {"plain": [], "ray1": [], "ray2": []}  # wall time not spent inside an episode
    e2e = end_to_end()
    with tempfile.TemporaryDirectory(prefix="idda-bench-") as tmp:
        for i in range(repeats):
            wall, inside = _run(_PLAIN, Path(tmp) / f"plain{i}")
            plain.append(wall)
            outside["plain"].append(wall - inside)
            wall, inside, up = _run(_RAY, Path(tmp) / f"ray1_{i}", workers=1)
            ray1.append(wall)
            outside["ray1"].append(wall - inside)
            startup.append(up)
            wall, inside, _ = _run(_RAY, Path(tmp) / f"ray2_{i}", workers=2)
            ray2.append(wall)
            outside["ray2"].append(wall - inside / 2)  # two episodes at a time
    med = {k: statistics.median(v) for k, v in (("plain", plain), ("ray1", ray1), ("ray2", ray2), ("startup", startup))}
    med.update({f"outside_{k}": statistics.median(v) for k, v in outside.items()})
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
        "outside_episodes_s": outside,
        "overhead_ratio": med["ray1"] / med["plain"],
        "scaling_2_over_1": med["ray1"] / med["ray2"],
        "fps": {"plain": frames / med["plain"], "ray1": frames / med["ray1"], "ray2": frames / med["ray2"]},
        "cpus": os.cpu_count(),
        "cpu_model": cpu_model(),
        "end_to_end": e2e,
    }
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench_produce.json").write_text(json.dumps(result, indent=2) + "\n")
    (out / "bench_produce.md").write_text(_markdown(result, med))
    plot_timelines(e2e, out / "bench_produce.png")
    return result


def cpu_model() -> str:
    """The CPU's model name as Linux reports it (figures move with it), or "CPU unknown"."""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return "CPU unknown"


def _median(runs: list[dict], key: str) -> float:
    return statistics.median(r[key] for r in runs)


def _cpu_cell(runs: list[dict]) -> str:
    """Median machine CPU seconds per frame of ``runs`` (older records lack it)."""
    values = [r["machine_cpu_s_per_frame"] for r in runs if r.get("machine_cpu_s_per_frame") is not None]
    return f"{statistics.median(values):.3f}" if values else "-"


def _rounds_line(name: str, runs: list[dict]) -> str:
    return (f"{name}, round by round: " + ", ".join(f"{r['reported_fps']:.2f}" for r in runs) + " frames/s; "
            + ", ".join(_cpu_cell([r]) for r in runs) + " machine CPU-s per frame.")


def _markdown(result: dict, med: dict) -> str:
    e2e = result["end_to_end"]
    before, after, warm, six = e2e["before"], e2e["after"], e2e["after_warm"], e2e["after_six_warm"]
    jpg = e2e["after_jpg_warm"]
    lines = [
        "# Production benchmark",
        "",
        f"`{result['command']}` on a {result['cpus']}-core machine ({result.get('cpu_model', 'CPU not recorded')}), "
        f"{result['world']} world. Figures differ between kinds of machine (main gave 3.5-3.7 frames/s on the "
        "machine issue 35 was filed from): compare before and after within one run.",
        "",
        "## The user's run, end to end, before and after",
        "",
        f"`{e2e['command']}`: 120 frames, 2 episodes, on a fresh local Ray cluster. Before writes the paper's six",
        "outputs (all it has); after writes the default eight (the six plus `instance` and `objects`), and one",
        "more after run writes only the six (`--outputs " + ",".join(SEED_OUTPUTS) + "`), like for like; a last",
        "one writes the eight with the rgb as JPEG (`--rgb-format jpg`, quality 95).",
        "Frames/s is the rate the command reports (world builds, shader compiles and Ray start-up included);",
        f"before: revision `{e2e['baseline']}` (`BENCH_BASELINE`); after: this tree; alternately, {e2e['rounds']} of each,",
        "medians. After runs start with an empty world cache, as a first run does. Machine CPU-s per frame: the",
        "seconds the whole machine was busy during the run (every process, Ray's included; /proc/stat) over the",
        "frames; on a noisy host it moves far less than the rate does.",
        "",
        "| variant | reported frames/s | command wall s | machine CPU-s / frame | runs |",
        "|---|---:|---:|---:|---:|",
    ]
    if before:
        lines.append(f"| before | {_median(before, 'reported_fps'):.2f} | {_median(before, 'command_wall_s'):.1f} | "
                     f"{_cpu_cell(before)} | {len(before)} |")
    else:
        lines.append(f"| before | not measured ({e2e['before_missing']}) | | | |")
    lines += [
        f"| **after** | **{_median(after, 'reported_fps'):.2f}** | {_median(after, 'command_wall_s'):.1f} | "
        f"{_cpu_cell(after)} | {len(after)} |",
    ]
    lines += [f"| {name} | {run['reported_fps']:.2f} | {run['command_wall_s']:.1f} | {_cpu_cell([run])} | 1 |"
              for name, run in (("after, worlds already in the disk cache", warm),
                                ("after, worlds cached, the paper's six outputs only", six),
                                ("after, worlds cached, `--rgb-format jpg`", jpg))]
    lines += [
        "",
        *([_rounds_line("Before", before)] if before else []),
        _rounds_line("After", after),
        "",
        "Per stage in those runs, seconds per frame summed over both workers' episodes (medians):",
        "",
        "| stage | before | after |",
        "|---|---:|---:|",
    ]
    for stage in STAGES:
        a = statistics.median(r["stage_s_per_frame"].get(stage, 0.0) for r in after)
        b = (f"{statistics.median(r['stage_s_per_frame'].get(stage, 0.0) for r in before):.3f}"
             if before and any(stage in r["stage_s_per_frame"] for r in before) else "-")
        lines.append(f"| {stage} | {b} | {a:.3f} |")
    loads = [r["load_average"] for r in before + after + [warm, six, jpg]]
    lines += [
        "",
        "After, only the GL passes (`scene_update`, `color_pass`, `class_pass`) run on the render thread;",
        "`resolve` (the sky behind the colour pass, ids and depth out of the reads of the labels the colour pass draws), `post_fx`,",
        "`outputs` and `sink` (PNG encoding, hashing, writing) run on a second thread that",
        "finishes frame i while frame i + 1 is drawn; before, all but the sink were part of the frame.",
        "`sink_wait` is the time drawing waited for that thread. Stages overlap and two workers share",
        "two cores, so these are CPU shares rather than parts of the wall time.",
        f"Load average (1 min) after each run: {', '.join(f'{x:.1f}' for x in loads)}.",
        "",
    ]
    return "\n".join(lines + _timeline_section(e2e) + _overhead_section(result, med))


def _timeline_median(runs: list[dict], key: str) -> str:
    values = [r["timeline"][key] for r in runs if r.get("timeline", {}).get(key) is not None]
    return f"{statistics.median(values):.2f}" if values else "-"


def _timeline_section(e2e: dict) -> list[str]:
    """Start, steady rate and tail of the runs above (their rgb files' times), and the long run."""
    long = e2e.get("after_long")
    if long is None or not any(r.get("timeline") for r in e2e["after"]):
        return []  # a record from before the timelines
    rows = [("before", e2e["before"]), ("after", e2e["after"]), ("after, worlds cached", [e2e["after_warm"]]),
            (f"after, {2 * e2e['long_frames_per_scenario']} frames (one run)", [long])]
    lines = [
        "## Where a run's time goes: start, steady rate, tail",
        "",
        "From the same runs: when the first rgb file was stored (seconds after the command started), the",
        "rate between the 10% and the 90% marks of the frames (both workers rendering: no start, no tail), and",
        "when the last one was stored; medians. One more after run renders "
        f"{e2e['long_frames_per_scenario']} frames per scenario (`--frames-per-scenario "
        f"{e2e['long_frames_per_scenario']}`, empty world cache), where the start weighs less.",
        "",
        "| variant | first frame s | steady frames/s | last frame s | command wall s | reported frames/s |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for name, runs in rows:
        if runs:
            lines.append(f"| {name} | {_timeline_median(runs, 'first_s')} | {_timeline_median(runs, 'steady_fps')} | "
                         f"{_timeline_median(runs, 'last_s')} | {_median(runs, 'command_wall_s'):.1f} | "
                         f"{_median(runs, 'reported_fps'):.2f} |")
    lines += ["", "![frames stored over time, before and after](bench_produce.png)", ""]
    return lines


def plot_timelines(e2e: dict, path: Path) -> None:
    """Frames stored over time: each before and after run of the 120-frame command, and the long run."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4))
    for runs, colour, label in ((e2e["before"], "0.55", f"before ({e2e['baseline']})"), (e2e["after"], "C0", "after")):
        for i, run in enumerate(runs):
            times = run.get("timeline", {}).get("times_s") or []
            left.plot(times, range(1, len(times) + 1), color=colour, lw=1.2, label=label if i == 0 else None)
    left.set(title=f"{E2E_COMMAND.split(' --width')[0]}", xlabel="seconds after the command started",
             ylabel="frames stored")
    left.title.set_fontsize(8)
    times = (e2e.get("after_long") or {}).get("timeline", {}).get("times_s") or []
    right.plot(times, range(1, len(times) + 1), color="C0", lw=1.2, label="after")
    if times:
        right.plot([0, times[-1]], [0, 5 * times[-1]], "k--", lw=0.8, label="5 frames/s from the command's start")
    right.set(title=f"{2 * e2e.get('long_frames_per_scenario', 0)} frames", xlabel="seconds after the command started")
    for ax in (left, right):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _overhead_section(result: dict, med: dict) -> list[str]:
    frames, repeats = result["frames"], result["repeats"]
    lines = [
        "## Ray overhead and scaling (after)",
        "",
        f"{result['resolution']}, {frames} frames in 4 episodes (all six outputs encoded and written), median of "
        f"{repeats} runs. Each run is a fresh process with the world cache off, so every variant pays for its",
        "world builds and shader compiles inside the timing. Module imports are outside it in both: the plain",
        "loop imports before its clock starts, and Ray's workers import the same modules in a warm-up task",
        "before `produce` is timed, on the local cluster `produce` starts (workers at the driver's priority);",
        "that start-up is reported apart. Both sides run with the thread settings Ray gives a one-CPU task",
        "(`OMP_NUM_THREADS=1`; llvmpipe's own threads as the machine has cores).",
        "",
        "| variant | median wall time (s) | frames/s | of it outside episodes (s) |",
        "|---|---:|---:|---:|",
        f"| plain loop, one process | {med['plain']:.2f} | {result['fps']['plain']:.2f} | {med['outside_plain']:.3f} |",
        f"| Ray, 1 worker | {med['ray1']:.2f} | {result['fps']['ray1']:.2f} | {med['outside_ray1']:.3f} |",
        f"| Ray, 2 workers | {med['ray2']:.2f} | {result['fps']['ray2']:.2f} | {med['outside_ray2']:.3f} |",
        "",
        "Outside episodes: the wall time minus the time spent inside `run_episode` (for 2 workers, minus",
        "half of it): task dispatch, result collection and index compaction, the orchestration itself;",
        "it moves far less with the machine's load than the wall times do.",
        "",
        f"* Orchestration overhead, Ray 1 worker / plain loop: **{result['overhead_ratio']:.3f}** (target <= 1.03).",
        f"* Scaling, 2 workers over 1: **{result['scaling_2_over_1']:.2f}x** on 2 cores "
        "(two workers fill the cores, so each GL context rasterises on its render thread: `LP_NUM_THREADS=0`, as produce sets).",
        f"* Ray start-up and worker warm-up (not included above): median {med['startup']:.1f} s.",
        "",
        "GPU: not measured (no GPU machine was available to these runs).",
        "",
    ]
    return lines


if __name__ == "__main__":
    main()
