"""The paper's domain-shift table ("Assessing IDDA") with a small network trained from scratch.

For each of the paper's three cases (viewpoint T01_CS_A -> T01_CS_J, weather
T01_CS_J -> T01_HRN_J, city T01_HRN_A -> T07_HRN_A) a fresh
:class:`analysis.segnet.SegNet` is trained on the source domain's training
frames and scored (mean IoU over the catalog's evaluated classes present in
the ground truth, :mod:`analysis.metrics`) on the source's held-out frames and
on all frames of the target. Two kept fractions:

* ``kept`` = target mIoU / held-out source mIoU (how much of what it learned
  carries over);
* ``oracle_kept``, the paper's definition: the source network's mIoU on the
  target's held-out frames / the mIoU there of an *oracle*, the same network
  trained on the target's training frames. The paper's is DeepLab V2
  source-only / source=target (62.60 / 79.13, 40.24 / 78.31, 21.65 / 78.02).

One network is trained per domain (on its training frames) and serves every
case that needs it: the weather case's source model (T01_CS_J) is also the
viewpoint case's oracle. A domain's network is seeded by the first case that
has it as source, else by the case that has it as target.

Held-out source frames: the frames of the source's ``val`` and ``test``
episodes (the manifest split) when the source has both training and held-out
episodes; otherwise (small runs, where every episode is ``train``) the last
``HOLDOUT_TAIL`` of the frames of every episode, by frame index.

Frames are read through :class:`analysis.loaders.FrameDataset`, resized to
the network's input (RGB with area interpolation, labels with nearest) and
kept in memory. Training is deterministic for a given config: seeded
weights, a seeded batch order and flips, a fixed torch thread count and
torch's deterministic algorithms; on a GPU the same config gives the same
numbers run after run on that GPU.

``pairs`` adds cases for any pair of domains (no paper values): declared
scenario codes, or ``real``, a folder in Cityscapes layout (``analysis.real``:
its cities stand for episodes, its labelIds map onto the 16 classes).
A domain in none of the paper's cases seeds its network from its name.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import time
import zlib
from dataclasses import asdict, dataclass, field

import numpy as np

from analysis.distances import PAPER_PAIRS, PaperPair, pair_table_start
from analysis.loaders import FrameDataset
from analysis.metrics import EVAL_CLASSES, IGNORE, NUM_EVAL, TRAIN_INDEX_LUT, class_iou, confusion, mean_iou
from analysis.real import (
    CITYSCAPES_TO_INDEX, REAL, RealFolder, check_real_pairs, read_label_ids, read_rgb, scored_images,
)
from analysis.segnet import SegNet
from domains.catalog import lookup
from manifests.query import Query
from manifests.reader import as_storage, read_manifest

log = logging.getLogger(__name__)

HOLDOUT_TAIL = 0.2  # share of each episode's last frames held out when the split has no held-out episode
HELD_OUT_SPLITS = ("val", "test")
DEVICES = ("auto", "cpu", "cuda")
INSTALL_HINT = "pip install -e '.[analysis]'"
RGB_MEAN, RGB_STD = 0.45, 0.25  # fixed input normalisation of [0, 1] RGB
INPUT_MULTIPLE = 16  # input sides: multiples of SegNet's total stride (checked without importing torch)


@dataclass(frozen=True)
class ShiftCase:
    pair: PaperPair  # source / target: one of the paper's pairs (shared with analysis.distances), or a pair asked for
    paper_source_only: float | None = None  # DeepLab V2 trained on the source, mIoU % on the target
    paper_oracle: float | None = None  # DeepLab V2 trained on the target (source = target), mIoU % on the target

    @property
    def name(self) -> str:
        return self.pair.case or "-"

    @property
    def paper_kept(self) -> float | None:
        return None if self.paper_source_only is None else self.paper_source_only / self.paper_oracle


def pair_case(source: str, target: str) -> ShiftCase:
    """A case for any pair of domains (a declared scenario code, or ``real``): no paper values."""
    return ShiftCase(PaperPair("", source, target, math.nan, math.nan, math.nan))


_PAPER_MIOU = {"viewpoint": (62.60, 79.13), "weather": (40.24, 78.31), "city": (21.65, 78.02)}
CASES: tuple[ShiftCase, ...] = tuple(ShiftCase(p, *_PAPER_MIOU[p.case]) for p in PAPER_PAIRS)
CASE_BY_NAME = {c.name: c for c in CASES}


@dataclass(frozen=True)
class ShiftConfig:
    root: str  # output root: local path or s3:// URI
    cases: tuple[str, ...] = tuple(CASE_BY_NAME)  # which of the paper's cases to run
    pairs: tuple[tuple[str, str], ...] = ()  # more SOURCE, TARGET pairs: scenario codes or "real"
    real: str | None = None  # a folder in Cityscapes layout, the domain "real" (analysis.real)
    real_splits: tuple[str, ...] = ("val",)  # which of its splits
    steps: int = 800  # optimiser steps per case
    batch_size: int = 8
    lr: float = 3e-3  # AdamW peak learning rate (linear warm-up, cosine decay)
    width: int = 160  # network input size; multiples of 16
    height: int = 96
    max_frames: int | None = None  # first N frames per domain (manifest order); None: all
    seed: int = 0
    threads: int = 2  # torch CPU threads
    device: str = "auto"  # auto: cuda when available, else cpu

    def validate(self) -> None:
        if not self.cases and not self.pairs:
            raise ValueError(f"give at least one case or pair; valid cases: {', '.join(CASE_BY_NAME)}")
        for name in self.cases:
            lookup_case(name)
        check_real_pairs(self.pairs, self.real)
        check_training(self)
        if self.max_frames is not None and self.max_frames < 2:
            raise ValueError(f"max frames per domain must be at least 2, got {self.max_frames}")

    @property
    def all_cases(self) -> list[ShiftCase]:
        """The chosen paper cases, then a case per pair asked for."""
        return [lookup_case(name) for name in self.cases] + [pair_case(s, t) for s, t in dict.fromkeys(self.pairs)]

    @property
    def domains(self) -> list[str]:
        """Every domain the chosen cases need, in case order."""
        return list(dict.fromkeys(code for case in self.all_cases for code in (case.pair.source, case.pair.target)))


def check_training(config, multiple: int = INPUT_MULTIPLE) -> None:
    """ValueError for a training setting of ``config`` out of range: steps, batch size, threads,
    learning rate, input size (positive multiples of ``multiple``), seed, device."""
    for label, value in (("steps", config.steps), ("batch size", config.batch_size), ("threads", config.threads)):
        if value < 1:
            raise ValueError(f"{label} must be at least 1, got {value}")
    if not config.lr > 0:
        raise ValueError(f"learning rate must be positive, got {config.lr}")
    for label, value in (("width", config.width), ("height", config.height)):
        if value < multiple or value % multiple:
            raise ValueError(f"input {label} must be a positive multiple of {multiple}, got {value}")
    if config.seed < 0:
        raise ValueError(f"seed must be non-negative, got {config.seed}")
    if config.device not in DEVICES:
        raise ValueError(f"unknown device {config.device!r}; valid devices: {', '.join(DEVICES)}")


def lookup_case(name: str) -> ShiftCase:
    return lookup(CASE_BY_NAME, name, "case")


@dataclass
class CaseResult:
    case: str
    source: str
    target: str
    source_miou: float  # on the source's held-out frames
    target_miou: float  # on all target frames
    kept: float  # target_miou / source_miou
    paper_kept: float | None  # None for a pair that is not one of the paper's
    target_held_out_miou: float  # the source network on the target's held-out frames
    oracle_miou: float  # a network trained on the target's training frames, on its held-out frames
    oracle_kept: float  # target_held_out_miou / oracle_miou: the paper's definition
    constant_miou: float  # predicting the source's most frequent training class everywhere (held-out source)
    train_frames: int
    held_out_frames: int
    target_frames: int
    target_held_out_frames: int
    held_out_rule: str  # "split" or "tail" (source and target)
    final_loss: float
    seconds: float
    source_iou: dict[str, float | None] = field(default_factory=dict)  # per class (None: absent)
    target_iou: dict[str, float | None] = field(default_factory=dict)


@dataclass
class ShiftReport:
    config: ShiftConfig
    device: str
    parameters: int
    results: list[CaseResult]
    seconds: float

    def to_json(self) -> dict:
        return {"config": asdict(self.config), "device": self.device, "parameters": self.parameters,
                "classes": list(EVAL_CLASSES), "seconds": round(self.seconds, 1),
                "results": [asdict(r) for r in self.results]}


# ------------------------------------------------------------ data ----------
@dataclass
class Frames:
    """A domain's frames at the network's input size."""

    images: np.ndarray  # N x 3 x H x W float32, normalised
    labels: np.ndarray  # N x H x W uint8 training indices (IGNORE for unscored classes)
    episodes: np.ndarray  # N episode numbers
    frames: np.ndarray  # N frame numbers within the episode
    splits: np.ndarray  # N manifest splits

    def subset(self, keep: np.ndarray) -> "Frames":
        return Frames(self.images[keep], self.labels[keep], self.episodes[keep], self.frames[keep], self.splits[keep])

    def __len__(self) -> int:
        return len(self.labels)


def prepare(rgb: np.ndarray, ids: np.ndarray, lut: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Network input (3 x H x W, normalised) and training indices (``lut`` of the resized class ids)."""
    import cv2

    rgb = cv2.resize(rgb, (width, height), interpolation=cv2.INTER_AREA)
    labels = cv2.resize(ids, (width, height), interpolation=cv2.INTER_NEAREST)
    image = (rgb.astype(np.float32) / np.float32(255.0) - np.float32(RGB_MEAN)) / np.float32(RGB_STD)
    return np.ascontiguousarray(image.transpose(2, 0, 1)), lut[labels]


def load_domain(root, code: str, width: int, height: int, max_frames: int | None = None) -> Frames:
    """The domain's frames (the first ``max_frames`` in manifest order), resized for the network."""
    data = FrameDataset(root, Query(domains=code), outputs=("rgb", "semantic_raw"))
    n = len(data) if max_frames is None else min(len(data), max_frames)
    images, labels, meta = [], [], []
    for i in range(n):
        sample = data[i]
        image, label = prepare(sample["rgb"], sample["semantic"], TRAIN_INDEX_LUT, width, height)
        images.append(image)
        labels.append(label)
        meta.append((sample["episode"], sample["frame"], sample["split"]))
    return Frames(np.stack(images), np.stack(labels), np.array([m[0] for m in meta]),
                  np.array([m[1] for m in meta]), np.array([m[2] for m in meta]))


def held_out_mask(episodes: np.ndarray, frames: np.ndarray, splits: np.ndarray) -> tuple[np.ndarray, str]:
    """Which frames are held out, and by which rule ("split" or "tail"; see the module notes)."""
    by_split = np.isin(splits, HELD_OUT_SPLITS)
    if by_split.any() and not by_split.all():
        return by_split, "split"
    mask = np.zeros(len(frames), dtype=bool)
    for episode in np.unique(episodes):
        mine = episodes == episode
        count = int(mine.sum())
        held = min(count - 1, max(1, math.ceil(HOLDOUT_TAIL * count))) if count > 1 else 0
        if held:
            cutoff = np.sort(frames[mine])[count - held]
            mask |= mine & (frames >= cutoff)
    if not mask.any() or mask.all():
        raise ValueError("cannot hold out source frames: the source needs at least 2 frames in one episode")
    return mask, "tail"


def check_domains(root, codes: list[str]) -> None:
    """Raise ValueError naming the domains that have no frames under ``root``."""
    import pyarrow.compute as pc


    storage = as_storage(root)
    present = set(pc.unique(read_manifest(storage, columns=["scenario"]).column("scenario")).to_pylist())
    codes = [c for c in codes if c != REAL]
    missing = [c for c in codes if c not in present]
    if missing:
        raise ValueError(
            f"{storage.uri} has no frames for {', '.join(missing)}; make them with: "
            f"idda produce --domains {','.join(codes)} --out {storage.uri} --extend"
        )


# ------------------------------------------------------------ torch ---------
def require_torch():
    try:
        import torch
    except ImportError as exc:
        raise ImportError(f"idda shifts needs PyTorch: {INSTALL_HINT}") from exc
    return torch


@contextlib.contextmanager
def deterministic_torch(threads: int):
    """Fixed thread count and deterministic algorithms for the block; restores torch's settings after."""
    torch = require_torch()
    saved = (torch.get_num_threads(), torch.are_deterministic_algorithms_enabled(),
             torch.is_deterministic_algorithms_warn_only_enabled(), torch.backends.cudnn.benchmark)
    os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")  # deterministic cuBLAS
    torch.set_num_threads(threads)
    torch.use_deterministic_algorithms(True, warn_only=True)  # GPU bilinear backward has none: warn, not fail
    torch.backends.cudnn.benchmark = False
    try:
        yield torch
    finally:
        torch.set_num_threads(saved[0])
        torch.use_deterministic_algorithms(saved[1], warn_only=saved[2])
        torch.backends.cudnn.benchmark = saved[3]


def _device(torch, name: str) -> str:
    if name == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if name == "cuda" and not torch.cuda.is_available():
        raise ValueError("device cuda asked for, but torch sees no CUDA GPU")
    return name


def _learning_rate(step: int, steps: int, peak: float) -> float:
    warm = max(1, steps // 20)
    if step < warm:
        return peak * (step + 1) / warm
    return 0.5 * peak * (1.0 + math.cos(math.pi * (step - warm) / max(1, steps - warm)))


def train(torch, data: Frames, config: ShiftConfig, device: str, seed: int, num_classes: int = NUM_EVAL):
    """A fresh SegNet trained on ``data``; returns (model, mean loss of the last tenth of the steps).
    ``config`` gives steps, batch_size and lr."""
    torch.manual_seed(seed)
    model = SegNet(num_classes).to(device)
    optimiser = torch.optim.AdamW(model.parameters(), lr=config.lr, weight_decay=1e-4)
    images = torch.from_numpy(data.images).to(device)
    labels = torch.from_numpy(data.labels.astype(np.int64)).to(device)
    rng = np.random.default_rng([seed, 11])
    order = np.empty(0, dtype=np.int64)
    losses = []
    model.train()
    for step in range(config.steps):
        if len(order) < config.batch_size:
            order = np.concatenate([order, rng.permutation(len(data))])
        batch, order = order[: config.batch_size], order[config.batch_size:]
        flip = torch.from_numpy(rng.random(len(batch)) < 0.5).to(device)
        index = torch.from_numpy(batch).to(device)
        x, y = images[index], labels[index]
        x = torch.where(flip[:, None, None, None], x.flip(-1), x)
        y = torch.where(flip[:, None, None], y.flip(-1), y)
        for group in optimiser.param_groups:
            group["lr"] = _learning_rate(step, config.steps, config.lr)
        loss = torch.nn.functional.cross_entropy(model(x), y, ignore_index=IGNORE)
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        optimiser.step()
        losses.append(float(loss.detach()))
    tail = losses[-max(1, config.steps // 10):]
    return model, float(np.mean(tail))


def predict(torch, model, data: Frames, device: str, batch_size: int = 32) -> np.ndarray:
    """Class indices (N x H x W uint8) for every frame."""
    model.eval()
    out = []
    with torch.no_grad():
        for start in range(0, len(data), batch_size):
            x = torch.from_numpy(data.images[start:start + batch_size]).to(device)
            out.append(model(x).argmax(1).to(torch.uint8).cpu().numpy())
    return np.concatenate(out)


def _ious(matrix: np.ndarray) -> dict[str, float | None]:
    return {name: (None if math.isnan(v) else round(float(v), 4)) for name, v in zip(EVAL_CLASSES, class_iou(matrix))}


def constant_prediction_miou(train_labels: np.ndarray, test_labels: np.ndarray) -> float:
    """mIoU of predicting the most frequent training class everywhere (a floor any trained net should beat)."""
    counts = np.bincount(train_labels[train_labels != IGNORE].ravel(), minlength=NUM_EVAL)
    return mean_iou(confusion(test_labels, np.full_like(test_labels, int(np.argmax(counts)))))


def case_seed(run_seed: int, index: int) -> int:
    """Torch seed of the ``index``-th case (table position) for a run seed."""
    return int(np.random.default_rng([run_seed, index]).integers(2**31))


def model_seed(run_seed: int, code: str) -> int:
    """Torch seed of a domain's network: that of the first case with the domain as source
    (so a source network's seed does not depend on which cases run), else of the first
    case with it as target, offset past the cases; a domain in none of them: from its name."""
    for offset, side in ((0, "source"), (len(CASES), "target")):
        for index, case in enumerate(CASES):
            if getattr(case.pair, side) == code:
                return case_seed(run_seed, offset + index)
    return int(np.random.default_rng([run_seed, 2 * len(CASES), zlib.crc32(code.encode())]).integers(2**31))


@dataclass
class DomainModel:
    """A network trained on a domain's training frames, and the domain's held-out frames."""

    model: object
    train_set: Frames
    held_out: Frames
    rule: str  # "split" or "tail"
    final_loss: float
    seconds: float


def split_domain(data: Frames) -> tuple[Frames, Frames, str]:
    """(training frames, held-out frames, rule) of a domain."""
    held, rule = held_out_mask(data.episodes, data.frames, data.splits)
    return data.subset(~held), data.subset(held), rule


def domain_model(torch, code: str, data: Frames, config: ShiftConfig, device: str) -> DomainModel:
    start = time.perf_counter()
    train_set, held_out, rule = split_domain(data)
    model, final_loss = train(torch, train_set, config, device, seed=model_seed(config.seed, code))
    return DomainModel(model, train_set, held_out, rule, final_loss, time.perf_counter() - start)


def _score(torch, net: DomainModel, data: Frames, device: str) -> np.ndarray:
    return confusion(data.labels, predict(torch, net.model, data, device))


def run_case(torch, case: ShiftCase, domains: dict[str, Frames], models: dict[str, DomainModel],
             config: ShiftConfig, device: str) -> CaseResult:
    """Score one case; trains the source's and the target's networks unless ``models`` has them."""
    start = time.perf_counter()
    for code in (case.pair.source, case.pair.target):
        if code not in models:
            log.info("training on %s (%d steps on %s)", code, config.steps, device)
            models[code] = domain_model(torch, code, domains[code], config, device)
    source, oracle, target = models[case.pair.source], models[case.pair.target], domains[case.pair.target]
    source_cm = _score(torch, source, source.held_out, device)
    target_cm = _score(torch, source, target, device)
    source_miou, target_miou = mean_iou(source_cm), mean_iou(target_cm)
    target_held_miou = mean_iou(_score(torch, source, oracle.held_out, device))
    oracle_miou = mean_iou(_score(torch, oracle, oracle.held_out, device))
    return CaseResult(
        case=case.name, source=case.pair.source, target=case.pair.target,
        source_miou=source_miou, target_miou=target_miou,
        kept=target_miou / source_miou if source_miou > 0 else 0.0, paper_kept=case.paper_kept,
        target_held_out_miou=target_held_miou, oracle_miou=oracle_miou,
        oracle_kept=target_held_miou / oracle_miou if oracle_miou > 0 else 0.0,
        constant_miou=constant_prediction_miou(source.train_set.labels, source.held_out.labels),
        train_frames=len(source.train_set), held_out_frames=len(source.held_out), target_frames=len(target),
        target_held_out_frames=len(oracle.held_out), held_out_rule=source.rule, final_loss=source.final_loss,
        seconds=time.perf_counter() - start, source_iou=_ious(source_cm), target_iou=_ious(target_cm),
    )


def run_shifts(config: ShiftConfig) -> ShiftReport:
    """Train and score every chosen case on the frames under ``config.root``."""
    config.validate()
    check_domains(config.root, config.domains)
    real = RealFolder(config.real, config.real_splits) if config.real else None
    if real is not None:
        scored_images(real)  # a folder not in Cityscapes layout fails before any training
    start = time.perf_counter()
    with deterministic_torch(config.threads) as torch:
        from analysis.segnet import SegNet, parameter_count

        device = _device(torch, config.device)
        domains = {}
        for code in config.domains:
            log.info("reading %s", code)
            domains[code] = (load_real(real, config.width, config.height, config.max_frames) if code == REAL else
                             load_domain(config.root, code, config.width, config.height, config.max_frames))
        results, models = [], {}
        for case in config.all_cases:
            results.append(run_case(torch, case, domains, models, config, device))
        parameters = parameter_count(SegNet(NUM_EVAL))
    return ShiftReport(config=config, device=device, parameters=parameters, results=results,
                       seconds=time.perf_counter() - start)


# ------------------------------------------------------------ output --------
def format_shift_table(report: ShiftReport) -> str:
    """One line per case: held-out source and target mIoU, kept fraction, the paper's."""
    w, lines = pair_table_start(report.results, f"{'source mIoU':>11} {'target mIoU':>11} {'kept':>6} "
                                                f"{'target* mIoU':>12} {'oracle mIoU':>11} {'kept*':>6} {'paper kept':>10}")
    for r in report.results:
        lines.append(f"{r.case:<10} {r.source:<{w}} {r.target:<{w}} {r.source_miou:>11.3f} {r.target_miou:>11.3f} "
                     f"{r.kept:>6.2f} {r.target_held_out_miou:>12.3f} {r.oracle_miou:>11.3f} {r.oracle_kept:>6.2f} "
                     f"{'-' if r.paper_kept is None else format(r.paper_kept, '.2f'):>10}")
    cfg = report.config
    rules = sorted({r.held_out_rule for r in report.results})
    lines.append(
        f"SegNet ({report.parameters:,} parameters) at {cfg.width}x{cfg.height}, {cfg.steps} steps of "
        f"{cfg.batch_size} frames per domain network, seed {cfg.seed}, on {report.device}, {report.seconds:.0f} s; "
        f"mIoU over the evaluated classes present in the ground truth; held-out frames by "
        f"{' / '.join(rules)} rule"
    )
    lines.append("kept = target / held-out source; * on the target's held-out frames: kept* = target* / oracle "
                 "(a network trained on the target), the paper's definition")
    ours = [r for r in report.results if r.paper_kept is not None]
    if len(ours) > 1:
        paper = " > ".join(r.case for r in sorted(ours, key=lambda r: -r.paper_kept))
        for label, key in (("kept", "kept"), ("kept*", "oracle_kept")):
            order = sorted(ours, key=lambda r: -getattr(r, key))
            lines.append(f"{label}: {' > '.join(r.case for r in order)} (paper: {paper})")
    return "\n".join(lines)


def load_real(folder: RealFolder, width: int, height: int, max_frames: int | None = None):
    """The folder's frames for ``analysis.shift_table`` (``Frames``): cities as episodes, labels as training indices."""
    images = scored_images(folder)
    images = images if max_frames is None else images[:max_frames]
    cities = {key: i for i, key in enumerate(dict.fromkeys((im.split, im.city) for im in images))}
    arrays, labels, episodes, frames = [], [], [], []
    seen = [0] * len(cities)  # images so far per city: the frame number
    for im in images:
        image, label = prepare(read_rgb(im.image), read_label_ids(im.label), CITYSCAPES_TO_INDEX, width, height)
        arrays.append(image)
        labels.append(label)
        episodes.append(cities[(im.split, im.city)])
        frames.append(seen[episodes[-1]])
        seen[episodes[-1]] += 1
    return Frames(np.stack(arrays), np.stack(labels), np.array(episodes), np.array(frames),
                  np.array([im.split for im in images]))
