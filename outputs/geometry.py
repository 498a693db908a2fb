"""Camera calibration and poses as the manifest stores them, and depth to points.

One convention for every manifest row (docs/conventions.md draws it):

* camera frame: OpenCV, x right, y down, z forward (along the optical axis);
* ego frame: x forward, y left, z up, origin on the road under the ego's centre;
* world frame: the town's, z up, metres;
* pixels: ``(u, v)`` = (column, row) with integer values at pixel centres, so
  the image's centre is ``((W - 1) / 2, (H - 1) / 2)``.

Row columns (all ``list<double>``, row-major): ``K`` (3x3 intrinsics in
pixels), ``cam_to_world``, ``ego_to_world`` and ``cam_to_ego`` (4x4). A point
``p_cam`` in the camera frame is ``cam_to_world @ [p_cam, 1]`` in the world.
Depth images hold planar depth: the camera-frame z of the surface seen at a pixel.
"""

from __future__ import annotations

import math

import numpy as np

# OpenGL camera axes (x right, y up, looking along -z: pyrender's) -> OpenCV's.
CV_FROM_GL = np.diag([1.0, -1.0, -1.0, 1.0])
HFOV_DEG = 90.0  # the ego camera's horizontal field of view, at any resolution
POSE_COLUMNS = ("K", "cam_to_world", "ego_to_world", "cam_to_ego")


def intrinsics(width: int, height: int, hfov_deg: float) -> np.ndarray:
    """3x3 K of a centred pinhole camera with square pixels and horizontal FoV ``hfov_deg``."""
    f = width / 2.0 / math.tan(math.radians(hfov_deg) / 2.0)
    return np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]])


def flat(matrix: np.ndarray) -> list[float]:
    """A matrix as the manifest stores it: its values row-major, as Python floats."""
    return [float(v) for v in np.asarray(matrix, dtype=np.float64).ravel()]


def unflat(values, size: int) -> np.ndarray:
    """A ``size`` x ``size`` matrix from a manifest cell (row-major list of size**2 numbers)."""
    array = np.asarray(values, dtype=np.float64)
    if array.shape != (size * size,):
        raise ValueError(f"expected {size * size} values for a {size}x{size} matrix, got {array.shape}")
    return array.reshape(size, size)


def as_matrix(value, size: int) -> np.ndarray:
    """A matrix from either a manifest cell (flat list) or an array of shape (size, size)."""
    return unflat(value, size) if np.ndim(value) == 1 else np.asarray(value, dtype=np.float64).reshape(size, size)


def pose_cells(K: np.ndarray, cam_to_world: np.ndarray, ego_to_world: np.ndarray,
               cam_to_ego: np.ndarray) -> dict[str, list[float]]:
    """The four calibration and pose cells of a manifest row."""
    return dict(zip(POSE_COLUMNS, map(flat, (K, cam_to_world, ego_to_world, cam_to_ego))))


def depth_to_world(depth: np.ndarray, K, cam_to_world, max_depth: float = 999.0) -> np.ndarray:
    """(N, 3) world points of the pixels of a planar depth image (metres) nearer than ``max_depth``.

    ``K`` and ``cam_to_world`` may be manifest cells (flat lists) or matrices.
    This is the snippet docs/conventions.md shows."""
    K, T = as_matrix(K, 3), as_matrix(cam_to_world, 4)
    v, u = np.nonzero(depth < max_depth)  # rows, columns; sky is stored as 1000 m
    z = depth[v, u].astype(np.float64)
    x = (u - K[0, 2]) * z / K[0, 0]
    y = (v - K[1, 2]) * z / K[1, 1]
    points_cam = np.stack([x, y, z], axis=1)
    return points_cam @ T[:3, :3].T + T[:3, 3]


def world_to_camera(points: np.ndarray, cam_to_world) -> np.ndarray:
    """(N, 3) world points -> (N, 3) points in the camera frame (OpenCV axes)."""
    T = as_matrix(cam_to_world, 4)
    return (np.asarray(points, dtype=np.float64) - T[:3, 3]) @ T[:3, :3]


def project(points_cam: np.ndarray, K) -> np.ndarray:
    """(N, 3) camera-frame points (z > 0) -> (N, 2) pixel coordinates (u, v)."""
    K = as_matrix(K, 3)
    p = np.asarray(points_cam, dtype=np.float64)
    return np.stack([K[0, 0] * p[:, 0] / p[:, 2] + K[0, 2], K[1, 1] * p[:, 1] / p[:, 2] + K[1, 2]], axis=1)


def normals_from_depth(depth: np.ndarray, K) -> np.ndarray:
    """HxWx3 float32 unit surface normals in the camera frame (OpenCV axes), facing the camera,
    from a planar depth image (metres); 0 where there is no surface (depth >= 999: the sky).

    Each pixel's surface point is back-projected with ``K``; along each image axis the
    one-sided difference to the neighbour of nearer depth is taken (so a normal does not
    straddle an occluding edge), and the normal is their cross product. On the renderer's
    flat-shaded triangles this is the triangle's normal away from its edges."""
    K = as_matrix(K, 3)
    h, w = depth.shape
    z = depth.astype(np.float64)
    u = (np.arange(w) - K[0, 2]) / K[0, 0]
    v = (np.arange(h) - K[1, 2]) / K[1, 1]
    points = np.stack([u[None, :] * z, v[:, None] * z, z], axis=-1)
    padded = np.pad(points, ((1, 1), (1, 1), (0, 0)), constant_values=np.nan)  # no neighbour past the border

    def tangent(before: np.ndarray, after: np.ndarray) -> np.ndarray:
        back, ahead = points - before, after - points
        step_back = np.nan_to_num(np.abs(back[..., 2]), nan=np.inf)
        use_back = step_back < np.nan_to_num(np.abs(ahead[..., 2]), nan=np.inf)
        return np.where(use_back[..., None], back, ahead)

    du = tangent(padded[1:-1, :-2], padded[1:-1, 2:])
    dv = tangent(padded[:-2, 1:-1], padded[2:, 1:-1])
    n = np.cross(du, dv)
    n *= -np.sign(np.einsum("hwc,hwc->hw", n, points))[..., None]  # face the camera
    length = np.linalg.norm(n, axis=-1, keepdims=True)
    valid = (z < 999.0)[..., None] & (length > 0)
    return np.where(valid, n / np.where(length > 0, length, 1.0), 0.0).astype(np.float32)
