"""WebDataset: ``idda export ROOT --format webdataset --to DIR`` (local or s3://).

Tar shards that the ``webdataset`` package, Ray Data's ``read_webdataset``
and img2dataset's readers stream with no project code::

    train/train-000000.tar ...   one shard set per split (val/, test/ alike)
    stats/train-000000.json      a shard's size, sha256 and frames: written right after it, its "done" marker
    webdataset.json              the plan (source, query, outputs, shard bound, shard names): written first
    shards.json                  the index of shards: split, name, frames, bytes, sha256
    frames.csv                   the index of frames: uid, frame id, scenario, episode, frame, split, shard, offset
    EXPORT.json                  written last: the export is finished

One sample per frame, keyed by its ``uid`` (``<episode>_<frame>_<scenario>``,
no dots), with one member per selected output, ``<uid>.<output>.<ext>`` (the
root's own file bytes, e.g. ``.rgb.png``, ``.depth_raw.png``,
``.objects.parquet``), and ``<uid>.json``: the frame's whole manifest row
(calibration ``K``, ``cam_to_world``, ``cam_to_ego``, conditions, pixel
counts, every file's path, size and sha256). ``offset`` in frames.csv is the
byte offset of the sample's first tar header, for random access.

Shards hold at most ``shard_size`` bytes (a single frame larger than that
gets a shard of its own). The plan is made from the manifest before any file
is read (it lists every file's size), so it is the same for the same root and
selection, and so are the shards' bytes: USTAR headers with mtime 0, uid and
gid 0, no user names, mode 0644, members in plan order.

Resumable: a shard counts as done when its stats file exists, names the same
plan, and the tar's size and sha256 match it; an interrupted export run again
writes only the shards not done. Verified: every root file is checked against
the size and sha256 its manifest row lists as it is read
(``exports.shared.CheckedSource``). The target must be empty, or hold only
what an export of ours wrote: the same plan resumes (no ``--force`` needed);
another plan is replaced only with ``--force``, and only when every file there
is one that plan lists; any other file refuses the export (with or without
``--force``), and symlinks are never followed. A local target that is a
finished export of another format is replaced under ``--force`` by the same
rule as every export (``roots.contract.check_export_target``).
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import logging
import math
import os
import shutil
import tarfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass

from exports.shared import CheckedSource, ExportReport, Layout, listed_files
from manifests.query import SPLITS, count_frames, run_query
from manifests.reader import read_manifest, require_outputs
from manifests.schema import output_columns, with_uids
from outputs.table import OUTPUTS
from roots.contract import RootError, check_export_target, enclosing_root, export_tree, is_our_root
from storage import Storage, sha256_bytes

log = logging.getLogger(__name__)

SHARD_SIZE = 1 << 30  # default bound on a shard's bytes (about 1 GB, as img2dataset and webdataset advise)
MIN_SHARD_SIZE = 1 << 16  # 64 KiB: a smaller bound is surely a unit slip (tests use small bounds)
PLAN = "webdataset.json"
SHARDS_INDEX = "shards.json"
FRAMES_INDEX = "frames.csv"
STATS = "stats"
MARKER = "EXPORT.json"  # roots.contract.EXPORT_MARKER
_BLOCK = 512
_RECORD = 20 * _BLOCK  # tarfile pads the archive to whole records
_END = 2 * _BLOCK  # two zero blocks end a tar


def tar_bytes(member_sizes) -> int:
    """The size of a USTAR archive of members of ``member_sizes`` bytes, as tarfile writes it."""
    body = sum(_BLOCK + -(-size // _BLOCK) * _BLOCK for size in member_sizes) + _END
    return -(-body // _RECORD) * _RECORD


def parse_size(text: str) -> int:
    """Bytes from ``1GB``, ``500MB``, ``64KiB`` or a plain number; ValueError otherwise."""
    units = {"": 1, "B": 1, "KB": 10**3, "MB": 10**6, "GB": 10**9, "TB": 10**12,
             "KIB": 2**10, "MIB": 2**20, "GIB": 2**30, "TIB": 2**40}
    clean = text.strip().upper().replace(" ", "")
    number = clean.rstrip("KMGTIB")
    unit = clean[len(number):]
    try:
        value = float(number)
    except ValueError:
        value = -1.0
    if unit not in units or value <= 0:
        raise ValueError(f"bad size {text!r}: give bytes or a number with a unit, e.g. 1GB, 500MB, 256MiB")
    return int(value * units[unit])


# ------------------------------------------------------------------ plan ----
@dataclass(frozen=True)
class Member:
    name: str  # name in the tar: <uid>.<output>.<ext> or <uid>.json
    rel: str | None  # the root file it copies (None: the row's JSON, given by ``data``)
    size: int
    sha256: str  # the manifest's for a root file; of ``data`` for the JSON
    data: bytes | None = None


@dataclass(frozen=True)
class Shard:
    name: str  # <split>/<split>-NNNNNN.tar
    split: str
    samples: tuple[tuple[str, tuple[Member, ...]], ...]  # (uid, members) in order

    @property
    def size(self) -> int:
        return tar_bytes(m.size for _, members in self.samples for m in members)

    @property
    def stats(self) -> str:
        return f"{STATS}/{os.path.basename(self.name)[:-4]}.json"


def selected_outputs(table, outputs: tuple[str, ...] | None) -> tuple[str, ...]:
    """``outputs`` checked against the rows (each row must hold each), or every output all rows hold."""
    if outputs is not None:
        require_outputs(table, outputs, "the webdataset export")
        return tuple(outputs)
    held = []
    for name in OUTPUTS:
        column = output_columns(name)[0]
        if column in table.column_names and table.column(column).null_count == 0:
            held.append(name)
    return tuple(held)


def strict_json(value):
    """``value`` with every non-finite float as None: strict JSON has no Infinity or NaN (a clear day's
    ``visibility_m`` is infinite), and readers outside Python refuse them."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: strict_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [strict_json(v) for v in value]
    return value


def _row_json(row: dict) -> bytes:
    return (json.dumps(strict_json(row), sort_keys=True, separators=(",", ":"), allow_nan=False) + "\n").encode()


def _members(row: dict, outputs: tuple[str, ...]) -> tuple[Member, ...]:
    uid = row["uid"]
    found = []
    for name in outputs:
        path, size, sha = output_columns(name)
        ext = os.path.splitext(row[path])[1]
        found.append(Member(f"{uid}.{name}{ext}", row[path], int(row[size]), row[sha]))
    data = _row_json(row)
    found.append(Member(f"{uid}.json", None, len(data), hashlib.sha256(data).hexdigest(), data))
    return tuple(found)


def plan_shards(table, outputs: tuple[str, ...], shard_size: int) -> list[Shard]:
    """The shards of ``table``'s rows (manifest order within each split), each at most ``shard_size`` bytes."""
    rows = with_uids(table).to_pylist()
    shards: list[Shard] = []
    for split in SPLITS:
        current: list[tuple[str, tuple[Member, ...]]] = []
        sizes: list[int] = []
        count = 0

        def close() -> None:
            nonlocal count
            if current:
                shards.append(Shard(f"{split}/{split}-{count:06d}.tar", split, tuple(current)))
                count += 1

        for row in (r for r in rows if r["split"] == split):
            members = _members(row, outputs)
            if current and tar_bytes(sizes + [m.size for m in members]) > shard_size:
                close()
                current, sizes = [], []
            current.append((row["uid"], members))
            sizes.extend(m.size for m in members)
        close()
    return shards


def plan_digest(source: str, query: dict, outputs, shard_size: int, shards: list[Shard]) -> str:
    """What pins the shards' bytes: source, selection, outputs, bound and every member's name and sha256."""
    spec = {"source": source, "query": query, "outputs": list(outputs), "shard_size": shard_size,
            "shards": [[s.name, [[m.name, m.size, m.sha256] for _, ms in s.samples for m in ms]] for s in shards]}
    return hashlib.sha256(json.dumps(spec, sort_keys=True).encode()).hexdigest()


# ------------------------------------------------------------- writing ----
def _tar_info(member: Member) -> tarfile.TarInfo:
    info = tarfile.TarInfo(member.name)
    info.size, info.mtime, info.mode = member.size, 0, 0o644
    info.uid = info.gid = 0
    info.uname = info.gname = ""
    return info


def shard_bytes(source, shard: Shard, pool: ThreadPoolExecutor) -> tuple[memoryview, list[int]]:
    """The tar of ``shard`` (files read through ``source``, checked) and each sample's byte offset."""
    members = [m for _, ms in shard.samples for m in ms]
    datas = pool.map(lambda m: m.data if m.rel is None else source.read_bytes(m.rel), members)
    out = io.BytesIO()
    offsets = []
    with tarfile.open(fileobj=out, mode="w", format=tarfile.USTAR_FORMAT) as tar:
        it = iter(datas)
        for _, sample in shard.samples:
            offsets.append(out.tell())
            for member in sample:
                tar.addfile(_tar_info(member), io.BytesIO(next(it)))
    data = out.getbuffer()  # no copy: a shard is held once, beside the files it was made of
    if len(data) != shard.size:  # the plan's bound rests on this
        raise AssertionError(f"{shard.name}: wrote {len(data)} bytes, planned {shard.size}")
    return data, offsets


def _done(target, shard: Shard, plan: str) -> dict | None:
    """The stats of ``shard`` if it was written under ``plan`` and its tar still matches them, else None."""
    try:
        stats = json.loads(target.read_bytes(shard.stats))
        if stats.get("plan") != plan or target.size(shard.name) != stats["bytes"]:
            return None
        return stats if sha256_bytes(target.read_bytes(shard.name)) == stats["sha256"] else None
    except (FileNotFoundError, ValueError, KeyError, TypeError, AttributeError):
        return None


# -------------------------------------------------------------- target ----
def _ours(plan: dict) -> set[str]:
    """Every file an export of ``plan`` (a webdataset.json) writes."""
    names = {PLAN, SHARDS_INDEX, FRAMES_INDEX, MARKER}
    for name in plan.get("shards", []):
        names.add(name)
        names.add(f"{STATS}/{os.path.basename(name)[:-4]}.json")
    return names


def _check_local(path: str, source) -> None:
    if os.path.islink(path):
        raise RootError(f"export target {path} is a symlink; give a real directory (symlinks are never followed)")
    if os.path.lexists(path) and not os.path.isdir(path):
        raise ValueError(f"export target {path} exists and is not a directory")
    real = os.path.realpath(path)
    outer = enclosing_root(real)
    if outer is not None or (os.path.isdir(real) and is_our_root(Storage.from_uri(real))):
        raise RootError(f"export target {path} is or is inside the output root {outer or path}; export outside any output root")
    if source.is_local:
        src = os.path.realpath(source.path())
        if os.path.commonpath([src, real]) in (src, real):
            raise ValueError(f"export target {path} must not be the source root {source.uri}, inside it or contain it")


def _prepare_target(target, plan: dict, force: bool) -> str:
    """Check the target and clear what must go; returns "fresh", "resume" or "replace"."""
    listed = target.walk()
    if not listed:
        return "fresh"
    links = [entry.rel for entry in listed if entry.link]
    if links:
        raise RootError(f"export target {target.uri} holds the symlink {links[0]}; symlinks are never followed, "
                        "choose an empty or new directory")
    try:
        old = json.loads(target.read_bytes(PLAN))
        if not isinstance(old, dict) or old.get("format") != "webdataset":
            raise ValueError
    except (FileNotFoundError, ValueError):
        old = None
    if old is None:
        if not target.is_local:
            raise RootError(f"export target {target.uri} is not empty and holds no webdataset export of ours "
                            f"(no {PLAN}); choose an empty prefix")
        check_export_target(target.path(), force)  # another format's finished export, replaced only with --force
        for name in target.entries():
            full = target.path(name)
            shutil.rmtree(full) if os.path.isdir(full) and not os.path.islink(full) else os.unlink(full)
        return "replace"
    foreign = sorted({entry.rel for entry in listed} - _ours(old))
    if foreign:
        raise RootError(f"export target {target.uri} holds {foreign[0]}, which no export wrote; "
                        "--force deletes only an export's own files; choose an empty or new directory")
    if old.get("plan") == plan["plan"]:
        return "resume"
    if not force:
        raise ValueError(f"export target {target.uri} holds a webdataset export of another selection, root or "
                         "shard size; pass --force to replace it")
    for entry in listed:
        target.delete(entry.rel)
    return "replace"


# -------------------------------------------------------------- export ----
def export_webdataset(config):
    """Write the WebDataset shards of ``config`` (an ``exports.export.ExportConfig``); returns its ExportReport."""
    from dataclasses import replace


    config.validate()
    start = time.perf_counter()
    storage = Storage.from_uri(config.root)
    target = Storage.from_uri(config.to)
    if target.is_local:
        _check_local(target.path(), storage)
    manifest = read_manifest(storage)
    result = run_query(manifest, config.query)
    if len(result.table) == 0:
        raise ValueError(f"no frames in {storage.uri} match the query; nothing to export")
    table = result.table
    if config.as_split is not None:
        import pyarrow as pa

        table = table.set_column(table.column_names.index("split"), "split", pa.array([config.as_split] * len(table)))
    outputs = selected_outputs(table, config.outputs)
    shards = plan_shards(table, outputs, config.shard_size)
    query = asdict(config.query)
    digest = plan_digest(storage.uri, query, outputs, config.shard_size, shards)
    plan = {"format": "webdataset", "plan": digest, "source": storage.uri, "query": query, "outputs": list(outputs),
            "shard_size": config.shard_size, "as_split": config.as_split, "shards": [s.name for s in shards]}
    state = _prepare_target(target, plan, config.force)
    if target.is_local:
        for folder in sorted({os.path.dirname(s.name) for s in shards} | {STATS}):
            target.remove_stale_temp(folder)  # a killed write's temp file
    target.write_bytes(PLAN, (json.dumps(plan, indent=1, sort_keys=True) + "\n").encode())

    source = CheckedSource(storage, listed_files(table))
    index, frames_rows, resumed = [], [], 0
    with ThreadPoolExecutor(max_workers=config.threads) as pool:
        for shard in shards:
            stats = _done(target, shard, digest) if state == "resume" else None
            if stats is None:
                data, offsets = shard_bytes(source, shard, pool)
                target.write_bytes(shard.name, data)
                stats = {"plan": digest, "name": shard.name, "split": shard.split, "bytes": len(data),
                         "sha256": sha256_bytes(data), "frames": [uid for uid, _ in shard.samples], "offsets": offsets}
                target.write_bytes(shard.stats, (json.dumps(stats, sort_keys=True) + "\n").encode())
                log.info("wrote %s (%d frames, %d bytes)", shard.name, len(shard.samples), len(data))
            else:
                resumed += 1
            index.append({k: stats[k] for k in ("name", "split", "bytes", "sha256")} | {"frames": len(shard.samples)})
            frames_rows.extend((uid, shard.name, off) for uid, off in zip(stats["frames"], stats["offsets"]))

    meta = {r["uid"]: r for r in with_uids(table).select(
        ["uid", "frame_id", "scenario", "episode", "frame", "split"]).to_pylist()}
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(["uid", "frame_id", "scenario", "episode", "frame", "split", "shard", "offset"])
    for uid, name, offset in frames_rows:
        m = meta[uid]
        writer.writerow([uid, m["frame_id"], m["scenario"], m["episode"], m["frame"], m["split"], name, offset])
    target.write_bytes(FRAMES_INDEX, out.getvalue().encode())
    target.write_bytes(SHARDS_INDEX, (json.dumps(index, indent=1) + "\n").encode())
    # a sample per sensor frame (manifest row); the marker and the report count frames, as the other formats'
    # do, and in a rig's root say the sensor frames (samples) beside them
    frames = {(r["scenario"], r["episode"], r["frame"], r["split"]) for r in meta.values()}
    per_split = {s: sum(1 for f in frames if f[3] == s) for s in SPLITS}
    per_scenario: dict[str, int] = {}
    for f in frames:
        per_scenario[f[0]] = per_scenario.get(f[0], 0) + 1
    files = 2 * len(shards) + 4
    marker = {"format": "webdataset", "source": storage.uri, "query": query, "frames": len(frames), "files": files,
              "per_split": per_split, "per_scenario": per_scenario, "as_split": config.as_split, "plan": digest,
              "outputs": list(outputs), "shards": len(shards), "shard_size": config.shard_size}
    if len(meta) != len(frames):
        marker["sensor_frames"] = len(meta)
    if target.is_local:
        marker["tree"] = export_tree(target.path())  # what --force of any export may delete later
    target.write_bytes(MARKER, (json.dumps(marker, indent=2, sort_keys=True) + "\n").encode())
    return replace(ExportReport(
        target=target.uri, format="webdataset", frames=len(frames), held=count_frames(manifest), files=files,
        per_split=per_split, shortfall=dict(result.shortfall), seconds=time.perf_counter() - start,
    ), resumed=resumed, sensor_frames=len(meta), held_sensor_frames=len(manifest))


LAYOUT = Layout(outputs=(), build=None, run=export_webdataset)  # every output is optional: --outputs picks
