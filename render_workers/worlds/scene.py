"""Plain scene objects shared by the world builders and the renderer.

This module imports no renderer: worlds are built and tested as data, and the
renderer (``render_workers.render.renderer``) watches them.

Conventions:
* World frame is z-up, metres: x east, y north, the road surface at z = 0.
* An actor's local frame: +x forward, +y left, +z up, origin on the ground at
  the actor's centre.
* Colours are uint8 RGB(A) vertex colours (albedo); the class id is carried
  per part, never inferred from colour.
"""

from __future__ import annotations

import functools

from dataclasses import dataclass, field

import numpy as np
import trimesh

# Surface looks the renderer knows. Unknown keys raise ValueError in the renderer.
MATERIALS = ("matte", "glossy", "metal", "glass", "emissive", "road", "water")


@dataclass(frozen=True, eq=False)
class Part:
    """A piece of geometry with one class and one material."""

    class_id: int
    mesh: trimesh.Trimesh  # vertex colours hold the albedo
    material: str = "matte"
    texture: str = ""  # name of a World texture multiplied into the colours (static parts); "" = none

    def __post_init__(self) -> None:
        if self.material not in MATERIALS:
            raise ValueError(f"unknown material {self.material!r}; valid: {', '.join(MATERIALS)}")


@dataclass(frozen=True, eq=False)
class Path:
    """A polyline on the ground that actors follow."""

    points: np.ndarray  # (K, 3) float64, world frame
    closed: bool = False

    @property
    def cumulative(self) -> np.ndarray:
        """Arc length at each point of the loop (read-only)."""
        return self._arc[1]

    @property
    def length(self) -> float:
        return float(self.cumulative[-1])

    def _loop(self) -> np.ndarray:
        return self._arc[0]

    @functools.cached_property
    def _arc(self) -> tuple[np.ndarray, np.ndarray]:
        """(the points, closed by the first again; their arc lengths), both read-only: made once per
        path, not at every ``at`` (every actor's pose, every frame)."""
        pts = np.vstack([self.points, self.points[:1]]) if self.closed else self.points.copy()
        seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        cum = np.concatenate([[0.0], np.cumsum(seg)])
        pts.flags.writeable = cum.flags.writeable = False
        return pts, cum

    def at(self, s: float) -> tuple[np.ndarray, float]:
        """Position and heading (radians from +x) at arc length ``s``.

        Closed paths wrap around; open paths are driven back and forth.
        """
        pts = self._loop()
        cum = self.cumulative
        total = cum[-1]
        if total <= 0:
            return pts[0].copy(), 0.0
        if self.closed:
            s = s % total
            direction = 1.0
        else:
            period = s % (2 * total)
            direction = 1.0 if period <= total else -1.0
            s = period if period <= total else 2 * total - period
        i = min(max(int(np.searchsorted(cum, s, side="right")) - 1, 0), len(pts) - 2)
        seg = pts[i + 1] - pts[i]
        seg_len = cum[i + 1] - cum[i]
        frac = 0.0 if seg_len == 0 else (s - cum[i]) / seg_len
        pos = pts[i] + frac * seg
        heading = float(np.arctan2(seg[1], seg[0]))
        if direction < 0:
            heading += np.pi
        return pos, heading


def pose_matrix(position: np.ndarray, heading: float) -> np.ndarray:
    """4x4 world-from-local transform for a ground actor."""
    c, s = np.cos(heading), np.sin(heading)
    m = np.eye(4)
    m[:2, :2] = [[c, -s], [s, c]]
    m[:3, 3] = position
    return m


@dataclass(frozen=True, eq=False)
class Actor:
    """Something that moves (or is parked) along a path."""

    kind: str  # "sedan", "suv", "van", "truck", "bus", "pedestrian", "cyclist", ...
    parts: tuple[Part, ...]  # in the actor frame
    path: Path
    offset_m: float = 0.0  # start distance along the path
    speed_mps: float = 0.0  # 0 for parked / standing
    lateral_m: float = 0.0  # sideways shift from the path (+ = left)

    def pose(self, t: float) -> np.ndarray:
        pos, heading = self.path.at(self.offset_m + self.speed_mps * t)
        if self.lateral_m:
            pos = pos + self.lateral_m * np.array([-np.sin(heading), np.cos(heading), 0.0])
        return pose_matrix(pos, heading)


@dataclass(frozen=True, eq=False)
class Loop:
    """A closed lane loop and what traffic needs to know about it."""

    path: Path
    kind: str  # "block" | "perimeter" | "freeway"
    lane: int  # 0 = next to the centre line / median
    min_radius_m: float  # tightest corner
    parking: tuple[tuple[float, float], ...]  # arc-length spans with a kerbside parking strip
    parking_lateral_m: float  # lateral offset of parked cars (negative = right)
    kerb_lateral_m: float  # lateral offset for riders at the lane's right edge
    lane_sep_m: float = 3.5  # distance to the nearest lane centre of another loop or lane


@dataclass(frozen=True, eq=False)
class Crosswalk:
    """A zebra crossing on one approach of a junction (sidewalk towns only)."""

    centre: np.ndarray  # (2,) middle of the zebra, on the street's centre line
    across: np.ndarray  # (2,) unit vector across the street
    half_road: float  # centre line to kerb
    reach: tuple[float, float]  # straight sidewalk beyond the kerb on the -across / +across side
    kerb_h: float = 0.15  # height of the sidewalks at both ends


@dataclass(frozen=True, eq=False)
class World:
    """A town's static geometry and the paths traffic can use."""

    town: str  # town code, e.g. T01
    seed: int
    static: tuple[Part, ...]  # merged geometry: few, large parts
    lanes: tuple[Path, ...]  # drivable lane centre lines
    walkways: tuple[Path, ...] = ()  # sidewalk and crossing paths
    bounds: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)  # xmin, ymin, xmax, ymax
    loops: tuple[Loop, ...] = ()  # the lanes with their kind, parking spans and kerb offsets (same order)
    crosswalks: tuple[Crosswalk, ...] = ()  # zebra crossings
    walk_lanes: tuple[tuple[Path, ...], ...] = ()  # per lane: the closed walkways moved k lanes off the road
    textures: dict = field(default_factory=dict)  # texture name -> (px, px, 3) uint8, for Part.texture
    lights: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # (N, 3) street lamps' luminaires (centres)
    street_density: float = 0.0  # the town's Town.street_density: traffic fills its kerbs and pavements by it


@dataclass(frozen=True, eq=False)
class EpisodeScene:
    """A world populated for one episode."""

    world: World
    actors: tuple[Actor, ...]
    ego: Actor  # the camera car; its parts are not drawn (the hood is)
    n_vehicles: int
    n_pedestrians: int
    extras: dict = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class Frame:
    """One rendered frame: its named buffers and what the manifest records (``manifests.writer.frame_row``).

    The episode job (``pipeline.episode_job``) encodes the buffers into the
    spec's outputs and files; rendering knows no output table."""

    index: int  # frame index within the episode
    sim_time_s: float  # simulated time of the frame (index * the spec's frame interval)
    buffers: dict  # rgb (post effects applied), depth, classes, instance, and objects (a table) when asked
    class_counts: np.ndarray  # (24,) int64 pixel count per class id, sums to W*H
    object_counts: dict  # manifest column obj_<class> -> visible objects of that class
    camera_height_m: float
    hood_fraction: float  # share of pixels covered by the ego hood
    ego_speed_mps: float
    n_vehicles: int  # the episode's traffic
    n_pedestrians: int
    # Calibration and poses, flat row-major (outputs.geometry: OpenCV camera axes, world z up, metres)
    K: list  # 9 values, 3x3 intrinsics in pixels
    cam_to_world: list  # 16 values, 4x4
    ego_to_world: list  # 16 values, 4x4
    cam_to_ego: list  # 16 values, 4x4, fixed per viewpoint
    conditions: dict  # condition column -> value (domains.conditions): the weather this frame was rendered under
    sensor: str = ""  # the rig's sensor that saw it (domains.rigs); "" in the default rig (no sensor column)
