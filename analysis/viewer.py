"""Look at an episode: ``idda view ROOT --scenario CODE --episode N`` writes a
rerun recording (``.rrd``, https://rerun.io; ``pip install -e '.[view]'``).

Entities, per frame on the ``frame`` timeline (and ``sim_time``, seconds):

* ``world/camera``: the camera pose, ``cam_to_world`` as a Transform3D
  (translation and 3x3 rotation; world z up, metres);
* ``world/camera/image``: the pinhole (``K``, resolution, OpenCV camera axes
  RDF), so the viewer draws the frustum, with ``rgb`` (Image),
  ``semantic`` (SegmentationImage of the class ids, coloured and named by the
  catalog's classes through the AnnotationContext on ``world``), ``depth``
  (DepthImage, metres) and ``boxes`` (the objects' 2D boxes);
* ``world/camera/boxes``: the objects' 3D boxes in the camera frame, where the
  ``objects`` output puts them (centre, size, yaw about the camera's y axis);
* ``world/depth``: the depth as a point cloud in world coordinates
  (``outputs.geometry.depth_to_world``), coloured by the RGB, every
  ``stride``-th pixel in both directions, sky left out;
* ``world/trajectory``: the camera path over the episode (static);
* ``conditions/<column>``: each condition column (sun, clouds, rain, fog,
  wetness, snow, visibility) and the ego's speed as a time series.

Outputs the root lacks are left out (a root without ``objects`` has no boxes).
The recording id is the root's URI with the episode, so the same root and
episode give the same recording.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from domains.catalog import LABELS
from domains.conditions import CONDITION_COLUMNS
from manifests.reader import as_storage, read_manifest
from outputs.encoding import decode_depth_raw
from outputs.geometry import as_matrix, depth_to_world
from outputs.table import read_output
from manifests.schema import output_columns

APP_ID = "idda"
SERIES = (*CONDITION_COLUMNS, "fog_density", "ego_speed_mps")  # time series under conditions/
MAX_POINTS = 200_000  # the default stride keeps a frame's point cloud under this
SKY_M = 999.0  # depth at or beyond this is sky (stored as 1000 m)


@dataclass(frozen=True)
class ViewConfig:
    root: str  # output root: local path or s3:// URI
    scenario: str
    episode: int
    out: str | None = None  # .rrd file to write (None: only --spawn)
    spawn: bool = False  # open the rerun viewer and stream to it
    stride: int | None = None  # point cloud: every stride-th pixel (None: keep at most MAX_POINTS)

    def validate(self) -> None:
        if self.out is None and not self.spawn:
            raise ValueError("give --out FILE.rrd, --spawn or both")
        if self.out is not None and not self.out.endswith(".rrd"):
            raise ValueError(f"--out must name a .rrd file, got {self.out}")
        if self.episode < 0:
            raise ValueError(f"episode must be 0 or more, got {self.episode}")
        if self.stride is not None and self.stride < 1:
            raise ValueError(f"stride must be at least 1, got {self.stride}")


@dataclass(frozen=True)
class ViewReport:
    frames: int
    out: str | None


def _rerun():
    try:
        import rerun
    except ImportError as exc:
        raise ImportError("idda view needs rerun-sdk: pip install -e '.[view]'") from exc
    return rerun


def episode_rows(storage, scenario: str, episode: int) -> list[dict]:
    """The manifest rows of one episode, in frame order; ValueError naming what the root holds."""
    import pyarrow.compute as pc


    table = read_manifest(storage)
    rows = table.filter(pc.and_(pc.equal(table.column("scenario"), scenario),
                                pc.equal(table.column("episode"), episode))).to_pylist()
    if not rows:
        held = sorted(set(zip(table.column("scenario").to_pylist(), table.column("episode").to_pylist())))
        scenarios = sorted({s for s, _ in held})
        episodes = [e for s, e in held if s == scenario]
        where = (f"{scenario} has episodes {', '.join(map(str, episodes))}" if episodes
                 else f"scenarios: {', '.join(scenarios[:8])}{' ...' if len(scenarios) > 8 else ''}")
        raise ValueError(f"{storage.uri} holds no episode {episode} of {scenario}; {where}")
    return sorted(rows, key=lambda r: r["frame"])


def _read(storage, row: dict, name: str):
    path = row.get(output_columns(name)[0])
    return None if path is None else read_output(name, storage.read_bytes(path), path)


def annotation_context(rr):
    return rr.AnnotationContext([rr.AnnotationInfo(id=l.id, label=l.name, color=tuple(l.color)) for l in LABELS])


def box_rotation(yaw: float) -> np.ndarray:
    """The 3x3 rotation whose columns are a box's forward, left and up axes in the camera frame
    (``outputs.objects.box_corners``' axes)."""
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, s, 0.0], [0.0, 0.0, -1.0], [-s, c, 0.0]])


def _log_objects(rr, rec, objects) -> None:
    from scipy.spatial.transform import Rotation

    n = objects.num_rows
    cols = {name: objects.column(name).to_numpy(zero_copy_only=False) for name in objects.column_names}
    ids = cols["class_id"].astype(int)
    labels = [f"{c} {i}" for c, i in zip(cols["class_name"], cols["instance_id"])]
    rec.log("world/camera/image/boxes", rr.Boxes2D(
        array=np.stack([cols["x0"], cols["y0"], cols["x1"], cols["y1"]], axis=1).reshape(n, 4),
        array_format=rr.Box2DFormat.XYXY, class_ids=ids, labels=labels))
    rec.log("world/camera/boxes", rr.Boxes3D(
        centers=np.stack([cols["cx"], cols["cy"], cols["cz"]], axis=1).reshape(n, 3),
        sizes=np.stack([cols["length"], cols["width"], cols["height"]], axis=1).reshape(n, 3),
        quaternions=[rr.Quaternion(xyzw=Rotation.from_matrix(box_rotation(float(y))).as_quat()) for y in cols["yaw"]],
        class_ids=ids, labels=labels))


def _stride(row: dict, stride: int | None) -> int:
    return stride or max(1, math.ceil(math.sqrt(row["width"] * row["height"] / MAX_POINTS)))


def log_frame(rr, rec, storage, row: dict, stride: int | None) -> None:
    """Everything of one frame (the time is set by the caller)."""
    K, T = as_matrix(row["K"], 3), as_matrix(row["cam_to_world"], 4)
    rec.log("world/camera", rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]))
    rec.log("world/camera/image", rr.Pinhole(image_from_camera=K, resolution=[row["width"], row["height"]],
                                             camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=2.0))
    rgb = _read(storage, row, "rgb")
    if rgb is not None:
        rec.log("world/camera/image/rgb", rr.Image(rgb))
    semantic = _read(storage, row, "semantic_raw")
    if semantic is not None:
        rec.log("world/camera/image/semantic", rr.SegmentationImage(semantic[..., 0]))
    depth_image = _read(storage, row, "depth_raw")
    if depth_image is not None:
        depth = decode_depth_raw(depth_image).astype(np.float32)
        rec.log("world/camera/image/depth", rr.DepthImage(depth, meter=1.0))
        step = _stride(row, stride)
        sub = depth[::step, ::step]
        K_sub = K.copy()
        K_sub[:2] /= step  # pixel (u, v) of the subsampled image is (u * step, v * step) of the full one
        K_sub[:2, 2] = K[:2, 2] / step
        points = depth_to_world(sub, K_sub, T, max_depth=SKY_M)
        colors = rgb[::step, ::step][sub < SKY_M] if rgb is not None else None
        rec.log("world/depth", rr.Points3D(points, colors=colors, radii=rr.Radius.ui_points(1.5)))
    objects = _read(storage, row, "objects")
    if objects is not None:
        _log_objects(rr, rec, objects)
    for column in SERIES:
        value = row.get(column)
        if value is not None and math.isfinite(value):
            rec.log(f"conditions/{column}", rr.Scalars(float(value)))


def view(config: ViewConfig) -> ViewReport:
    """Write (and or stream) the recording of one episode."""
    config.validate()
    rr = _rerun()
    storage = as_storage(config.root)
    rows = episode_rows(storage, config.scenario, config.episode)
    rec = rr.RecordingStream(APP_ID, recording_id=f"{storage.uri}#{config.scenario}/{config.episode}")
    if config.spawn:
        rec.spawn()
    if config.out is not None:
        rec.save(config.out)  # (with spawn: saved and streamed)
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    rec.log("world", annotation_context(rr), static=True)
    path = np.array([as_matrix(r["cam_to_world"], 4)[:3, 3] for r in rows])
    rec.log("world/trajectory", rr.LineStrips3D([path]), static=True)
    for row in rows:
        rec.set_time("frame", sequence=int(row["frame"]))
        rec.set_time("sim_time", duration=float(row["sim_time_s"]))
        log_frame(rr, rec, storage, row, config.stride)
    rec.flush()
    rec.disconnect()
    return ViewReport(frames=len(rows), out=config.out)
