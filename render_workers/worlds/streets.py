"""Streets: asphalt, markings, junctions and roundabouts, sidewalks or verges,
and the street furniture (lamps, signs, traffic lights, trees, props).

The town's style picks the asphalt and its wear, the marking scheme and
paint, kerbs and paving, or the verge (gravel, dirt) where there are no
sidewalks.
"""

from __future__ import annotations

import numpy as np

from render_workers.worlds import meshes as M
from render_workers.worlds.builder import PALETTE, Kit, split_span
from render_workers.worlds.roadway import asphalt, markings, road_marks, track
from render_workers.worlds.styles import is_urban
from render_workers.worlds.town_plan import CURB_H, MARK_Z, OUTER_Z, ZEBRA_FROM, ZEBRA_LEN, corner_offset

VERGE_LAP = 0.2  # verges reach this far over the road edge


def track_segments(kit: Kit) -> frozenset:
    """Street segments that are unpaved farm tracks (``Style.track_share``), keyed ("x", i, j) for the
    north-south one from junction (i, j) to (i, j + 1) and ("y", i, j) for the east-west one to (i + 1, j).
    Drawn from a generator of their own, so the kit's draws stay as they were; segments that cross the
    river (bridges) stay paved."""
    lay, share = kit.lay, kit.style.track_share
    if share <= 0:
        return frozenset()
    rng = np.random.default_rng([lay.seed, lay.town.stream, 7])
    out = set()
    for i in range(len(lay.xs)):
        for j in range(len(lay.ys) - 1):
            bridge = lay.river is not None and lay.ys[j] < lay.river[0] < lay.ys[j + 1]
            if rng.random() < share and not bridge:
                out.add(("x", i, j))
    for j in range(len(lay.ys)):
        for i in range(len(lay.xs) - 1):
            if rng.random() < share:
                out.add(("y", i, j))
    return frozenset(out)


def streets(kit: Kit) -> None:
    lay, hw = kit.lay, kit.lay.hw
    xs, ys = lay.xs, lay.ys
    cell = 3.0
    tracks = track_segments(kit)
    for i, x in enumerate(xs):  # north-south segments
        for j in range(len(ys) - 1):
            a, b = ys[j] + hw, ys[j + 1] - hw
            if ("x", i, j) in tracks:
                track(kit, np.array([x, a]), np.array([0.0, 1.0]), b - a)
                continue
            v, f = M.grid((x - hw, a, 0), (2 * hw, 0, 0), (0, b - a, 0), int(2 * hw / cell), int((b - a) / cell))
            asphalt(kit, v, f, tiled=True)
            markings(kit, np.array([x, a]), np.array([0.0, 1.0]), b - a)
    for j, y in enumerate(ys):  # east-west segments
        for i in range(len(xs) - 1):
            a, b = xs[i] + hw, xs[i + 1] - hw
            if ("y", i, j) in tracks:
                track(kit, np.array([a, y]), np.array([1.0, 0.0]), b - a)
                continue
            v, f = M.grid((a, y - hw, 0), (b - a, 0, 0), (0, 2 * hw, 0), int((b - a) / cell), int(2 * hw / cell))
            asphalt(kit, v, f, tiled=True)
            markings(kit, np.array([a, y]), np.array([1.0, 0.0]), b - a)
    for i, x in enumerate(xs):
        for j, y in enumerate(ys):
            v, f = M.ground_rect(x - hw, y - hw, x + hw, y + hw, 0.0, cell)
            asphalt(kit, v, f)
            if (i, j) in lay.roundabouts:
                roundabout(kit, x, y)
            junction_marks(kit, i, j)


def junction_marks(kit, i: int, j: int) -> None:
    """Zebra crossings and stop lines on every approach of a junction."""
    lay, hw = kit.lay, kit.lay.hw
    x, y = lay.xs[i], lay.ys[j]
    approaches = []
    if j + 1 < len(lay.ys):
        approaches.append(np.array([0.0, 1.0]))
    if j > 0:
        approaches.append(np.array([0.0, -1.0]))
    if i + 1 < len(lay.xs):
        approaches.append(np.array([1.0, 0.0]))
    if i > 0:
        approaches.append(np.array([-1.0, 0.0]))
    p0s, us, vs = [], [], []
    c = np.array([x, y])
    for d in approaches:
        n = np.array([-d[1], d[0]])
        if lay.sidewalk_w:
            stripes = np.arange(-hw + 0.4, hw - 0.4, 1.1)
            for s in stripes:
                p = c + d * (hw + ZEBRA_FROM) + n * s
                p0s.append([*p, MARK_Z]); us.append([*(d * ZEBRA_LEN), 0]); vs.append([*(n * 0.55), 0])
        if (i, j) in lay.signals or (not lay.sidewalk_w and kit.rng.random() < 0.5):
            # stop line across the incoming half (right-hand traffic: incoming on -n side)
            p = c + d * (hw + 4.2) - n * (lay.town.lanes * lay.lane_w)
            p0s.append([*p, MARK_Z]); us.append([*(d * 0.4), 0]); vs.append([*(n * lay.town.lanes * lay.lane_w), 0])
    road_marks(kit, p0s, us, vs)


def roundabout(kit, x: float, y: float) -> None:
    lay = kit.lay
    d0 = 0.5 * lay.lane_w
    c = corner_offset(lay)
    r = np.sqrt(2) * c - (c - d0) - 2.6
    ang = np.linspace(0, 2 * np.pi, 25)
    ring = np.stack([x + r * np.cos(ang), y + r * np.sin(ang)], 1)
    v, f = M.ribbon(ring, 0.0, 0.35, MARK_Z)
    kit.paint("road line", v, f, "marking white")
    top = np.concatenate([[[x, y, CURB_H + 0.1]], np.c_[ring[:-1] + 0.0, np.full(24, CURB_H)]])
    top[1:, :2] = np.array([x, y]) + (ring[:-1] - np.array([x, y])) * (r - 0.4) / r
    fan = np.stack([np.zeros(24, int), 1 + np.arange(24), 1 + (np.arange(24) + 1) % 24], 1)
    kit.paint("terrain", top, M.orient_up(top, fan), kit.style.verge)
    curb_b = np.c_[ring[:-1] * 0 + ring[:-1], np.zeros(24)]
    curb_b[:, :2] = np.array([x, y]) + (ring[:-1] - np.array([x, y])) * (r - 0.4) / r
    curb_t = curb_b.copy()
    curb_t[:, 2] = CURB_H
    nxt = np.roll(np.arange(24), -1)
    p0, u, v = curb_b, curb_b[nxt] - curb_b, curb_t - curb_b
    vv, ff = M.quads(p0, u, v)
    kit.paint("sidewalk", vv, ff, kit.style.kerb)
    kit.tree(np.array([x, y, CURB_H]), scale=0.8)
    kit.props_box("other", [x + 1.2, y, CURB_H], [0.8, 0.8, 2.4], 0.3, (150, 120, 90), "metal")


def sidewalk_ring(kit, x0, y0, x1, y1, w, outward: bool, gaps=()) -> None:
    """A sidewalk band of width w inside (or outside) a rectangle, with curbs."""
    z = CURB_H
    bands = []
    if not outward:
        bands = [((x0, y0, x1, y0 + w), "s"), ((x0, y1 - w, x1, y1), "n"),
                 ((x0, y0 + w, x0 + w, y1 - w), "w"), ((x1 - w, y0 + w, x1, y1 - w), "e")]
    else:
        bands = [((x0 - w, y0 - w, x1 + w, y0), "s_out"), ((x0 - w, y1, x1 + w, y1 + w), "n_out"),
                 ((x0 - w, y0, x0, y1), "w_out"), ((x1, y0, x1 + w, y1), "e_out")]
    look = kit.pick(kit.style.paving)
    planting = kit.rng.random() < 0.5 * (1.0 - kit.t.street_density)  # dense streets are paved to the kerb
    for (a0, b0, a1, b1), side in bands:
        pieces = split_span(a0, a1, gaps, 0.5) if side == "s_out" else [(a0, a1)]
        for p0_, p1_ in pieces:
            v, f = M.ground_rect(p0_, b0, p1_, b1, z, 2.0)
            kit.paint("sidewalk", v, f, look, fine=0.08, tiled=True)
            curb_faces(kit, p0_, b0, p1_, b1, side)
            if side[0] in "sn":  # end faces of the bands that span the corners
                low = OUTER_Z if side.endswith("_out") else 0.0
                for xe, sgn in ((p0_, -1), (p1_, 1)):
                    p = np.array([xe, b0 if sgn > 0 else b1, low])
                    vv, ff = M.quads(p, np.array([0, sgn * (b1 - b0), 0]), np.array([0, 0, z - low]))
                    kit.paint("sidewalk", vv, ff, kit.style.kerb)
        if planting and side in ("s", "n", "w", "e"):
            planting_strip(kit, a0, b0, a1, b1, side)


def planting_strip(kit, a0, b0, a1, b1, side) -> None:
    """A grass strip along the kerb, interrupted near the corners."""
    g = 1.2
    if side in "sn":
        yy = (b0, b0 + g) if side == "s" else (b1 - g, b1)
        rect = (a0 + 6, yy[0], a1 - 6, yy[1])
    else:
        xx = (a0, a0 + g) if side == "w" else (a1 - g, a1)
        rect = (xx[0], b0 + 3, xx[1], b1 - 3)
    if rect[2] - rect[0] > 2 and rect[3] - rect[1] > 0.5:
        v, f = M.ground_rect(*rect, CURB_H + 0.03, 2.0)
        kit.paint("terrain", v, f, kit.style.verge, fine=0.1, tiled=True)


def curb_faces(kit, a0, b0, a1, b1, side) -> None:
    """Vertical curb faces on the road side(s) of one sidewalk band."""
    z = CURB_H
    faces = []
    if side in ("s", "n_out"):
        faces.append(((a0, b0, 0), (a1 - a0, 0, 0)))
    if side in ("n", "s_out"):
        faces.append(((a1, b1, 0), (a0 - a1, 0, 0)))
    if side in ("w", "e_out"):
        faces.append(((a0, b1, 0), (0, b0 - b1, 0)))
    if side in ("e", "w_out"):
        faces.append(((a1, b0, 0), (0, b1 - b0, 0)))
    if side.endswith("_out"):  # drop to the outer terrain on the far side
        low = OUTER_Z - z
        if side == "s_out":
            faces.append(((a0, b0, low), (a1 - a0, 0, 0)))
        if side == "n_out":
            faces.append(((a1, b1, low), (a0 - a1, 0, 0)))
        if side == "w_out":
            faces.append(((a0, b1, low), (0, b0 - b1, 0)))
        if side == "e_out":
            faces.append(((a1, b0, low), (0, b1 - b0, 0)))
    for p, u in faces:
        h = z - p[2] if p[2] < 0 else z
        # side faces wind so that u x up points away from the band
        vv, ff = M.quads(np.array(p, float), np.array(u, float), np.array([0, 0, h]))
        kit.paint("sidewalk", vv, ff, kit.style.kerb)


def sidewalks(kit: Kit) -> None:
    lay, hw, w = kit.lay, kit.lay.hw, kit.lay.sidewalk_w or kit.lay.verge_w
    xs, ys = lay.xs, lay.ys
    gaps = []
    if lay.freeway:
        gaps = [(xs[0] - hw, xs[0] + hw), (xs[-1] - hw, xs[-1] + hw)]
    if lay.sidewalk_w:
        for i in range(len(xs) - 1):
            for j in range(len(ys) - 1):
                sidewalk_ring(kit, xs[i] + hw, ys[j] + hw, xs[i + 1] - hw, ys[j + 1] - hw, w, False)
        sidewalk_ring(kit, xs[0] - hw, ys[0] - hw, xs[-1] + hw, ys[-1] + hw, w, True, gaps)
    else:  # verges level with the road, lapping VERGE_LAP over its edge (no seam to see the sky through)
        lap = VERGE_LAP
        for i in range(len(xs) - 1):
            for j in range(len(ys) - 1):
                verge_ring(kit, xs[i] + hw - lap, ys[j] + hw - lap, xs[i + 1] - hw + lap, ys[j + 1] - hw + lap, w + lap)
        e, g = hw + w, hw - lap
        for (a0, b0, a1, b1) in [(xs[0] - e, ys[0] - e, xs[-1] + e, ys[0] - g),
                                 (xs[0] - e, ys[-1] + g, xs[-1] + e, ys[-1] + e),
                                 (xs[0] - e, ys[0] - g, xs[0] - g, ys[-1] + g),
                                 (xs[-1] + g, ys[0] - g, xs[-1] + e, ys[-1] + g)]:
            v, f = M.ground_rect(a0, b0, a1, b1, 0.02, 3.0)
            kit.paint("terrain", v, f, kit.style.verge, tiled=True)


def verge_ring(kit, x0, y0, x1, y1, w) -> None:
    for (a0, b0, a1, b1) in [(x0, y0, x1, y0 + w), (x0, y1 - w, x1, y1),
                             (x0, y0 + w, x0 + w, y1 - w), (x1 - w, y0 + w, x1, y1 - w)]:
        v, f = M.ground_rect(a0, b0, a1, b1, 0.02, 3.0)
        kit.paint("terrain", v, f, kit.style.verge, tiled=True)


def furniture(kit: Kit) -> None:
    """Trees, lamps, signs, traffic lights and props along every street."""
    lay, t = kit.lay, kit.t
    xs, ys = lay.xs, lay.ys
    urban = is_urban(t)
    z = CURB_H if urban else 0.02
    kerb = 0.75 if urban else 1.6  # distance of the furniture line from the road edge
    spacing = 9.0 if urban else 12.0
    for i, x in enumerate(xs):
        for j, y in enumerate(ys):
            for d in (np.array([1.0, 0]), np.array([-1.0, 0]), np.array([0, 1.0]), np.array([0, -1.0])):
                nb = (i + int(d[0]), j + int(d[1]))
                if not (0 <= nb[0] < len(xs) and 0 <= nb[1] < len(ys)):
                    continue
                length = abs((xs[nb[0]] - x) + (ys[nb[1]] - y))
                if urban and t.street_density > 0:
                    dense_street_side(kit, np.array([x, y]), d, length, spacing, kerb, z)
                else:
                    street_side(kit, np.array([x, y]), d, length, spacing, kerb, z, urban)
                junction_furniture(kit, (i, j), np.array([x, y]), d, kerb, z, urban)


def street_side(kit, c, d, length, spacing, kerb, z, urban) -> None:
    """Furniture along the right-hand side of the street leaving c along d."""
    lay, rng, t = kit.lay, kit.rng, kit.t
    n_right = np.array([d[1], -d[0]])
    s_vals = np.arange(lay.hw + 9.0, length - lay.hw - 5.0, spacing)
    yaw_to_road = float(np.arctan2(-n_right[1], -n_right[0]))
    bridge = kit.on_river
    for k, s in enumerate(s_vals):
        p = c + d * (s + rng.uniform(-1.5, 1.5)) + n_right * (lay.hw + kerb)
        if bridge(p[1], 4.0):
            continue
        base = np.array([p[0], p[1], z])
        u = rng.random()
        if k % 3 == 1:
            if urban or rng.random() < 0.5:
                if urban:
                    kit.street_lamp(base, yaw_to_road)
                else:
                    kit.pole_with(base, 8.0, 0.13, wood=True)
                    kit.props_box("pole", base + np.array([0, 0, 7.3]), [0.12, 1.6, 0.12], yaw_to_road, PALETTE["wood_pole"])
        elif u < min(0.9, t.vegetation_density * 1.5):
            kit.tree(base, scale=rng.uniform(0.85, 1.25))
        elif urban and u < t.vegetation_density + 0.25:
            q = base + np.array([*n_right, 0.0]) * 0.3
            kit.static_prop(q, yaw_to_road)
        elif not urban and u < 0.9:
            hb = base + np.array([*n_right, 0.0]) * 1.5
            kit.tree(hb, species="bush")


# On dense streets (Town.street_density 1) the furniture line is this much closer-set and its trees this
# much rarer; what is not a lamp or a tree is a sign pole (DENSE_SIGN_SHARE of the slots) or street clutter.
DENSE_SPACING_CUT, DENSE_TREE_CUT, DENSE_SIGN_SHARE = 0.45, 0.4, 0.5


def dense_street_side(kit, c, d, length, spacing, kerb, z) -> None:
    """``street_side`` of a town with dense streets (``Town.street_density`` above 0): lamp posts every
    other slot, few trees, sign poles facing the traffic on this side, and bins, benches, bollards and
    boxes between them, on a furniture line closer-set by the density."""
    lay, rng, t = kit.lay, kit.rng, kit.t
    density = t.street_density
    n_right = np.array([d[1], -d[0]])
    s_vals = np.arange(lay.hw + 9.0, length - lay.hw - 5.0, spacing * (1.0 - DENSE_SPACING_CUT * density))
    yaw_to_road = float(np.arctan2(-n_right[1], -n_right[0]))
    facing = float(np.arctan2(-d[1], -d[0]))  # traffic on this side drives along d: plates face back along it
    tree_p = min(0.9, t.vegetation_density * 1.5) * (1.0 - DENSE_TREE_CUT * density)
    for k, s in enumerate(s_vals):
        p = c + d * (s + rng.uniform(-1.0, 1.0)) + n_right * (lay.hw + kerb)
        if kit.on_river(p[1], 4.0):
            continue
        base = np.array([p[0], p[1], z])
        u = rng.random()
        if k % 2 == 1:
            kit.street_lamp(base, yaw_to_road)
        elif u < tree_p:
            kit.tree(base, scale=rng.uniform(0.85, 1.25))
        elif u < tree_p + DENSE_SIGN_SHARE * density:
            kit.traffic_sign(base, facing)
        else:
            kit.static_prop(base + np.array([*n_right, 0.0]) * 0.3, yaw_to_road)


def junction_furniture(kit, q, c, d, kerb, z, urban) -> None:
    """Signs and lights where traffic arrives at junction q along -d."""
    lay, rng = kit.lay, kit.rng
    hw = lay.hw
    # Approaching traffic drives along -d on the right side: the right-hand
    # corner for them is on the +n_left side of d.
    n_left = np.array([-d[1], d[0]])
    facing = float(np.arctan2(d[1], d[0]))  # plate faces the incoming cars
    corner = c + d * (hw + 4.5 if urban else hw + 3.0) + n_left * (hw + kerb)
    deg = 4 - (q[0] in (0, len(lay.xs) - 1)) - (q[1] in (0, len(lay.ys) - 1))
    if deg == 2:
        if rng.random() < 0.4:
            kit.traffic_sign(np.array([*corner, z]), facing)
        return
    if q in lay.signals:
        arm = (lay.town.lanes * lay.lane_w + 0.5 * lay.parking_w + kerb) if lay.town.lanes > 1 or rng.random() < 0.5 else 0.0
        kit.traffic_light(np.array([*corner, z]), facing, arm)
        if rng.random() < 0.5:
            kit.traffic_sign(np.array([*(corner + d * 3.0), z]), facing)
    elif rng.random() < (0.8 if urban else 0.65):
        kit.traffic_sign(np.array([*corner, z]), facing)

