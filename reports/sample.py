"""The sample ``make report`` renders: its size, how it is produced, and which towns are urban.

One short episode per scenario at reduced resolution (``pipeline.driver.produce``),
rebuilt on every run in ``SAMPLE_ROOT``; ``reports.shift_section`` renders its five domains
the same way.
"""

from __future__ import annotations

import json
import logging
import shutil
from pathlib import Path

from domains.catalog import TOWNS
from manifests.schema import STATS_DIR, STATS_RE
from pipeline.driver import produce
from pipeline.settings import PlanConfig, ProduceConfig, RunConfig
from render_workers.render.episode import DEFAULT_WORLD
from render_workers.worlds.styles import is_urban

SAMPLE_ROOT = "/tmp/idda-worlds-sample"  # outside git; rebuilt on every run
FRAMES = 8  # per scenario: one episode of 8 frames (21 s of driving)
WIDTH, HEIGHT = 320, 180
WORKERS = 2
SEED = 0
LARGE = ("sky", "road", "vegetation", "building", "vehicle", "sidewalk", "terrain")
RARE = ("bicycle", "motorcycle", "rider", "traffic light", "traffic sign", "pedestrian")

log = logging.getLogger(__name__)


def produce_sample(root: str, frames: int, width: int, height: int, workers: int, domains: str = "all") -> dict:
    shutil.rmtree(root, ignore_errors=True)  # a stale root would be resumed, not re-rendered
    plan = PlanConfig(domains=domains, frames_per_scenario=frames, width=width, height=height, seed=SEED)
    config = ProduceConfig(run=RunConfig(plan=plan, world=DEFAULT_WORLD), out=root, workers=workers)
    last = [0.0]

    def progress(p) -> None:
        if p.elapsed_s - last[0] > 30 or p.episodes_done == p.episodes_total:
            last[0] = p.elapsed_s
            log.info("  %d/%d episodes, %.0f s", p.episodes_done, p.episodes_total, p.elapsed_s)

    report = produce(config, progress)
    if report.failed:
        raise RuntimeError(f"{len(report.failed)} episodes failed, e.g. {report.failed[0]}")
    return {"episodes": report.rendered_episodes, "frames": report.rendered_frames,
            "seconds": round(report.seconds, 1), "workers": workers}


def episode_stats(root: str) -> list[dict]:
    """The per-episode stats files the workers wrote (timings per stage), each with its scenario: any
    code the catalog allows (manifests.schema.STATS_RE), not the driver's own stats."""
    out = []
    for path in sorted(Path(root, STATS_DIR).glob("*.json")):
        if (match := STATS_RE.match(f"{STATS_DIR}/{path.name}")) is not None:
            out.append({**json.loads(path.read_text()), "scenario": match["scenario"]})
    return out


def urban_towns() -> tuple[str, ...]:
    """Towns with sidewalks and buildings (``render_workers.worlds.styles.urban``): the rare-class presence target's frames."""
    return tuple(t.code for t in TOWNS if is_urban(t))


def span(codes: tuple[str, ...]) -> str:
    """Town codes as a range when they are consecutive in the catalog (T01-T06), else listed."""
    order = [t.code for t in TOWNS]
    at = [order.index(c) for c in codes]
    if len(codes) > 2 and at == list(range(at[0], at[0] + len(at))):
        return f"{codes[0]}-{codes[-1]}"
    return ", ".join(codes)
