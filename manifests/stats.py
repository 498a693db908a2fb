"""Class pixel shares, overall or per scenario, as a table and a bar chart."""

from __future__ import annotations

import io

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from domains.catalog import LABELS

# Bar heights of the paper's Fig. "pixeldistr" (pixel counts by class). They
# sum to about 100x the dataset's pixels, so only their shares are meaningful.
PAPER_PIXELS = {
    "unlabeled": 228166868105, "building": 23307916655951, "fence": 1779701571219,
    "other": 1320683518913, "pedestrian": 263062977344, "pole": 1704540720549,
    "road line": 2034711600277, "road": 49463892689073, "sidewalk": 13314207832951,
    "vegetation": 30960901843803, "vehicle": 15990470980019, "wall": 1726015249312,
    "traffic sign": 246957080772, "traffic light": 185217810579, "guard rail": 585180908787,
    "dynamic": 88582431146, "bicycle": 24158844858, "motorcycle": 93951063337,
    "rider": 131531488672, "terrain": 10117187363386, "sky": 54695624758916,
    "railway": 442912155733, "ground": 5368632190, "static": 59054954097,
}
_PAPER_TOTAL = sum(PAPER_PIXELS.values())
PAPER_SHARES = {name: count / _PAPER_TOTAL for name, count in PAPER_PIXELS.items()}


def class_pixels(table: pa.Table) -> np.ndarray:
    """Total pixels per class id over the table's frames."""
    return np.array([pc.sum(table.column(label.column)).as_py() or 0 for label in LABELS], dtype=np.int64)


def class_presence(table: pa.Table) -> np.ndarray:
    """Share of frames in which each class appears."""
    if len(table) == 0:
        return np.zeros(len(LABELS))
    return np.array(
        [pc.sum(pc.greater(table.column(label.column), 0)).as_py() / len(table) for label in LABELS]
    )


def share_table(table: pa.Table, by_scenario: bool = False) -> pa.Table:
    """One row per class (and scenario): pixels, share, presence, paper share."""
    groups = {"all": table}
    if by_scenario:
        groups = {
            code: table.filter(pc.equal(table.column("scenario"), code))
            for code in sorted(set(table.column("scenario").to_pylist()))
        }
    rows: dict[str, list] = {k: [] for k in ("scenario", "class_id", "class", "pixels", "share", "presence", "paper_share")}
    for code, group in groups.items():
        pixels = class_pixels(group)
        total = max(int(pixels.sum()), 1)
        presence = class_presence(group)
        for label in LABELS:
            rows["scenario"].append(code)
            rows["class_id"].append(label.id)
            rows["class"].append(label.name)
            rows["pixels"].append(int(pixels[label.id]))
            rows["share"].append(pixels[label.id] / total)
            rows["presence"].append(float(presence[label.id]))
            rows["paper_share"].append(PAPER_SHARES[label.name])
    return pa.table(rows)


def format_share_table(shares: pa.Table) -> str:
    w = max([10, *map(len, shares.column("scenario").to_pylist())])  # a declared code may be longer than T01_HRN_A
    lines = [f"{'scenario':<{w}} {'id':>2}  {'class':<14} {'share %':>9} {'paper %':>9} {'in frames %':>11}"]
    for row in shares.to_pylist():
        lines.append(
            f"{row['scenario']:<{w}} {row['class_id']:>2}  {row['class']:<14} {100 * row['share']:>9.3f} "
            f"{100 * row['paper_share']:>9.3f} {100 * row['presence']:>11.1f}"
        )
    return "\n".join(lines)


def bar_chart_png(shares: pa.Table, title: str = "Class pixel shares") -> bytes:
    """Log-scale bars per class in palette colours, with the paper's shares as
    markers (like the paper's Fig. "pixeldistr"): one panel per scenario group
    of ``shares`` (one panel for an overall table, one per scenario for
    ``share_table(..., by_scenario=True)``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups: dict[str, list[dict]] = {}
    for row in shares.to_pylist():
        groups.setdefault(row["scenario"], []).append(row)
    if not groups:
        raise ValueError("no class shares to chart")
    fig, axes = plt.subplots(len(groups), 1, figsize=(12, 4.8 * len(groups)), dpi=110, squeeze=False)
    floor = 1e-4
    for ax, (group, rows) in zip(axes[:, 0], groups.items()):
        names = [r["class"] + ("" if LABELS[r["class_id"]].evaluated else "*") for r in rows]
        ours = np.array([100 * r["share"] for r in rows])
        paper = np.array([100 * r["paper_share"] for r in rows])
        colors = [np.array(LABELS[r["class_id"]].color) / 255.0 for r in rows]
        x = np.arange(len(rows))
        ax.bar(x, np.maximum(ours, floor), color=colors, edgecolor="black", linewidth=0.5, label="this dataset")
        ax.scatter(x, paper, marker="_", s=300, color="black", linewidths=2, label="IDDA paper", zorder=3)
        ax.set_yscale("log")
        ax.set_ylim(floor, 100)
        ax.set_ylabel("share of pixels (%)")
        ax.set_xticks(x, names, rotation=60, ha="right")
        ax.set_title(f"{title} ({group})")
        ax.legend(loc="upper left")
        ax.grid(axis="y", which="major", alpha=0.3)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", metadata={"Software": None})
    plt.close(fig)
    return buf.getvalue()
