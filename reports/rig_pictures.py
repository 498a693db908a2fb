"""The pictures of docs/conventions.md, "Sensor rigs": one frame of ``surround`` (six cameras around
the ego) and one of ``lidar64`` (the LiDAR's points, coloured by class, over the front camera's image).

Each rig renders one frame of one scenario with the worker function (no cluster) into a scratch
root; the pictures are drawn from the files and manifest rows alone (``K``, ``cam_to_world``).
Run ``python -m reports.rig_pictures``.
"""

from __future__ import annotations

import io
import logging
import math
import shutil
from pathlib import Path

import numpy as np

from domains.catalog import PALETTE
from manifests.reader import read_manifest
from outputs.encoding import decode_kitti_labels, decode_kitti_points, decode_png
from outputs.geometry import as_matrix, project, world_to_camera
from pipeline.episode_job import render_plan
from pipeline.planner import PlanConfig
from pipeline.settings import RunConfig
from storage import Storage

DOMAIN = "T01_CN_A"
SCRATCH = "/tmp/idda-rig-pictures"  # outside git; rebuilt on every run
# where each surround camera sits in a 3x3 grid around the ego (row, column)
GRID = {"frontleft": (0, 0), "front": (0, 1), "frontright": (0, 2), "backleft": (2, 0), "back": (2, 1),
        "backright": (2, 2)}

log = logging.getLogger(__name__)


def render_rig(rig: str, width: int, height: int, root: str, world: str = "procedural") -> list[dict]:
    """One frame of ``rig`` rendered into a fresh ``root``; its manifest rows in rig order."""
    shutil.rmtree(root, ignore_errors=True)
    plan = PlanConfig(domains=DOMAIN, frames_per_scenario=1, width=width, height=height, rig=rig)
    render_plan(Storage.from_uri(root), RunConfig(plan=plan, world=world))
    return read_manifest(root).to_pylist()


def _figure_png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", metadata={"Software": None})
    return buf.getvalue()


def surround_png(root: str, rows: list[dict]) -> bytes:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 3, figsize=(12, 6.2), dpi=100, layout="constrained")
    for ax in axes.ravel():
        ax.axis("off")
    for row in rows:
        r, c = GRID[row["sensor"]]
        axes[r, c].imshow(decode_png(Path(root, row["rgb_path"]).read_bytes()))
        axes[r, c].set_title(row["sensor"], fontsize=9)
    ax = axes[1, 1]  # the rig from above: each camera's field of view, ego x up
    ax.set_xlim(-1.2, 1.2)
    ax.set_ylim(-1.2, 1.2)
    ax.set_aspect("equal")
    for row in rows:
        T = as_matrix(row["cam_to_ego"], 4)
        K = as_matrix(row["K"], 3)
        half = math.atan(K[0, 2] / K[0, 0])
        yaw = math.atan2(T[1, 2], T[0, 2])  # the optical axis in the ego frame (x forward, y left)
        for a in (yaw - half, yaw + half):
            ax.plot([0, -math.sin(a)], [0, math.cos(a)], color="grey", linewidth=0.8)
        ax.annotate(row["sensor"], (-1.05 * math.sin(yaw), 1.05 * math.cos(yaw)), fontsize=7, ha="center", va="center")
    ax.plot([0], [0], marker="^", color="red", markersize=8)
    ax.set_title("from above (ego forward up)", fontsize=9)
    fig.suptitle(f"{DOMAIN}, rig surround: one frame, six cameras at the same instant", fontsize=11)
    png = _figure_png(fig)
    plt.close(fig)
    return png


def lidar_png(root: str, rows: list[dict]) -> bytes:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    front = next(r for r in rows if r["sensor"] == "front")
    lidar = next(r for r in rows if r["sensor"] == "lidar")
    image = decode_png(Path(root, front["rgb_path"]).read_bytes())
    points = decode_kitti_points(Path(root, lidar["lidar_points_path"]).read_bytes())
    labels = decode_kitti_labels(Path(root, lidar["lidar_labels_path"]).read_bytes())
    T = as_matrix(lidar["cam_to_world"], 4)
    cam = world_to_camera(points[:, :3].astype(np.float64) @ T[:3, :3].T + T[:3, 3], front["cam_to_world"])
    ahead = cam[:, 2] > 0.5
    uv = project(cam[ahead], front["K"])
    h, w = image.shape[:2]
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
    fig, ax = plt.subplots(figsize=(w / 100, h / 100 + 0.4), dpi=100, layout="constrained")
    ax.imshow(image)
    colors = PALETTE[(labels[ahead][inside] & 0xFFFF).astype(int)] / 255.0
    ax.scatter(uv[inside, 0], uv[inside, 1], c=colors, s=1.5, marker="s", linewidths=0.3, edgecolors="black")
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)
    ax.axis("off")
    ax.set_title(f"{DOMAIN}, rig lidar64: {len(points):,} points of one sweep, {int(inside.sum()):,} in the front "
                 "camera's view, coloured by their class", fontsize=9)
    png = _figure_png(fig)
    plt.close(fig)
    return png


def main(out_dir: str = "docs/images") -> None:
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    root = f"{SCRATCH}/surround"
    Path(out_dir, "rig_surround.png").write_bytes(surround_png(root, render_rig("surround", 480, 270, root)))
    root = f"{SCRATCH}/lidar64"
    Path(out_dir, "rig_lidar64.png").write_bytes(lidar_png(root, render_rig("lidar64", 960, 540, root)))
    log.info("wrote %s/rig_surround.png and %s/rig_lidar64.png", out_dir, out_dir)


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    main()
