"""Procedural worlds report: class shares, presence, domain distances, contact sheets.

``.venv/bin/python -m reports.worlds`` renders a sample of all 105
scenarios with the procedural world (``pipeline.driver.produce``, one short
episode per scenario at reduced resolution, frames 3 s apart), then writes
``docs/worlds.md`` and ``docs/worlds.json`` with figures in ``docs/images/``:

* class pixel shares over the sample next to the paper's (table + log bars),
  and per town;
* class presence (share of frames showing a class), overall and over the
  urban towns T01-T06;
* the paper's three domain distances (``analysis.distances``) and a 2-D
  embedding of all domains;
* the paper's domain-shift table (``reports.shift_section``: ``idda shifts``
  on its five domains, 150 frames each);
* synthetic to real on CamVid at two seeds (``reports.camvid_section``: ``idda shifts
  --camvid``; the folder from ``$IDDA_CAMVID``, else the section says it was skipped);
* one contact sheet per weather (7 towns x 5 viewpoints): frame 0 of episode 0
  of every scenario, i.e. exactly what ``render_workers.render.preview.write_preview``
  renders for the same seed and size;
* build_world / populate times per town next to the sample's render times.
"""

from __future__ import annotations

import json
import logging
import statistics
import time
from pathlib import Path

import numpy as np

from analysis.distances import DistanceConfig, domain_distances, embedding_png, format_distance_table
from domains.catalog import LABELS, TOWNS, split_code
from manifests.reader import read_manifest
from manifests.stats import PAPER_SHARES, bar_chart_png, class_pixels, class_presence, share_table
from pipeline.planner import EPISODE_FRAMES
from render_workers.render.episode import WORLDS
from render_workers.worlds import traffic, world
from render_workers.worlds.styles import look
from reports.camvid_section import measure as measure_camvid
from reports.shift_section import measure as measure_shifts
from reports.charts import CELL_WIDTH, MAX_PNG_BYTES, contact_sheets, presence_png, town_share_png, town_sheet
from reports.sample import FRAMES, HEIGHT, LARGE, RARE, SAMPLE_ROOT, SEED, WIDTH, WORKERS, episode_stats, produce_sample, urban_towns
from reports.worlds_md import markdown
from roots.episode_spec import town_seed

log = logging.getLogger(__name__)


def _shares(pixels: np.ndarray) -> np.ndarray:
    return pixels / max(int(pixels.sum()), 1)


def class_tables(table) -> dict:
    import pyarrow as pa
    import pyarrow.compute as pc


    towns = pc.utf8_slice_codeunits(table.column("scenario"), 0, 3)
    urban = table.filter(pc.is_in(towns, value_set=pa.array(urban_towns())))
    overall = _shares(class_pixels(table))
    out = {
        "frames": len(table),
        "urban_frames": len(urban),
        "classes": [label.name for label in LABELS],
        "evaluated": [label.evaluated for label in LABELS],
        "share": overall.tolist(),
        "paper_share": [PAPER_SHARES[label.name] for label in LABELS],
        "presence": class_presence(table).tolist(),
        "presence_urban": class_presence(urban).tolist(),
        "share_by_town": {},
    }
    for t in TOWNS:
        sub = table.filter(pc.equal(towns, t.code))
        out["share_by_town"][t.code] = _shares(class_pixels(sub)).tolist()
    return out


def checks(stats: dict) -> dict:
    names = stats["classes"]
    large = {}
    for name in LARGE:
        i = names.index(name)
        ratio = stats["share"][i] / stats["paper_share"][i]
        large[name] = {"share": stats["share"][i], "paper": stats["paper_share"][i], "ratio": ratio,
                       "ok": 0.5 <= ratio <= 2.0}
    rare = {name: {"presence_urban": stats["presence_urban"][names.index(name)],
                   "ok": stats["presence_urban"][names.index(name)] >= 0.10} for name in RARE}
    return {"large_within_2x": large, "rare_urban_presence": rare,
            "all_ok": all(v["ok"] for v in large.values()) and all(v["ok"] for v in rare.values())}


def distances(root: str, images: Path) -> dict:
    report = domain_distances(DistanceConfig(root=root, samples=500, threads=2))
    (images / "worlds_domain_embedding.png").write_bytes(embedding_png(report))
    pairs = [{"case": p.case, "source": p.source, "target": p.target, "euclidean": p.euclidean,
              "cosine": p.cosine, "bhattacharyya": p.bhattacharyya,
              "paper": None if p.paper is None else {"euclidean": p.paper.euclidean, "cosine": p.paper.cosine,
                                                      "bhattacharyya": p.paper.bhattacharyya}}
             for p in report.pairs]
    # Every viewpoint / weather / town change in the sample, to see whether the
    # paper's three pairs are typical: mean Euclidean distance per kind of change.
    codes = report.domains
    mean_of = dict(zip(codes, report.means))
    by_kind: dict[str, list[float]] = {"viewpoint": [], "weather": [], "city": []}
    for i, a in enumerate(codes):
        for b in codes[i + 1:]:
            ta, wa, va = split_code(a)
            tb, wb, vb = split_code(b)
            diff = (ta != tb, wa != wb, va != vb)
            if sum(diff) != 1:
                continue
            kind = ("city", "weather", "viewpoint")[diff.index(True)]
            by_kind[kind].append(float(np.linalg.norm(mean_of[a] - mean_of[b])))
    return {
        "table": format_distance_table(report),
        "pairs": pairs,
        "components": report.components,
        "explained": report.explained,
        "samples_per_domain": sorted(set(report.samples.values())),
        "mean_euclidean_by_change": {k: (statistics.mean(v) if v else None) for k, v in by_kind.items()},
        "n_pairs_by_change": {k: len(v) for k, v in by_kind.items()},
    }


def world_timings(stats: list[dict]) -> dict:
    """Fresh build_world and populate times per town (this process), and the sample's render times."""
    out = {}
    for t in TOWNS:
        world.plan.cache_clear()
        start = time.perf_counter()
        static = world.build_world(t.code, town_seed(SEED, t))
        build = time.perf_counter() - start
        pops = []
        for k in range(5):
            start = time.perf_counter()
            traffic.populate(static, "A", 1000 + k)
            pops.append(time.perf_counter() - start)
        mine = [s for s in stats if s["scenario"].startswith(t.code) and s.get("frames")]
        setup = ("world", "populate", "load")
        per_frame = [(s["seconds"] - sum(s.get("stages", {}).get(k, 0.0) for k in setup)) / s["frames"] for s in mine]
        episode_setup = [sum(s.get("stages", {}).get(k, 0.0) for k in setup) for s in mine]
        out[t.code] = {
            "build_world_s": round(build, 3),
            "populate_s": round(statistics.median(pops), 4),
            "triangles": int(sum(len(p.mesh.faces) for p in static.static)),
            "static_parts": len(static.static),
            "sample_s_per_frame": round(statistics.median(per_frame), 3) if per_frame else None,
            "sample_setup_s": round(statistics.median(episode_setup), 3) if episode_setup else None,
        }
    out["_note"] = (f"full-scale episodes hold {EPISODE_FRAMES[0]}-{EPISODE_FRAMES[1]} frames at 1920x1080; "
                    "build_world runs once per town per worker process (cached), populate once per episode")
    return out


def bench_render(docs: Path) -> dict | None:
    path = docs / "bench_render.json"
    if not path.exists():
        return None
    try:
        return json.loads(path.read_text())
    except ValueError:
        return None


def _styles() -> dict:
    def row(s) -> dict:
        return {"name": s.name, "architecture": s.architecture, "road": s.asphalt, "road_edge": s.road_edge,
                "edge_surfaces": list(s.paving) if s.sidewalks else [s.verge], "lane_w_m": s.lane_w_m,
                "markings": s.markings, "trees": [sp for sp, _ in s.trees], "crops": list(s.crops),
                "relief_m": s.relief_m, "mountains_m": s.mountains_m}

    return {t.code: row(look(t)) for t in TOWNS}


def _bench_summary(bench: dict | None) -> str | None:
    """One line of whole-frame seconds per world from bench_render.json, whatever its exact layout."""
    if not bench:
        return None

    parts = []
    for world in WORLDS:
        node = bench.get(world) or bench.get("worlds", {}).get(world)
        if not isinstance(node, dict):
            continue
        stages = node.get("stages") if isinstance(node.get("stages"), dict) else {}
        total = stages.get("frame_median_s", node.get("frame_median_s"))
        if total is not None:
            parts.append(f"world `{world}` {float(total):.2f} s per frame (one process)")
    return "; ".join(parts) or None


def main(out_dir: str = "docs", frames: int = FRAMES, width: int = WIDTH, height: int = HEIGHT,
         root: str = SAMPLE_ROOT, workers: int = WORKERS, domains: str = "all", camvid: str | None = None) -> dict:
    docs = Path(out_dir)
    images = docs / "images"
    images.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    log.info("rendering the sample into %s (%d frames per scenario, %dx%d)", root, frames, width, height)
    sample = produce_sample(root, frames, width, height, workers, domains)
    sample.update(frames_per_scenario=frames, width=width, height=height, root=root)
    table = read_manifest(root)

    log.info("class shares and presence")
    stats = class_tables(table)
    (images / "worlds_class_shares.png").write_bytes(
        bar_chart_png(share_table(table), title=f"Class pixel shares, procedural sample of {len(table)} frames"))
    (images / "worlds_class_presence.png").write_bytes(presence_png(stats))
    (images / "worlds_town_shares.png").write_bytes(town_share_png(stats))

    log.info("contact sheets")
    sheets = contact_sheets(root, table, images, CELL_WIDTH)
    towns = town_sheet(root, table, images)

    log.info("domain distances")
    try:
        dist = distances(root, images)
    except ImportError as exc:  # analysis.distances not available
        dist = {"error": f"analysis.distances unavailable ({exc})"}

    log.info("domain shift table")
    shifts = measure_shifts(workers=workers)

    log.info("synthetic to real on CamVid")
    camvid = measure_camvid(camvid, docs=str(docs), workers=workers)

    log.info("build_world / populate timings")
    timings = world_timings(episode_stats(root))

    result = {
        "sample": sample,
        "stats": stats,
        "checks": checks(stats),
        "distances": dist,
        "shifts": shifts,
        "camvid": camvid,
        "timings": timings,
        "contact_sheets": [str(Path(p).relative_to(docs)) for p in sheets],
        "town_sheet": str(Path(towns).relative_to(docs)),
        "styles": _styles(),
        "bench_render": _bench_summary(bench_render(docs)),
        "report_seconds": None,
    }
    result["report_seconds"] = round(time.perf_counter() - start, 1)
    (docs / "worlds.json").write_text(json.dumps(result, indent=1, default=float) + "\n")
    (docs / "worlds.md").write_text(markdown(result))
    for png in images.glob("worlds_*.png"):
        if png.stat().st_size > MAX_PNG_BYTES:
            log.warning("%s is %d bytes (over %d)", png, png.stat().st_size, MAX_PNG_BYTES)
    log.info("wrote %s and %s in %.0f s", docs / "worlds.md", docs / "worlds.json", result["report_seconds"])
    return result


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    main()
