"""Export throughput: `idda export --format webdataset` on a local full-HD root.

A root of FRAMES frames at 1920x1080 (procedural world, the default eight
outputs) is rendered once into a temp folder; then, each ROUNDS times in
turn (in a rotated order), into a fresh local target: the WebDataset export at the default bound
(1 GB: one shard a split here) and at a small bound (several shards a
split), the same export run again over its finished target (every shard
verified and kept: what a resume costs), and the HuggingFace Parquet export
beside them for reference. Medians; frames/s and MB/s of root files read.
"""

from __future__ import annotations

import json
import os
import platform
import shutil
import statistics
import tempfile
import time
from pathlib import Path

from exports.export import ExportConfig, export

FRAMES = 48  # two scenarios of 24 frames
DOMAINS = "T01_CN_A,T03_CS_M"
SMALL_BOUND = 16 * 2**20
ROUNDS = 6


def _root_bytes(root: Path) -> int:
    from manifests.reader import read_manifest
    from outputs.table import OUTPUTS
    from manifests.schema import output_columns
    from storage import Storage

    table = read_manifest(Storage.from_uri(str(root)))
    return sum(sum(v for v in table.column(output_columns(o)[1]).to_pylist() if v) for o in OUTPUTS
               if output_columns(o)[1] in table.column_names)


def _render(root: Path, frames: int, width: int, height: int, world: str) -> float:
    from pipeline.planner import PlanConfig
    from pipeline.settings import RunConfig
    from tests.roots import render_root

    start = time.perf_counter()
    render_root(root, RunConfig(plan=PlanConfig(domains=DOMAINS, frames_per_scenario=frames // 2, width=width,
                                                height=height, seed=0), world=world))
    return time.perf_counter() - start


VARIANTS = {  # name: ExportConfig keywords
    "webdataset, 1 GB shards": {"format": "webdataset"},
    "webdataset, run again over the finished export (verify and keep)": {"format": "webdataset"},
    f"webdataset, {SMALL_BOUND // 2**20} MiB shards": {"format": "webdataset", "shard_size": SMALL_BOUND},
    "hf (Parquet, reference)": {"format": "hf"},
}
# Run in groups, each into a fresh target (the second variant runs over the first one's export); a round
# takes the groups in a rotated order, so no variant always runs first or after the same one.
GROUPS = ((0, 1), (2,), (3,))


def measure(root: Path, work: Path, rounds: int) -> dict:
    names = list(VARIANTS)
    seconds: dict[str, list[float]] = {name: [] for name in names}
    shards: dict[str, int] = {}
    target = work / "target"
    for r in range(rounds):
        for group in GROUPS[r % len(GROUPS):] + GROUPS[:r % len(GROUPS)]:
            shutil.rmtree(target, ignore_errors=True)
            for name in (names[i] for i in group):
                report = export(ExportConfig(root=str(root), to=str(target), **VARIANTS[name]))
                seconds[name].append(report.seconds)
                shards[name] = len(list(target.rglob("*.tar")))
    return {name: {"seconds": statistics.median(s), "all": s, "shards": shards[name]} for name, s in seconds.items()}


def main(out_dir: str = "docs", frames: int = FRAMES, width: int = 1920, height: int = 1080,
         world: str = "procedural", rounds: int = ROUNDS) -> dict:
    with tempfile.TemporaryDirectory(prefix="bench_export_") as tmp:
        root = Path(tmp) / "root"
        render_s = _render(root, frames, width, height, world)
        size = _root_bytes(root)
        found = measure(root, Path(tmp), rounds)
    result = {"frames": frames, "width": width, "height": height, "world": world, "rounds": rounds,
              "root_mb": size / 1e6, "render_s": render_s, "cpus": os.cpu_count(), "platform": platform.platform(),
              "load": os.getloadavg(), "variants": found}
    for v in found.values():
        v["frames_per_s"] = frames / v["seconds"]
        v["mb_per_s"] = size / 1e6 / v["seconds"]
    os.makedirs(out_dir, exist_ok=True)
    with open(os.path.join(out_dir, "bench_export.json"), "w") as f:
        json.dump(result, f, indent=1)
        f.write("\n")
    with open(os.path.join(out_dir, "bench_export.md"), "w") as f:
        f.write(markdown(result))
    return result


def markdown(r: dict) -> str:
    lines = [
        "# Export benchmark",
        "",
        f"`BENCH=export make bench` (benchmarks/bench_export.py): a local root of {r['frames']} frames at "
        f"{r['width']}x{r['height']} ({r['world']} world, `{DOMAINS}`, the default eight outputs, "
        f"{r['root_mb']:.0f} MB of files), exported into a fresh local folder on the same disk; "
        f"medians of {r['rounds']} rounds. {r['cpus']} CPU cores ({r['platform']}); load average "
        f"{r['load'][0]:.1f} at the end (other jobs share the cores). The root's files are in the page "
        "cache (just rendered), so this is the export's own cost: read, check each file's sha256 against "
        "the manifest, write the tar, hash the shard.",
        "",
        "| export | seconds | frames/s | MB/s read | shards |",
        "|---|---:|---:|---:|---:|",
    ]
    for name, v in r["variants"].items():
        lines.append(f"| {name} | {v['seconds']:.2f} | {v['frames_per_s']:.1f} | {v['mb_per_s']:.0f} | "
                     f"{v['shards'] or '-'} |")
    lines += ["", "The hf export decodes the semantic PNG and re-encodes it as one channel, so it does more "
              "work per frame than the WebDataset export, which copies the root's bytes.", ""]
    return "\n".join(lines)
