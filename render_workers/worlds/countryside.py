"""Land outside the town and between country roads.

* ``farmland_blocks``: for towns without sidewalks, every block becomes a crop
  field (the style's low crops in rows, or a stand of its tall crops, maize,
  right up to the verge), a meadow, a wood or a farmyard (farmhouse, barn,
  silos, hay bales); all but the tall crops are bounded by the style's mix of
  hedgerows, fences and stone walls (``Style.field_bounds``), with tree rows along the roads.
* ``outskirts``: the terrain around every town, rising into the style's hills
  (``Style.relief_m``) away from the streets, with woods; and, where the
  style has one (``Style.mountains_m``), a mountain backdrop with rock and snow.
"""

from __future__ import annotations

import numpy as np

from render_workers.worlds.styles import surface, is_urban
from render_workers.worlds import meshes as M
from render_workers.worlds.builder import Kit, rect_distance

TALL_CROP_M = 2.6  # height of a maize stand
HEADLAND_M = 1.5  # bare soil between a tall crop and its field's edge
MOUNTAIN_BAND_M = 500.0  # depth of the mountain backdrop beyond the town's bounds
MOUNTAIN_CELL_M = 35.0


# --------------------------------------------------------------------------
# Farmland blocks
# --------------------------------------------------------------------------
def farmland_blocks(kit: Kit) -> None:
    """Fields, meadows, woods and farms in every block (towns without sidewalks)."""
    if is_urban(kit.t):
        return
    z = kit.block_level()
    for rect, _sides, river_side in kit.block_rects():
        countryside(kit, rect, z)
        kit.river_railing(rect, river_side)


def countryside(kit: Kit, rect, z) -> None:
    """One block: a field, meadow, wood or farm, its boundary and its tree rows."""
    x0, y0, x1, y1 = rect
    rng, t, style = kit.rng, kit.t, kit.style
    fields = bool(style.crops or style.tall_crops)
    kinds = ["field", "farm", "wood", "meadow"] if fields else ["meadow", "farm", "wood"]
    p = np.array([0.45, 0.22, 0.13, 0.2] if fields else [0.55, 0.25, 0.2])
    kind = kinds[int(rng.choice(len(kinds), p=p))]
    if kind == "field" and style.tall_crops and (not style.crops or rng.random() < style.tall_crop_share):
        return tall_field(kit, rect, z, kit.pick(style.tall_crops))  # up to the verge, no boundary or tree rows
    if kind == "field":
        low_field(kit, rect, z, surface(kit.pick(style.crops)))
    else:
        v, f = M.ground_rect(x0, y0, x1, y1, z, 5.0)
        kit.paint("terrain", v, f, style.ground, tiled=True)
    # boundary: the style's mix of hedgerows, fences and dry-stone walls (one draw per edge)
    for q0, q1 in [((x0, y0), (x1, y0)), ((x1, y1), (x0, y1)), ((x0, y1), (x0, y0)), ((x1, y0), (x1, y1))]:
        boundary(kit, np.array(q0), np.array(q1), z, rng.random())
    # tree rows along the block edges
    n_trees = int(t.vegetation_density * (2 * (x1 - x0) + 2 * (y1 - y0)) / 16)
    row = kit.species()
    for _ in range(n_trees):
        side = rng.integers(4)
        if side < 2:
            q = np.array([rng.uniform(x0 + 2, x1 - 2), (y0 + 3.0) if side == 0 else (y1 - 3.0)])
        else:
            q = np.array([(x0 + 3.0) if side == 2 else (x1 - 3.0), rng.uniform(y0 + 2, y1 - 2)])
        kit.tree(np.array([*q, z]), rng.uniform(0.9, 1.5), species=row if rng.random() < 0.7 else None)
    if kind == "wood":
        for _ in range(int((x1 - x0) * (y1 - y0) / 140)):
            q = np.array([rng.uniform(x0 + 6, x1 - 6), rng.uniform(y0 + 6, y1 - 6)])
            kit.tree(np.array([*q, z]), rng.uniform(1.0, 1.6))
    if kind == "farm":
        farmyard(kit, rect, z)


def boundary(kit: Kit, q0, q1, z, u: float) -> None:
    """The edge q0-q1 of a block, for a uniform draw ``u``: whichever of the style's
    ``field_bounds`` the draw falls in, or nothing past their summed shares."""
    for kind, share in kit.style.field_bounds:
        if u < share:
            if kind == "hedge":
                kit.hedge_line(q0, q1, z, height=(1.0, 1.7))
            elif kind == "fence":
                kit.fence_line(q0, q1, z, 1.1)
            else:
                kit.wall_line(q0, q1, z, 0.8, color=surface("stone wall").color)
            return
        u -= share


def low_field(kit: Kit, rect, z, crop) -> None:
    """Low crops (terrain) in ploughed rows, alternate rows darker."""
    x0, y0, x1, y1 = rect
    rng = kit.rng
    along_x = rng.random() < 0.5
    row = 2.4
    nx = int(np.ceil((x1 - x0) / (row if not along_x else 8.0)))
    ny = int(np.ceil((y1 - y0) / (row if along_x else 8.0)))
    v, f = M.grid((x0, y0, z), (x1 - x0, 0, 0), (0, y1 - y0, 0), nx, ny)
    col = M.noisy_colors(v, kit.base_color(crop) * rng.uniform(0.92, 1.08), crop.noise, crop.scale_m,
                         seed=int(rng.integers(1 << 16)))
    k = np.round((v[:, 1] - y0) / row if along_x else (v[:, 0] - x0) / row).astype(int)
    dark = k % 2 == 0
    col[dark, :3] = (col[dark, :3] * 0.72).astype(np.uint8)
    kit.add_colored("terrain", v, f, col, tiled=True, texture=crop.texture)


def tall_field(kit: Kit, rect, z, name: str) -> None:
    """A stand of tall crops (maize: vegetation) behind a headland of bare soil:
    a block of ``TALL_CROP_M`` with a ragged top, textured with stalks."""
    rng = kit.rng
    x0, y0, x1, y1 = rect
    v, f = M.ground_rect(x0, y0, x1, y1, z, 6.0)
    kit.paint("terrain", v, f, "soil", tiled=True)
    a0, b0, a1, b1 = x0 + HEADLAND_M, y0 + HEADLAND_M, x1 - HEADLAND_M, y1 - HEADLAND_M
    if a1 - a0 < 4 or b1 - b0 < 4:
        return
    crop = surface(name)
    seed = int(rng.integers(1 << 16))
    height = TALL_CROP_M * rng.uniform(0.85, 1.1)

    def top(p):  # ragged top: the same heights on the roof and the walls' upper edge
        return z + height * (0.85 + 0.3 * M.value_noise(p * np.array([1, 1, 0]), 3.0, seed))

    cell = 4.0
    nu, nv = int(np.ceil((a1 - a0) / cell)), int(np.ceil((b1 - b0) / cell))
    v, f = M.grid((a0, b0, 0), (a1 - a0, 0, 0), (0, b1 - b0, 0), nu, nv)
    v[:, 2] = top(v)
    parts = [(v, M.orient_up(v, f))]
    corners = [(a0, b0), (a1, b0), (a1, b1), (a0, b1)]
    for k, n in enumerate((nu, nv, nu, nv)):  # walls wound outwards (counter-clockwise seen from above)
        p, q = np.array(corners[k]), np.array(corners[(k + 1) % 4])
        v, f = M.grid((*p, z), (*(q - p), 0), (0, 0, 1.0), n, 1)
        v[v[:, 2] > z + 0.5, 2] = top(v[v[:, 2] > z + 0.5])
        parts.append((v, f))
    v, f = M._concat(parts)
    col = M.noisy_colors(v, kit.base_color(crop) * rng.uniform(0.92, 1.08), crop.noise, crop.scale_m, seed=seed)
    low = v[:, 2] < z + 0.5  # shade at the foot of the stand
    col[low, :3] = (col[low, :3] * 0.6).astype(np.uint8)
    kit.add_colored("vegetation", v, f, col, tiled=True, texture=crop.texture)


def farmyard(kit: Kit, rect, z) -> None:
    """Farmhouse, barn, silos and hay bales in one corner of the block."""
    rng, style = kit.rng, kit.style
    x0, y0, x1, y1 = rect
    cx = rng.uniform(x0 + 25, max(x0 + 26, x1 - 25))
    cy = y0 + 14 if rng.random() < 0.5 else y1 - 14
    v, f = M.ground_rect(cx - 30, cy - 12, cx + 30, cy + 12, z + 0.02, 4.0)
    kit.paint("terrain", v, f, "gravel")
    w, d = rng.uniform(9, 13), rng.uniform(8, 10)
    lo, hi = kit.t.building_height_m
    farm_building(kit, [cx, cy, z], w, d, rng.uniform(lo, hi) * 0.8, kit.pick([f for f in style.facades if f != "barn red"] or list(style.facades)),
                  kit.pick(style.roofs), pitch=0.45)
    bx = cx + rng.choice([-1, 1]) * (w / 2 + 14)
    bw, bd, bh = rng.uniform(14, 22), rng.uniform(10, 13), rng.uniform(4.5, 6.5)
    bx = float(np.clip(bx, x0 + bw / 2 + 2, x1 - bw / 2 - 2))
    if abs(bx - cx) > (w + bw) / 2 + 1:
        farm_building(kit, [bx, cy, z], bw, bd, bh, "barn red", "roof metal", pitch=0.6, windows=False)
    sy = cy + (10 if cy < (y0 + y1) / 2 else -10)
    for k in range(int(rng.integers(1, 4))):  # silos with conical caps
        base = np.array([[cx - 6 + 5.0 * k, sy, z]])
        r, h = rng.uniform(2.2, 3.0), rng.uniform(10, 16)
        sv, sf = M.cylinders(base, h, r, 10)
        kit.paint("other", sv, sf, "silo metal")
        cv, cf = M.cones(base + np.array([0, 0, h]), 1.6, r * 1.05, 10)
        kit.paint("other", cv, cf, "silo metal", tint=0.85)
        kit.buildings.append((float(base[0, 0]), float(base[0, 1]), 2 * r, 2 * r, 0.0))
    for _ in range(4):  # hay bales
        q = [rng.uniform(x0 + 4, x1 - 4), rng.uniform(y0 + 4, y1 - 4), z]
        kit.props_box("static", q, [1.4, 1.4, 1.2], 0.0, (196, 170, 96))


def farm_building(kit: Kit, c, w, d, h, facade, roof, pitch=0.4, windows=True) -> None:
    c = np.asarray(c, float)
    yaw = 0.0
    v, f = M.boxes(c[None], np.array([[w, d, h]]), yaw)
    kit.paint("building", v, f, facade)
    kit.buildings.append((float(c[0]), float(c[1]), float(w), float(d), yaw))
    v, f = M.prism_roofs((c + np.array([0, 0, h]))[None], np.array([[w + 0.8, d + 0.8, 0]]), pitch * d, yaw)
    kit.paint("building", v, f, roof)
    if windows:  # a few windows on the long sides
        n = max(1, int(w / 3.5))
        xs = np.linspace(-w / 2 + 1.5, w / 2 - 2.5, n)
        p0 = np.array([[x, -d / 2 - 0.05, h * 0.45] for x in xs] + [[x + 1.0, d / 2 + 0.05, h * 0.45] for x in xs])
        u = np.array([[1.0, 0, 0]] * n + [[-1.0, 0, 0]] * n)
        vv, ff = M.quads(M.transform(p0, c, yaw), M.transform(u, [0, 0, 0], yaw), np.array([[0, 0, 1.2]]))
        kit.add("building", vv, ff, (46, 60, 74), "glass", 0.1)
    else:  # big barn doors on both gable ends
        for sgn in (-1, 1):
            p0 = c + np.array([sgn * (w / 2 + 0.05), -sgn * 2.0, 0])
            vv, ff = M.quads(p0, np.array([0, sgn * 4.0, 0]), np.array([0, 0, 3.8]))
            kit.add("building", vv, ff, (92, 60, 42), amount=0.1)


# --------------------------------------------------------------------------
# Outskirts: hills, woods, mountains
# --------------------------------------------------------------------------
def outskirts(kit: Kit) -> None:
    """Terrain around the street grid, rising into hills, with woods."""
    lay, rng, t = kit.lay, kit.rng, kit.t
    bx0, by0, bx1, by1 = lay.bounds
    rx0, ry0, rx1, ry1 = lay.rect
    cell = 12.0

    def breaks(a, b, c, d):
        return np.unique(np.concatenate([np.linspace(a, b, max(2, int((b - a) / cell) + 1)),
                                         np.linspace(b, c, max(2, int((c - b) / cell) + 1)),
                                         np.linspace(c, d, max(2, int((d - c) / cell) + 1))]))
    xb = breaks(bx0, rx0, rx1, bx1)
    if lay.river:
        ylo, yhi = lay.river_band
        yb = np.unique(np.concatenate([breaks(by0, ry0, ylo, yhi), breaks(yhi, ry1, ry1 + 1, by1)]))
    else:
        yb = breaks(by0, ry0, ry1, by1)
    X0, Y0 = np.meshgrid(xb[:-1], yb[:-1], indexing="ij")
    X1, Y1 = np.meshgrid(xb[1:], yb[1:], indexing="ij")
    cx, cy = (X0 + X1) / 2, (Y0 + Y1) / 2
    keep = ~((cx > rx0) & (cx < rx1) & (cy > ry0) & (cy < ry1))
    if lay.river:
        keep &= ~((cy > ylo) & (cy < yhi))
    X0, Y0, X1, Y1 = X0[keep], Y0[keep], X1[keep], Y1[keep]
    p0 = np.stack([X0, Y0, np.zeros_like(X0)], 1)
    v, f = M.quads(p0, np.stack([X1 - X0, 0 * X0, 0 * X0], 1), np.stack([0 * X0, Y1 - Y0, 0 * X0], 1))
    v[:, 2] = kit.ground_z(v[:, :2])
    ground = surface(kit.style.ground)
    col = M.noisy_colors(v, kit.base_color(ground), ground.noise, 18.0, seed=lay.seed % 1000, fine=0.08)
    dirt = M.value_noise(v * np.array([1, 1, 0]), 40.0, 5) > 0.68
    col[dirt, :3] = np.array(surface("dirt").color, np.uint8)
    kit.add_colored("terrain", v, M.orient_up(v, f), col, tiled=True, texture=ground.texture)
    # woods: clusters of trees, denser with vegetation_density
    n_clusters = int(6 + 20 * t.vegetation_density)
    for _ in range(n_clusters):
        for _tries in range(20):
            c = np.array([rng.uniform(bx0 + 10, bx1 - 10), rng.uniform(by0 + 10, by1 - 10)])
            if kit.free_outside(c, 25.0):
                break
        else:
            continue
        for _ in range(int(rng.integers(6, 16))):
            q = c + rng.normal(0, 12, 2)
            if kit.free_outside(q, 6.0):
                kit.tree(np.array([*q, kit.ground_z(q)[0]]), rng.uniform(1.0, 1.7))
    mountains(kit)


def mountains(kit: Kit) -> None:
    """A ring of mountains beyond the bounds: meadow, rock, then snow towards the peaks."""
    peak = kit.style.mountains_m
    if peak <= 0:
        return
    bx0, by0, bx1, by1 = kit.lay.bounds
    B = MOUNTAIN_BAND_M
    xs = np.arange(bx0 - B, bx1 + B + 1e-6, MOUNTAIN_CELL_M)
    ys = np.arange(by0 - B, by1 + B + 1e-6, MOUNTAIN_CELL_M)
    X0, Y0 = np.meshgrid(xs[:-1], ys[:-1], indexing="ij")
    X1, Y1 = X0 + MOUNTAIN_CELL_M, Y0 + MOUNTAIN_CELL_M
    outside = ~((X0 >= bx0) & (X1 <= bx1) & (Y0 >= by0) & (Y1 <= by1))
    X0, Y0, X1, Y1 = X0[outside], Y0[outside], X1[outside], Y1[outside]
    v, f = M.quads(np.stack([X0, Y0, 0 * X0], 1), np.stack([X1 - X0, 0 * X0, 0 * X0], 1),
                   np.stack([0 * X0, Y1 - Y0, 0 * X0], 1))
    ramp = np.clip(rect_distance(v[:, 0], v[:, 1], kit.lay.bounds) / 200.0, 0, 1)
    flat = v * np.array([1, 1, 0])
    ridges = 0.45 + 0.55 * M.value_noise(flat, 260.0, 41) + 0.25 * (M.value_noise(flat, 70.0, 43) - 0.5)
    v[:, 2] = kit.ground_z(v[:, :2]) + peak * ramp * ridges
    frac = (v[:, 2] / peak) + 0.15 * (M.value_noise(flat, 50.0, 47) - 0.5)
    col = M.noisy_colors(v, surface(kit.style.ground).color, 0.25, 30.0, seed=53)
    rock = M.noisy_colors(v, surface("rock").color, 0.25, 20.0, seed=59)
    snow = M.noisy_colors(v, surface("snow").color, 0.05, 20.0, seed=61)
    col[frac > 0.35] = rock[frac > 0.35]
    col[frac > 0.72] = snow[frac > 0.72]
    kit.add_colored("terrain", v, M.orient_up(v, f), col, tiled=True)
