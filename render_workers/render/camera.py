"""The ego camera rig per viewpoint, and the ego hood that is attached to it.

Frames:
* camera (pyrender/OpenGL): +x right, +y up, looking along -z;
* ego (``render_workers.worlds.scene``): +x forward, +y left, +z up, origin on the road.

The camera is level (no pitch or roll), ``Viewpoint.camera_height_m`` above the
road, looking along the ego's +x, with the viewpoint's horizontal field of view
(``hfov_deg``, 90 degrees unless a domain file says otherwise) at any
resolution (the vertical one follows from the aspect ratio). Pixel centres
sit at half-integers, so row r looks along ``(cy - r - 0.5) / f`` and a flat
road at depth Z appears at row ``cy + f*h/Z - 0.5``.

The hood (viewpoints with ``hood_fraction > 0``) is a flat mesh on a plane
``hood_drop_m`` below the camera, built by intersecting camera rays with that
plane, so its top edge in the image is the parabola ``y(u) = y_c + k*u**2``
(u in [-1, 1] across the width, y a fraction of the image height from the top,
k = ``hood_curvature``). The covered share is ``1 - y_c - k/3``, so
``y_c = 1 - hood_fraction - k/3`` makes it exactly ``hood_fraction`` in the
limit of infinite resolution, at any field of view.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import trimesh

from domains.catalog import Viewpoint, viewpoint as lookup_viewpoint
from domains.rigs import Sensor
from outputs.geometry import CV_FROM_GL, intrinsics

CAMERA_FORWARD_M = 0.2  # camera position ahead of the ego's centre (rear-view mirror)
HOOD_SEGMENTS = 96  # segments along the hood's top edge (chord error ~1e-5 of the image)
HOOD_ROWS = 6  # vertex rows from the edge down, for the paint gradient
HOOD_BOTTOM = 1.15  # the hood mesh runs past the image's bottom edge (image heights)
HOOD_SIDE = 1.03  # and past its sides (half widths)

# ego (x fwd, y left, z up) <- camera (x right, y up, -z forward)
EGO_FROM_CAMERA_ROT = np.array([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def _as_viewpoint(view: Viewpoint | str) -> Viewpoint:
    return lookup_viewpoint(view) if isinstance(view, str) else view


@dataclass(frozen=True)
class CameraRig:
    """Intrinsics and mounting of the ego camera for one viewpoint and resolution."""

    viewpoint: Viewpoint
    width: int
    height: int
    sensor: Sensor | None = None  # a rig's camera (domains.rigs), mounted relative to the viewpoint's; None: the viewpoint's

    def __post_init__(self) -> None:
        if self.width < 1 or self.height < 1:
            raise ValueError(f"camera size must be positive, got {self.width}x{self.height}")

    @property
    def hfov_deg(self) -> float:
        """The viewpoint's own camera (a rig's mount camera too) has the viewpoint's; a rig's other cameras their own."""
        if self.sensor is None or self.sensor.is_mount_camera:
            return self.viewpoint.hfov_deg
        return self.sensor.hfov_deg

    @property
    def has_hood(self) -> bool:
        """Whether this camera sees the ego's hood: the viewpoint's own camera only."""
        return self.sensor is None or self.sensor.is_mount_camera

    @property
    def tan_half_h(self) -> float:
        return math.tan(math.radians(self.hfov_deg) / 2)

    @property
    def tan_half_v(self) -> float:
        return self.tan_half_h * self.height / self.width

    @property
    def yfov(self) -> float:
        """Vertical field of view in radians."""
        return 2.0 * math.atan(self.tan_half_v)

    @property
    def aspect(self) -> float:
        return self.width / self.height

    @property
    def focal_px(self) -> float:
        """Focal length in pixels (square pixels: fx = fy)."""
        return self.width / 2.0 / self.tan_half_h

    @property
    def cx(self) -> float:
        return self.width / 2.0

    @property
    def cy(self) -> float:
        """Principal point row; with a level camera also the horizon row."""
        return self.height / 2.0

    @cached_property
    def ego_from_camera(self) -> np.ndarray:
        m = np.eye(4)
        m[:3, :3] = EGO_FROM_CAMERA_ROT
        m[:3, 3] = (CAMERA_FORWARD_M, 0.0, self.viewpoint.camera_height_m)
        if self.sensor is not None and not self.sensor.is_mount_camera:  # ego <- mount <- sensor <- GL camera
            m = mount_to_ego(self.viewpoint) @ self.sensor.mount_from_sensor() @ _rotation(EGO_FROM_CAMERA_ROT)
        return m

    def world_from_camera(self, world_from_ego: np.ndarray) -> np.ndarray:
        return world_from_ego @ self.ego_from_camera

    @property
    def K(self) -> np.ndarray:
        """3x3 intrinsics in the manifest's convention (``outputs.geometry``: OpenCV, pixel centres at integers)."""
        return intrinsics(self.width, self.height, self.hfov_deg)

    @cached_property
    def cam_to_ego(self) -> np.ndarray:
        """4x4 ego-from-camera with OpenCV camera axes (x right, y down, z forward), as the manifest stores it."""
        return self.ego_from_camera @ CV_FROM_GL

    def project(self, points_cam: np.ndarray) -> np.ndarray:
        """Pixel coordinates (x right, y down; centres at +0.5) of camera-frame points."""
        p = np.atleast_2d(points_cam)
        z = -p[:, 2]
        return np.stack(
            [self.cx + self.focal_px * p[:, 0] / z, self.cy - self.focal_px * p[:, 1] / z], axis=1
        )

    def ground_depth(self, row: float) -> float:
        """Planar depth of a flat road seen at pixel row ``row`` (inf at or above the horizon)."""
        dv = row + 0.5 - self.cy
        return math.inf if dv <= 0 else self.focal_px * self.viewpoint.camera_height_m / dv


def camera_rig(view: Viewpoint | str, width: int, height: int, sensor: Sensor | None = None) -> CameraRig:
    return CameraRig(_as_viewpoint(view), width, height, sensor)


def _rotation(rot: np.ndarray) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = rot
    return m


def mount_to_ego(view: Viewpoint | str) -> np.ndarray:
    """4x4: the viewpoint's camera mount (ego axes, 0.2 m ahead, ``camera_height_m`` up) in the ego frame;
    a rig's sensor poses are given from it (domains.rigs)."""
    m = np.eye(4)
    m[:3, 3] = (CAMERA_FORWARD_M, 0.0, _as_viewpoint(view).camera_height_m)
    return m


# --------------------------------------------------------------------------
# Hood
# --------------------------------------------------------------------------
def hood_fraction(view: Viewpoint | str) -> float:
    """Analytic covered share (continuous limit): ``1 - y_c - k/3``."""
    vp = _as_viewpoint(view)
    if not vp.hood_visible:
        return 0.0
    return 1.0 - hood_edge_centre(vp) - vp.hood_curvature / 3.0


def hood_edge_centre(view: Viewpoint | str) -> float:
    """y_c: the top edge's height at the image centre, as a fraction from the top."""
    vp = _as_viewpoint(view)
    return 1.0 - vp.hood_fraction - vp.hood_curvature / 3.0


def hood_edge(view: Viewpoint | str, u: np.ndarray) -> np.ndarray:
    """The hood's top edge y(u) (fraction of image height from the top) for u in [-1, 1]."""
    vp = _as_viewpoint(view)
    return hood_edge_centre(vp) + vp.hood_curvature * np.square(u)


def hood_mask(view: Viewpoint | str, width: int, height: int) -> np.ndarray:
    """Analytic HxW bool mask of pixels whose centre lies under the hood's edge."""
    vp = _as_viewpoint(view)
    if not vp.hood_visible:
        return np.zeros((height, width), dtype=bool)
    u = (np.arange(width) + 0.5) / width * 2.0 - 1.0
    y = (np.arange(height) + 0.5) / height
    return y[:, None] > hood_edge(vp, u)[None, :]


def measured_hood_fraction(mask: np.ndarray) -> float:
    """Share of True pixels in a rendered hood mask."""
    return float(np.count_nonzero(mask)) / mask.size if mask.size else 0.0


def hood_mesh(view: Viewpoint | str, aspect: float) -> trimesh.Trimesh | None:
    """The hood in the camera frame (None without a hood); vertex colours hold the paint.

    ``aspect`` is width / height; the mesh depends on it only through the
    vertical field of view, so the image-space outline is the same at any size.
    """
    vp = _as_viewpoint(view)
    if not vp.hood_visible:
        return None
    if hood_edge_centre(vp) <= 0.5:
        raise ValueError(f"viewpoint {vp.code}: hood edge must stay below the horizon")
    tan_h = math.tan(math.radians(vp.hfov_deg) / 2)
    tan_v = tan_h / aspect
    u = np.linspace(-HOOD_SIDE, HOOD_SIDE, HOOD_SEGMENTS + 1)
    s = np.linspace(0.0, 1.0, HOOD_ROWS)
    top = hood_edge(vp, u)
    y = top[None, :] + (HOOD_BOTTOM - top[None, :]) * s[:, None]  # (rows, cols)
    uu = np.broadcast_to(u, y.shape)
    t = vp.hood_drop_m / ((2.0 * y - 1.0) * tan_v)  # ray length factor: z = -t
    vertices = np.stack([uu * tan_h * t, np.full_like(t, -vp.hood_drop_m), -t], axis=-1).reshape(-1, 3)

    cols = HOOD_SEGMENTS + 1
    r, c = np.meshgrid(np.arange(HOOD_ROWS - 1), np.arange(HOOD_SEGMENTS), indexing="ij")
    a = (r * cols + c).ravel()
    b, d, e = a + 1, a + cols, a + cols + 1
    faces = np.concatenate([np.stack([a, d, b], 1), np.stack([b, d, e], 1)])

    # Paint: a soft highlight along the middle and darker flanks and lip.
    shade = 0.78 + 0.22 * (1.0 - np.square(uu / HOOD_SIDE)) - 0.12 * (1.0 - s[:, None])
    rgb = np.clip(np.asarray(vp.hood_color, dtype=np.float64)[None, :] * shade.reshape(-1, 1), 0, 255)
    colors = np.concatenate([rgb, np.full((len(rgb), 1), 255.0)], axis=1).astype(np.uint8)
    mesh = trimesh.Trimesh(vertices, faces, vertex_colors=colors, process=False)
    if mesh.face_normals[:, 1].mean() < 0:  # face the sky (+y in the camera frame)
        mesh.invert()
    return mesh


def sun_direction(elevation_deg: float, azimuth_deg: float) -> np.ndarray:
    """Unit world vector towards the sun (azimuth from +x towards +y, z up)."""
    e, a = math.radians(elevation_deg), math.radians(azimuth_deg)
    return np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])
