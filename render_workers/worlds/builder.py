"""The shared kit of the world's features: how geometry is added, and the small
things every feature places (trees, poles, signs, lights, fences, walls, hedges,
guard rails, props).

A :class:`Kit` holds one town's plan, its style row, the builder's random
generator and the :class:`~render_workers.worlds.meshes.MeshBatch` everything goes
into. Feature modules (``streets``, ``buildings``, ``countryside``, ``freeway``,
``river``, ``railway``) are functions of a Kit; they import this module and
``town_plan``, never each other.

Surfaces (asphalt, paving, facades, crops...) are named in the town's style
and looked up in ``render_workers.worlds.styles.SURFACES``; poles, signal heads,
sign plates, fences and walls take the colours of the style's furniture row
(``Style.props``); the few colours here are for what every town shares.
"""

from __future__ import annotations

import numpy as np

from domains.catalog import class_id
from render_workers.worlds.styles import look, surface
from render_workers.worlds import meshes as M
from render_workers.worlds.textures import TEXTURE_MEAN
from render_workers.worlds.town_plan import CURB_H, FREEWAY_MEDIAN, OUTER_Z, Layout

# What every style shares (the style's furniture row has poles, signals, signs, fences, walls).
PALETTE = {
    "wood_pole": (96, 76, 56),
    "guard": (175, 176, 180), "ballast": (104, 98, 92), "rail": (90, 86, 84), "sleeper": (92, 72, 52),
    "water": (44, 66, 74), "window": (46, 60, 74), "window_frame": (226, 222, 212), "door": (70, 52, 40),
    "lamp": (255, 240, 200), "ground": (120, 112, 100),
}
FLAT_BAND_M = 30.0  # relief starts this far from the streets, freeway, railway and river


def split_segment(p0, p1, max_len: float) -> list:
    """Cut a 2D segment into pieces no longer than max_len."""
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    n = max(1, int(np.ceil(np.linalg.norm(p1 - p0) / max_len)))
    t = np.linspace(0.0, 1.0, n + 1)
    pts = p0[None] + t[:, None] * (p1 - p0)[None]
    return [(pts[k], pts[k + 1]) for k in range(n)]


def line_pieces(p0, p1):
    """Pieces of a wall, fence or hedge line as (p0, p1, length, yaw): lines over
    45 m are cut into pieces of at most 40 m, and pieces under 1 m are dropped."""
    long = np.linalg.norm(np.asarray(p1) - np.asarray(p0)) > 45.0
    for a, b in split_segment(p0, p1, 40.0) if long else [(p0, p1)]:
        d = b - a
        length = float(np.linalg.norm(d))
        if length >= 1:
            yield a, b, length, float(np.arctan2(d[1], d[0]))


def split_span(a, b, gaps, min_len: float = 1.0):
    """The pieces of [a, b] outside the (g0, g1) gaps, each over ``min_len`` metres."""
    pieces = [(a, b)]
    for g0, g1 in gaps:
        pieces = [q for p in pieces for q in ((p[0], min(p[1], g0)), (max(p[0], g1), p[1])) if q[1] - q[0] > min_len]
    return pieces


def rect_distance(x, y, rect) -> np.ndarray:
    x0, y0, x1, y1 = rect
    dx = np.maximum(np.maximum(x0 - x, 0.0), x - x1)
    dy = np.maximum(np.maximum(y0 - y, 0.0), y - y1)
    return np.hypot(dx, dy)


class Kit:
    """One town's builder state: plan, style, generator and mesh batch."""

    def __init__(self, lay: Layout) -> None:
        self.lay = lay
        self.t = lay.town
        self.style = look(lay.town)
        self.rng = np.random.default_rng([lay.seed, lay.town.stream, 2])
        self.batch = M.MeshBatch()
        self.buildings: list[tuple[float, float, float, float, float]] = []  # cx, cy, sx, sy, yaw
        self.lights: list[np.ndarray] = []  # luminaires' centres (World.lights)
        self._cseed = 0
        species = self.style.trees
        self._species = [name for name, _ in species]
        w = np.array([wt for _, wt in species], float)
        self._species_p = w / w.sum()

    # ---- adding geometry ------------------------------------------------
    def add(self, cls: str, verts, faces, base, material="matte", amount=0.12, scale=3.0,
            tiled=False, fine=0.05, texture=""):
        self._cseed += 1
        colors = M.NoiseColors(verts, base, amount, scale, seed=self._cseed % 9973, fine=fine)  # made with the batch's
        self.add_colored(cls, verts, faces, colors, material, tiled, texture)

    def paint(self, cls: str, verts, faces, name: str, tiled=False, fine=0.05, tint: float = 1.0):
        """Add geometry in one of the catalog's surfaces (colour, variation, material, texture)."""
        s = surface(name)
        self.add(cls, verts, faces, self.base_color(s) * tint, s.look, s.noise, s.scale_m, tiled, fine, s.texture)

    @staticmethod
    def base_color(s) -> np.ndarray:
        """A surface's vertex colour: brighter where its texture will darken it."""
        return np.clip(np.array(s.color, float) / (TEXTURE_MEAN if s.texture else 1.0), 0, 255)

    def add_colored(self, cls, verts, faces, colors, material="matte", tiled=False, texture=""):
        if tiled:
            self.batch.add_tiled(class_id(cls), material, verts, faces, colors, texture)
        else:
            self.batch.add(class_id(cls), material, verts, faces, colors, texture=texture)

    def pick(self, options):
        return options[int(self.rng.integers(len(options)))]

    # ---- where things may go --------------------------------------------
    def on_river(self, y: float, pad: float = 0.0) -> bool:
        band = self.lay.river_band
        return band is not None and band[0] - pad < y < band[1] + pad

    def free_outside(self, p, pad) -> bool:
        """True when p is clear of the grid, the river, freeway and railway."""
        lay = self.lay
        rx0, ry0, rx1, ry1 = lay.rect
        if rx0 - pad < p[0] < rx1 + pad and ry0 - pad < p[1] < ry1 + pad:
            return False
        b = lay.bounds
        if not (b[0] + 3 < p[0] < b[2] - 3 and b[1] + 3 < p[1] < b[3] - 3):
            return False
        if self.on_river(p[1], pad):
            return False
        fw = lay.freeway
        if fw and fw["x0"] - 40 - pad < p[0] < fw["x1"] + 40 + pad and abs(p[1] - fw["y"]) < FREEWAY_MEDIAN / 2 + fw["cw"] + pad + 6:
            return False
        if fw and p[1] > fw["y"] and p[1] < ry0 + pad and (abs(p[0] - lay.xs[0]) < lay.hw + pad + 4 or abs(p[0] - lay.xs[-1]) < lay.hw + pad + 4):
            return False
        if lay.railway_y is not None and abs(p[1] - lay.railway_y) < 8 + pad:
            return False
        return True

    def block_level(self) -> float:
        """Ground level inside the blocks: sidewalk height, or just above the road."""
        return CURB_H if self.lay.sidewalk_w else 0.05

    def block_rects(self) -> list[tuple[tuple[float, float, float, float], str, str]]:
        """Every block inside its sidewalks (verges) as (rect, street sides, river
        side); the blocks the river crosses come as two halves."""
        lay = self.lay
        e = lay.hw + (lay.sidewalk_w or lay.verge_w)
        out = []
        for i in range(len(lay.xs) - 1):
            for j in range(len(lay.ys) - 1):
                x0, y0, x1, y1 = lay.xs[i] + e, lay.ys[j] + e, lay.xs[i + 1] - e, lay.ys[j + 1] - e
                if lay.river and y0 < lay.river[0] < y1:
                    yr0, yr1 = lay.river_band
                    out += [((x0, y0, x1, yr0), "swe", "n"), ((x0, yr1, x1, y1), "nwe", "s")]
                else:
                    out.append(((x0, y0, x1, y1), "nswe", ""))
        return [b for b in out if b[0][2] - b[0][0] >= 4 and b[0][3] - b[0][1] >= 4]

    def river_blocks(self) -> list[tuple[float, float, float]]:
        """(x0, x1, level) of the blocks the river runs through."""
        lay = self.lay
        if not lay.river:
            return []
        e = lay.hw + (lay.sidewalk_w or lay.verge_w)
        return [(lay.xs[i] + e, lay.xs[i + 1] - e, self.block_level()) for i in range(len(lay.xs) - 1)
                if any(lay.ys[j] + e < lay.river[0] < lay.ys[j + 1] - e for j in range(len(lay.ys) - 1))]

    def river_railing(self, rect, river_side: str) -> None:
        """Railing along a half block's river bank."""
        if river_side:
            x0, y0, x1, y1 = rect
            y = y1 if river_side == "n" else y0
            self.fence_line(np.array([x0, y]), np.array([x1, y]), self.block_level(), 1.1, metal=True)

    def flat_zones(self) -> list[tuple[float, float, float, float]]:
        """Rectangles that stay at the plan's levels: the grid, freeway, railway, river."""
        lay = self.lay
        bx0, _, bx1, _ = lay.bounds
        zones = [lay.rect]
        fw = lay.freeway
        if fw:
            e = FREEWAY_MEDIAN / 2 + fw["cw"]
            zones.append((fw["x0"] - e - 10, fw["y"] - e - 10, fw["x1"] + e + 10, lay.rect[1]))
        if lay.railway_y is not None:
            zones.append((bx0 - 1e4, lay.railway_y - 8, bx1 + 1e4, lay.railway_y + 8))
        if lay.river:
            y0, y1 = lay.river_band
            zones.append((bx0 - 1e4, y0, bx1 + 1e4, y1))
        return zones

    def ground_z(self, xy: np.ndarray) -> np.ndarray:
        """Terrain height outside the grid: flat near the plan, rising into the
        style's hills (``Style.relief_m``) farther out."""
        xy = np.atleast_2d(np.asarray(xy, float))
        relief = self.style.relief_m
        if relief <= 0:
            return np.full(len(xy), OUTER_Z)
        d = np.min([rect_distance(xy[:, 0], xy[:, 1], z) for z in self.flat_zones()], axis=0)
        ramp = np.clip((d - FLAT_BAND_M) / 120.0, 0.0, 1.0)
        ramp = ramp * ramp * (3 - 2 * ramp)
        pts = np.c_[xy, np.zeros(len(xy))]
        hills = 0.35 + 0.65 * M.value_noise(pts, 140.0, self.lay.seed % 1000 + 11)
        return OUTER_Z + relief * ramp * hills

    # ---- small objects ---------------------------------------------------
    def props_box(self, cls, base, size, yaw, color, material="matte"):
        v, f = M.boxes(np.array([base], float), np.array([size], float), yaw)
        self.add(cls, v, f, color, material, amount=0.08, scale=1.0)

    def species(self) -> str:
        """A tree species drawn from the style's mix."""
        return self._species[int(self.rng.choice(len(self._species), p=self._species_p))]

    def tree(self, base: np.ndarray, scale: float = 1.0, species: str | None = None) -> None:
        """A tree of the given (else a style-drawn) species standing on ``base``."""
        rng = self.rng
        kind = species or self.species()
        canopy = surface(self.pick(self.style.canopies))
        if kind == "bush":
            return self.bush(base, scale)
        h = scale * rng.uniform(2.2, 3.8)
        r = scale * rng.uniform(2.4, 3.9)
        bark = "birch bark" if kind == "birch" else self.style.bark
        v, f = M.cylinders(base[None], h + (1.6 * r if kind == "poplar" else 1.0), scale * rng.uniform(0.14, 0.24), 6)
        self.paint("vegetation", v, f, bark)
        if kind == "conifer":  # stacked cones, narrowing upwards
            tiers = 3
            hh = 2.6 * r
            bases = np.array([base + np.array([0, 0, h * 0.5 + k * hh * 0.28]) for k in range(tiers)])
            v, f = M.cones(bases, hh * np.array([0.55, 0.5, 0.45]), 0.62 * r * np.array([1.0, 0.78, 0.55]), 8)
            col = np.array(surface(self.style.conifer).color, float) * rng.uniform(0.85, 1.15)
            self.add("vegetation", v, f, col, amount=0.2, scale=1.0, fine=0.1)
            return
        if kind == "poplar":
            radii = np.array([[0.42 * r, 0.42 * r, 1.7 * r]])
            cen = base + np.array([0, 0, h + 1.5 * r])
        elif kind == "birch":
            radii = np.array([[0.7 * r, 0.65 * r, 1.0 * r]])
            cen = base + np.array([0, 0, h + 0.9 * r])
        else:
            radii = np.array([[r, r * rng.uniform(0.8, 1.1), r * rng.uniform(0.75, 1.0)]])
            cen = base + np.array([0, 0, h + 0.7 * r])
        v, f = M.blobs(cen[None], radii, seed=int(rng.integers(1 << 20)))
        col = np.array(canopy.color, float) * rng.uniform(0.88, 1.12)
        self.add("vegetation", v, f, col, amount=canopy.noise, scale=canopy.scale_m, fine=0.1)

    def bush(self, base, scale: float = 1.0):
        r = scale * self.rng.uniform(0.8, 1.5)
        v, f = M.blobs((base + np.array([0, 0, 0.5 * r]))[None], np.array([[r, r, 0.8 * r]]), int(self.rng.integers(1 << 20)))
        self.paint("vegetation", v, f, self.style.hedge)

    def pole_with(self, base, height, radius=0.08, wood=False):
        v, f = M.cylinders(np.array([base], float), height, radius, 6)
        props = self.style.props
        self.add("pole", v, f, PALETTE["wood_pole"] if wood else props.pole, "matte" if wood else props.pole_look,
                 0.1, 1.0)

    def street_lamp(self, base, yaw):
        """A lamp post with an arm towards the road (yaw points to the road)."""
        self.pole_with(base, 7.5, 0.09)
        d = np.array([np.cos(yaw), np.sin(yaw), 0])
        arm_c = np.asarray(base) + d * 0.9 + np.array([0, 0, 7.4])
        props = self.style.props
        self.props_box("pole", arm_c - np.array([0, 0, 0.05]), [1.8, 0.12, 0.12], yaw, props.pole, props.pole_look)
        head = np.asarray(base) + d * 1.7 + np.array([0, 0, 7.25])
        self.props_box("pole", head, [0.6, 0.3, 0.15], yaw, PALETTE["lamp"], "emissive")
        self.lights.append(head + np.array([0, 0, 0.075]))  # the box's base is ``head``: its centre is half up

    def traffic_sign(self, base, facing):
        """Pole plus a plate facing ``facing`` (radians, towards approaching cars)."""
        self.pole_with(base, 2.9, 0.05)
        face = self.pick(self.style.props.signs)
        centre = np.asarray(base, float) + np.array([0, 0, 2.2])
        d = np.array([np.cos(facing), np.sin(facing), 0.0])
        v, f = M.boxes(centre[None] + d[None] * 0.06, np.array([[0.05, 0.75, 0.75]]), facing)
        self.add("traffic sign", v, f, face, "glossy", 0.05, 0.5)

    def traffic_light(self, base, facing, arm: float):
        """A signal pole at a corner; ``arm`` > 0 adds a mast arm over the road."""
        base = np.asarray(base, float)
        self.pole_with(base, 5.6 if arm else 3.2, 0.1)
        d = np.array([np.cos(facing), np.sin(facing), 0.0])
        left = np.array([-d[1], d[0], 0.0])  # towards the road centre for a right-corner pole
        heads = [base + np.array([0, 0, 2.3]) + d * 0.2]
        if arm:
            c = base + left * (arm / 2) + np.array([0, 0, 5.45])
            v, f = M.boxes(c[None], np.array([[arm, 0.16, 0.16]]), facing + np.pi / 2)
            self.add("pole", v, f, self.style.props.pole, self.style.props.pole_look, 0.1, 1.0)
            heads.append(base + left * arm * 0.85 + np.array([0, 0, 4.4]) + d * 0.1)
        for h in heads:
            v, f = M.boxes(h[None], np.array([[0.35, 0.4, 1.05]]), facing)
            self.add("traffic light", v, f, self.style.props.signal, "matte", 0.05, 0.3)
            lamps = np.array([h + d * 0.18 + np.array([0, 0, z]) for z in (0.17, 0.5, 0.83)])
            col = self.pick([(255, 40, 30), (40, 255, 90), (255, 190, 30)])
            vv, ff = M.boxes(lamps - np.array([0, 0, 0.11]), np.array([[0.04, 0.22, 0.22]]), facing)
            self.add("traffic light", vv, ff, col, "emissive", 0.02, 0.3)

    def static_prop(self, base, yaw) -> None:
        kind = self.pick(["bin", "bench", "hydrant", "box", "dyn_bin", "dyn_box", "bollard"])
        if kind == "bin":
            self.props_box("static", base, [0.6, 0.6, 1.0], yaw, (40, 80, 50))
        elif kind == "bench":
            self.props_box("static", base, [0.6, 1.8, 0.45], yaw, (110, 80, 55))
            self.props_box("static", base - np.array([np.cos(yaw), np.sin(yaw), 0]) * 0.25 + np.array([0, 0, 0.45]),
                           [0.1, 1.8, 0.45], yaw, (110, 80, 55))
        elif kind == "hydrant":
            v, f = M.cylinders(base[None], 0.8, 0.16, 6)
            self.add("static", v, f, (190, 40, 30), "glossy", 0.05, 0.5)
        elif kind == "bollard":
            v, f = M.cylinders(base[None], 0.9, 0.1, 6)
            self.add("static", v, f, (60, 60, 60), "metal", 0.05, 0.5)
        elif kind == "box":
            self.props_box("static", base, [1.2, 1.2, 1.4], yaw, (60, 90, 120), "metal")
        elif kind == "dyn_bin":
            self.props_box("dynamic", base, [0.7, 0.8, 1.1], yaw, self.pick([(30, 110, 60), (60, 60, 70), (150, 120, 40)]))
        else:
            self.props_box("dynamic", base, [0.9, 0.7, 0.7], yaw, (150, 115, 70))

    # ---- lines: walls, fences, hedges, guard rails ----------------------
    def wall_line(self, p0, p1, z, h, color=None):
        for p0, p1, L, yaw in line_pieces(p0, p1):
            mid = (p0 + p1) / 2
            v, f = M.boxes(np.array([[mid[0], mid[1], z]]), np.array([[L, 0.3, h]]), yaw)
            self.add("wall", v, f, color or self.pick(self.style.props.walls), amount=0.15, scale=1.0)

    def fence_line(self, p0, p1, z, h, metal=False):
        for p0, p1, L, yaw in line_pieces(p0, p1):
            self._fence_piece(p0, p1, L, yaw, z, h, metal)

    def _fence_piece(self, p0, p1, L, yaw, z, h, metal):
        e = (p1 - p0) / L
        col = self.style.props.pole if metal else self.pick(self.style.props.fences)
        n_posts = int(L / 2.5) + 1
        s = np.linspace(0, L, n_posts)
        posts = np.c_[p0[None] + s[:, None] * e[None], np.full(n_posts, z)]
        v, f = M.boxes(posts, np.array([[0.1, 0.1, h]]), yaw)
        self.add("fence", v, f, col, "metal" if metal else "matte", 0.1, 1.0)
        mid = (p0 + p1) / 2
        for zz, hh in ((0.15, h * 0.12), (h * 0.75, h * 0.12)) if metal else ((0.1, h * 0.85),):
            v, f = M.boxes(np.array([[mid[0], mid[1], z + zz]]), np.array([[L, 0.04, hh]]), yaw)
            self.add("fence", v, f, col, "metal" if metal else "matte", 0.15, 0.6, fine=0.2)

    def hedge_line(self, p0, p1, z, height=(0.9, 1.8)):
        for p0, p1, L, yaw in line_pieces(p0, p1):
            mid = (p0 + p1) / 2
            h = self.rng.uniform(*height)
            v, f = M.grid((-L / 2, -0.5, h), (L, 0, 0), (0, 1.0, 0), max(1, int(L / 1.5)), 1)
            bv, bf = M.boxes(np.array([[0, 0, 0]]), np.array([[L, 1.0, h]]))
            f = np.concatenate([f, bf + len(v)])
            v = M.transform(np.concatenate([v, bv]), [mid[0], mid[1], z], yaw)
            self.paint("vegetation", v, f, self.style.hedge, fine=0.15)

    def guard_rail(self, pts: np.ndarray) -> None:
        """Posts and a double-sided beam along a 2D polyline."""
        pts = np.asarray(pts, float)
        pts = np.concatenate([np.array(split_segment(p, q, 40.0))[:, 0] for p, q in zip(pts[:-1], pts[1:])] + [pts[-1:]])
        seg = np.diff(pts, axis=0)
        L = np.linalg.norm(seg, axis=1)
        for (p, q), l in zip(zip(pts[:-1], pts[1:]), L):
            if l < 0.5:
                continue
            yaw = float(np.arctan2(q[1] - p[1], q[0] - p[0]))
            mid = (p + q) / 2
            v, f = M.boxes(np.array([[mid[0], mid[1], 0.5]]), np.array([[l, 0.12, 0.32]]), yaw)
            self.add("guard rail", v, f, PALETTE["guard"], "metal", 0.08, 2.0)
            n = max(1, int(l / 4.0))
            s = np.linspace(0, 1, n + 1)
            posts = np.c_[p[None] + s[:, None] * (q - p)[None], np.zeros(n + 1)]
            v, f = M.boxes(posts, np.array([[0.12, 0.12, 0.75]]), yaw)
            self.add("guard rail", v, f, PALETTE["guard"], "metal", 0.08, 2.0)

    def skirt(self, seg: np.ndarray, facing_neg_y: bool) -> None:
        """Vertical strip from a road edge at z = 0 down to the outer terrain."""
        if np.linalg.norm(seg[1] - seg[0]) > 60.0:
            for a, b in split_segment(seg[0], seg[1], 50.0):
                self.skirt(np.array([a, b]), facing_neg_y)
            return
        p0 = np.array([*seg[0], OUTER_Z - 0.05])
        u = np.array([*(seg[1] - seg[0]), 0.0])
        if not facing_neg_y:
            p0 = np.array([*seg[1], OUTER_Z - 0.05])
            u = -u
        v, f = M.quads(p0, u, np.array([0, 0, -OUTER_Z + 0.05]))
        self.paint("terrain", v, f, self.style.verge, tiled=True)
