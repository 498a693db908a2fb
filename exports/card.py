"""The dataset card: a README.md written into an output root.

It describes what the root holds (domains and frames per split, class pixel
shares with a bar chart, a contact sheet if one exists), how the files are
encoded and decoded, where the data came from (run.json: config, seed,
package versions, git revision), and how to query, export and load it. All
numbers come from the manifest; the card is deterministic (no timestamps).
"""

from __future__ import annotations

import json
import os
import tempfile
from collections import Counter
from dataclasses import dataclass

import pyarrow as pa
import pyarrow.compute as pc

from domains.catalog import LABELS, scenario, split_code
from manifests.layout import NEW_ROOT_LAYOUT, PATTERNS, layout_of_path
from manifests.reader import part_files, read_manifest
from manifests.stats import bar_chart_png, share_table
from outputs.table import OUTPUTS, file_of_path, markdown_table
from manifests.schema import PART_SCHEMA, output_columns, part_path
from exports.hf import HF_SPLITS, card_header, citation_section
from manifests.query import FRAME_KEY, SPLITS, count_frames, rig_sensors
from roots.contract import CARD_FILE, CHART_FILE, PREVIEW_DIR  # the root's own names (verify knows them)
from roots.run_file import REPAIR_HINT, ConfigShape, RunRecordError, read_record
from roots.verify import verify
from storage import Storage

PREVIEW_MAX_WIDTH = 480  # contact-sheet frames are rendered at most this wide
CARD_MARK = "<!-- written by idda card: it replaces this file when run again -->"
_OUR_CARD_SIGNS = (CARD_MARK.encode(), b"# IDDA-style synthetic driving dataset")  # the second: cards before the mark


def is_our_card(data: bytes) -> bool:
    """True if a README.md was written by ``idda card`` (so it may be replaced)."""
    return any(sign in data for sign in _OUR_CARD_SIGNS)


@dataclass(frozen=True)
class CardConfig:
    root: str  # output root: local path or s3:// URI
    contact_sheet: bool = False  # render a contact sheet into <root>/preview/ first
    verify: bool = True  # verify the root first; the card says what verify found
    shape: ConfigShape | None = None  # what run.json's config may hold (pipeline.settings.CONFIG_SHAPE)


@dataclass
class CardResult:
    card: str  # URI of the README.md
    chart: str  # URI of the class-share chart
    previews: list[str]  # root-relative preview images linked from the card
    frames: int  # distinct frames (a rig's root holds a manifest row per sensor of each)
    problems: dict[str, int] | None = None  # what verify found, by kind ({}: none); None: not verified


# -------------------------------------------------------------- sections ----
def split_counts(table: pa.Table) -> dict[str, dict[str, int]]:
    """Frames per scenario and split: {scenario: {split: n}} (every split present); a frame of a rig counts once."""
    counts: dict[str, dict[str, int]] = {}
    frames = table.select([*FRAME_KEY, "split"]).group_by([*FRAME_KEY, "split"]).aggregate([])  # a frame's sensors once
    for code, split in zip(frames.column("scenario").to_pylist(), frames.column("split").to_pylist()):
        row = counts.setdefault(code, {s: 0 for s in SPLITS})
        row[split] = row.get(split, 0) + 1
    return dict(sorted(counts.items()))


def manifest_splits(table: pa.Table, listed: dict[str, dict[int, str]] | None = None
                    ) -> tuple[dict[str, tuple[int, int]], dict[str, list[str]]]:
    """The card's ``manifest`` config: per HF split name its (frames, Arrow
    bytes of the part columns) and its manifest parts. A part holds one episode,
    so each part belongs to one split; parts hold no town/weather/viewpoint
    (those are hive path keys, which ``datasets`` does not read). ``listed``: the
    root's part files as listed (``reader.part_files``: old roots' names too);
    without it, the names the writer gives (rows counted in ``table``)."""
    parts = table.select(PART_SCHEMA.names)
    sizes: dict[str, tuple[int, int]] = {}
    files: dict[str, list[str]] = {}
    for split in SPLITS:
        rows = parts.filter(pc.equal(parts.column("split"), split))
        if len(rows):
            sizes[HF_SPLITS[split]] = (len(rows), rows.nbytes)
            episodes = Counter(zip(rows.column("scenario").to_pylist(), rows.column("episode").to_pylist()))
            files[HF_SPLITS[split]] = sorted((listed or {}).get(code, {}).get(episode) or part_path(code, episode, n)
                                             for (code, episode), n in episodes.items())
    return sizes, files


def _domain_section(table: pa.Table) -> list[str]:
    counts = split_counts(table)
    lines = [
        "## Domains and splits",
        "",
        "| scenario | town | weather | viewpoint | " + " | ".join(SPLITS) + " | total |",
        "|---|---|---|---|" + "---:|" * (len(SPLITS) + 1),
    ]
    for code, row in counts.items():
        s = scenario(code)
        cells = " | ".join(f"{row[split]:,}" for split in SPLITS)
        lines.append(
            f"| {code} | {s.town.code} ({s.town.name}) | {s.weather.code} ({s.weather.name}) | "
            f"{s.viewpoint.code} ({s.viewpoint.vehicle}) | {cells} | {sum(row.values()):,} |"
        )
    totals = {split: sum(row[split] for row in counts.values()) for split in SPLITS}
    cells = " | ".join(f"**{totals[split]:,}**" for split in SPLITS)
    lines.append(f"| **total** ({len(counts)} scenarios) | | | | {cells} | **{sum(totals.values()):,}** |")
    lines += ["", "Splits are by episode: all frames of an episode share its split (above). Any run of three "
              "or more episodes has all three splits, and each scenario tends to 80/10/10 % train/val/test; "
              "extending a run never moves an episode to another split (the rule: idda-pipeline's "
              "docs/layout.md, \"Splits\")."]
    return lines


def _class_section(table: pa.Table) -> list[str]:
    lines = [
        "## Classes and pixel shares",
        "",
        f"![class pixel shares]({CHART_FILE})",
        "",
        "Share of all pixels per class in this root, next to the IDDA paper's full-scale shares. "
        "\\* marks the classes excluded from evaluation (Cityscapes ignores them).",
        "",
        "| id | class | colour | Cityscapes id | trainId | share % | paper % | in frames % |",
        "|---:|---|---|---:|---:|---:|---:|---:|",
    ]
    for row in share_table(table).to_pylist():
        label = LABELS[row["class_id"]]
        star = "" if label.evaluated else "\\*"
        train = "ignore" if label.train_id == 255 else str(label.train_id)
        lines.append(
            f"| {label.id} | {label.name}{star} | {label.color} | {label.cityscapes_id} | {train} | "
            f"{100 * row['share']:.3f} | {100 * row['paper_share']:.3f} | {100 * row['presence']:.1f} |"
        )
    return lines


def _preview_section(previews: list[str]) -> list[str]:
    if not previews:
        return [
            "## Preview",
            "",
            "No preview in this root yet: `idda card ROOT --contact-sheet` renders one "
            "(one frame per scenario; rows are viewpoints, columns towns).",
        ]
    lines = ["## Preview", ""]
    for rel in previews:
        lines += [f"![{os.path.basename(rel)}]({rel})", ""]
    return lines[:-1]


def held_outputs(table: pa.Table) -> tuple[str, ...]:
    """The outputs the frames of ``table`` hold, in table order."""
    return tuple(o for o in OUTPUTS if table.column(output_columns(o)[0]).null_count < len(table))


def _encoding_section(table: pa.Table) -> list[str]:
    held = held_outputs(table)
    example = table.column("depth_raw_path")[0].as_py() if "depth_raw" in held else "<depth_raw path>"
    rgb_format = file_of_path("rgb", table.column("rgb_path")[0].as_py()) if "rgb" in held else "png"
    first = table.column(output_columns(held[0])[0])[0].as_py() if held else ""
    pattern = PATTERNS.get(layout_of_path(first), PATTERNS[NEW_ROOT_LAYOUT])  # an old root's is flat
    return [
        "## Files and encodings",
        "",
        f"`{pattern}.<png|jpg|parquet>`, per frame one file per output "
        f"this root holds ({', '.join(held)}; image encodings follow CARLA's conventions):",
        "",
        *markdown_table(held, rgb_format),
        "",
        "Depth in metres from `depth_raw`: `depth_m = 1000 * (R + G*256 + B*65536) / (256**3 - 1)`. "
        "OpenCV reads BGR, so R is channel 2:",
        "",
        "```python",
        "import cv2, numpy as np",
        f'bgr = cv2.imread("{example}", cv2.IMREAD_COLOR).astype(np.float64)',
        "depth_m = 1000 * (bgr[..., 2] + bgr[..., 1] * 256 + bgr[..., 0] * 65536) / (256**3 - 1)",
        "```",
    ]


def _provenance_section(record: dict | None) -> list[str]:
    lines = ["## Provenance", ""]
    if record is None:
        return lines + ["This root has no `run.json`; its config and versions are unknown."]
    config = record.get("config", {})
    lines += [
        f"Produced by idda-pipeline at git revision `{record.get('git_revision', 'unknown')}` "
        f"with run seed {config.get('seed')} and the `{config.get('world', 'procedural')}` world. "
        "The same config and seed give the same bytes. Config (from `run.json`):",
        "",
        "```json",
        json.dumps(config, indent=2, sort_keys=True),
        "```",
        "",
        "| package | version |",
        "|---|---|",
    ]
    lines += [f"| {name} | {version} |" for name, version in sorted(record.get("versions", {}).items())]
    history = record.get("history", [])
    if len(history) > 1:
        lines += ["", f"The root was extended {len(history) - 1} time(s); `run.json` keeps every config."]
    return lines


def _usage_section(uri: str, scenario: str) -> list[str]:
    """How to read the root; the query example selects the town and weather of ``scenario``, one it holds."""
    where = "this directory" if uri == "." else f"`{uri}`"
    town, weather = split_code(scenario)[:2]
    return [
        "## Query, export and load",
        "",
        f"Commands and code below read the dataset at {where}.",
        "",
        "```sh",
        f"idda status {uri}                      # done / pending per scenario",
        f"idda verify {uri}                      # recompute every checksum",
        f"idda query {uri} --preset best-case --out best.txt",
        f"idda query {uri} --domains 'towns={town} weathers={weather}' --split train --has rider --total 100 "
        "--out sample.csv",
        f"idda export {uri} --format cityscapes --to export/cityscapes --split val",
        f"idda export {uri} --format idda --to export/idda",
        f"idda distances {uri} --chart domains.png",
        "```",
        "",
        "In Python (numpy arrays; works with `torch.utils.data.DataLoader`, or Ray Data "
        "with `analysis.loaders.ray_dataset`):",
        "",
        "```python",
        "from analysis.loaders import FrameDataset",
        "from manifests.query import Query",
        "from manifests.reader import read_manifest",
        "",
        f'table = read_manifest("{uri}")          # one row per frame (pyarrow)',
        f'data = FrameDataset("{uri}", Query(splits=("train",)), outputs=("rgb", "semantic_raw", "depth_raw"))',
        'sample = data[0]   # sample["rgb"] HxWx3 uint8, sample["semantic"] HxW class ids, sample["depth"] metres',
        "```",
    ]


def _integrity_section(verified) -> list[str]:
    """What verify found when the card was written (``verified``: a VerifyReport, or None: not run)."""
    lines = ["## Integrity", ""]
    if verified is None:
        return lines + ["Not verified when this card was written (`idda card --no-verify`); `idda verify` checks every file."]
    if verified.ok:
        return lines + [f"Verified when this card was written: all {verified.files_checked:,} files match the "
                        "sizes and sha256 checksums the manifest lists, and every manifest part and index is sound."]
    found = ", ".join(f"{n} {kind}" for kind, n in sorted(verified.counts().items()))
    return lines + [f"**This root failed verification when this card was written** ({found}); the numbers "
                    "below may count damaged frames. `idda verify` lists the damage, `idda produce --repair` mends it."]


def _rig_clause(table: pa.Table) -> str:
    """In a rig's root: the sensors that see every frame, and the sensor frames (manifest rows) they make."""
    sensors = rig_sensors(table)
    if not sensors:
        return ""
    return (f"each seen by the {len(sensors)} sensor(s) of its rig ({', '.join(sensors)}; "
            f"{len(table):,} sensor frames, one manifest row each), ")


def card_markdown(table: pa.Table, record: dict | None, uri: str, previews: list[str],
                  parts: dict[str, dict[int, str]] | None = None, verified=None) -> str:
    """The card's text for a manifest ``table`` (all frames of the root); ``uri``
    is how the usage examples name the root; ``verified``: verify's report (None: not verified)."""
    if len(table) == 0:
        raise ValueError(f"{uri} has no frames yet; produce some before writing its card")
    sizes = sorted({(w, h) for w, h in zip(table.column("width").to_pylist(), table.column("height").to_pylist())})
    resolution = ", ".join(f"{w}x{h}" for w, h in sizes)
    episodes = len(set(zip(table.column("scenario").to_pylist(), table.column("episode").to_pylist())))
    scenarios = len(set(table.column("scenario").to_pylist()))
    held = held_outputs(table)
    intro = [
        "# IDDA-style synthetic driving dataset",
        "",
        f"{count_frames(table):,} frames in {episodes:,} episodes over {scenarios} scenarios (town x weather x viewpoint), "
        f"{_rig_clause(table)}at {resolution}, each with {len(held)} output file(s): {', '.join(held)} "
        f"(\"Files and encodings\" below says what each holds; {len(LABELS)} semantic classes). Made in the manner of IDDA "
        "(Alberti et al., 2020) by idda-pipeline; every frame is listed with checksums and per-class "
        "pixel counts in the Parquet manifest under `manifest/`.",
    ]
    sizes, files = manifest_splits(table, parts)
    header = card_header(sizes, files, config="manifest")
    sections = [
        intro,
        _integrity_section(verified),
        _domain_section(table),
        _class_section(table),
        _preview_section(previews),
        _encoding_section(table),
        _provenance_section(record),
        _usage_section(uri, min(table.column("scenario").to_pylist())),
        [citation_section()],
    ]
    return header + "\n" + "\n\n".join("\n".join(s) for s in sections) + "\n" + CARD_MARK + "\n"


# --------------------------------------------------------------- writing ----
def find_previews(storage) -> list[str]:
    """Preview PNGs under ``preview/``: contact sheets first, then the rest, sorted."""
    files = [rel for rel in storage.list_files(PREVIEW_DIR + "/", suffix=".png")]
    return sorted(files, key=lambda rel: (not os.path.basename(rel).startswith("contact_sheet"), rel))


def render_contact_sheet(storage, record: dict | None, codes: list[str]) -> list[str]:
    """Render a contact sheet of ``codes`` with the run's seed and world into ``preview/``."""
    try:
        from render_workers.render.preview import write_preview
    except ImportError as exc:
        raise ImportError(f"rendering a contact sheet needs render_workers.render.preview ({exc})") from exc
    config = (record or {}).get("config", {})
    width, height = int(config.get("width", 1920)), int(config.get("height", 1080))
    if width > PREVIEW_MAX_WIDTH:
        width, height = PREVIEW_MAX_WIDTH, max(2, round(height * PREVIEW_MAX_WIDTH / width / 2) * 2)
    written = []
    with tempfile.TemporaryDirectory() as tmp:
        paths = write_preview(tmp, codes, width, height, int(config.get("seed", 0)), world=config.get("world", "procedural"))
        for path in sorted(str(p) for p in paths):
            rel = f"{PREVIEW_DIR}/{os.path.basename(path)}"
            with open(path, "rb") as f:
                storage.write_bytes(rel, f.read())
            written.append(rel)
    return written


def write_card(config: CardConfig) -> CardResult:
    """Write ``README.md`` and ``class_shares.png`` into the root (and a contact sheet if asked)."""
    storage = Storage.from_uri(config.root)
    if storage.exists(CARD_FILE) and not is_our_card(storage.read_bytes(CARD_FILE)):
        raise ValueError(f"{storage.join(CARD_FILE)} exists and was not written by `idda card`; move it away first")
    storage.ensure_writable()  # the card goes into the root: say so before any work if it cannot
    table = read_manifest(storage)
    if len(table) == 0:
        raise ValueError(f"{storage.uri} has no frames yet; produce some before writing its card")
    try:
        record = read_record(storage, config.shape)
    except RunRecordError as exc:
        raise ValueError(f"{exc}; {REPAIR_HINT}") from None
    if config.contact_sheet:
        render_contact_sheet(storage, record, sorted(set(table.column("scenario").to_pylist())))
    previews = find_previews(storage)
    verified = None
    if config.verify:
        verified = verify(storage, shape=config.shape)
    # Local cards say "." (run the commands in the root, which may move); s3 cards the URI.
    text = card_markdown(table, record, "." if storage.is_local else storage.uri, previews, part_files(storage), verified)
    frames = count_frames(table)
    storage.write_bytes(CHART_FILE, bar_chart_png(share_table(table), title=f"Class pixel shares, {frames:,} frames"))
    storage.write_bytes(CARD_FILE, text.encode())
    return CardResult(storage.join(CARD_FILE), storage.join(CHART_FILE), previews, frames,
                      None if verified is None else verified.counts())
