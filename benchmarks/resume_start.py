"""When a resume starts rendering: ``python -m benchmarks.resume_start ROOT``.

Deletes ROOT's ``_index/`` (a root without indexes; ``PROBE_KEEP_INDEX=1`` keeps it), then runs ``produce()`` of the full plan on
it with a stand-in episode function that only notes when it starts, and stops the run as soon as
one has. Prints JSON: seconds from the call to the end of each step before the first episode
(listing, footers and the misfiled check, run.json checks, the in-the-way check, Ray attached,
the first progress report, which comes just before the first episode is submitted, the first
episode's start; on a root without indexes, this tree reads the footers beside it:
``summaries_and_misfiled_done`` may then come after it). ``PROBE_NO_RAY=1`` stops before Ray.
ROOT: e.g. ``benchmarks.bench_control_root``'s synthetic full-scale root with a few parts removed
(docs/bench_control_root.md).
"""

from __future__ import annotations

import json
import os
import shutil
import sys
import tempfile
import time


def standin(spec, storage, world=None, on_frame=None, fence=None):
    """An episode that only notes when it started."""
    import socket

    from pipeline.episode_job import EpisodeResult

    with open(os.environ["PROBE_MARK"], "a") as f:
        f.write(f"{time.time()}\n")
    return EpisodeResult(spec.scenario, spec.episode, spec.frames, 0.0, socket.gethostname(), os.getpid())


def main(root: str) -> None:
    import pipeline.driver as driver
    from pipeline.planner import PlanConfig
    from pipeline.settings import RunConfig
    if not os.environ.get("PROBE_KEEP_INDEX"):
        shutil.rmtree(os.path.join(root, "_index"), ignore_errors=True)
    mark = os.environ["PROBE_MARK"] = os.path.join(tempfile.gettempdir(), f"idda-resume-start.{os.getpid()}")
    marks = {}
    t0 = time.perf_counter()
    def wrap(mod, name, label):
        real = getattr(mod, name)
        def w(*a, **k):
            try:
                return real(*a, **k)
            finally:
                marks.setdefault(label, time.perf_counter() - t0)
        setattr(mod, name, w)
    wrap(driver, "scan", "scan_done")
    wrap(driver, "refuse_misfiled", "summaries_and_misfiled_done")
    wrap(driver, "prepare_root", "prepare_root_done")
    wrap(driver, "refuse_in_the_way", "in_the_way_done")
    wrap(driver, "_connect", "ray_connected")
    real_render = driver._render_on_ray
    def render_on_ray(*a, **k):
        marks.setdefault("render_on_ray_start", time.perf_counter() - t0)
        if os.environ.get("PROBE_NO_RAY"):
            raise KeyboardInterrupt
        return real_render(*a, **k)
    driver._render_on_ray = render_on_ray
    real_compact = driver.compact
    def compact(*a, **k):
        marks.setdefault("first_fold_start", time.perf_counter() - t0)
        r = real_compact(*a, **k)
        marks.setdefault("first_fold_end", time.perf_counter() - t0)
        return r
    driver.compact = compact
    def progress(p):
        marks.setdefault("first_progress", time.perf_counter() - t0)
        if os.path.exists(mark) and open(mark).read().strip():
            raise KeyboardInterrupt  # the first episode started: that is all this probe measures
    t_wall0 = time.time()
    try:
        report = driver.produce(driver.ProduceConfig(run=RunConfig(plan=PlanConfig()), out=root), progress=progress,
                                episode_fn=standin)
    except driver.ProduceInterrupted as exc:
        report = exc.report
    marks["total"] = time.perf_counter() - t0
    if os.path.exists(mark):
        starts = sorted(float(x) for x in open(mark).read().split())
        os.unlink(mark)
        marks["first_episode_start"] = starts[0] - t_wall0
    marks["rendered"] = report.rendered_episodes
    marks["load"] = os.getloadavg()[0]
    print(json.dumps(marks))


if __name__ == "__main__":
    main(sys.argv[1])
