"""The freeway: a dual carriageway south of the grid with turn-around loops,
guard rails, a planted median, an optional tunnel under a mound, and two
connector roads up to the grid's corners."""

from __future__ import annotations

import numpy as np

from render_workers.worlds.styles import surface
from render_workers.worlds import meshes as M
from render_workers.worlds.builder import PALETTE, Kit, split_span
from render_workers.worlds.roadway import asphalt, markings
from render_workers.worlds.town_plan import FREEWAY_LANE_W, FREEWAY_MEDIAN, MARK_Z, OUTER_Z


def freeway(kit: Kit) -> None:
    lay = kit.lay
    fw = lay.freeway
    if not fw:
        return
    y, x0, x1, cw = fw["y"], fw["x0"], fw["x1"], fw["cw"]
    m2 = FREEWAY_MEDIAN / 2
    for sgn in (-1, 1):  # two carriageways
        ya, yb = sorted((y + sgn * m2, y + sgn * (m2 + cw)))
        v, f = M.grid((x0, ya, 0), (x1 - x0, 0, 0), (0, yb - ya, 0), int((x1 - x0) / 4), int(cw / 3))
        asphalt(kit, v, f, tiled=True)
        kit.skirt(np.array([[x0, ya], [x1, ya]]), sgn < 0)
        kit.skirt(np.array([[x0, yb], [x1, yb]]), sgn > 0)
        # lane lines
        for k in range(1, fw["lanes"]):
            yy = y + sgn * (m2 + 1.0 + k * FREEWAY_LANE_W)
            s = np.arange(x0 + 2, x1 - 8, 15.0)
            p0 = np.stack([s, np.full_like(s, yy - 0.08), np.full_like(s, MARK_Z)], 1)
            vv, ff = M.quads(p0, np.array([[6.0, 0, 0]]), np.array([[0, 0.16, 0]]))
            kit.paint("road line", vv, ff, "marking white", tiled=True)
        for yy in (y + sgn * (m2 + 0.7), y + sgn * (m2 + cw - 1.8)):
            vv, ff = M.grid((x0, yy - 0.1, MARK_Z), (x1 - x0, 0, 0), (0, 0.2, 0), int((x1 - x0) / 20), 1)
            kit.paint("road line", vv, ff, "marking white", tiled=True)
    # the turn-around loops at both ends (half annuli)
    for xe, a0 in ((x1, -90.0), (x0, 90.0)):
        ang = np.radians(np.linspace(a0, a0 + 180.0, 25))
        rmid = m2 + cw / 2
        pts = np.stack([xe + rmid * np.cos(ang), y + rmid * np.sin(ang)], 1)
        v, f = M.ribbon(pts, cw / 2, cw / 2 + m2, 0.0, 4)
        asphalt(kit, v, f)
        outer = np.stack([xe + (m2 + cw) * np.cos(ang), y + (m2 + cw) * np.sin(ang)], 1)
        kit.guard_rail(outer)
        # two tree rows behind the turn-around, so the view from the loop is not an empty plain
        for rr, step in ((m2 + cw + 8.0, 8.0), (m2 + cw + 16.0, 10.0)):
            for a in np.radians(np.arange(a0 + 8.0, a0 + 173.0, np.degrees(step / rr))):
                p = np.array([xe + rr * np.cos(a), y + rr * np.sin(a)]) + kit.rng.uniform(-1.5, 1.5, 2)
                kit.tree(np.array([*p, OUTER_Z]), kit.rng.uniform(1.0, 1.5))
    # median: concrete strip with a guard rail; outer guard rails
    v, f = M.grid((x0, y - m2, 0.0), (x1 - x0, 0, 0), (0, 2 * m2, 0), int((x1 - x0) / 6), 4)
    kit.paint("terrain", v, f, kit.style.verge, tiled=True)
    for x in np.arange(x0 + 6, x1 - 6, 11.0):
        if not (fw["tunnel"] and fw["tunnel"][0] - 5 < x < fw["tunnel"][1] + 5):
            kit.tree(np.array([x + kit.rng.uniform(-3, 3), y + kit.rng.uniform(-m2 + 5, m2 - 5), 0.0]), 1.1)
    tun = fw["tunnel"]
    spans = [(x0, x1)] if not tun else [(x0, tun[0]), (tun[1], x1)]
    for a, b in spans:
        for sgn in (-1, 1):
            kit.guard_rail(np.array([[a, y + sgn * (m2 - 0.3)], [b, y + sgn * (m2 - 0.3)]]))
        for sgn in (-1, 1):
            yy = y + sgn * (m2 + cw - 0.3)
            # leave gaps where the connectors join the north carriageway
            if sgn > 0:
                for ga, gb in split_span(a, b, [(lay.xs[0] - lay.hw - 8, lay.xs[0] + lay.hw + 8),
                                                     (lay.xs[-1] - lay.hw - 8, lay.xs[-1] + lay.hw + 8)]):
                    kit.guard_rail(np.array([[ga, yy], [gb, yy]]))
            else:
                kit.guard_rail(np.array([[a, yy], [b, yy]]))
    if tun:
        tunnel(kit, tun[0], tun[1])
    connectors(kit)


def tunnel(kit, a: float, b: float) -> None:
    fw = kit.lay.freeway
    y, cw = fw["y"], fw["cw"]
    e = FREEWAY_MEDIAN / 2 + cw
    H = 6.0
    for sgn in (-1, 1):  # side walls
        kit.props_box("wall", [(a + b) / 2, y + sgn * (e + 0.4), 0], [b - a, 0.8, H], 0.0, (150, 146, 140))
    for sgn in (-1, 1):  # inner walls: one tube per carriageway
        kit.props_box("wall", [(a + b) / 2, y + sgn * (FREEWAY_MEDIAN / 2 - 0.4), 0], [b - a, 0.8, H], 0.0, (160, 156, 150))
    kit.props_box("building", [(a + b) / 2, y, H], [b - a, 2 * e + 1.6, 0.9], 0.0, (120, 118, 112))
    v, f = M.quads(np.array([a, y + e, H - 0.001]), np.array([b - a, 0, 0]), np.array([0, -2 * e, 0]))
    kit.add("building", v, f, (90, 88, 84))
    # earth mound over the tunnel
    for sgn in (-1, 1):
        ya, yb = y + sgn * (e + 0.8), y + sgn * (e + 14)
        v, f = M.grid((a, ya, H + 0.9), (b - a, 0, 0), (0, yb - ya, OUTER_Z - H - 0.9), int((b - a) / 6), 3)
        kit.add("terrain", v, M.orient_up(v, f), surface(kit.style.ground).color, amount=0.25, scale=5.0)
    v, f = M.ground_rect(a, y - e - 0.8, b, y + e + 0.8, H + 0.92, 6.0)
    kit.add("terrain", v, f, surface(kit.style.ground).color, amount=0.25, scale=5.0)
    for k in range(3):
        kit.tree(np.array([a + (k + 0.5) * (b - a) / 3, y + kit.rng.uniform(-6, 6), H + 0.9]), 1.1)
    # ceiling lamps
    xs = np.arange(a + 4, b - 4, 8.0)
    for sgn in (-1, 1):
        p = np.stack([xs, np.full_like(xs, y + sgn * (FREEWAY_MEDIAN / 2 + cw / 2)), np.full_like(xs, H - 0.2)], 1)
        v, f = M.boxes(p, np.array([[2.0, 0.4, 0.15]]))
        kit.add("other", v, f, PALETTE["lamp"], "emissive", 0.02)
        kit.lights.extend(p + np.array([0, 0, 0.075]))


def connectors(kit) -> None:
    """Two-lane connector roads from the grid's south corners to the freeway."""
    lay, fw = kit.lay, kit.lay.freeway
    y_top = lay.ys[0] - lay.hw
    y_bot = fw["y"] + FREEWAY_MEDIAN / 2 + fw["cw"]
    for x in (lay.xs[0], lay.xs[-1]):
        v, f = M.grid((x - lay.hw, y_bot, 0), (2 * lay.hw, 0, 0), (0, y_top - y_bot, 0), 4, int((y_top - y_bot) / 3) + 1)
        asphalt(kit, v, f)
        markings(kit, np.array([x, y_bot]), np.array([0.0, 1.0]), y_top - y_bot)
        for sgn in (-1, 1):
            kit.skirt(np.array([[x + sgn * lay.hw, y_bot], [x + sgn * lay.hw, y_top]]), False)
            kit.guard_rail(np.array([[x + sgn * (lay.hw + 0.4), y_bot + 2], [x + sgn * (lay.hw + 0.4), y_top - 1]]))
        # the sidewalk gap's terrain skirt is the grid ring's job; add a sign
        kit.traffic_sign(np.array([x + lay.hw + 1.2, y_bot + 8, OUTER_Z]), np.pi / 2 * -1)
