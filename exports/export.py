"""Export a query's frames into layouts that existing training code reads.

One module per format, each a ``Layout`` (the outputs it reads and its
builder); ``FORMATS`` names them, so a new format is one module plus one line
there:

* ``cityscapes`` (``exports.cityscapes``): leftImg8bit/ + gtFine/ as
  cityscapesScripts and Cityscapes loaders expect;
* ``idda`` (``exports.idda``): the published IDDA layout and its split files
  (or FedDrive's federated splits);
* ``coco`` (``exports.coco``): images and COCO instance annotations (RLE masks
  and boxes); needs the ``instance`` and ``objects`` outputs;
* ``hf`` (``exports.hf``): Parquet shards with embedded images and a card;
* ``webdataset`` (``exports.webdataset``): tar shards of bounded size, local or
  s3://, written in place and resumable (its ``Layout.run`` replaces the flow
  below).

What they share (the frames, file placing, decoders) is ``exports.shared``.
Every layout also gets ``frames.csv`` (one row per frame: source frame id,
scenario, split and the exported paths) and, written last, ``EXPORT.json``
(format, source root, query, counts): an export without it is unfinished.

Files are never re-rendered. Unchanged images are hard-linked into the
target (falling back to a copy across file systems), symlinked, or copied;
s3:// roots are always downloaded. The export is built in a hidden temp
directory next to the target and renamed into place when complete, so a
half-finished export is never mistaken for a finished one.
"""

from __future__ import annotations

import json
import logging
import os
import re
import shutil
import socket
import time
import uuid
from dataclasses import asdict, dataclass, field, replace

from domains.selection import parse_selection
from exports import cityscapes, coco, hf, idda, webdataset
from exports.idda import SPLIT_FILES
from exports.shared import (
    FILE_MODES, CheckedSource, DamagedFile, ExportReport, Layout, frames_of, index_csv, listed_files, write,
)
from exports.webdataset import MIN_SHARD_SIZE, SHARD_SIZE
from manifests.query import SPLITS, Query, count_frames, run_query
from manifests.reader import read_manifest, require_outputs
from outputs.table import check_outputs
from roots.contract import EXPORT_MARKER, RootError, check_export_target, export_tree
from storage import Storage
from storage.atomic import sync_dir

log = logging.getLogger(__name__)

MARKER = EXPORT_MARKER  # written last: its presence means the export is complete
INDEX = "frames.csv"

# Export formats by name: the module whose LAYOUT writes each (a format's optional dependency, e.g.
# pycocotools, is imported by its module only when it writes).
FORMATS = {"cityscapes": cityscapes, "idda": idda, "hf": hf, "coco": coco, "webdataset": webdataset}


def layout(name: str) -> Layout:
    """The layout of export format ``name``; ValueError naming the valid formats."""
    if name not in FORMATS:
        raise ValueError(f"unknown export format {name!r}; valid formats: {', '.join(FORMATS)}")
    return FORMATS[name].LAYOUT


# ---------------------------------------------------------------- export ----
@dataclass(frozen=True)
class ExportConfig:
    root: str  # source output root: local path or s3:// URI
    to: str  # target directory (local)
    format: str = "cityscapes"  # a key of FORMATS
    query: Query = field(default_factory=Query)
    files: str = "hardlink"  # a key of FILE_MODES; s3 sources are always copied
    force: bool = False  # replace a non-empty target
    threads: int = 8  # frames converted in parallel
    as_split: str | None = None  # put every exported frame in this split
    splits: str = "scenario"  # idda layout: a key of exports.idda.SPLIT_FILES
    holdout: str | None = None  # feddrive splits: domains for test_user_diff_domain
    skip_damaged: bool = False  # leave out frames with a damaged file (counted) instead of refusing
    outputs: tuple[str, ...] | None = None  # webdataset: the outputs written per frame (None: all the rows hold)
    shard_size: int = SHARD_SIZE  # webdataset: the most bytes a shard holds

    def validate(self) -> None:
        if self.format not in FORMATS:
            raise ValueError(f"unknown export format {self.format!r}; valid formats: {', '.join(FORMATS)}")
        if self.as_split is not None and self.as_split not in SPLITS:
            raise ValueError(f"unknown split {self.as_split!r}; valid splits: {', '.join(SPLITS)}")
        if self.splits not in SPLIT_FILES:
            raise ValueError(f"unknown split files {self.splits!r}; valid: {', '.join(SPLIT_FILES)}")
        if self.splits != "scenario" and self.format != "idda":
            raise ValueError(f"split files {self.splits!r} are for the idda format, not {self.format!r}")
        if self.holdout is not None:
            if self.splits != "feddrive":
                raise ValueError("a holdout selection needs --splits feddrive")
            parse_selection(self.holdout)
        if self.files not in FILE_MODES:
            raise ValueError(f"unknown file mode {self.files!r}; valid modes: {', '.join(FILE_MODES)}")
        webdataset = self.format == "webdataset"
        if "://" in self.to and not self.to.startswith("file://") and not (webdataset and self.to.startswith("s3://")):
            raise ValueError(f"export target must be a local directory (or s3:// for webdataset), got {self.to}")
        if not webdataset and (self.outputs is not None or self.shard_size != SHARD_SIZE):
            raise ValueError(f"--outputs and --shard-size are for the webdataset format, not {self.format!r}")
        if webdataset:
            if self.outputs is not None:
                check_outputs(self.outputs)
            if self.shard_size < MIN_SHARD_SIZE:
                raise ValueError(f"shard size must be at least {MIN_SHARD_SIZE:,} bytes, got {self.shard_size:,}")
            if self.skip_damaged:
                raise ValueError("--skip-damaged is not available for webdataset (its shards are planned before "
                                 "reading); `idda produce --repair` mends the root")
        if self.threads < 1:
            raise ValueError(f"threads must be at least 1, got {self.threads}")
        self.query.validate()


def _target_dir(to: str) -> str:
    storage = Storage.from_uri(to)
    return storage.path()


def _is_within(path: str, directory: str) -> bool:
    path, directory = os.path.realpath(path), os.path.realpath(directory)
    return os.path.commonpath([path, directory]) == directory


# Our temp folders beside a target: ".<target name>.idda-export.<host>.<pid>.<uuid>.tmp" (the export being
# built) and "....old" (the export it replaces, between the two renames). The owner in the name tells a
# leftover of a killed export (same host, process gone) from the folder of an export still running.
_TEMP_TAG = "idda-export"


def _temp_dir(target: str, kind: str) -> str:
    name = f".{os.path.basename(target)}.{_TEMP_TAG}.{socket.gethostname()}.{os.getpid()}.{uuid.uuid4().hex}.{kind}"
    return os.path.join(os.path.dirname(target), name)


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process: alive
        return True
    return True


def _leftovers(target: str) -> list[tuple[str, str]]:
    """(path, "tmp" or "old") of our temp folders beside ``target`` whose export was killed:
    made on this host by a process that no longer runs. Never a folder of a live export or another host's."""
    parent, base = os.path.split(target)
    pattern = re.compile(
        rf"^\.{re.escape(base)}\.{_TEMP_TAG}\.(?P<host>.+)\.(?P<pid>\d+)\.[0-9a-f]{{32}}\.(?P<kind>tmp|old)$"
    )
    found = []
    try:
        names = sorted(os.listdir(parent))
    except FileNotFoundError:
        return []
    for name in names:
        match = pattern.match(name)
        path = os.path.join(parent, name)
        if (match is None or os.path.islink(path) or not os.path.isdir(path)
                or match["host"] != socket.gethostname() or _pid_alive(int(match["pid"]))):
            continue
        found.append((path, match["kind"]))
    return found


def clean_leftovers(target: str) -> list[str]:
    """Remove what killed exports to ``target`` left beside it; returns the paths handled.

    A ``.tmp`` (an export never finished) is deleted. A ``.old`` is the
    finished export an export was replacing when it was killed between its
    two renames: put back as ``target`` when nothing is there (so it is not
    lost), else deleted (the replacement is in place)."""
    handled = []
    for path, kind in _leftovers(target):
        if kind == "old" and not os.path.lexists(target) and os.path.isfile(os.path.join(path, MARKER)):
            os.rename(path, target)
            log.warning("put back %s: an export killed while replacing it had moved it to %s", target, path)
        else:
            shutil.rmtree(path)
            log.info("removed %s, left by a killed export", path)
        handled.append(path)
    return handled


def _commit(tmp: str, target: str, tree: dict | None) -> None:
    """Move the finished temp directory to ``target``, replacing what is there.

    ``tree`` is what check_export_target found the replaced export to hold;
    it is checked again once that export is moved aside (nothing can be added
    to it after that), and it is moved back if anything changed meanwhile."""
    if os.path.isdir(target) and os.listdir(target):
        old = _temp_dir(target, "old")
        os.rename(target, old)
        found = export_tree(old)
        if tree is None or found["sha256"] != tree["sha256"]:
            os.rename(old, target)
            raise RootError(f"export target {target} changed while exporting; nothing was replaced")
        os.rename(tmp, target)
        sync_dir(os.path.dirname(os.path.abspath(target)))  # the commit on disk before the old export goes
        shutil.rmtree(old)  # never follows symlinks: an export's links are removed, not their targets
    else:
        os.replace(tmp, target)  # an empty directory is replaced atomically
        sync_dir(os.path.dirname(os.path.abspath(target)))


def export(config: ExportConfig) -> ExportReport:
    """Export the frames of ``config.query`` from ``config.root`` into ``config.to``."""
    config.validate()
    if layout(config.format).run is not None:  # a format that writes its target itself
        return layout(config.format).run(config)
    start = time.perf_counter()
    storage = Storage.from_uri(config.root)
    target = _target_dir(config.to)
    clean_leftovers(target)  # of exports killed before they finished
    check_export_target(target, config.force)  # never inside or over an output root, never foreign files
    replaced = export_tree(target) if os.path.isdir(target) and os.listdir(target) else None
    if storage.is_local and _is_within(storage.path(), target):
        raise ValueError(f"export target {target} must not be the source root {storage.uri} or contain it")
    manifest = read_manifest(storage)
    result = run_query(manifest, config.query)
    if len(result.table) == 0:
        raise ValueError(f"no frames in {storage.uri} match the query; nothing to export")
    chosen = layout(config.format)
    require_outputs(result.table, chosen.outputs, f"{storage.uri} ({config.format} export)")
    frames = frames_of(result.table)
    if config.as_split is not None:
        frames = [replace(f, split=config.as_split) for f in frames]

    expected = listed_files(result.table)
    parent = os.path.dirname(target)
    os.makedirs(parent, exist_ok=True)
    tmp = _temp_dir(target, "tmp")
    os.makedirs(tmp)
    damaged: set[str] = set()
    asked = len(frames)
    try:
        while True:  # each file checked as it is read; --skip-damaged builds again without the frames found damaged
            source = CheckedSource(storage, expected)
            try:
                exported, extras = chosen.build(source, frames, tmp, config)
            except DamagedFile:
                if not config.skip_damaged:
                    raise
            if not source.damaged:
                break
            damaged |= source.damaged
            frames = [f for f in frames if not damaged & set(f.paths.values())]
            if not frames:
                raise DamagedFile(storage.uri, min(damaged), f"as are files of every other frame chosen: {len(damaged)} damaged")
            shutil.rmtree(tmp)
            os.makedirs(tmp)
        write(os.path.join(tmp, INDEX), index_csv(frames, exported))
        per_split = {s: sum(f.split == s for f in frames) for s in SPLITS}
        per_scenario: dict[str, int] = {}
        for f in frames:
            per_scenario[f.scenario] = per_scenario.get(f.scenario, 0) + 1
        files = sum(len(paths) for paths in exported) + len(extras) + 2
        marker = {
            "format": config.format,
            "source": storage.uri,
            "query": asdict(config.query),
            "frames": len(frames),
            "files": files,
            "file_mode": config.files if storage.is_local else "copy",
            "per_split": per_split,
            "per_scenario": per_scenario,
            "as_split": config.as_split,
            "tree": export_tree(tmp),  # what --force may delete later, and nothing else
        }
        write(os.path.join(tmp, MARKER), (json.dumps(marker, indent=2, sort_keys=True) + "\n").encode())
        _commit(tmp, target, replaced)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return ExportReport(
        target=target,
        format=config.format,
        frames=len(frames),  # of one sensor (frames_of)
        held=count_frames(manifest),
        files=files,
        per_split=per_split,
        shortfall=dict(result.shortfall),
        seconds=time.perf_counter() - start,
        damaged=sorted(damaged),
        skipped=asked - len(frames),
        sensor_frames=len(frames),
        held_sensor_frames=len(manifest),
    )


def is_complete(target: str) -> bool:
    """True if ``target`` holds a finished export (its marker exists)."""
    return os.path.isfile(os.path.join(target, MARKER))
