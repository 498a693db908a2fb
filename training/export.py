"""Export a query's frames into layouts that existing training code reads.

Two layouts, chosen by name (see ``LAYOUTS``):

* ``cityscapes``: what cityscapesScripts and Cityscapes data loaders expect::

      leftImg8bit/<split>/<scenario>/<name>_leftImg8bit.png       the rgb (linked; from a root made with
                                                                  --rgb-format jpg: the JPEG's pixels as a PNG)
      gtFine/<split>/<scenario>/<name>_gtFine_labelIds.png        Cityscapes label ids
      gtFine/<split>/<scenario>/<name>_gtFine_labelTrainIds.png   trainIds, 255 = ignore
      gtFine/<split>/<scenario>/<name>_gtFine_color.png           Cityscapes colours
      gtFine/<split>/<scenario>/<name>_gtFine_instanceIds.png     instances (16 bit)

  ``<name>`` is ``<city>_<episode:06d>_<frame:06d>`` with ``<city>`` the
  scenario code with ``-`` for ``_`` (``T01-CS-A``): cityscapesScripts splits
  file names at ``_`` into city, sequence and frame, and finds a prediction
  for a ground-truth file by the pattern ``<city>_<seq>_<frame>*.png``. The
  instance image holds, as Cityscapes does, ``label id * 1000 + index`` on the
  objects of Cityscapes' instance classes (person, rider, car, motorcycle,
  bicycle; index counts the frame's objects of that class from 0, in instance
  id order) and the label id elsewhere (the hood too). A root produced
  without the ``instance`` output gets label ids only. Excluded IDDA classes
  map to Cityscapes ids that the evaluation ignores.

* ``idda``: the published IDDA layout::

      <scenario>/RGB/<frameid>_<scenario>.jpg        the rgb as JPEG, quality 95 (linked from a
                                                     root made with --rgb-format jpg)
      <scenario>/Semantic/<frameid>_<scenario>.png   the semantic_raw image (linked)
      train.json, val.json, test.json                {scenario: [frame ids]} per split

  IDDA's own split files are not documented in the paper; we write one JSON
  object per split mapping each exported scenario to its sorted frame ids
  (every split file lists every exported scenario, possibly with ``[]``).

* ``coco``: images and COCO instance annotations (RLE masks and boxes), see
  ``training.coco``; needs the ``instance`` and ``objects`` outputs.

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

import csv
import errno
import io
import json
import os
import shutil
import time
import uuid
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field, replace
from typing import Callable

import numpy as np
import pyarrow as pa

from manifests.catalog import CITYSCAPES_ID_LUT, LABELS, TRAIN_ID_LUT
from manifests.encoding import decode_png16, encode_jpeg
from manifests.outputs import file_of_path, read_output
from manifests.query import SPLITS, Query, run_query
from manifests.objects import HOOD_ID
from manifests.reader import require_outputs
from manifests.root import EXPORT_MARKER, check_export_target

MARKER = EXPORT_MARKER  # written last: its presence means the export is complete
INDEX = "frames.csv"

# Cityscapes label ids and colours (cityscapesScripts helpers/labels.py) for
# the ids the catalog maps to; the gtFine colour image derives from this.
CITYSCAPES_COLORS: dict[int, tuple[int, int, int]] = {
    0: (0, 0, 0),  # unlabeled
    4: (0, 0, 0),  # static
    5: (111, 74, 0),  # dynamic
    6: (81, 0, 81),  # ground
    7: (128, 64, 128),  # road
    8: (244, 35, 232),  # sidewalk
    10: (230, 150, 140),  # rail track
    11: (70, 70, 70),  # building
    12: (102, 102, 156),  # wall
    13: (190, 153, 153),  # fence
    14: (180, 165, 180),  # guard rail
    17: (153, 153, 153),  # pole
    19: (250, 170, 30),  # traffic light
    20: (220, 220, 0),  # traffic sign
    21: (107, 142, 35),  # vegetation
    22: (152, 251, 152),  # terrain
    23: (70, 130, 180),  # sky
    24: (220, 20, 60),  # person
    25: (255, 0, 0),  # rider
    26: (0, 0, 142),  # car
    32: (0, 0, 230),  # motorcycle
    33: (119, 11, 32),  # bicycle
}
_missing = sorted({label.cityscapes_id for label in LABELS} - set(CITYSCAPES_COLORS))
if _missing:
    raise RuntimeError(f"no Cityscapes colour for label ids {_missing}")
# IDDA class id -> colour of its Cityscapes label (256 entries, unknown ids black).
# RGBA with opaque alpha: Cityscapes' colour images are RGBA PNGs.
CITYSCAPES_COLOR_LUT = np.full((256, 4), 255, dtype=np.uint8)
CITYSCAPES_COLOR_LUT[: len(CITYSCAPES_ID_LUT), :3] = [CITYSCAPES_COLORS.get(int(i), (0, 0, 0)) for i in CITYSCAPES_ID_LUT]


# ------------------------------------------------------------ file modes ----
_NO_LINK = {errno.EPERM, errno.EXDEV, errno.EMLINK, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EACCES}


def _place_copy(storage, rel: str, dest: str) -> None:
    if storage.is_local:
        shutil.copyfile(storage.path(rel), dest)
    else:
        with open(dest, "wb") as f:
            f.write(storage.read_bytes(rel))


def _place_hardlink(storage, rel: str, dest: str) -> None:
    if not storage.is_local:
        return _place_copy(storage, rel, dest)
    try:
        os.link(storage.path(rel), dest)
    except OSError as exc:
        if exc.errno not in _NO_LINK:
            raise
        _place_copy(storage, rel, dest)  # another file system: copy instead


def _place_symlink(storage, rel: str, dest: str) -> None:
    if not storage.is_local:
        return _place_copy(storage, rel, dest)
    os.symlink(storage.path(rel), dest)


FILE_MODES: dict[str, Callable[[object, str, str], None]] = {
    "hardlink": _place_hardlink,
    "symlink": _place_symlink,
    "copy": _place_copy,
}


# ---------------------------------------------------------------- images ----
def _png(image: np.ndarray) -> bytes:
    """Lossless PNG of an HxW (uint8 or uint16), HxWx3 RGB or HxWx4 RGBA uint8 array."""
    import cv2

    if image.ndim == 3:
        to_bgr = cv2.COLOR_RGBA2BGRA if image.shape[2] == 4 else cv2.COLOR_RGB2BGR
        image = cv2.cvtColor(np.ascontiguousarray(image), to_bgr)
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(image), [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:
        raise ValueError(f"PNG encoding failed for an array of shape {image.shape}")
    return buf.tobytes()


def _decode(storage, rel: str, output: str = "semantic_raw") -> np.ndarray:
    return read_output(output, storage.read_bytes(rel), storage.join(rel))


def _is_jpeg(rel: str) -> bool:
    """Whether a root's rgb file is a JPEG (``--rgb-format jpg``)."""
    return file_of_path("rgb", rel) == "jpg"


# Cityscapes label ids with instances (helpers/labels.py hasInstances), among those the catalog maps to.
CITYSCAPES_INSTANCE_IDS = (24, 25, 26, 27, 28, 29, 30, 31, 32, 33)


def cityscapes_instance_ids(classes: np.ndarray, instance: np.ndarray | None) -> np.ndarray:
    """Cityscapes' instanceIds image: label id * 1000 + index on instance-class objects, label id elsewhere."""
    label_ids = CITYSCAPES_ID_LUT[classes]
    out = label_ids.astype(np.int32)
    if instance is None:
        return out.astype(np.uint16)
    objects = (instance > HOOD_ID) & np.isin(label_ids, CITYSCAPES_INSTANCE_IDS)
    for cs_id in np.unique(label_ids[objects]):
        ids = np.unique(instance[objects & (label_ids == cs_id)])
        for index, iid in enumerate(ids):
            out[(instance == iid) & (label_ids == cs_id)] = int(cs_id) * 1000 + index
    return out.astype(np.uint16)


def cityscapes_targets(classes: np.ndarray, instance: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """The four gtFine images of an HxW uint8 IDDA class-id image (and its instance ids)."""
    return {
        "labelIds": CITYSCAPES_ID_LUT[classes],
        "labelTrainIds": TRAIN_ID_LUT[classes],
        "color": CITYSCAPES_COLOR_LUT[classes],  # RGBA, as Cityscapes' *_gtFine_color.png
        "instanceIds": cityscapes_instance_ids(classes, instance),
    }


# --------------------------------------------------------------- layouts ----
def cityscapes_name(scenario: str, episode: int, frame: int) -> str:
    """``T01-CS-A_000003_000012``: a file stem cityscapesScripts can parse."""
    return f"{cityscapes_city(scenario)}_{episode:06d}_{frame:06d}"


@dataclass(frozen=True)
class _Frame:
    frame_id: str
    scenario: str
    episode: int
    frame: int
    split: str
    width: int
    height: int
    rgb_path: str | None
    semantic_raw_path: str | None
    depth_raw_path: str | None
    instance_path: str | None
    objects_path: str | None


def cityscapes_city(scenario: str) -> str:
    """``T01-CS-A``: the city folder, equal to the file names' city prefix."""
    return scenario.replace("_", "-")


def _cityscapes_frame(storage, frame: _Frame, tmp: str, place) -> dict[str, str]:
    name = cityscapes_name(frame.scenario, frame.episode, frame.frame)
    image_dir = f"leftImg8bit/{frame.split}/{cityscapes_city(frame.scenario)}"
    gt_dir = f"gtFine/{frame.split}/{cityscapes_city(frame.scenario)}"
    rgb_rel = f"{image_dir}/{name}_leftImg8bit.png"
    if _is_jpeg(frame.rgb_path):  # Cityscapes names PNGs: the JPEG's pixels, re-encoded losslessly
        _write(os.path.join(tmp, rgb_rel), _png(_decode(storage, frame.rgb_path, "rgb")))
    else:
        place(storage, frame.rgb_path, os.path.join(tmp, rgb_rel))
    classes = _decode(storage, frame.semantic_raw_path)[..., 0]
    instance = None
    if frame.instance_path is not None:
        instance = decode_png16(storage.read_bytes(frame.instance_path), storage.join(frame.instance_path))
    written = {"image": rgb_rel}
    for kind, array in cityscapes_targets(classes, instance).items():
        rel = f"{gt_dir}/{name}_gtFine_{kind}.png"
        _write(os.path.join(tmp, rel), _png(array))
        written[kind] = rel
    return written


def _idda_paths(frame: _Frame) -> tuple[str, str]:
    """A frame's RGB and Semantic paths in the IDDA layout (the split files list the same)."""
    stem = f"{frame.frame_id}_{frame.scenario}"
    return f"{frame.scenario}/RGB/{stem}.jpg", f"{frame.scenario}/Semantic/{stem}.png"


def _idda_frame(storage, frame: _Frame, tmp: str, place) -> dict[str, str]:
    rgb_rel, sem_rel = _idda_paths(frame)
    if _is_jpeg(frame.rgb_path):  # already IDDA's format: the file itself, not a second lossy pass
        place(storage, frame.rgb_path, os.path.join(tmp, rgb_rel))
    else:
        _write(os.path.join(tmp, rgb_rel), encode_jpeg(_decode(storage, frame.rgb_path, "rgb"), storage.join(frame.rgb_path)))
    _write(os.path.join(tmp, sem_rel), _png(_decode(storage, frame.semantic_raw_path)[..., 0]))
    return {"image": rgb_rel, "semantic": sem_rel}


def _cityscapes_dirs(frames: list[_Frame]) -> set[str]:
    return {f"{top}/{f.split}/{cityscapes_city(f.scenario)}" for f in frames for top in ("leftImg8bit", "gtFine")}


def _idda_dirs(frames: list[_Frame]) -> set[str]:
    return {f"{f.scenario}/{sub}" for f in frames for sub in ("RGB", "Semantic")}


def _no_extras(frames: list[_Frame], tmp: str, config: "ExportConfig") -> list[str]:
    return []


def _json(tmp: str, rel: str, body) -> str:
    os.makedirs(os.path.dirname(os.path.join(tmp, rel)), exist_ok=True)
    _write(os.path.join(tmp, rel), (json.dumps(body, indent=1, sort_keys=True) + "\n").encode())
    return rel


def _scenario_split_files(frames: list[_Frame], tmp: str, config: "ExportConfig") -> list[str]:
    """train/val/test.json: {scenario: [frame ids]}, every scenario in every file."""
    scenarios = sorted({f.scenario for f in frames})
    written = []
    for split in SPLITS:
        listing = {s: [] for s in scenarios}
        for f in frames:
            if f.split == split:
                listing[f.scenario].append(f.frame_id)
        written.append(_json(tmp, f"{split}.json", {s: sorted(ids) for s, ids in listing.items()}))
    return written


# FedDrive's test users (its IDDA settings): frames of the training domains,
# and frames of the held-out domains.
FEDDRIVE_SAME_DOMAIN = "test_user_same_domain"
FEDDRIVE_DIFF_DOMAIN = "test_user_diff_domain"


def _leaf(users: dict[str, list[_Frame]]) -> dict:
    """LEAF-style split: users, num_samples, user_data {user: {x: RGB paths, y: Semantic paths}}."""
    names = [u for u, fs in users.items() if fs]
    data = {}
    for user in names:
        ordered = sorted(users[user], key=lambda f: (f.scenario, f.episode, f.frame))
        pairs = [_idda_paths(f) for f in ordered]
        data[user] = {"x": [x for x, _ in pairs], "y": [y for _, y in pairs]}
    return {"users": names, "num_samples": [len(data[u]["x"]) for u in names], "user_data": data}


def _feddrive_split_files(frames: list[_Frame], tmp: str, config: "ExportConfig") -> list[str]:
    """FedDrive's federated IDDA splits, one client per training scenario (its
    "heterogeneous" setting): ``feddrive/train/idda_train_clients.json`` holds
    the train frames per scenario; ``feddrive/test/idda_test_clients.json``
    holds ``test_user_same_domain`` (test frames of the training scenarios)
    and, with ``holdout``, ``test_user_diff_domain`` (every frame of the
    held-out scenarios); ``feddrive/val/idda_val_clients.json`` the val
    frames of the training scenarios. Paths are relative to the export root."""
    from manifests.selection import parse_selection

    held = {s.code for s in parse_selection(config.holdout)} if config.holdout else set()
    train: dict[str, list[_Frame]] = {}
    val: list[_Frame] = []
    same: list[_Frame] = []
    diff: list[_Frame] = []
    for f in frames:
        if f.scenario in held:
            diff.append(f)
        elif f.split == "train":
            train.setdefault(f.scenario, []).append(f)
        else:
            (val if f.split == "val" else same).append(f)
    return [
        _json(tmp, "feddrive/train/idda_train_clients.json", _leaf(dict(sorted(train.items())))),
        _json(tmp, "feddrive/val/idda_val_clients.json", _leaf({FEDDRIVE_SAME_DOMAIN: val})),
        _json(tmp, "feddrive/test/idda_test_clients.json", _leaf({FEDDRIVE_SAME_DOMAIN: same, FEDDRIVE_DIFF_DOMAIN: diff})),
    ]


SPLIT_FILES: dict[str, Callable] = {
    "scenario": _scenario_split_files,  # train/val/test.json, {scenario: [frame ids]}
    "feddrive": _feddrive_split_files,  # FedDrive's LEAF-style federated splits
}


def _idda_split_files(frames: list[_Frame], tmp: str, config: "ExportConfig") -> list[str]:
    return SPLIT_FILES[config.splits](frames, tmp, config)


def _per_frame(frame: Callable, directories: Callable, extras: Callable) -> Callable:
    """A layout builder that writes each frame's files, then the per-export files."""

    def build(storage, frames: list[_Frame], tmp: str, config: "ExportConfig"):
        for rel in sorted(directories(frames)):
            os.makedirs(os.path.join(tmp, rel), exist_ok=True)
        place = FILE_MODES[config.files]
        with ThreadPoolExecutor(max_workers=config.threads) as pool:
            exported = list(pool.map(lambda f: frame(storage, f, tmp, place), frames))
        return exported, extras(frames, tmp, config)

    return build


def _hf_build(storage, frames: list[_Frame], tmp: str, config: "ExportConfig"):
    from training.hf import write_hf

    return write_hf(storage, frames, tmp, threads=config.threads)


def _coco_build(storage, frames: list[_Frame], tmp: str, config: "ExportConfig"):
    from training.coco import write_coco

    return write_coco(storage, frames, tmp, FILE_MODES[config.files], threads=config.threads)


LAYOUTS: dict[str, Callable] = {
    # (storage, frames, tmp dir, config) -> ([{kind: exported rel path}] per frame, [per-export files])
    "cityscapes": _per_frame(_cityscapes_frame, _cityscapes_dirs, _no_extras),
    "idda": _per_frame(_idda_frame, _idda_dirs, _idda_split_files),
    "hf": _hf_build,
    "coco": _coco_build,
}
# The outputs each layout reads (the cityscapes one also uses instance when the root holds it).
LAYOUT_OUTPUTS: dict[str, tuple[str, ...]] = {
    "cityscapes": ("rgb", "semantic_raw"),
    "idda": ("rgb", "semantic_raw"),
    "hf": ("rgb", "semantic_raw", "depth_raw"),
    "coco": ("rgb", "instance", "objects"),
}


# ---------------------------------------------------------------- export ----
@dataclass(frozen=True)
class ExportConfig:
    root: str  # source output root: local path or s3:// URI
    to: str  # target directory (local)
    format: str = "cityscapes"  # a key of LAYOUTS
    query: Query = field(default_factory=Query)
    files: str = "hardlink"  # a key of FILE_MODES; s3 sources are always copied
    force: bool = False  # replace a non-empty target
    threads: int = 8  # frames converted in parallel
    as_split: str | None = None  # put every exported frame in this split
    splits: str = "scenario"  # idda layout: a key of SPLIT_FILES
    holdout: str | None = None  # feddrive splits: domains for test_user_diff_domain

    def validate(self) -> None:
        if self.format not in LAYOUTS:
            raise ValueError(f"unknown export format {self.format!r}; valid formats: {', '.join(LAYOUTS)}")
        if self.as_split is not None and self.as_split not in SPLITS:
            raise ValueError(f"unknown split {self.as_split!r}; valid splits: {', '.join(SPLITS)}")
        if self.splits not in SPLIT_FILES:
            raise ValueError(f"unknown split files {self.splits!r}; valid: {', '.join(SPLIT_FILES)}")
        if self.splits != "scenario" and self.format != "idda":
            raise ValueError(f"split files {self.splits!r} are for the idda format, not {self.format!r}")
        if self.holdout is not None:
            from manifests.selection import parse_selection

            if self.splits != "feddrive":
                raise ValueError("a holdout selection needs --splits feddrive")
            parse_selection(self.holdout)
        if self.files not in FILE_MODES:
            raise ValueError(f"unknown file mode {self.files!r}; valid modes: {', '.join(FILE_MODES)}")
        if "://" in self.to and not self.to.startswith("file://"):
            raise ValueError(f"export target must be a local directory, got {self.to}")
        if self.threads < 1:
            raise ValueError(f"threads must be at least 1, got {self.threads}")
        self.query.validate()


@dataclass
class ExportReport:
    target: str
    format: str
    frames: int
    files: int
    per_split: dict[str, int]
    shortfall: dict[str, int]
    seconds: float


def _write(path: str, data: bytes) -> None:
    with open(path, "wb") as f:
        f.write(data)


def _target_dir(to: str) -> str:
    from storage import Storage

    storage = Storage.from_uri(to)
    return storage.path()


def _is_within(path: str, directory: str) -> bool:
    path, directory = os.path.realpath(path), os.path.realpath(directory)
    return os.path.commonpath([path, directory]) == directory


def _frames(table: pa.Table) -> list[_Frame]:
    names = [f for f in _Frame.__dataclass_fields__]
    cols = [table.column(n).to_pylist() for n in names]
    return [_Frame(*values) for values in zip(*cols)]


def _index_csv(frames: list[_Frame], exported: list[dict[str, str]]) -> bytes:
    kinds = list(exported[0]) if exported else []
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(["frame_id", "scenario", "episode", "frame", "split", *kinds])
    for f, paths in zip(frames, exported):
        writer.writerow([f.frame_id, f.scenario, f.episode, f.frame, f.split, *(paths[k] for k in kinds)])
    return buf.getvalue().encode()


def _commit(tmp: str, target: str) -> None:
    """Move the finished temp directory to ``target``, replacing what is there."""
    if os.path.isdir(target) and os.listdir(target):
        old = os.path.join(os.path.dirname(target), f".{os.path.basename(target)}.{uuid.uuid4().hex}.old")
        os.rename(target, old)
        os.rename(tmp, target)
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.replace(tmp, target)  # an empty directory is replaced atomically


def export(config: ExportConfig) -> ExportReport:
    """Export the frames of ``config.query`` from ``config.root`` into ``config.to``."""
    from manifests.reader import read_manifest
    from storage import Storage

    config.validate()
    start = time.perf_counter()
    storage = Storage.from_uri(config.root)
    target = _target_dir(config.to)
    check_export_target(target, config.force)  # never inside or over an output root
    if storage.is_local and _is_within(storage.path(), target):
        raise ValueError(f"export target {target} must not be the source root {storage.uri} or contain it")
    manifest = read_manifest(storage)
    result = run_query(manifest, config.query)
    if len(result.table) == 0:
        raise ValueError(f"no frames in {storage.uri} match the query; nothing to export")
    require_outputs(result.table, LAYOUT_OUTPUTS[config.format], f"{storage.uri} ({config.format} export)")
    frames = _frames(result.table)
    if config.as_split is not None:
        frames = [replace(f, split=config.as_split) for f in frames]
    build = LAYOUTS[config.format]

    parent = os.path.dirname(target)
    os.makedirs(parent, exist_ok=True)
    tmp = os.path.join(parent, f".{os.path.basename(target)}.{uuid.uuid4().hex}.tmp")
    os.makedirs(tmp)
    try:
        exported, extras = build(storage, frames, tmp, config)
        _write(os.path.join(tmp, INDEX), _index_csv(frames, exported))
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
        }
        _write(os.path.join(tmp, MARKER), (json.dumps(marker, indent=2, sort_keys=True) + "\n").encode())
        _commit(tmp, target)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return ExportReport(
        target=target,
        format=config.format,
        frames=len(frames),
        files=files,
        per_split=per_split,
        shortfall=dict(result.shortfall),
        seconds=time.perf_counter() - start,
    )


def is_complete(target: str) -> bool:
    """True if ``target`` holds a finished export (its marker exists)."""
    return os.path.isfile(os.path.join(target, MARKER))
