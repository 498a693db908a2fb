"""A small deterministic test world: one rectangular loop road lined with every class.

Same interface as the procedural world (``render_workers.worlds.world``):

* ``build_world(town_code, seed) -> World``
* ``populate(world, viewpoint_code, episode_seed) -> EpisodeScene``

The loop's size follows the town's block length. Every ``MODULE_M`` metres each
side of the road repeats a module holding all static classes 1..23 except sky
(including a standing person, a parked bicycle and a motorcycle with its
rider), so wherever the ego drives every class is in view. Traffic drives
counter-clockwise on the outer lane and clockwise on the inner lane (right-hand
traffic); pedestrians walk the sidewalks. Counts follow IDDA: vehicles in
[20, 150] and pedestrians in [0, 100], drawn from ``episode_seed``.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import trimesh
from trimesh.transformations import transform_points

from domains.catalog import CLASS_IDS, town as lookup_town, viewpoint as lookup_viewpoint
from render_workers.worlds.scene import Actor, EpisodeScene, Part, Path, World

MODULE_M = 40.0  # length of the repeated roadside module
ROAD_HALF_M = 5.0  # road half width (two 3.5 m lanes plus parking strips)
LANE_M = 1.75  # lane centre offset from the road centre line
PARK_M = 3.7  # parked cars' offset from the road centre line
WALK_M = 6.5  # sidewalk centre offset
VEHICLES = (20, 150)  # IDDA: random number of vehicles per episode
PEDESTRIANS = (0, 100)  # IDDA: random number of pedestrians per episode

C = CLASS_IDS  # class name -> id


# --------------------------------------------------------------------------
# Geometry helpers
# --------------------------------------------------------------------------
class _Mesh(NamedTuple):
    """Vertices and faces only: all a collected piece needs until it is merged (a Trimesh per box
    cost 3 ms, most of an episode's population; this gives the same numbers in a thirtieth)."""

    vertices: np.ndarray
    faces: np.ndarray


class _Collector:
    """Accumulates coloured meshes per (class id, material) and merges them into Parts."""

    def __init__(self) -> None:
        self._groups: dict[tuple[int, str], list[tuple[np.ndarray, np.ndarray, np.ndarray]]] = {}

    def add(self, cls: int, mesh: trimesh.Trimesh | _Mesh, color, material: str = "matte") -> None:
        rgba = np.array([*color, 255][:4], dtype=np.uint8)
        piece = (mesh.vertices, mesh.faces, np.tile(rgba, (len(mesh.vertices), 1)))
        self._groups.setdefault((cls, material), []).append(piece)

    def parts(self) -> tuple[Part, ...]:
        return tuple(Part(cls, _merge(pieces), material) for (cls, material), pieces in sorted(self._groups.items()))


def _merge(pieces: list[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> trimesh.Trimesh:
    vertices, faces, colors, base = [], [], [], 0
    for v, f, c in pieces:
        vertices.append(v)
        faces.append(f + base)
        colors.append(c)
        base += len(v)
    return trimesh.Trimesh(np.vstack(vertices), np.vstack(faces), vertex_colors=np.vstack(colors), process=False)


_UNIT_BOX = trimesh.creation.box(extents=(1.0, 1.0, 1.0))  # centred; scaling it by extents is what box() does
_BOX_VERTICES, _BOX_FACES = _UNIT_BOX.vertices.copy(), _UNIT_BOX.faces.copy()


def _box(extents, centre, yaw: float = 0.0) -> _Mesh:
    """trimesh.creation.box(extents) moved by (centre, yaw), to the bit (tests/test_world.py)."""
    return _Mesh(transform_points(_BOX_VERTICES * np.asarray(extents, dtype=np.float64), _transform(centre, yaw)),
                 _BOX_FACES)


def _cylinder(radius: float, height: float, base, sections: int = 8) -> trimesh.Trimesh:
    m = trimesh.creation.cylinder(radius=radius, height=height, sections=sections)
    m.apply_translation(np.asarray(base, dtype=float) + [0.0, 0.0, height / 2])
    return m


def _ball(radius: float, centre) -> trimesh.Trimesh:
    m = trimesh.creation.icosphere(subdivisions=1, radius=radius)
    m.apply_translation(centre)
    return m


def _transform(centre, yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    t = np.eye(4)
    t[:2, :2] = [[c, -s], [s, c]]
    t[:3, 3] = centre
    return t


def _quad(corners: np.ndarray) -> trimesh.Trimesh:
    """A flat, upward-facing quad from 4 counter-clockwise corners (seen from above)."""
    return trimesh.Trimesh(corners, [[0, 1, 2], [0, 2, 3]], process=False)


def _rect_loop(a: float, b: float, clockwise: bool = False) -> Path:
    pts = np.array([[-a, -b, 0.0], [a, -b, 0.0], [a, b, 0.0], [-a, b, 0.0]])
    return Path(pts[::-1].copy() if clockwise else pts, closed=True)


# --------------------------------------------------------------------------
# World
# --------------------------------------------------------------------------
class _Edge:
    """Local frame along one straight edge: s along, l to the left (inside the loop), z up."""

    def __init__(self, p0: np.ndarray, p1: np.ndarray) -> None:
        self.p0 = p0
        d = p1 - p0
        self.length = float(np.linalg.norm(d))
        self.d = d / self.length
        self.n = np.array([-self.d[1], self.d[0], 0.0])
        self.yaw = math.atan2(self.d[1], self.d[0])

    def at(self, s: float, l: float, z: float = 0.0) -> np.ndarray:
        return self.p0 + s * self.d + l * self.n + [0.0, 0.0, z]

    def box(self, s0: float, s1: float, l0: float, l1: float, z0: float, z1: float) -> trimesh.Trimesh:
        centre = self.at((s0 + s1) / 2, (l0 + l1) / 2, (z0 + z1) / 2)
        return _box((abs(s1 - s0), abs(l1 - l0), abs(z1 - z0)), centre, self.yaw)


def _road(col: _Collector, e: _Edge) -> None:
    step = 10.0
    for s0 in np.arange(-ROAD_HALF_M, e.length + ROAD_HALF_M, step):
        s1 = min(s0 + step, e.length + ROAD_HALF_M)
        col.add(C["road"], _quad(np.array([e.at(s0, -ROAD_HALF_M), e.at(s1, -ROAD_HALF_M),
                                           e.at(s1, ROAD_HALF_M), e.at(s0, ROAD_HALF_M)])), (72, 70, 76), "road")
    for s0 in np.arange(2.0, e.length - 3.0, 9.0):  # dashed centre line
        col.add(C["road line"], e.box(s0, s0 + 3.0, -0.08, 0.08, 0.0, 0.03), (235, 235, 225), "road")
    for l in (-ROAD_HALF_M + 0.25, ROAD_HALF_M - 0.25):  # solid edge lines
        for s0 in np.arange(ROAD_HALF_M, e.length - ROAD_HALF_M, 20.0):
            s1 = min(s0 + 20.0, e.length - ROAD_HALF_M)
            col.add(C["road line"], e.box(s0, s1, l - 0.06, l + 0.06, 0.0, 0.03), (230, 230, 230), "road")


def _module(col: _Collector, e: _Edge, m: float, rng: np.random.Generator, town_height) -> None:
    """One roadside module starting at arc length ``m``: every static class on both sides."""
    out, inn = -1.0, 1.0  # lateral sign of the outer and inner side
    grey = lambda v: (v, v, v)  # noqa: E731
    for side in (out, inn):
        col.add(C["sidewalk"], e.box(m, m + MODULE_M, side * 5.0, side * 8.0, 0.0, 0.15), grey(150))
    # outer side: buildings, wall, fence, street furniture
    h = float(rng.uniform(*town_height))
    shade = rng.integers(90, 200, size=3)
    col.add(C["building"], e.box(m + 2, m + 21, -11.0, -23.0, 0.0, h), tuple(shade))
    col.add(C["building"], e.box(m + 4, m + 19, -10.5, -11.0, 0.0, min(h, 3.0) + 0.5), tuple(shade // 2 + 40))
    col.add(C["wall"], e.box(m + 23, m + 38, -11.5, -12.1, 0.0, 3.2), (150, 135, 120))
    col.add(C["fence"], e.box(m + 23, m + 38, -9.3, -9.4, 0.0, 1.1), (120, 110, 95))
    col.add(C["pole"], _cylinder(0.12, 6.5, e.at(m + 5, -5.5)), grey(110), "metal")
    col.add(C["pole"], e.box(m + 4.8, m + 5.2, -5.5, -3.5, 6.3, 6.5), grey(110), "metal")
    col.add(C["traffic light"], e.box(m + 4.9, m + 5.25, -3.9, -3.5, 5.3, 6.3), (40, 40, 35), "glossy")
    col.add(C["traffic light"], e.box(m + 4.85, m + 4.9, -3.85, -3.55, 5.95, 6.2), (255, 60, 40), "emissive")
    col.add(C["pole"], _cylinder(0.06, 2.6, e.at(m + 15, -5.6)), grey(140), "metal")
    col.add(C["traffic sign"], e.box(m + 14.95, m + 15.0, -5.2, -6.0, 2.0, 2.8), (230, 230, 240), "glossy")
    col.add(C["traffic sign"], e.box(m + 14.9, m + 14.95, -5.3, -5.9, 2.1, 2.7), (200, 30, 30), "glossy")
    col.add(C["vegetation"], _cylinder(0.18, 2.6, e.at(m + 10, -7.2)), (90, 70, 45))
    col.add(C["vegetation"], _ball(2.0, e.at(m + 10, -7.2, 4.3)), (55 + int(rng.integers(0, 30)), 110, 40))
    col.add(C["vegetation"], e.box(m + 30, m + 37, -8.6, -9.2, 0.0, 1.2), (60, 105, 45))
    col.add(C["dynamic"], e.box(m + 19.7, m + 20.3, -5.4, -6.0, 0.15, 1.15), (70, 90, 60), "glossy")
    col.add(C["static"], e.box(m + 24, m + 25.8, -7.3, -7.8, 0.15, 0.65), (130, 95, 60))
    col.add(C["other"], e.box(m + 35.5, m + 36.7, -6.8, -7.9, 0.15, 2.4), (170, 150, 80), "glossy")
    # a standing person, a parked bicycle and a motorcycle with its rider
    col.add(C["pedestrian"], e.box(m + 27.8, m + 28.2, -6.0, -6.45, 0.15, 1.45), (60, 60, 120))
    col.add(C["pedestrian"], _ball(0.13, e.at(m + 28.0, -6.22, 1.6)), (220, 180, 150))
    col.add(C["bicycle"], e.box(m + 32.0, m + 33.7, -5.3, -5.4, 0.15, 1.05), (20, 20, 20), "metal")
    col.add(C["motorcycle"], e.box(m + 12.0, m + 14.0, -4.3, -4.7, 0.0, 1.1), (160, 20, 20), "glossy")
    col.add(C["rider"], e.box(m + 12.6, m + 13.2, -4.25, -4.75, 1.1, 1.9), (40, 40, 40))
    col.add(C["rider"], _ball(0.16, e.at(m + 12.9, -4.5, 2.05)), (230, 230, 230), "glossy")
    # inner side: guard rail, grass, dirt, railway, bushes
    col.add(C["guard rail"], e.box(m + 2, m + 20, 5.05, 5.15, 0.45, 0.85), grey(175), "metal")
    col.add(C["terrain"], e.box(m, m + MODULE_M, 8.0, 15.0, -0.1, 0.06), (95, 125, 60))
    col.add(C["ground"], e.box(m + 20, m + 31, 8.5, 13.5, -0.1, 0.09), (120, 100, 75))
    col.add(C["railway"], e.box(m, m + MODULE_M, 15.5, 18.5, -0.1, 0.12), (110, 95, 85))
    for l in (16.3, 17.7):
        col.add(C["railway"], e.box(m, m + MODULE_M, l - 0.04, l + 0.04, 0.12, 0.25), grey(150), "metal")
    col.add(C["vegetation"], _ball(1.3, e.at(m + 8, 11.0, 0.9)), (70, 120, 50))


def _ground(col: _Collector, xmin: float, ymin: float, xmax: float, ymax: float, cell: float = 40.0) -> None:
    xs = np.arange(xmin, xmax, cell)
    ys = np.arange(ymin, ymax, cell)
    for x in xs:
        for y in ys:
            corners = np.array([[x, y, -0.1], [x + cell, y, -0.1], [x + cell, y + cell, -0.1], [x, y + cell, -0.1]])
            col.add(C["terrain"], _quad(corners), (88, 112, 62))


def loop_size(town_code: str) -> tuple[float, float]:
    """Half length and half width of the town's loop road centre line."""
    t = lookup_town(town_code)
    return max(120.0, 3.0 * t.block_m), max(60.0, 1.5 * t.block_m)


def build_world(town_code: str, seed: int) -> World:
    """The test world for a town (its size and building heights follow the town)."""
    t = lookup_town(town_code)
    rng = np.random.default_rng([seed, 101])
    a, b = loop_size(town_code)
    col = _Collector()
    loop = _rect_loop(a, b).points
    for i in range(4):
        e = _Edge(loop[i], loop[(i + 1) % 4])
        _road(col, e)
        for m in np.arange(ROAD_HALF_M + 3.0, e.length - ROAD_HALF_M - 3.0 - MODULE_M + 1e-6, MODULE_M):
            _module(col, e, float(m), rng, t.building_height_m)
    margin = 150.0
    _ground(col, -a - margin, -b - margin, a + margin, b + margin)
    lanes = (_rect_loop(a + LANE_M, b + LANE_M), _rect_loop(a - LANE_M, b - LANE_M, clockwise=True))
    walkways = (_rect_loop(a + WALK_M, b + WALK_M), _rect_loop(a - WALK_M, b - WALK_M, clockwise=True))
    return World(town=t.code, seed=seed, static=col.parts(), lanes=lanes, walkways=walkways,
                 bounds=(-a - margin, -b - margin, a + margin, b + margin))


# --------------------------------------------------------------------------
# Episode
# --------------------------------------------------------------------------
def _vehicle_parts(rng: np.random.Generator, length: float = 4.4) -> tuple[Part, ...]:
    col = _Collector()
    paint = tuple(int(v) for v in rng.integers(20, 235, size=3))
    width, body_h = 1.8, float(rng.uniform(0.6, 0.9))
    col.add(C["vehicle"], _box((length, width, body_h), (0.0, 0.0, 0.3 + body_h / 2)), paint, "glossy")
    col.add(C["vehicle"], _box((length * 0.5, width * 0.9, 0.55), (-0.2, 0.0, 0.3 + body_h + 0.27)), (35, 45, 55), "glass")
    for x in (-length * 0.32, length * 0.32):
        for y in (-width / 2, width / 2):
            col.add(C["vehicle"], _box((0.65, 0.25, 0.65), (x, y, 0.33)), (25, 25, 25), "glass")
    return col.parts()


def _pedestrian_parts(rng: np.random.Generator) -> tuple[Part, ...]:
    col = _Collector()
    h = float(rng.uniform(1.5, 1.9))
    shirt = tuple(int(v) for v in rng.integers(30, 220, size=3))
    col.add(C["pedestrian"], _box((0.3, 0.45, h - 0.3), (0.0, 0.0, (h - 0.3) / 2)), shirt)
    col.add(C["pedestrian"], _ball(0.13, (0.0, 0.0, h - 0.15)), (225, 185, 150))
    return col.parts()


def _slots(rng: np.random.Generator, length: float, spacing: float, count: int,
            avoid: tuple[float, float] | None = None) -> np.ndarray:
    slots = np.arange(0.0, length - spacing, spacing)
    if avoid is not None:
        lo, hi = avoid
        rel = (slots - lo) % length
        slots = slots[rel > (hi - lo)]
    return np.sort(rng.choice(slots, size=min(count, len(slots)), replace=False))


def populate(world: World, viewpoint_code: str, episode_seed: int) -> EpisodeScene:
    """Ego, traffic and pedestrians for one episode, all drawn from ``episode_seed``."""
    vp = lookup_viewpoint(viewpoint_code)
    rng = np.random.default_rng([episode_seed, 202])
    n_vehicles = int(rng.integers(VEHICLES[0], VEHICLES[1] + 1))
    n_pedestrians = int(rng.integers(PEDESTRIANS[0], PEDESTRIANS[1] + 1))
    ego_lane, other_lane = world.lanes[0], world.lanes[1]
    ego_start = float(rng.uniform(0.0, ego_lane.length))
    ego_speed = float(rng.uniform(7.0, 12.0))
    ego = Actor(kind=vp.vehicle, parts=(), path=ego_lane, offset_m=ego_start, speed_mps=ego_speed)

    actors: list[Actor] = []
    # one vehicle just ahead of the ego, at its speed, so traffic is always in view
    actors.append(Actor("sedan", _vehicle_parts(rng), ego_lane, ego_start + 22.0, ego_speed))
    n_moving = (n_vehicles - 1) // 2
    n_parked = n_vehicles - 1 - n_moving
    n_same = n_moving // 2
    oncoming_speed = float(rng.uniform(7.0, 12.0))
    for s in _slots(rng, ego_lane.length, 25.0, n_same, avoid=(ego_start - 15.0, ego_start + 45.0)):
        actors.append(Actor("sedan", _vehicle_parts(rng), ego_lane, float(s), ego_speed))
    for s in _slots(rng, other_lane.length, 25.0, n_moving - n_same):
        actors.append(Actor("sedan", _vehicle_parts(rng), other_lane, float(s), oncoming_speed))
    for k, s in enumerate(_slots(rng, 2 * ego_lane.length, 9.0, n_parked)):
        lane = ego_lane if k % 2 == 0 else other_lane
        actors.append(Actor("sedan", _vehicle_parts(rng), lane, float(s) % lane.length, 0.0,
                            lateral_m=-(PARK_M - LANE_M)))
    n_vehicles = len(actors)
    for k in range(n_pedestrians):
        walk = world.walkways[k % len(world.walkways)]
        actors.append(Actor("pedestrian", _pedestrian_parts(rng), walk, float(rng.uniform(0.0, walk.length)),
                            float(rng.uniform(0.8, 1.6)), lateral_m=float(rng.uniform(-1.0, 1.0))))
    return EpisodeScene(world=world, actors=tuple(actors), ego=ego, n_vehicles=n_vehicles,
                        n_pedestrians=n_pedestrians, extras={"world": "test"})
