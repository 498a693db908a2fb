"""A still picture of a recording that ``idda view`` wrote, for places without a
display (a README, a report, a headless node): ``idda view ... --out ep.rrd
--picture ep.png``.

The picture is drawn from the ``.rrd`` itself, read back through rerun's own
reader (``rerun.chunk.RrdReader``), so it shows what the recording holds, not
what the root holds: one frame's RGB with the semantic layer over it and the
objects' 2D boxes; a bird's-eye view of every frame's depth point cloud in world
coordinates with the camera path and the frame's frustum; the condition series
over the episode.
"""

from __future__ import annotations

import io

import numpy as np

from domains.catalog import LABELS, PALETTE

Recording = dict  # {entity path: {column: [(frame or None, value), ...] sorted by frame}}
SEMANTIC_ALPHA = 0.45
BEV_POINTS = 150_000  # the bird's-eye view draws at most this many points
BEV_MARGIN_M = 60.0  # ... around the camera path


def read_recording(path: str) -> Recording:
    """Every component column of every entity of ``path``, with the frame it was logged at (None: static)."""
    from rerun.chunk import RrdReader

    found: Recording = {}
    for chunk in RrdReader(path).stream():
        batch = chunk.to_record_batch()
        frames = batch.column("frame").to_pylist() if "frame" in batch.schema.names else [None] * batch.num_rows
        columns = found.setdefault(chunk.entity_path, {})
        for name in batch.schema.names:
            if ":" in name:
                columns.setdefault(name, []).extend(zip(frames, batch.column(name).to_pylist()))
    for columns in found.values():
        for values in columns.values():
            values.sort(key=lambda fv: -1 if fv[0] is None else fv[0])
    return found


def frames_of(recording: Recording) -> list[int]:
    """The frames that hold an RGB image."""
    return [f for f, v in recording.get("/world/camera/image/rgb", {}).get("Image:buffer", []) if v is not None]


def _at(recording: Recording, entity: str, column: str, frame: int):
    for f, value in recording.get(entity, {}).get(column, []):
        if f == frame and value is not None:
            return value
    return None


def _image(recording: Recording, entity: str, kind: str, frame: int) -> np.ndarray | None:
    buffer = _at(recording, entity, f"{kind}:buffer", frame)
    fmt = _at(recording, entity, f"{kind}:format", frame)
    if buffer is None or fmt is None:
        return None
    data = np.asarray(buffer[0], dtype=np.uint8)
    return data.reshape(fmt[0]["height"], fmt[0]["width"], -1)


def _frustum(recording: Recording, frame: int, far_m: float = 25.0) -> np.ndarray | None:
    """The frame's frustum footprint in world x, y: camera centre, far-left and far-right corners."""
    t = _at(recording, "/world/camera", "Transform3D:translation", frame)
    r = _at(recording, "/world/camera", "Transform3D:mat3x3", frame)
    k = _at(recording, "/world/camera/image", "Pinhole:image_from_camera", frame)
    size = _at(recording, "/world/camera/image", "Pinhole:resolution", frame)
    if t is None or r is None or k is None or size is None:
        return None
    centre = np.asarray(t[0])
    rotation = np.asarray(r[0]).reshape(3, 3, order="F")  # rerun stores mat3x3 column-major
    fx, cx = k[0][0], k[0][6]
    corners = [rotation @ (np.array([(u - cx) / fx, 0.0, 1.0]) * far_m) + centre for u in (0.0, size[0][0])]
    return np.array([corners[0], centre, corners[1]])


def picture_png(recording: Recording, frame: int | None = None) -> bytes:
    """The picture of ``frame`` (default: the middle one) as PNG bytes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    frames = frames_of(recording)
    if not frames:
        raise ValueError("the recording holds no RGB frame")
    frame = frames[len(frames) // 2] if frame is None else frame
    if frame not in frames:
        raise ValueError(f"frame {frame} is not in the recording (it holds {frames[0]}..{frames[-1]})")
    rgb = _image(recording, "/world/camera/image/rgb", "Image", frame)[..., :3]
    fig = plt.figure(figsize=(14, 6.2), dpi=100)
    grid = fig.add_gridspec(2, 2, width_ratios=(1.35, 1), height_ratios=(2.2, 1))
    ax = fig.add_subplot(grid[0, 0])
    shown = rgb.astype(np.float32)
    semantic = _image(recording, "/world/camera/image/semantic", "SegmentationImage", frame)
    if semantic is not None:
        shown = (1 - SEMANTIC_ALPHA) * shown + SEMANTIC_ALPHA * PALETTE[semantic[..., 0]].astype(np.float32)
    ax.imshow(shown.astype(np.uint8))
    centers = _at(recording, "/world/camera/image/boxes", "Boxes2D:centers", frame) or []
    halves = _at(recording, "/world/camera/image/boxes", "Boxes2D:half_sizes", frame) or []
    ids = _at(recording, "/world/camera/image/boxes", "Boxes2D:class_ids", frame) or []
    for (x, y), (hw, hh), cid in zip(centers, halves, ids):
        ax.add_patch(Rectangle((x - hw, y - hh), 2 * hw, 2 * hh, fill=False, lw=1.2,
                               edgecolor=np.array(LABELS[cid].color) / 255.0))
    ax.set_title(f"frame {frame}: RGB, semantic layer ({SEMANTIC_ALPHA:.0%}), 2D boxes", fontsize=10)
    ax.axis("off")

    bev = fig.add_subplot(grid[:, 1])
    points = [(np.asarray(p), np.asarray(c, dtype=np.uint32))
              for f in frames
              for p, c in [(_at(recording, "/world/depth", "Points3D:positions", f),
                            _at(recording, "/world/depth", "Points3D:colors", f))] if p is not None]
    if points:
        xyz = np.concatenate([p for p, _ in points])
        rgba = np.concatenate([c for _, c in points])
        keep = np.linspace(0, len(xyz) - 1, min(len(xyz), BEV_POINTS)).astype(int)
        colours = np.stack([(rgba[keep] >> s) & 0xFF for s in (24, 16, 8)], axis=1) / 255.0
        bev.scatter(xyz[keep, 0], xyz[keep, 1], s=0.3, c=colours, linewidths=0)
    path = recording.get("/world/trajectory", {}).get("LineStrips3D:strips", [])
    if path:
        line = np.asarray(path[0][1][0])
        bev.plot(line[:, 0], line[:, 1], color="black", lw=1.5, label="camera path")
        low, high = line[:, :2].min(axis=0) - BEV_MARGIN_M, line[:, :2].max(axis=0) + BEV_MARGIN_M
        bev.set_xlim(low[0], high[0])
        bev.set_ylim(low[1], high[1])
    wedge = _frustum(recording, frame)
    if wedge is not None:
        bev.fill(wedge[:, 0], wedge[:, 1], color="red", alpha=0.3, label=f"frustum, frame {frame}")
    bev.set_aspect("equal")
    bev.set_title(f"depth as world points, {len(frames)} frames (bird's eye, metres)", fontsize=10)
    bev.legend(loc="upper right", fontsize=8)

    series = fig.add_subplot(grid[1, 0])
    for entity in sorted(e for e in recording if e.startswith("/conditions/")):
        values = [(f, v[0]) for f, v in recording[entity].get("Scalars:scalars", []) if v]
        if values:
            f, v = zip(*values)
            span = max(v) - min(v)
            series.plot(f, [(x - min(v)) / span if span else 0.5 for x in v], lw=1.2,
                        label=f"{entity.split('/')[-1]} {min(v):.3g}..{max(v):.3g}")
    series.axvline(frame, color="red", lw=1)
    series.set_xlabel("frame")
    series.set_ylabel("scaled to its range")
    series.legend(fontsize=7, ncol=3, loc="upper center", bbox_to_anchor=(0.5, -0.35))
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", metadata={"Software": None})
    plt.close(fig)
    return buf.getvalue()
