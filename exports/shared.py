"""What every export format shares: the frames it exports, how files are
placed into the target, the decoders and the PNG encoder, and the per-frame
builder. A format module (``cityscapes``, ``idda``, ``coco``, ``hf``) adds only
its own layout; ``exports.export`` runs any of them through one registry.
"""

from __future__ import annotations

import csv
import errno
import io
import json
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Callable, Mapping

import numpy as np
import pyarrow as pa

from manifests.schema import output_columns, with_uids
from outputs.table import OUTPUTS, file_of_path, read_output
from storage import sha256_bytes


# ------------------------------------------------------------ the frames ----
_META = ("frame_id", "uid", "scenario", "episode", "frame", "split", "width", "height", "K", "cam_to_world",
         "cam_to_ego")


@dataclass(frozen=True)
class ExportFrame:
    """One manifest row as an export needs it: identity, split, size, and the
    root-relative file of every output the root holds (None where it has not)."""

    frame_id: str
    uid: str  # unique in the root (manifests.schema.frame_uid)
    scenario: str
    episode: int
    frame: int
    split: str
    width: int
    height: int
    K: list | None  # row-major 3x3 intrinsics (docs/conventions.md); None in roots written before it
    cam_to_world: list | None  # row-major 4x4, OpenCV camera axes
    cam_to_ego: list | None  # row-major 4x4, OpenCV camera axes -> ego (x forward, y left, z up)
    paths: Mapping[str, str | None]

    def path(self, output: str) -> str | None:
        """The frame's file of ``output`` (a name of the output table), None if the root lacks it."""
        if output not in OUTPUTS:
            raise ValueError(f"unknown output {output!r}; valid outputs: {', '.join(OUTPUTS)}")
        return self.paths.get(output)


def frames_of(table: pa.Table) -> list[ExportFrame]:
    """The export frames of a manifest table, in its row order. ValueError for the frames of several
    sensors of a rig: the layouts name files per frame, so one sensor's would overwrite another's."""
    sensors = sorted(set(table.column("sensor").to_pylist()) - {None}) if "sensor" in table.column_names else []
    if len(sensors) > 1:
        raise ValueError(f"these frames are seen by the sensors {', '.join(sensors)} of the root's rig; an export "
                         "names its files per frame, so export one sensor at a time (--sensor NAME)")
    table = with_uids(table)
    meta = {name: table.column(name).to_pylist() for name in _META}
    paths = {o: table.column(output_columns(o)[0]).to_pylist()
             for o in OUTPUTS if output_columns(o)[0] in table.column_names}
    return [ExportFrame(**{name: meta[name][i] for name in _META}, paths={o: p[i] for o, p in paths.items()})
            for i in range(len(table))]


# --------------------------------------------------------- checked reads ----
class DamagedFile(ValueError):
    """A root file whose bytes are not those its manifest row lists (size or sha256)."""

    exit_code = 1  # damaged data

    def __init__(self, source: str, rel: str, detail: str) -> None:
        super().__init__(
            f"{source}: {rel} is damaged ({detail}); exported nothing: `idda verify` lists the damage, "
            "`idda produce --repair` mends it, or export the rest with --skip-damaged")
        self.rel = rel


class CheckedSource:
    """The source root as an export reads it: every file read is checked against the
    size and sha256 its manifest row lists, as it is read (no extra read). A damaged
    file is recorded in ``damaged`` and raises DamagedFile. Anything else is the storage's own."""

    def __init__(self, storage, expected: Mapping[str, tuple[int, str]]) -> None:
        self._storage, self._expected = storage, expected
        self.damaged: set[str] = set()

    def __getattr__(self, name):
        return getattr(self._storage, name)

    def read_bytes(self, rel: str) -> bytes:
        data = self._storage.read_bytes(rel)
        size, sha = self._expected.get(rel, (None, None))
        if sha is not None and (len(data) != size or sha256_bytes(data) != sha):
            detail = f"{len(data)} bytes, the manifest lists {size}" if len(data) != size else "its sha256 differs from the manifest's"
            self.damaged.add(rel)
            raise DamagedFile(self._storage.uri, rel, detail)
        return data

    def check(self, rel: str) -> None:
        """Read and check ``rel`` (a file placed by a link, which is otherwise never read)."""
        self.read_bytes(rel)


# ------------------------------------------------------------ file modes ----
_NO_LINK = {errno.EPERM, errno.EXDEV, errno.EMLINK, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EACCES}


def _place_copy(storage, rel: str, dest: str) -> None:
    write(dest, storage.read_bytes(rel))  # read once: checked as it is copied (CheckedSource)


def _place_hardlink(storage, rel: str, dest: str) -> None:
    if not storage.is_local:
        return _place_copy(storage, rel, dest)
    storage.check(rel)
    try:
        os.link(storage.path(rel), dest)
    except OSError as exc:
        if exc.errno not in _NO_LINK:
            raise
        _place_copy(storage, rel, dest)  # another file system: copy instead


def _place_symlink(storage, rel: str, dest: str) -> None:
    if not storage.is_local:
        return _place_copy(storage, rel, dest)
    storage.check(rel)
    os.symlink(storage.path(rel), dest)


FILE_MODES: dict[str, Callable[[object, str, str], None]] = {
    "hardlink": _place_hardlink,
    "symlink": _place_symlink,
    "copy": _place_copy,
}


# ---------------------------------------------------------------- images ----
def png(image: np.ndarray) -> bytes:
    """Lossless PNG of an HxW (uint8 or uint16), HxWx3 RGB or HxWx4 RGBA uint8 array."""
    import cv2

    if image.ndim == 3:
        to_bgr = cv2.COLOR_RGBA2BGRA if image.shape[2] == 4 else cv2.COLOR_RGB2BGR
        image = cv2.cvtColor(np.ascontiguousarray(image), to_bgr)
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(image), [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:
        raise ValueError(f"PNG encoding failed for an array of shape {image.shape}")
    return buf.tobytes()


def decode(storage, rel: str, output: str = "semantic_raw") -> np.ndarray:
    """A root file decoded as the output table's loader decodes ``output``."""
    return read_output(output, storage.read_bytes(rel), storage.join(rel))


def is_jpeg(rel: str) -> bool:
    """Whether a root's rgb file is a JPEG (``--rgb-format jpg``)."""
    return file_of_path("rgb", rel) == "jpg"


# ------------------------------------------------------------ the files -----
def write(path: str, data: bytes) -> None:
    with open(path, "wb") as f:
        f.write(data)


def write_json(tmp: str, rel: str, body) -> str:
    """``body`` as indented JSON at ``tmp/rel``; returns ``rel``."""
    os.makedirs(os.path.dirname(os.path.join(tmp, rel)), exist_ok=True)
    write(os.path.join(tmp, rel), (json.dumps(body, indent=1, sort_keys=True) + "\n").encode())
    return rel


def index_csv(frames: list[ExportFrame], exported: list[dict[str, str]]) -> bytes:
    """frames.csv: one row per frame, its source identity and the files it became."""
    kinds = list(exported[0]) if exported else []
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(["frame_id", "scenario", "episode", "frame", "split", "uid", *kinds])
    for f, paths in zip(frames, exported):
        writer.writerow([f.frame_id, f.scenario, f.episode, f.frame, f.split, f.uid, *(paths[k] for k in kinds)])
    return buf.getvalue().encode()


def no_extras(frames: list[ExportFrame], tmp: str, config) -> list[str]:
    return []


# A layout builder: (storage, frames, tmp dir, config) -> ([{kind: exported rel path}] per frame, [per-export files])
Builder = Callable[[object, list, str, object], tuple[list[dict], list[str]]]


def per_frame(frame: Callable, directories: Callable, extras: Callable = no_extras) -> Builder:
    """A layout builder that writes each frame's files (in parallel), then the per-export files."""

    def build(storage, frames: list[ExportFrame], tmp: str, config):
        for rel in sorted(directories(frames)):
            os.makedirs(os.path.join(tmp, rel), exist_ok=True)
        place = FILE_MODES[config.files]

        def one(f: ExportFrame) -> dict | None:
            try:
                return frame(storage, f, tmp, place)
            except DamagedFile:  # recorded by the source; with --skip-damaged the rest go on
                if not getattr(config, "skip_damaged", False):
                    raise
                return None

        with ThreadPoolExecutor(max_workers=config.threads) as pool:
            exported = list(pool.map(one, frames))
        return exported, extras(frames, tmp, config)

    return build


@dataclass(frozen=True)
class Layout:
    """An export format: the outputs it reads and the builder that writes it."""

    outputs: tuple[str, ...]  # outputs the root must hold (a format may also use others when present)
    build: Builder | None  # None for a format with ``run``
    # a format that writes its target itself (webdataset: in place, resumable, local or s3): the whole export,
    # ExportConfig -> ExportReport; None for the others, which ``exports.export.export`` builds in a temp folder
    run: Callable | None = None


@dataclass
class ExportReport:
    target: str
    format: str
    frames: int  # frames exported (a rig's root: of the same instant, distinct (scenario, episode, frame))
    held: int  # frames the root holds (the query chose ``frames`` of them)
    files: int
    per_split: dict[str, int]
    shortfall: dict[str, int]
    seconds: float
    damaged: list[str] = field(default_factory=list)  # files found damaged (--skip-damaged: their frames left out)
    skipped: int = 0  # frames left out for them
    resumed: int = 0  # webdataset: shards an interrupted export had written and verified, kept
    sensor_frames: int = 0  # manifest rows exported: ``frames`` but in a rig's root, a row per sensor of each
    held_sensor_frames: int = 0  # manifest rows the root holds: ``held`` but in a rig's root


def listed_files(table) -> dict[str, tuple[int, str]]:
    """Every file the manifest rows of ``table`` list: {path: (bytes, sha256)}."""
    listed = {}
    for name in OUTPUTS:
        path, size, sha = output_columns(name)
        if path in table.column_names:
            rows = zip(*(table.column(c).to_pylist() for c in (path, size, sha)))
            listed.update((p, (n, h)) for p, n, h in rows if p is not None)
    return listed
