"""Domain distances as in the IDDA paper, with an offline feature extractor.

Method (paper, Sec. "Experimental setup"): take the features of the first
``samples`` frames of each domain (scenario, in manifest order), fit a PCA on
all sampled features together and keep the first 50 components, then

* Euclidean distance between the two domains' mean vectors in PCA space;
* cosine distance ``1 - <a, b> / (|a| |b|)`` between the same mean vectors
  (PCA space is centred on the pooled mean, so it can exceed 1, as in the
  paper's 1.26). Centred on the mean of the sampled domains, the means of
  two domains point in opposite directions (the distance is always 2) and
  those of three close a triangle (the angles follow from the Euclidean
  distances): with fewer than ``MIN_COSINE_DOMAINS`` domains no cosine
  distance is given, and the table says why;
* Bhattacharyya distance per PCA feature, modelling each feature of each
  domain as a 1-D Gaussian with mean ``m`` and variance ``v`` (ddof 0)::

      D_B = 1/4 ln( 1/4 (v1/v2 + v2/v1 + 2) ) + 1/4 (m1 - m2)^2 / (v1 + v2)

  averaged over the features (variances are floored at 1e-12).

Features. The paper uses an ImageNet-trained ResNet-101; this module must
run offline with no downloaded weights, so it uses a fixed, seeded
multi-scale filter bank on the RGB image resized to 72x128 (area / linear
interpolation):

* colour: per-channel mean and standard deviation on a 3x3 grid, and a
  global 8-bin histogram per channel (illumination, weather grading, sky);
* gradients: magnitude-weighted 8-bin orientation histograms (unsigned) on a
  4x4 grid at two scales (edge density and direction: layout, blur, rain);
* Gabor energy: 4 orientations x 2 wavelengths, mean |response| on a 3x3 grid
  (oriented texture such as facades, foliage, road markings);
* random convolutions: 16 zero-mean, unit-norm 5x5x3 filters drawn from
  ``default_rng([seed, 7])``, rectified and mean-pooled on a 2x2 grid at two
  scales (generic colour-texture responses, like a network's first layer).

That is 534 numbers per image, standardised per feature over all samples
before the PCA. Like early and middle CNN layers these respond to exactly
what separates IDDA's domains (colour and illumination for weather, texture
for town, spatial layout and the hood for viewpoint), and the extractor is
fixed and deterministic, so distances are comparable across runs. It has no
learned semantics, so absolute values differ from the paper's; compare the
ordering of the three cases, not the numbers.

A real folder in Cityscapes layout (``analysis.real``) is one more domain,
``real``, in pairs such as ``T01_CN_A:real``: its first ``samples`` images.
"""

from __future__ import annotations

import io
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
import pyarrow as pa

from analysis.real import REAL, RealFolder, check_real_pairs, real_features
from domains.catalog import (active, code_axes, scenario as lookup_scenario, split_code,
                               weather as lookup_weather)
from manifests.query import Query, filter_frames, rig_sensors
from manifests.reader import read_manifest, require_outputs
from outputs.table import read_output
from storage import Storage

IMAGE_SIZE = (72, 128)  # (height, width) every frame is resized to
VAR_FLOOR = 1e-12


@dataclass(frozen=True)
class PaperPair:
    case: str  # which change the pair isolates
    source: str
    target: str
    euclidean: float  # the paper's values (Tab. "Scenarios Distances")
    cosine: float
    bhattacharyya: float


PAPER_PAIRS: tuple[PaperPair, ...] = (
    PaperPair("viewpoint", "T01_CS_A", "T01_CS_J", 2.7604, 0.2590, 0.0149),
    PaperPair("weather", "T01_CS_J", "T01_HRN_J", 5.6555, 1.2633, 0.0337),
    PaperPair("city", "T01_HRN_A", "T07_HRN_A", 6.4551, 1.0586, 0.0426),
)


# ------------------------------------------------------------- the math ----
def euclidean_distance(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(np.asarray(a, float) - np.asarray(b, float)))


MIN_COSINE_DOMAINS = 4  # below this, centred means fix the cosine distance (see the module's docstring)


def cosine_distance(a: np.ndarray, b: np.ndarray) -> float:
    """``1 - cos(a, b)``, in [0, 2]; ValueError for a zero vector."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    na, nb = np.linalg.norm(a), np.linalg.norm(b)
    if na == 0.0 or nb == 0.0:
        raise ValueError("cosine distance is undefined for a zero vector")
    return float(1.0 - np.dot(a, b) / (na * nb))


def bhattacharyya_gaussian(m1, v1, m2, v2) -> np.ndarray:
    """Bhattacharyya distance between 1-D Gaussians (means m, variances v), elementwise."""
    m1, m2 = np.asarray(m1, float), np.asarray(m2, float)
    v1 = np.maximum(np.asarray(v1, float), VAR_FLOOR)
    v2 = np.maximum(np.asarray(v2, float), VAR_FLOOR)
    return 0.25 * np.log(0.25 * (v1 / v2 + v2 / v1 + 2.0)) + 0.25 * (m1 - m2) ** 2 / (v1 + v2)


def bhattacharyya_distance(xa: np.ndarray, xb: np.ndarray) -> float:
    """Per-feature Gaussian Bhattacharyya distance of two samples (rows), averaged over features."""
    xa, xb = np.atleast_2d(np.asarray(xa, float)), np.atleast_2d(np.asarray(xb, float))
    if xa.shape[1] != xb.shape[1]:
        raise ValueError(f"samples have {xa.shape[1]} and {xb.shape[1]} features")
    d = bhattacharyya_gaussian(xa.mean(0), xa.var(0), xb.mean(0), xb.var(0))
    return float(d.mean())


@dataclass(frozen=True)
class PCA:
    mean: np.ndarray  # (features,)
    components: np.ndarray  # (k, features), orthonormal rows
    explained_variance: np.ndarray  # (k,), variance along each component
    total_variance: float

    def transform(self, x: np.ndarray) -> np.ndarray:
        return (np.asarray(x, float) - self.mean) @ self.components.T


def fit_pca(x: np.ndarray, k: int) -> PCA:
    """PCA by SVD of the centred data, keeping ``min(k, rows, features)`` components.

    Signs are fixed (each component's largest-magnitude loading is positive),
    so the result is deterministic.
    """
    x = np.asarray(x, float)
    if x.ndim != 2 or len(x) < 2:
        raise ValueError(f"PCA needs a 2-D array with at least 2 rows, got shape {x.shape}")
    if k < 1:
        raise ValueError(f"number of components must be at least 1, got {k}")
    mean = x.mean(0)
    _, s, vt = np.linalg.svd(x - mean, full_matrices=False)
    k = min(k, vt.shape[0])
    comps = vt[:k]
    signs = np.sign(comps[np.arange(k), np.abs(comps).argmax(1)])
    comps = comps * np.where(signs == 0, 1.0, signs)[:, None]
    var = s**2 / (len(x) - 1)
    return PCA(mean, comps, var[:k], float(var.sum()))


def standardise(x: np.ndarray) -> np.ndarray:
    """Z-score each column; constant columns become 0."""
    x = np.asarray(x, float)
    std = x.std(0)
    return (x - x.mean(0)) / np.where(std > 1e-8, std, 1.0)


# ---------------------------------------------------------- the features ----
class FilterBank:
    """The fixed, seeded feature extractor described in the module docstring."""

    GRID_COLOR = 3
    GRID_GRAD = 4
    GRID_GABOR = 3
    GRID_RANDOM = 2
    BINS = 8

    def __init__(self, seed: int = 0, n_random: int = 16, size: int = 5) -> None:
        import cv2

        if seed < 0:
            raise ValueError(f"seed must be non-negative, got {seed}")
        rng = np.random.default_rng([seed, 7])
        filters = rng.standard_normal((n_random, size, size, 3))
        filters -= filters.mean(axis=(1, 2, 3), keepdims=True)
        filters /= np.linalg.norm(filters.reshape(n_random, -1), axis=1)[:, None, None, None]
        self.random = filters.astype(np.float32)
        self.gabor = [
            cv2.getGaborKernel((11, 11), sigma=0.56 * lam, theta=theta, lambd=lam, gamma=0.5, psi=0.0).astype(np.float32)
            for lam in (4.0, 8.0)
            for theta in np.arange(4) * np.pi / 4
        ]
        self.seed = seed

    @property
    def size(self) -> int:
        g = self
        return (
            g.GRID_COLOR**2 * 6 + 3 * g.BINS + 2 * g.GRID_GRAD**2 * g.BINS
            + len(g.gabor) * g.GRID_GABOR**2 + 2 * len(g.random) * g.GRID_RANDOM**2
        )

    def __call__(self, rgb: np.ndarray) -> np.ndarray:
        """Feature vector (float64) of an HxWx3 uint8 RGB image."""
        import cv2

        if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
            raise ValueError(f"expected an HxWx3 uint8 RGB image, got {rgb.dtype} {rgb.shape}")
        h, w = IMAGE_SIZE
        shrink = rgb.shape[0] >= h and rgb.shape[1] >= w
        image = cv2.resize(rgb, (w, h), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)
        image = image.astype(np.float32) / 255.0
        gray = image @ np.array([0.299, 0.587, 0.114], np.float32)
        half = cv2.resize(image, (w // 2, h // 2), interpolation=cv2.INTER_AREA)
        parts = [self._colour(image), self._gradients(gray), self._gabor(gray)]
        parts += [self._random(img) for img in (image, half)]
        return np.concatenate(parts).astype(np.float64)

    def _colour(self, image: np.ndarray) -> np.ndarray:
        cells = _cells(image, self.GRID_COLOR)
        stats = [np.concatenate([c.mean((0, 1)), c.std((0, 1))]) for c in cells]
        hist = [np.histogram(image[..., ch], bins=self.BINS, range=(0.0, 1.0))[0] / image[..., ch].size for ch in range(3)]
        return np.concatenate(stats + hist)

    def _gradients(self, gray: np.ndarray) -> np.ndarray:
        import cv2

        out = []
        for img in (gray, cv2.resize(gray, (gray.shape[1] // 2, gray.shape[0] // 2), interpolation=cv2.INTER_AREA)):
            gx = cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=3)
            gy = cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=3)
            mag = np.hypot(gx, gy)
            bins = np.minimum((np.mod(np.arctan2(gy, gx), np.pi) / np.pi * self.BINS).astype(int), self.BINS - 1)
            for m, b in zip(_cells(mag, self.GRID_GRAD), _cells(bins, self.GRID_GRAD)):
                out.append(np.bincount(b.ravel(), weights=m.ravel(), minlength=self.BINS) / m.size)
        return np.concatenate(out)

    def _gabor(self, gray: np.ndarray) -> np.ndarray:
        import cv2

        out = []
        for kernel in self.gabor:
            response = np.abs(cv2.filter2D(gray, cv2.CV_32F, kernel, borderType=cv2.BORDER_REFLECT))
            out.extend(c.mean() for c in _cells(response, self.GRID_GABOR))
        return np.array(out)

    def _random(self, image: np.ndarray) -> np.ndarray:
        import cv2

        out = []
        for f in self.random:
            response = sum(
                cv2.filter2D(np.ascontiguousarray(image[..., c]), cv2.CV_32F, f[..., c], borderType=cv2.BORDER_REFLECT)
                for c in range(3)
            )
            response = np.maximum(response, 0.0)
            out.extend(c.mean() for c in _cells(response, self.GRID_RANDOM))
        return np.array(out)


def _cells(array: np.ndarray, n: int) -> list[np.ndarray]:
    """Split an image into an n x n grid of cells (row-major)."""
    rows = np.array_split(np.arange(array.shape[0]), n)
    cols = np.array_split(np.arange(array.shape[1]), n)
    return [array[r[0] : r[-1] + 1, c[0] : c[-1] + 1] for r in rows for c in cols]


# ------------------------------------------------------------ the report ----
@dataclass
class PairDistance:
    case: str  # "viewpoint", "weather", "city" for the paper's pairs, "" otherwise
    source: str
    target: str
    euclidean: float | None = None  # None when a domain has no frames
    cosine: float | None = None
    bhattacharyya: float | None = None
    paper: PaperPair | None = None
    missing: tuple[str, ...] = ()


@dataclass
class DistanceReport:
    domains: list[str]  # sorted scenario codes with features
    samples: dict[str, int]  # frames used per domain
    components: int  # PCA components kept
    explained: float  # share of the standardised feature variance they keep
    means: np.ndarray  # (domains, components) mean vector per domain
    embedding: np.ndarray  # (domains, 2) 2-D PCA of the domain means
    pairs: list[PairDistance] = field(default_factory=list)
    sensor: str | None = None  # in a rig's root: the camera whose images were sampled (rig_camera)


def rig_camera(table: pa.Table) -> str | None:
    """In a rig's root, the camera whose frames stand for the root's: the first sensor of the rig (in its
    rows' order) with RGB in every row; None in a root of the default rig (a row is a frame)."""
    sensors = rig_sensors(table)
    if not sensors:
        return None
    named, rgb = table.column("sensor").to_pylist(), table.column("rgb_path").to_pylist()
    lacking = {s for s, path in zip(named, rgb) if path is None}
    cameras = [s for s in sensors if s not in lacking]
    if not cameras:
        raise ValueError(f"no sensor of the root's rig ({', '.join(sensors)}) has RGB in every frame")
    return cameras[0]


def parse_pairs(text: str) -> tuple[tuple[str, str], ...]:
    """``"T01_CS_A:T01_CS_J,T01_CN_A:real"`` -> pairs of checked scenario codes (of the catalog in
    force: declared domains too) or ``real``, the real folder (analysis.real)."""
    def code(text: str) -> str:
        return REAL if text == REAL else lookup_scenario(text).code

    pairs = []
    for item in (p.strip() for p in text.split(",")):
        if not item:
            continue
        source, sep, target = item.partition(":")
        if not sep or not source or not target:
            raise ValueError(f"a pair is SOURCE:TARGET such as T01_CS_A:T01_CS_J, got {item!r}")
        pairs.append((code(source.strip()), code(target.strip())))
    return tuple(pairs)


def _embedding(means: np.ndarray) -> np.ndarray:
    if len(means) < 2:
        return np.zeros((len(means), 2))
    coords = fit_pca(means, 2).transform(means)
    return np.pad(coords, ((0, 0), (0, 2 - coords.shape[1])))


def compare_domains(
    features: dict[str, np.ndarray], pairs: tuple[tuple[str, str], ...] = (), components: int = 50
) -> DistanceReport:
    """Distances for the paper's pairs (those present) plus ``pairs``.

    ``features`` maps each domain to its (samples, features) array. Every
    pair in ``pairs`` must name domains in ``features``; the paper's pairs
    whose domains are absent are reported as missing.
    """
    domains = sorted(d for d, x in features.items() if len(x))
    for source, target in pairs:
        absent = [d for d in (source, target) if d not in domains]
        if absent:
            raise ValueError(
                f"no frames for {', '.join(absent)}; domains with frames: {', '.join(domains) or 'none'}"
            )
    if sum(len(features[d]) for d in domains) < 2:
        raise ValueError("need at least 2 sampled frames to fit a PCA")
    stacked = standardise(np.concatenate([np.asarray(features[d], float) for d in domains]))
    pca = fit_pca(stacked, components)
    projected = pca.transform(stacked)
    bounds = np.cumsum([0] + [len(features[d]) for d in domains])
    by_domain = {d: projected[bounds[i] : bounds[i + 1]] for i, d in enumerate(domains)}
    means = np.stack([by_domain[d].mean(0) for d in domains])
    mean_of = dict(zip(domains, means))

    rows = [PairDistance(p.case, p.source, p.target, paper=p) for p in PAPER_PAIRS]
    known = {(p.source, p.target) for p in PAPER_PAIRS}
    rows += [PairDistance("", s, t) for s, t in dict.fromkeys(pairs) if (s, t) not in known]
    for row in rows:
        row.missing = tuple(d for d in (row.source, row.target) if d not in by_domain)
        if row.missing:
            continue
        row.euclidean = euclidean_distance(mean_of[row.source], mean_of[row.target])
        if len(domains) >= MIN_COSINE_DOMAINS:
            row.cosine = cosine_distance(mean_of[row.source], mean_of[row.target])
        row.bhattacharyya = bhattacharyya_distance(by_domain[row.source], by_domain[row.target])
    return DistanceReport(
        domains=domains,
        samples={d: len(features[d]) for d in domains},
        components=len(pca.components),
        explained=float(pca.explained_variance.sum() / pca.total_variance) if pca.total_variance else 0.0,
        means=means,
        embedding=_embedding(means),
        pairs=rows,
    )


@dataclass(frozen=True)
class DistanceConfig:
    root: str  # output root: local path or s3:// URI
    pairs: tuple[tuple[str, str], ...] = ()  # compared in addition to the paper's three
    samples: int = 500  # first N frames per domain
    components: int = 50
    domains: str | None = None  # domains to sample (and embed); None: every scenario the root holds
    splits: tuple[str, ...] = ()  # empty: any split
    seed: int = 0  # filter bank seed
    threads: int = 4
    real: str | None = None  # a folder in Cityscapes layout, the domain "real" (analysis.real)
    real_splits: tuple[str, ...] = ("val",)  # which of its splits

    def validate(self) -> None:
        if self.samples < 1:
            raise ValueError(f"samples per domain must be at least 1, got {self.samples}")
        if self.components < 1:
            raise ValueError(f"components must be at least 1, got {self.components}")
        if self.threads < 1:
            raise ValueError(f"threads must be at least 1, got {self.threads}")
        for pair in self.pairs:
            for code in pair:
                if code != REAL:
                    lookup_scenario(code)
        check_real_pairs(self.pairs, self.real, must_name=False)
        Query(domains=self.domains, splits=self.splits, seed=self.seed).validate()


def first_frames(table: pa.Table, samples: int) -> dict[str, list[str]]:
    """RGB paths of the first ``samples`` frames of each scenario (table order)."""
    out: dict[str, list[str]] = {}
    for code, rel in zip(table.column("scenario").to_pylist(), table.column("rgb_path").to_pylist()):
        paths = out.setdefault(code, [])
        if len(paths) < samples:
            paths.append(rel)
    return out


def domain_features(storage, paths: dict[str, list[str]], bank: FilterBank, threads: int = 4) -> dict[str, np.ndarray]:
    """Feature arrays per domain for the given RGB files."""
    def one(rel: str) -> np.ndarray:
        return bank(read_output("rgb", storage.read_bytes(rel), storage.join(rel)))  # PNG or JPEG

    jobs = [(code, rel) for code in sorted(paths) for rel in paths[code]]
    with ThreadPoolExecutor(max_workers=threads) as pool:
        vectors = list(pool.map(lambda job: one(job[1]), jobs))
    out: dict[str, list[np.ndarray]] = {code: [] for code in paths}
    for (code, _), vector in zip(jobs, vectors):
        out[code].append(vector)
    return {code: np.stack(v) if v else np.zeros((0, bank.size)) for code, v in out.items()}


def domain_distances(config: DistanceConfig) -> DistanceReport:
    """Sample, extract features, and compare domains of a produced root (and the real folder, if any:
    with no pair naming it, every sampled domain is paired with it)."""
    config.validate()
    real = RealFolder(config.real, config.real_splits) if config.real else None
    if real is not None:
        real.images()  # a folder not in Cityscapes layout fails before any reading
    storage = Storage.from_uri(config.root)
    table = filter_frames(read_manifest(storage), Query(domains=config.domains, splits=config.splits))
    if len(table) == 0:
        raise ValueError(f"{storage.uri} has no frames" + (f" for {config.domains!r}" if config.domains else ""))
    sensor = rig_camera(table)  # a frame's images, not its rows: one camera of a rig, as the paper's one
    if sensor is not None:
        table = filter_frames(table, Query(sensors=(sensor,)))
    require_outputs(table, ("rgb",), storage.uri)
    bank = FilterBank(config.seed)
    features = domain_features(storage, first_frames(table, config.samples), bank, config.threads)
    pairs = config.pairs
    if real is not None:
        features[REAL] = real_features(real, bank, config.samples, config.threads)
        if not any(REAL in pair for pair in pairs):
            pairs += tuple((code, REAL) for code in sorted(features) if code != REAL)
    report = compare_domains(features, pairs, config.components)
    report.sensor = sensor
    return report


# ------------------------------------------------------------ presenting ----
def _fmt(value: float | None, digits: int) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def pair_table_start(rows, columns: str) -> tuple[int, list[str]]:
    """The width of the source/target columns of ``rows`` (each with .source and .target; declared codes
    have any length) and the table's first lines: the head (case, source, target, then ``columns``) and
    its rule."""
    w = max([10, *(len(code) for r in rows for code in (r.source, r.target))])
    head = f"{'case':<10} {'source':<{w}} {'target':<{w}} {columns}"
    return w, [head, "-" * len(head)]


def format_distance_table(report: DistanceReport) -> str:
    """One line per pair: our three distances next to the paper's."""
    w, lines = pair_table_start(report.pairs, f"{'euclidean':>9} {'paper':>7} {'cosine':>7} {'paper':>7} "
                                              f"{'bhattach.':>9} {'paper':>7}")
    for r in report.pairs:
        p = r.paper
        line = (
            f"{r.case or '-':<10} {r.source:<{w}} {r.target:<{w}} {_fmt(r.euclidean, 4):>9} {_fmt(p and p.euclidean, 4):>7} "
            f"{_fmt(r.cosine, 4):>7} {_fmt(p and p.cosine, 4):>7} {_fmt(r.bhattacharyya, 4):>9} {_fmt(p and p.bhattacharyya, 4):>7}"
        )
        if r.missing:
            line += f"  (not produced: {', '.join(r.missing)})"
        lines.append(line)
    n = sorted(set(report.samples.values()))
    span = str(n[0]) if len(n) == 1 else f"{n[0]}-{n[-1]}"
    lines.append(
        f"{len(report.domains)} domains, {span} frames each"
        + (f" (the rig's {report.sensor} camera)" if report.sensor else "")
        + f", PCA to {report.components} components "
        f"({100 * report.explained:.1f}% of the standardised feature variance)"
    )
    if len(report.domains) < MIN_COSINE_DOMAINS:
        lines.append(f"cosine: not given: the means of {len(report.domains)} domains, centred on their own mean, fix it "
                     f"(2 domains: always 2); sample {MIN_COSINE_DOMAINS} or more domains for it to mean anything")
    return "\n".join(lines)


def embedding_png(report: DistanceReport, title: str = "Domains: 2-D PCA of the domain mean features") -> bytes:
    """Scatter of the domains' 2-D embedding: colour = town, marker = weather, label = viewpoint."""
    import matplotlib


    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    cmap = plt.get_cmap("tab10")
    cat = active()  # the root's catalog, with any user entries (pipeline.cli.domain_files)
    town_color = {t.code: cmap(i % 10) for i, t in enumerate(cat.towns)}
    fig, ax = plt.subplots(figsize=(7.5, 6), dpi=110)
    paper_domains = {d for p in PAPER_PAIRS for d in (p.source, p.target)}
    for code, (x, y) in zip(report.domains, report.embedding):
        if code == REAL:
            ax.scatter(x, y, s=160, color="black", marker="*")
            ax.annotate(REAL, (x, y), textcoords="offset points", xytext=(6, 4), fontsize=9)
            continue
        town, weather, view = split_code(code)
        ax.scatter(x, y, s=70, color=town_color[town], marker=lookup_weather(weather).marker, edgecolors="black", linewidths=0.5)
        ax.annotate(view, (x, y), textcoords="offset points", xytext=(5, 4), fontsize=8)
        if code in paper_domains:
            ax.scatter(x, y, s=260, facecolors="none", edgecolors="black", linewidths=1.0)
    synthetic = [d for d in report.domains if d != REAL]
    towns = sorted({code_axes(d)["town"] for d in synthetic})
    weathers = sorted({code_axes(d)["weather"] for d in synthetic}, key=[w.code for w in cat.weathers].index)
    handles = [Line2D([], [], marker="o", ls="", color=town_color[t], label=t) for t in towns]
    handles += [Line2D([], [], marker=lookup_weather(w).marker, ls="", color="grey", label=w) for w in weathers]
    handles += [Line2D([], [], marker="o", ls="", mfc="none", mec="black", ms=12, label="paper's pairs")]
    ax.legend(handles=handles, loc="best", fontsize=8)
    ax.set_xlabel("component 1")
    ax.set_ylabel("component 2")
    views = ", ".join(v.code for v in cat.viewpoints)
    ax.set_title(f"{title}\n(text: viewpoint {views})", fontsize=10)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", metadata={"Software": None})
    plt.close(fig)
    return buf.getvalue()
