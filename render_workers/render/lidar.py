"""A semantic LiDAR from depth renders: a rig's ``lidar`` sensor (``domains.rigs``), one sweep per frame.

How: four class passes (planar depth, class and instance ids: ``Renderer.render_labels``) from the
LiDAR's position, 90 degrees apart in yaw, cover the full turn; each beam (elevation x azimuth) takes
the pixel its ray falls on and returns the point at that pixel's depth along its own ray (interpolated
in 1/Z among the four pixels around the ray where they are one surface). Why not trimesh's ray
casting: it needs rtree (not installed) or Embree (``embreex``, a wheel exists for this Python) as a
new native dependency of every worker, and a second copy of the scene kept in step with the drawn
one (every actor re-posed per frame); the class pass draws the very triangles, actor poses and
culling the cameras draw, on the same GL context, with no new dependency (its cost:
``benchmarks.bench_rigs``). Embree would likely cast a sweep faster; that was not measured. The
price is sampling: within a pixel of an occluding edge a beam takes the nearest pixel's depth and
class, which may be the neighbour surface's.

A sweep is taken at one instant (the frame's): ``rate_hz`` is recorded, not simulated (no rolling
shutter). Points are in the sensor's frame (x forward, y left, z up, metres), in SemanticKITTI's
files: ``.bin`` float32 x, y, z, intensity (0: no reflectance model), ``.label`` uint32 class id in the
low 16 bits and the episode's instance id in the high 16. Beams with no return (sky, beyond
``range_m``) give no point.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from domains.catalog import class_id
from domains.conditions import frame_conditions
from domains.rigs import Sensor, rig_from_json
from outputs.geometry import flat, intrinsics
from render_workers.render.camera import mount_to_ego
from render_workers.worlds.scene import Frame

SKY_ID = class_id("sky")
OVERSAMPLE = 1  # face pixels per azimuth step
EDGE = 1.05  # neighbours whose depths differ by more than this ratio straddle an edge: no interpolation
# the face camera's OpenCV axes (x right, y down, z forward) in the sensor's (x forward, y left, z up)
SENSOR_FROM_CV = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


@dataclass
class LidarSweep:
    """One sweep: points (N, 4) float32 x y z intensity in the sensor frame, labels (N,) uint32."""

    points: np.ndarray
    labels: np.ndarray
    lidar_to_world: np.ndarray  # 4x4
    lidar_to_ego: np.ndarray  # 4x4
    t: float


@functools.lru_cache(maxsize=8)
def beam_directions(sensor: Sensor) -> np.ndarray:
    """(beams, points, 3) unit ray directions in the sensor frame: rows top beam first, azimuth from +x
    towards +y (left) in ``points`` equal steps."""
    elevation = np.radians(np.linspace(sensor.fov_up_deg, sensor.fov_down_deg, sensor.beams))
    azimuth = 2 * np.pi * np.arange(sensor.points) / sensor.points
    e, a = np.meshgrid(elevation, azimuth, indexing="ij")
    dirs = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], axis=-1)
    dirs.flags.writeable = False  # cached: shared by every sweep of the sensor
    return dirs


def face_size(sensor: Sensor) -> tuple[int, int]:
    """Width and height of each of the four 90-degree faces: every beam falls inside one."""
    width = max(8, OVERSAMPLE * sensor.points // 4)
    tan_need = max(abs(math.tan(math.radians(sensor.fov_up_deg))), abs(math.tan(math.radians(sensor.fov_down_deg))))
    height = 2 * math.ceil(width * tan_need * math.sqrt(2.0) * 1.02 / 2) + 2
    return width, height


def cull_distance(sensor: Sensor) -> float:
    """How far from the LiDAR a face pass must draw: a node wholly beyond this changes no point of the sweep.

    A point is kept only within ``range_m``, so its planar depth, and (1/Z interpolation being a weighted
    harmonic mean) the least of the four pixel depths around its ray, is at most ``range_m``. A surface
    farther than D from the sensor has planar depth at least D * cos(the widest angle of a face's pixel from
    its axis); past EDGE * range_m that depth straddles an edge with every such pixel, so the beam takes
    its nearest pixel, and that pixel, if it is the far surface's, returns a point beyond the range. So
    neither the far surface nor the background in its place gives or moves a point."""
    fw, fh = face_size(sensor)
    widest = 1.0 / math.sqrt(1.0 + 1.0 + (fh / fw) ** 2)  # a face corner: 45 degrees across, fh / fw up
    return 1.01 * EDGE * sensor.range_m / widest


def _depth_at(depth: np.ndarray, cls: np.ndarray, u: np.ndarray, v: np.ndarray, row: np.ndarray,
              col: np.ndarray) -> np.ndarray:
    """Planar depth at sub-pixel (u, v): bilinear in 1/Z (exact on a plane) among the four pixels around it
    where they are one class and one surface; the nearest pixel's elsewhere (edges)."""
    h, w = depth.shape
    u0 = np.clip(np.floor(u).astype(int), 0, w - 2)
    v0 = np.clip(np.floor(v).astype(int), 0, h - 2)
    fu, fv = np.clip(u - u0, 0.0, 1.0), np.clip(v - v0, 0.0, 1.0)
    corners = [(v0, u0), (v0, u0 + 1), (v0 + 1, u0), (v0 + 1, u0 + 1)]
    d = np.stack([depth[r, c] for r, c in corners]).astype(np.float64)
    same = np.all(np.stack([cls[r, c] for r, c in corners]) == cls[v0, u0], axis=0) & (d.max(0) < EDGE * d.min(0))
    weights = np.stack([(1 - fu) * (1 - fv), fu * (1 - fv), (1 - fu) * fv, fu * fv])
    smooth = 1.0 / (weights / d).sum(axis=0)
    return np.where(same, smooth, depth[row, col].astype(np.float64))


def lidar_sweep(renderer, sensor: Sensor, t: float, width: int, height: int) -> LidarSweep:
    """The sweep of ``sensor`` at time ``t`` of the renderer's loaded episode (the GL thread's work);
    the renderer is left on the viewpoint's camera at ``width`` x ``height``."""
    fw, fh = face_size(sensor)
    K = intrinsics(fw, fh, 90.0)
    dirs = beam_directions(sensor).reshape(-1, 3)
    azimuth = np.arctan2(dirs[:, 1], dirs[:, 0])
    face_of = np.round(azimuth / (np.pi / 2)).astype(int) % 4
    points = np.zeros((len(dirs), 3))
    classes = np.zeros(len(dirs), np.uint32)
    instance = np.zeros(len(dirs), np.uint32)
    hit = np.zeros(len(dirs), bool)
    lidar_to_ego = mount_to_ego(renderer.rig.viewpoint) @ sensor.mount_from_sensor()
    for face in range(4):
        yaw = face * 90.0
        face_sensor = Sensor(name=f"{sensor.name}face{face}", kind="camera", x=sensor.x, y=sensor.y, z=sensor.z,
                             yaw=sensor.yaw + yaw)
        renderer.use_sensor(face_sensor, fw, fh, hood=False)
        depth, cls, inst, _ = renderer.render_labels(t, cull_m=min(renderer.cull_m, cull_distance(sensor)))
        mine = np.nonzero(face_of == face)[0]
        c, s = math.cos(math.radians(yaw)), math.sin(math.radians(yaw))
        rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ SENSOR_FROM_CV  # sensor <- face's OpenCV
        d_cv = dirs[mine] @ rot  # rows: rot.T @ d
        u = K[0, 0] * d_cv[:, 0] / d_cv[:, 2] + K[0, 2]
        v = K[1, 1] * d_cv[:, 1] / d_cv[:, 2] + K[1, 2]
        col = np.clip(np.rint(u).astype(int), 0, fw - 1)
        row = np.clip(np.rint(v).astype(int), 0, fh - 1)
        z = _depth_at(depth, cls, u, v, row, col)
        points[mine] = (d_cv * (z / d_cv[:, 2])[:, None]) @ rot.T
        classes[mine] = cls[row, col]
        instance[mine] = inst[row, col]
        hit[mine] = (cls[row, col] != SKY_ID) & (z < renderer.zfar * 0.999)
    renderer.use_sensor(None, width, height)
    hit &= np.linalg.norm(points, axis=1) <= sensor.range_m
    xyz = points[hit].astype(np.float32)
    pts = np.concatenate([xyz, np.zeros((len(xyz), 1), np.float32)], axis=1)
    labels = (classes[hit] & 0xFFFF) | (instance[hit] << 16)
    ego_to_world = renderer._episode.ego.pose(t)
    return LidarSweep(pts, labels.astype(np.uint32), ego_to_world @ lidar_to_ego, lidar_to_ego, t)


def lidar_frame(sweep: LidarSweep, scene, spec, index: int, sensor: int, weather) -> Frame:
    """The manifest's view of a sweep taken under ``weather``: a frame with the ``lidar`` buffer, no pixels
    (class counts and K null)."""
    return Frame(
        index=index, sim_time_s=sweep.t, buffers={"lidar": (sweep.points, sweep.labels)}, class_counts=None,
        object_counts=None, camera_height_m=float(sweep.lidar_to_ego[2, 3]), hood_fraction=0.0,
        ego_speed_mps=float(scene.ego.speed_mps), n_vehicles=scene.n_vehicles, n_pedestrians=scene.n_pedestrians,
        K=None, cam_to_world=flat(sweep.lidar_to_world), ego_to_world=flat(scene.ego.pose(sweep.t)),
        cam_to_ego=flat(sweep.lidar_to_ego), conditions=frame_conditions(weather),
        sensor=rig_from_json(spec.rig).sensors[sensor].name,
    )
