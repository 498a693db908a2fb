"""Low-poly actors: vehicles (sedan, SUV, van, truck, bus), pedestrians and
riders on bicycles and motorcycles, as Parts in the actor frame (+x forward,
+y left, origin on the ground)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import trimesh

from domains.catalog import class_id
from render_workers.worlds import meshes as M
from render_workers.worlds.scene import Part


@dataclass(frozen=True)
class VehicleKind:
    name: str
    length: float
    width: float
    height: float
    wheel_r: float
    glass_from: float  # share of the height where the windows start
    cabin: tuple[float, float]  # cabin span along x as shares of the length (rear, front)


VEHICLE_KINDS = {
    k.name: k
    for k in (
        VehicleKind("sedan", 4.5, 1.8, 1.45, 0.32, 0.6, (-0.32, 0.18)),
        VehicleKind("suv", 4.8, 1.9, 1.75, 0.36, 0.58, (-0.4, 0.2)),
        VehicleKind("van", 5.2, 2.0, 2.15, 0.34, 0.55, (-0.48, 0.4)),
        VehicleKind("truck", 7.5, 2.4, 3.2, 0.5, 0.55, (0.3, 0.48)),
        VehicleKind("bus", 11.0, 2.55, 3.1, 0.5, 0.5, (-0.47, 0.49)),
    )
}
PAINTS = [(200, 30, 30), (240, 240, 240), (20, 20, 24), (130, 130, 135), (30, 60, 150), (200, 200, 205),
          (20, 90, 50), (230, 180, 20), (110, 20, 30), (70, 110, 160), (180, 90, 30), (90, 90, 95)]
CLOTHES = [(30, 40, 80), (180, 30, 40), (40, 40, 45), (200, 200, 195), (60, 110, 60), (150, 120, 80),
           (220, 170, 40), (90, 60, 120), (120, 120, 130), (30, 110, 160)]
SKIN = [(224, 180, 150), (190, 140, 100), (140, 95, 65), (90, 60, 40)]


def _wheels(xs, half_track, radius, width, sides=8):
    """Wheels as prisms with their axis along y."""
    v, f = M.cylinders(np.zeros((1, 3)), width, radius, sides)
    v = v[:, [0, 2, 1]]  # axis z -> y (this mirrors, so flip the winding)
    v[:, 1] -= width / 2
    f = f[:, [0, 2, 1]]
    vs, fs = [], []
    for x in xs:
        for y in (-half_track, half_track):
            vs.append(v + np.array([x, y, radius]))
            fs.append(f)
    return M._concat(list(zip(vs, fs)))


@lru_cache(maxsize=None)
def _vehicle_geometry(name: str):
    """(body, glass, dark) geometry of one vehicle kind."""
    k = VEHICLE_KINDS[name]
    L, Wd, H = k.length, k.width, k.height
    clear = k.wheel_r * 0.8
    zg = H * k.glass_from
    body = [M.boxes([[0, 0, clear]], [[L, Wd, zg - clear]])]
    r0, r1 = k.cabin
    cab_len = (r1 - r0) * L
    cab_x = (r0 + r1) / 2 * L
    glass = M.boxes([[cab_x, 0, zg]], [[cab_len, Wd * 0.92, (H - zg) * 0.8]])
    body.append(M.boxes([[cab_x, 0, zg + (H - zg) * 0.8]], [[cab_len * 0.98, Wd * 0.94, (H - zg) * 0.2]]))
    if name == "truck":  # cargo box behind the cab
        body.append(M.boxes([[-0.18 * L, 0, clear + 0.2]], [[0.62 * L, Wd, H - clear - 0.2]]))
    xs = (L / 2 - 0.9 - k.wheel_r * 0.5, -L / 2 + 0.9 + k.wheel_r * 0.5)
    dark = [_wheels(xs, Wd / 2 - 0.12, k.wheel_r, 0.25)]
    dark.append(M.boxes([[L / 2 + 0.01, 0, clear + 0.05]], [[0.04, Wd * 0.9, 0.22]]))  # grille / bumper
    dark.append(M.boxes([[-L / 2 - 0.01, 0, clear + 0.05]], [[0.04, Wd * 0.9, 0.22]]))
    return M._concat(body), glass, M._concat(dark)


def _part(cls: str, geom, color, material: str, amount: float = 0.04) -> Part:
    v, f = geom
    cols = M.noisy_colors(v, color, amount, 0.7, seed=int(sum(color)) % 97)
    mesh = trimesh.Trimesh(vertices=v, faces=f, vertex_colors=cols, process=False)
    return Part(class_id(cls), mesh, material)


def vehicle_parts(name: str, paint) -> tuple[Part, ...]:
    body, glass, dark = _vehicle_geometry(name)
    return (_part("vehicle", body, paint, "glossy"),
            _part("vehicle", glass, (34, 44, 56), "glass"),
            _part("vehicle", dark, (26, 26, 28), "matte"))


def _person(height: float, sitting: bool = False):
    """(clothes_top, clothes_bottom, skin) geometry of a person, feet at z=0."""
    s = height / 1.75
    if sitting:
        legs = M.boxes([[0.15 * s, 0.12 * s, 0.55 * s], [0.15 * s, -0.12 * s, 0.55 * s]], [[0.5 * s, 0.15 * s, 0.18 * s]])
        shins = M.boxes([[0.38 * s, 0.12 * s, 0.15 * s], [0.38 * s, -0.12 * s, 0.15 * s]], [[0.14 * s, 0.14 * s, 0.45 * s]])
        bottom = M._concat([legs, shins])
        top = M.boxes([[0.0, 0, 0.72 * s]], [[0.3 * s, 0.42 * s, 0.6 * s]], 0.0)
        arms = M.boxes([[0.25 * s, 0.24 * s, 1.0 * s], [0.25 * s, -0.24 * s, 1.0 * s]], [[0.5 * s, 0.1 * s, 0.1 * s]])
        top = M._concat([top, arms])
        head = M.boxes([[0.05 * s, 0, 1.33 * s]], [[0.22 * s, 0.2 * s, 0.26 * s]])
    else:
        bottom = M.boxes([[0, 0.1 * s, 0], [0, -0.1 * s, 0]], [[0.18 * s, 0.15 * s, 0.86 * s]])
        top = M._concat([M.boxes([[0, 0, 0.86 * s]], [[0.26 * s, 0.44 * s, 0.6 * s]]),
                         M.boxes([[0, 0.27 * s, 0.8 * s], [0, -0.27 * s, 0.8 * s]], [[0.1 * s, 0.09 * s, 0.62 * s]])])
        head = M.boxes([[0, 0, 1.49 * s]], [[0.22 * s, 0.2 * s, 0.26 * s]])
    return top, bottom, head


def pedestrian_parts(rng) -> tuple[Part, ...]:
    height = float(rng.uniform(1.45, 1.95)) if rng.random() > 0.12 else float(rng.uniform(1.0, 1.4))
    top, bottom, head = _person(height)
    geom = M._concat([top, bottom, head])
    v, f = geom
    cols = np.empty((len(v), 4), np.uint8)
    n_top, n_bot = len(top[0]), len(bottom[0])
    cols[:n_top] = M.flat_colors(n_top, CLOTHES[int(rng.integers(len(CLOTHES)))])
    cols[n_top:n_top + n_bot] = M.flat_colors(n_bot, CLOTHES[int(rng.integers(len(CLOTHES)))])
    cols[n_top + n_bot:] = M.flat_colors(len(v) - n_top - n_bot, SKIN[int(rng.integers(len(SKIN)))])
    return (Part(class_id("pedestrian"), trimesh.Trimesh(v, f, vertex_colors=cols, process=False), "matte"),)


def rider_parts(rng, motor: bool) -> tuple[Part, ...]:
    """A bicycle or motorcycle (own class) with its rider (class rider)."""
    r = 0.3 if motor else 0.34
    wheels = _wheels((0.65, -0.65), 0.0, r, 0.12 if motor else 0.05, sides=10)
    if motor:
        frame = M._concat([wheels, M.boxes([[0.0, 0, 0.35]], [[1.2, 0.35, 0.45]]),
                           M.boxes([[0.25, 0, 0.75]], [[0.5, 0.3, 0.2]])])
        vcls, vcol = "motorcycle", PAINTS[int(rng.integers(len(PAINTS)))]
    else:
        frame = M._concat([wheels, M.boxes([[0.0, 0, 0.45]], [[1.0, 0.05, 0.05]]),
                           M.boxes([[-0.1, 0, 0.35]], [[0.05, 0.05, 0.5]]),
                           M.boxes([[0.5, 0, 0.35]], [[0.05, 0.05, 0.65]]),
                           M.boxes([[0.5, 0, 1.0]], [[0.05, 0.55, 0.04]])])
        vcls, vcol = "bicycle", CLOTHES[int(rng.integers(len(CLOTHES)))]
    top, bottom, head = _person(float(rng.uniform(1.6, 1.9)), sitting=True)
    lift = np.array([-0.25, 0, 0.35 if motor else 0.45])
    body = M._concat([top, bottom, head])
    v = body[0] + lift
    cols = M.flat_colors(len(v), CLOTHES[int(rng.integers(len(CLOTHES)))])
    n_h = len(head[0])
    cols[-n_h:] = M.flat_colors(n_h, (40, 40, 45) if motor else SKIN[int(rng.integers(len(SKIN)))])
    rider = Part(class_id("rider"), trimesh.Trimesh(v, body[1], vertex_colors=cols, process=False), "matte")
    fv, ff = frame
    bike = Part(class_id(vcls), trimesh.Trimesh(fv, ff, vertex_colors=M.flat_colors(len(fv), vcol), process=False),
                "glossy" if motor else "metal")
    return bike, rider
