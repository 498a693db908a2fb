"""Town blocks: buildings and fillers (gardens, parking courts, plazas) along
the street sides of every block, in the style's architecture kit.

Kits (``Style.architecture``; ``ARCHITECTURE`` maps each to its lot builder):

* ``european``: terraced houses on narrow lots at the pavement, brick and
  plaster, pitched tiled roofs, framed windows;
* ``modern``: mid- and high-rise on wide lots, glass curtain walls with
  spandrel bands or concrete window grids, flat roofs with plant rooms;
* ``alpine``: plastered houses with a timber top floor, steep slate or metal
  roofs with deep eaves;
* ``suburban``: detached sided houses behind lawns, and industrial sheds;
* ``farm``: farmhouses with barns behind them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from domains.catalog import lookup
from render_workers.worlds.styles import surface, is_urban
from render_workers.worlds import meshes as M
from render_workers.worlds.builder import PALETTE, Kit
from render_workers.worlds.town_plan import OUTER_Z

FLOOR_M = 3.2
DENSE_TALLER = 0.25  # at street density 1, buildings are this share taller (and their kits' floor caps too)


@dataclass(frozen=True)
class Lot:
    """One building lot on a block's street side."""

    o: np.ndarray  # block corner the side starts at
    a: np.ndarray  # along the street
    inw: np.ndarray  # into the block
    s0: float  # lot start along the side
    s1: float  # lot end
    depth: float  # lot depth from the back of the sidewalk
    z: float  # ground level

    @property
    def width(self) -> float:
        return self.s1 - self.s0

    @property
    def yaw(self) -> float:
        return float(np.arctan2(self.a[1], self.a[0]))

    def point(self, s: float, d: float) -> np.ndarray:
        return self.o + self.a * s + self.inw * d


# --------------------------------------------------------------------------
# One building: walls, roof, windows, door
# --------------------------------------------------------------------------
def house(kit: Kit, lot: Lot, s0: float, s1: float, setback: float, depth: float, floors: int,
          facade: str, roof: str, roof_kind: str, windows: str, floor_m: float = FLOOR_M,
          top_facade: str | None = None) -> None:
    """A box building on ``lot`` from s0 to s1, ``setback`` behind its front edge.

    roof_kind: "gable" (ridge along the street), "steep" (gable with deep eaves) or "flat";
    windows: "framed" (punched windows with light frames), "grid", "ribbon", "curtain" or "none";
    top_facade: another facade for the top floor (timber upper storeys).
    """
    rng = kit.rng
    width = s1 - s0
    if width < 4 or depth < 4:
        return
    z = lot.z
    h = floors * floor_m + 0.5
    yaw = lot.yaw
    mid = lot.point((s0 + s1) / 2, setback + depth / 2)
    kit.buildings.append((float(mid[0]), float(mid[1]), float(width), float(depth), yaw))
    corners = [lot.point(s0, setback), lot.point(s1, setback), lot.point(s1, setback + depth), lot.point(s0, setback + depth)]
    sign = np.sign(lot.a[0] * lot.inw[1] - lot.a[1] * lot.inw[0])
    vs, fs, off, faces_info = [], [], 0, []
    for k in range(4):
        p, q = corners[k], corners[(k + 1) % 4]
        if sign < 0:
            p, q = q, p
        edge = q - p
        L = float(np.linalg.norm(edge))
        v, f = M.grid((*p, z), (*edge, 0), (0, 0, h), max(1, int(L / 6)), max(1, floors))
        vs.append(v)
        fs.append(f + off)
        off += len(v)
        faces_info.append((p, edge / L, L, k == 0))
    verts, faces = np.concatenate(vs), np.concatenate(fs)
    s = surface(facade)
    base = kit.base_color(s) * rng.uniform(0.92, 1.08)
    cols = M.noisy_colors(verts, base, s.noise, s.scale_m, seed=int(rng.integers(1 << 16)), fine=0.04)
    if s.look != "glass":  # darker plinth
        plinth = verts[:, 2] - z < 0.05
        cols[plinth, :3] = (cols[plinth, :3] * 0.75).astype(np.uint8)
    if top_facade and floors > 1:
        top = verts[:, 2] > z + (floors - 1) * floor_m + 0.3
        cols[top, :3] = np.array(surface(top_facade).color, np.uint8)
    kit.add_colored("building", verts, faces, cols, s.look, texture=s.texture)
    rc = np.array([*mid, z + h])
    if roof_kind in ("gable", "steep"):
        eave = 0.9 if roof_kind == "steep" else 0.35
        pitch = 0.55 if roof_kind == "steep" else 0.38
        v, f = M.prism_roofs(rc[None], np.array([[width + 2 * eave, depth + 2 * eave, 0]]), pitch * depth, yaw)
        kit.paint("building", v, f, roof)
    else:
        v, f = M.ground_rect(-width / 2, -depth / 2, width / 2, depth / 2, 0, 8.0)
        v = M.transform(v, rc, yaw)
        kit.paint("building", v, M.orient_up(v, f), roof)
        if rng.random() < 0.6:  # plant room / parapet box
            kit.props_box("building", rc, [min(6, width / 3), min(5, depth / 3), 2.2], yaw, (150, 150, 150))
    _windows(kit, faces_info, z, floors, floor_m, windows, s.look)


def _windows(kit: Kit, facades, z, floors, floor_m, style: str, look: str) -> None:
    rng = kit.rng
    if style == "none":
        return
    glass, frames, doors = [], [], []
    bay = rng.uniform(2.6, 3.4) if style == "framed" else rng.uniform(3.0, 4.2)
    for p, e, L, front in facades:
        out = np.array([e[1], -e[0], 0.0])  # outward normal (faces wind outwards)
        n_bays = max(1, int(L / bay))
        margin = (L - n_bays * bay) / 2
        for fl in range(floors):
            zf = z + 0.5 + fl * floor_m
            if fl == 0 and style in ("framed", "grid") and front:
                k = int(rng.integers(n_bays))
                doors.append((np.array([*(p + e * (margin + k * bay + bay / 2 - 0.6)), z]) + out * 0.07, e * 1.2))
            if style == "curtain":  # glass walls with a spandrel band per floor
                frames.append((np.array([*(p + e * 0.05), zf + floor_m - 0.9]) + out * 0.05, e * (L - 0.1), 0.7))
                continue
            if style == "ribbon":
                glass.append((np.array([*(p + e * 0.4), zf + 0.8]) + out * 0.06, e * (L - 0.8), 1.4))
                continue
            if fl == 0 and style == "framed":
                continue  # shop fronts and doors on the ground floor
            w, hgt = (0.32 * bay, 1.5) if style == "framed" else (0.45 * bay, 1.6)
            for b in range(n_bays):
                c = p + e * (margin + b * bay + bay / 2 - w / 2)
                if style == "framed":
                    frames.append((np.array([*(c - e * 0.12), zf + 0.55]) + out * 0.04, e * (w + 0.24), hgt + 0.3))
                glass.append((np.array([*c, zf + 0.7]) + out * 0.07, e * w, hgt))
    for items, col, mat in ((frames, PALETTE["window_frame"] if style == "framed" else (96, 100, 106), "matte"),
                            (glass, PALETTE["window"], "glass")):
        if items:
            p0 = np.array([q[0] for q in items])
            u = np.array([[*q[1], 0.0] for q in items])
            v = np.array([[0, 0, q[2]] for q in items])
            vv, ff = M.quads(p0, u, v)
            kit.add("building", vv, ff, col, mat, 0.15, 2.0)
    if doors:
        vv, ff = M.quads(np.array([d[0] for d in doors]), np.array([[*d[1], 0.0] for d in doors]), np.array([[0, 0, 2.3]]))
        kit.add("building", vv, ff, PALETTE["door"], amount=0.1)


def _floors(kit: Kit, floor_m: float = FLOOR_M) -> int:
    lo, hi = kit.t.building_height_m
    h = (lo + (hi - lo) * kit.rng.random() ** 1.6) * (1.0 + DENSE_TALLER * kit.t.street_density)
    return max(1, int(round((h - 0.5) / floor_m)))


def _tight(kit: Kit, metres: float) -> float:
    """A setback or gap between buildings, shrunk towards 0 on dense streets (``Town.street_density``:
    facades meet the pavement and each other); as given at density 0."""
    return metres * (1.0 - kit.t.street_density)


def _max_floors(kit: Kit, floors: int) -> int:
    """A kit's floor cap, raised on dense streets (``DENSE_TALLER``)."""
    return floors + int(round(floors * DENSE_TALLER * kit.t.street_density))


# --------------------------------------------------------------------------
# Architecture kits: lot width range and a builder per kit
# --------------------------------------------------------------------------
def european(kit: Kit, lot: Lot) -> None:
    """Terraced town house at the pavement: brick or plaster, tiled gable roof."""
    rng = kit.rng
    depth = min(lot.depth, rng.uniform(9, 13))
    house(kit, lot, lot.s0, lot.s1, _tight(kit, rng.uniform(0.0, 0.8)), depth, min(_floors(kit), _max_floors(kit, 4)),
          kit.pick(kit.style.facades), kit.pick(kit.style.roofs), "gable", "framed")


def modern(kit: Kit, lot: Lot) -> None:
    """Office or apartment block: glass curtain wall or a concrete window grid, flat roof."""
    rng = kit.rng
    facade = kit.pick(kit.style.facades)
    glass = surface(facade).look == "glass"
    setback = _tight(kit, rng.uniform(1.0, 5.0))
    depth = lot.depth * rng.uniform(0.75, 1.0) - setback
    house(kit, lot, lot.s0 + _tight(kit, 0.5), lot.s1 - _tight(kit, 0.5), setback, depth, _floors(kit, 3.5), facade,
          kit.pick(kit.style.roofs), "flat", "curtain" if glass else kit.pick(["grid", "ribbon"]), floor_m=3.5)


def alpine(kit: Kit, lot: Lot) -> None:
    """Chalet-style house: plaster below, timber top floor, steep roof with deep eaves."""
    rng = kit.rng
    setback = _tight(kit, rng.uniform(2.0, 5.0))
    depth = min(lot.depth - setback, rng.uniform(9, 12))
    house(kit, lot, lot.s0 + _tight(kit, 1.0), lot.s1 - _tight(kit, 1.0), setback, depth,
          min(_floors(kit, 3.0), _max_floors(kit, 4)),
          kit.pick(kit.style.facades), kit.pick(kit.style.roofs), "steep", "grid",
          floor_m=3.0, top_facade="timber dark")


def suburban(kit: Kit, lot: Lot) -> None:
    """A detached sided house behind a lawn, or an industrial shed."""
    rng = kit.rng
    if lot.width > 24 and rng.random() < 0.55:  # shed: long, low, metal, roller doors
        setback = _tight(kit, rng.uniform(3.0, 8.0))
        facade = kit.pick([f for f in kit.style.facades if surface(f).look == "metal"] or list(kit.style.facades))
        house(kit, lot, lot.s0 + _tight(kit, 1), lot.s1 - _tight(kit, 1), setback, lot.depth - setback, 1, facade, "roof metal", "flat",
              "ribbon", floor_m=rng.uniform(6.5, 9.0))
        return
    setback = _tight(kit, rng.uniform(5.0, 9.0))
    depth = min(lot.depth - setback, rng.uniform(8, 11))
    house(kit, lot, lot.s0 + _tight(kit, 2), lot.s1 - _tight(kit, 2), setback, depth,
          _max_floors(kit, int(rng.integers(1, 3))),
          kit.pick(kit.style.facades), kit.pick(kit.style.roofs[:2]), "gable", "grid", floor_m=2.9)
    if rng.random() < 0.7 and setback > 1.0:  # a garden fence, where there is a front garden
        kit.fence_line(lot.point(lot.s0, 0.3), lot.point(lot.s1, 0.3), lot.z, 1.0)


def farm(kit: Kit, lot: Lot) -> None:
    """Farmhouse set back from the road, a barn behind it."""
    rng = kit.rng
    house(kit, lot, lot.s0 + 2, lot.s1 - 2, rng.uniform(6, 10), min(lot.depth - 10, 10), 2,
          kit.pick(kit.style.facades), kit.pick(kit.style.roofs), "gable", "grid", floor_m=2.9)


ARCHITECTURE: dict[str, tuple[tuple[float, float], Callable[[Kit, Lot], None]]] = {
    # kit: (lot width range in m, builder)
    "european": ((7.0, 13.0), european),
    "modern": ((18.0, 38.0), modern),
    "alpine": ((13.0, 20.0), alpine),
    "suburban": ((16.0, 40.0), suburban),
    "farm": ((24.0, 40.0), farm),
}


def architecture(name: str):
    return lookup(ARCHITECTURE, name, "architecture")


# --------------------------------------------------------------------------
# The feature: frontage along every town block
# --------------------------------------------------------------------------
def town_blocks(kit: Kit) -> None:
    """Ground, buildings and fillers of every block (towns with sidewalks)."""
    if not is_urban(kit.t):
        return
    z = kit.block_level()
    for rect, sides, river_side in kit.block_rects():
        x0, y0, x1, y1 = rect
        v, f = M.ground_rect(x0, y0, x1, y1, z, 4.0)
        if kit.rng.random() < 0.8:
            kit.paint("terrain", v, f, kit.style.ground, tiled=True)
        else:
            kit.add("ground", v, f, PALETTE["ground"], amount=0.2, scale=3.0, tiled=True)
        frontage(kit, rect, z, sides)
        kit.river_railing(rect, river_side)


OUTER_ROW_M = 14.0  # depth of the row of buildings dense streets put along the town's outer edge
OUTER_ROW_STEP_M = 2.0  # the row is laid where it is clear of river, freeway and railway, checked this often


def outer_row(kit: Kit) -> None:
    """Dense streets (``Town.street_density`` above 0) have buildings on both sides: a row of lots along
    the outside of the perimeter street too, where it is clear of the river, the freeway and its
    connectors and the railway (else the perimeter looks onto open country). Nothing, and no draw, at 0."""
    if not is_urban(kit.t) or kit.t.street_density <= 0:
        return
    rx0, ry0, rx1, ry1 = kit.lay.rect
    depth = OUTER_ROW_M
    rows = (  # origin, along, away from the street (as a block side's inward), length
        (np.array([rx1, ry0]), np.array([-1.0, 0]), np.array([0, -1.0]), rx1 - rx0),  # south, street to the north
        (np.array([rx0, ry1]), np.array([1.0, 0]), np.array([0, 1.0]), rx1 - rx0),  # north
        (np.array([rx0, ry0]), np.array([0, 1.0]), np.array([-1.0, 0]), ry1 - ry0),  # west
        (np.array([rx1, ry1]), np.array([0, -1.0]), np.array([1.0, 0]), ry1 - ry0),  # east
    )
    for o, a, away, length in rows:
        ss = np.arange(0.0, length + 1e-9, OUTER_ROW_STEP_M)
        clear = [all(kit.free_outside(o + a * s + away * d, 0.0) for d in (1.0, depth)) for s in ss]
        start = None
        for s, ok in zip([*ss, None], [*clear, False]):
            if ok and start is None:
                start = s
            elif not ok and start is not None:
                end = s - OUTER_ROW_STEP_M if s is not None else ss[-1]
                if end - start > 8:
                    lots(kit, o, a, away, start + 1.0, end - 1.0, depth, OUTER_Z)
                start = None


def frontage(kit: Kit, rect, z, sides) -> None:
    """Buildings and fillers along the street sides of a block."""
    x0, y0, x1, y1 = rect
    rng, t = kit.rng, kit.t
    W, H = x1 - x0, y1 - y0
    deep = t.building_height_m[1] > 30
    dmax_ns = min(rng.uniform(12, 24) * (1.3 if deep else 1.0), H / 2 - 1 if "n" in sides and "s" in sides else H - 2)
    dmax_we = min(rng.uniform(12, 22), W / 2 - 1)
    front = {
        # side: origin, along, inward, length, depth
        "s": (np.array([x0, y0]), np.array([1.0, 0]), np.array([0, 1.0]), W, dmax_ns),
        "n": (np.array([x1, y1]), np.array([-1.0, 0]), np.array([0, -1.0]), W, dmax_ns),
        "w": (np.array([x0, y1]), np.array([0, -1.0]), np.array([1.0, 0]), H, dmax_we),
        "e": (np.array([x1, y0]), np.array([0, 1.0]), np.array([-1.0, 0]), H, dmax_we),
    }
    ns = [s for s in "ns" if s in sides]
    for side in sides:
        o, a, inw, length, depth = front[side]
        s0, s1 = 0.0, length
        if side in "we":  # between the north and south rows
            if "s" in ns:
                s1 -= dmax_ns if side == "w" else 0
                s0 += dmax_ns if side == "e" else 0
            if "n" in ns:
                s0 += dmax_ns if side == "w" else 0
                s1 -= dmax_ns if side == "e" else 0
        lots(kit, o, a, inw, s0, s1, depth, z)


def lots(kit: Kit, o, a, inw, s0, s1, depth, z) -> None:
    rng, t = kit.rng, kit.t
    (w_lo, w_hi), build = architecture(kit.style.architecture)
    s = s0
    while s1 - s > 6:
        width = min(rng.uniform(w_lo, w_hi), s1 - s)
        if s1 - s - width < 6:
            width = s1 - s
        # dense streets (Town.street_density) fill the gaps: at 1 every lot has its building
        if rng.random() < t.building_density + t.street_density * (1.0 - t.building_density) and depth > 6:
            build(kit, Lot(o, a, inw, s, s + width, depth, z))
        else:
            filler(kit, o, a, inw, s, s + width, depth, z)
        s += width


def filler(kit: Kit, o, a, inw, s0, s1, depth, z) -> None:
    """A lot without a building: garden, parking court or plaza."""
    rng, t = kit.rng, kit.t
    kind = rng.choice(["garden", "parking", "wall_garden", "plaza"], p=[0.4, 0.2, 0.3, 0.1])
    p0, p1 = o + a * s0, o + a * s1
    if kind in ("garden", "wall_garden"):
        if kind == "wall_garden":
            kit.wall_line(p0 + inw * 0.3, p1 + inw * 0.3, z, rng.uniform(1.2, 2.6))
        elif rng.random() < 0.6:
            kit.fence_line(p0 + inw * 0.3, p1 + inw * 0.3, z, rng.uniform(1.0, 1.8))
        else:
            kit.hedge_line(p0 + inw * 0.6, p1 + inw * 0.6, z)
        for _ in range(int((s1 - s0) / 7 * (0.5 + t.vegetation_density))):
            p = o + a * rng.uniform(s0 + 2, s1 - 2) + inw * rng.uniform(3, max(3.5, depth - 2))
            kit.tree(np.array([*p, z]), rng.uniform(0.9, 1.4))
    elif kind == "parking":
        v, f = M.grid((*(o + a * s0), z + 0.01), (*(a * (s1 - s0)), 0), (*(inw * depth), 0), int((s1 - s0) / 4) + 1, int(depth / 4) + 1)
        kit.add("ground", v, M.orient_up(v, f), PALETTE["ground"], amount=0.15)
        kit.fence_line(p0 + inw * depth, p1 + inw * depth, z, 2.0)
        for _ in range(int(rng.integers(1, 4))):
            p = o + a * rng.uniform(s0 + 1, s1 - 1) + inw * rng.uniform(1, depth - 1)
            kit.static_prop(np.array([*p, z]), float(rng.uniform(0, np.pi)))
    else:  # plaza with a kiosk or sculpture ("other")
        v, f = M.grid((*(o + a * s0), z + 0.01), (*(a * (s1 - s0)), 0), (*(inw * depth), 0), int((s1 - s0) / 3) + 1, int(depth / 3) + 1)
        kit.paint("sidewalk", v, M.orient_up(v, f), kit.style.paving[-1])
        p = o + a * (s0 + s1) / 2 + inw * depth / 2
        kit.props_box("other", [*p, z], [rng.uniform(2, 4), rng.uniform(2, 4), rng.uniform(2.5, 4.5)], 0.0,
                      kit.pick([(140, 110, 80), (110, 120, 140), (160, 150, 120)]))
