"""Road surface helpers shared by the street grid and the freeway: asphalt in
the style's tone and wear, and painted markings in the style's scheme."""

from __future__ import annotations

import numpy as np

from render_workers.worlds.styles import surface
from render_workers.worlds import meshes as M
from render_workers.worlds.builder import Kit
from render_workers.worlds.town_plan import MARK_Z


def asphalt(kit: Kit, v, f, tiled: bool = False) -> None:
    """Road surface in the style's asphalt, with patches and worn spots by its wear."""
    s = surface(kit.style.asphalt)
    kit._cseed += 1
    col = M.noisy_colors(v, kit.base_color(s), s.noise, s.scale_m, seed=kit._cseed % 9973, fine=0.06)
    wear = kit.style.asphalt_wear
    if wear > 0:
        patch = M.value_noise(v, 9.0, 17) > 1.0 - 0.28 * wear
        worn = M.value_noise(v, 2.5, 29) > 1.0 - 0.22 * wear
        col[patch, :3] = (col[patch, :3] * 0.78).astype(np.uint8)
        col[worn, :3] = np.clip(col[worn, :3].astype(int) + 22, 0, 255).astype(np.uint8)
    kit.add_colored("road", v, f, col, s.look, tiled, s.texture)


def track(kit: Kit, start: np.ndarray, d: np.ndarray, length: float) -> None:
    """An unpaved farm track along one street segment: the style's track surface
    (road) with darker wheel ruts, and a crown of the verge's grass between them (terrain)."""
    hw = kit.lay.hw
    s = surface(kit.style.track)
    left = np.array([-d[1], d[0], 0.0])
    p0 = np.array([*start, 0.0]) - hw * left
    v, f = M.grid(p0, np.array([*(d * length), 0.0]), 2 * hw * left, max(1, int(length / 3.0)), 8)
    kit._cseed += 1
    col = M.noisy_colors(v, kit.base_color(s), s.noise, s.scale_m, seed=kit._cseed % 9973, fine=0.08)
    lateral = np.abs((v - p0) @ left - hw)
    ruts = np.abs(lateral - 0.75 * hw) < 0.2 * hw
    col[ruts, :3] = (col[ruts, :3] * 0.7).astype(np.uint8)
    kit.add_colored("road", v, f, col, s.look, True, s.texture)
    crown = 0.22 * hw  # half width of the grass strip
    v, f = M.grid(np.array([*(start + d), 0.03]) - crown * left, np.array([*(d * (length - 2.0)), 0.0]),
                  2 * crown * left, max(1, int(length / 3.0)), 1)
    kit.paint("terrain", v, f, kit.style.verge, tiled=True, fine=0.15)


def markings(kit, start: np.ndarray, d: np.ndarray, length: float) -> None:
    """Centre, lane and edge lines along one street segment."""
    lay, style = kit.lay, kit.style
    if style.markings == "none" or kit.rng.random() >= style.marked_share:
        return
    n = np.array([-d[1], d[0]])
    lines = []  # (lateral, dashed, width)
    if lay.town.lanes > 1:
        lines += [(-0.12, False, 0.12), (0.12, False, 0.12)]
    else:
        lines.append((0.0, True, 0.14))
    centre = len(lines)
    if style.markings == "full":
        for k in range(1, lay.town.lanes):
            lines += [(k * lay.lane_w, True, 0.14), (-k * lay.lane_w, True, 0.14)]
        if lay.parking_w:
            e = lay.town.lanes * lay.lane_w
            lines += [(e, False, 0.16), (-e, False, 0.16)]
        elif lay.verge_w:
            e = lay.town.lanes * lay.lane_w - 0.25
            lines += [(e, False, 0.14), (-e, False, 0.14)]
    p0s, us, vs = [], [], []
    off = 4.5 if lay.sidewalk_w else 0.5
    for k, (lat, dashed, w) in enumerate(lines):
        if k == centre:  # the centre line in the style's paint, the others white
            road_marks(kit, p0s, us, vs, style.marking)
            p0s, us, vs = [], [], []
        base = start + lat * n - 0.5 * w * n
        if dashed:
            dash, gap = 3.0, 6.0
            s = np.arange(off, length - off - dash, dash + gap)
            L = np.full(len(s), dash)
        else:
            s, L = np.array([off]), np.array([length - 2 * off])
        for si, li in zip(s, L):
            p0s.append([*(base + si * d), MARK_Z])
            us.append([*(d * li), 0])
            vs.append([*(n * w), 0])
    road_marks(kit, p0s, us, vs, style.marking if len(lines) == centre else "marking white")


def road_marks(kit, p0s: list, us: list, vs: list, paint: str = "marking white") -> None:
    """Add painted quads (corner p0, edges u, v) as road line, every quad facing up."""
    if not p0s:
        return
    p0, u, v = np.array(p0s), np.array(us), np.array(vs)
    flip = np.cross(u, v)[:, 2] < 0
    p0[flip] += v[flip]
    v[flip] = -v[flip]
    vv, ff = M.quads(p0, u, v)
    kit.paint("road line", vv, ff, paint)
