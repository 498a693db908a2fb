"""The bird's-eye picture of docs/conventions.md: one episode's camera path over its point cloud.

A short episode is rendered (``tests.roots``-style: the worker function, no cluster)
into a scratch root; every frame's planar depth is back-projected into the world with
the row's ``K`` and ``cam_to_world`` (``outputs.geometry.depth_to_world``), the
points coloured by their semantic class, and the camera centres and optical axes
drawn on top, seen from above (world x right, world y up). Where the frames' clouds
agree the calibration and poses agree; run ``python -m reports.conventions_bev``.
"""

from __future__ import annotations

import io
import logging
import shutil
from pathlib import Path

import numpy as np

from domains.catalog import LABELS
from manifests.reader import read_manifest
from outputs.encoding import decode_depth_raw, decode_png
from outputs.geometry import depth_to_world, unflat
from pipeline.episode_job import render_plan
from pipeline.settings import PlanConfig, RunConfig
from storage import Storage

DOMAIN = "T01_CS_A"
FRAMES = 8
INTERVAL_S = 0.5  # simulated seconds between frames
WIDTH, HEIGHT = 160, 90
SEED = 0
WORLD = "test"
SCRATCH = "/tmp/idda-conventions-bev"  # outside git; rebuilt on every run
MAX_POINTS = 20_000  # per frame, drawn (a fixed stride, so the picture is deterministic)
VIEW_M = 40.0  # the picture shows this far around the middle of the camera path

log = logging.getLogger(__name__)


def render_episode(root: str, domain: str = DOMAIN, frames: int = FRAMES, width: int = WIDTH,
                   height: int = HEIGHT, interval_s: float = INTERVAL_S, world: str = WORLD) -> None:
    """Render the planned episodes of ``domain`` into a fresh ``root`` with the worker function."""
    shutil.rmtree(root, ignore_errors=True)
    plan = PlanConfig(domains=domain, frames_per_scenario=frames, width=width, height=height, seed=SEED,
                      frame_interval_s=interval_s)
    render_plan(Storage.from_uri(root), RunConfig(plan=plan, world=world))


def episode_points(root: str) -> tuple[list[dict], np.ndarray, np.ndarray]:
    """The first episode's rows (frame order), its world points (N, 3) and their class ids (N,)."""
    storage = Storage.from_uri(root)
    rows = read_manifest(root).to_pylist()
    first = min((r["scenario"], r["episode"]) for r in rows)
    rows = sorted((r for r in rows if (r["scenario"], r["episode"]) == first), key=lambda r: r["frame"])
    points, classes = [], []
    for row in rows:
        depth = decode_depth_raw(decode_png(storage.read_bytes(row["depth_raw_path"])))
        semantic = decode_png(storage.read_bytes(row["semantic_raw_path"]))[..., 0]
        near = depth < 999.0
        stride = max(1, int(near.sum()) // MAX_POINTS)
        points.append(depth_to_world(depth, row["K"], row["cam_to_world"])[::stride])
        classes.append(semantic[near][::stride])
    return rows, np.concatenate(points), np.concatenate(classes)


def bev_png(rows: list[dict], points: np.ndarray, classes: np.ndarray) -> bytes:
    """The picture: points from above in their class colours, the camera path and axes on top."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt


    colors = np.zeros((256, 3))
    for label in LABELS:
        colors[label.id] = np.asarray(label.color) / 255.0
    poses = np.stack([unflat(r["cam_to_world"], 4) for r in rows])
    centres, forward = poses[:, :3, 3], poses[:, :3, 2]  # OpenCV z: the optical axis
    middle = (centres.min(axis=0) + centres.max(axis=0)) / 2
    shown = np.abs(points[:, :2] - middle[:2]).max(axis=1) < VIEW_M
    points, classes = points[shown], classes[shown]
    fig, ax = plt.subplots(figsize=(6.4, 6.4), dpi=100, layout="constrained")
    order = np.argsort(points[:, 2], kind="stable")  # higher points drawn last, as seen from above
    ax.scatter(points[order, 0], points[order, 1], c=colors[classes[order]], s=2.0, marker="s", linewidths=0)
    ax.plot(centres[:, 0], centres[:, 1], "-o", color="black", markersize=3, linewidth=1, label="camera centres")
    ax.quiver(centres[:, 0], centres[:, 1], forward[:, 0], forward[:, 1], color="red", angles="xy",
              scale_units="xy", scale=0.25, width=0.004, label="optical axis (camera z)")
    ax.set_xlim(middle[0] - VIEW_M, middle[0] + VIEW_M)
    ax.set_ylim(middle[1] - VIEW_M, middle[1] + VIEW_M)
    ax.set_aspect("equal")
    ax.set_xlabel("world x (m)")
    ax.set_ylabel("world y (m)")
    ax.set_title(f"{rows[0]['scenario']} episode {rows[0]['episode']}: {len(rows)} frames, depth to world")
    ax.legend(loc="upper right", fontsize=8)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", metadata={"Software": None})
    plt.close(fig)
    return buf.getvalue()


def write_bev(out: str, root: str = SCRATCH, **episode) -> str:
    """Render the episode into ``root``, draw it, write the PNG to ``out``; returns ``out``."""
    render_episode(root, **episode)
    png = bev_png(*episode_points(root))
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    Path(out).write_bytes(png)
    return out


def main(out: str = "docs/images/conventions_bev.png") -> None:
    log.info("wrote %s", write_bev(out))


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    main()
