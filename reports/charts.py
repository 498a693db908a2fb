"""The report's pictures: class charts, the town sheet and the contact sheets (PNG bytes or files)."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from domains.catalog import LABELS, NAME2LABEL, TOWNS, VIEWPOINTS, WEATHERS
from outputs.encoding import decode_png
from render_workers.render.preview import contact_sheet
from reports.sample import LARGE, span, urban_towns

CELL_WIDTH = 320  # contact sheet cell width (px)
TOWN_SHEET_CELL = 480  # the one-frame-per-town sheet's cell width (px)
MAX_PNG_BYTES = 300_000


def _png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", metadata={"Software": None})
    return buf.getvalue()


def presence_png(stats: dict) -> bytes:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt


    idx = [label.id for label in LABELS if label.evaluated]
    names = [LABELS[i].name for i in idx]
    x = np.arange(len(idx))
    fig, ax = plt.subplots(figsize=(10, 4.2), dpi=100)
    ax.bar(x - 0.2, [100 * stats["presence"][i] for i in idx], 0.4, label="all frames", color="#4c72b0")
    ax.bar(x + 0.2, [100 * stats["presence_urban"][i] for i in idx], 0.4, label=f"urban frames ({span(urban_towns())})", color="#dd8452")
    ax.axhline(10, color="black", ls="--", lw=1, label="10% target (rare classes, urban)")
    ax.set_xticks(x, names, rotation=50, ha="right")
    ax.set_ylabel("frames showing the class (%)")
    ax.set_ylim(0, 125)
    ax.set_yticks(range(0, 101, 20))
    ax.set_title(f"Class presence over the sample ({stats['frames']} frames, {stats['urban_frames']} urban)")
    ax.legend(loc="upper center", ncol=3, fontsize=8)
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    data = _png(fig)
    plt.close(fig)
    return data


def town_share_png(stats: dict) -> bytes:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt


    towns = list(stats["share_by_town"])
    fig, ax = plt.subplots(figsize=(9, 4), dpi=100)
    left = np.zeros(len(towns))
    shown = list(LARGE)
    for name in shown + ["other classes"]:
        if name == "other classes":
            vals = np.array([100 * (1 - sum(stats["share_by_town"][t][NAME2LABEL[n].id] for n in shown)) for t in towns])
            color = (0.8, 0.8, 0.8)
        else:
            vals = np.array([100 * stats["share_by_town"][t][NAME2LABEL[name].id] for t in towns])
            color = np.array(NAME2LABEL[name].color) / 255.0
        ax.barh(towns, vals, left=left, color=color, edgecolor="black", linewidth=0.4, label=name)
        left += vals
    paper = [100 * stats["paper_share"][NAME2LABEL[n].id] for n in shown]
    left_p = 0.0
    for name, val in zip(shown + ["other classes"], paper + [100 - sum(paper)]):
        color = (0.8, 0.8, 0.8) if name == "other classes" else np.array(NAME2LABEL[name].color) / 255.0
        ax.barh(["paper"], [val], left=[left_p], color=color, edgecolor="black", linewidth=0.4)
        left_p += val
    ax.invert_yaxis()
    ax.set_xlim(0, 100)
    ax.set_xlabel("share of pixels (%)")
    ax.set_title("Large-class pixel shares per town vs the paper")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=8, fontsize=8, frameon=False)
    fig.tight_layout()
    data = _png(fig)
    plt.close(fig)
    return data


def small_png(image: np.ndarray, limit: int = MAX_PNG_BYTES) -> bytes:
    """PNG of an RGB image, palette-quantised (fewer colours each try) until under ``limit`` bytes."""
    from PIL import Image

    pil = Image.fromarray(image)
    buf = io.BytesIO()
    pil.save(buf, format="PNG", optimize=True)
    for colors in (256, 128, 64, 32):
        if buf.tell() <= limit:
            break
        buf = io.BytesIO()
        pil.quantize(colors=colors, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE).save(
            buf, format="PNG", optimize=True)
    return buf.getvalue()


def town_sheet(root: str, table, out_dir: Path, cell_width: int = TOWN_SHEET_CELL, per_row: int = 4) -> str:
    """One ClearNoon frame per town (viewpoint A, episode 0, the episode's middle frame), each captioned with
    its code and style name, ``per_row`` to a row."""
    import cv2
    import pyarrow.compute as pc


    frames = sorted(set(table.column("frame").to_pylist()))
    middle = frames[len(frames) // 2]
    sel = table.filter(pc.and_(pc.equal(table.column("episode"), 0), pc.equal(table.column("frame"), middle)))
    paths = dict(zip(sel.column("scenario").to_pylist(), sel.column("rgb_path").to_pylist()))
    band = 30
    cells = []
    for t in TOWNS:
        rel = paths.get(f"{t.code}_CN_A")
        if rel is None:
            continue
        image = decode_png(Path(root, rel).read_bytes(), name=rel)
        h = round(image.shape[0] * cell_width / image.shape[1])
        cell = np.full((band + h, cell_width, 3), 24, np.uint8)
        cell[band:] = cv2.resize(image, (cell_width, h), interpolation=cv2.INTER_AREA)
        cv2.putText(cell, f"{t.code}: {t.style}", (8, band - 9), cv2.FONT_HERSHEY_SIMPLEX, 0.65, (235, 235, 235), 1,
                    cv2.LINE_AA)
        cells.append(cell)
    cells += [np.full_like(cells[0], 24)] * (-len(cells) % per_row)
    sheet = np.vstack([np.hstack(cells[k:k + per_row]) for k in range(0, len(cells), per_row)])
    path = out_dir / "towns_CN.png"
    path.write_bytes(small_png(sheet))
    return str(path)


def contact_sheets(root: str, table, out_dir: Path, cell_width: int) -> list[str]:
    """One sheet per weather: rows viewpoints, columns towns; frame 0 of episode 0 per scenario."""
    import cv2
    import pyarrow.compute as pc


    first = table.filter(pc.and_(pc.equal(table.column("episode"), 0), pc.equal(table.column("frame"), 0)))
    paths = dict(zip(first.column("scenario").to_pylist(), first.column("rgb_path").to_pylist()))
    written = []
    for w in WEATHERS:
        cells = {}
        for t in TOWNS:
            for v in VIEWPOINTS:
                rel = paths.get(f"{t.code}_{w.code}_{v.code}")
                if rel is None:
                    continue
                image = decode_png(Path(root, rel).read_bytes(), name=rel)
                if image.shape[1] != cell_width:
                    h = round(image.shape[0] * cell_width / image.shape[1])
                    image = cv2.resize(image, (cell_width, h), interpolation=cv2.INTER_AREA)
                cells[(v.code, t.code)] = image
        sheet = contact_sheet(cells, [v.code for v in VIEWPOINTS], [t.code for t in TOWNS],
                              title=f"{w.code} ({w.name}): rows = viewpoints, columns = towns")
        path = out_dir / f"contact_sheet_{w.code}.png"
        path.write_bytes(small_png(sheet))
        written.append(str(path))
    return written
