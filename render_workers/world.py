"""Procedural towns: one data-driven builder for all seven IDDA towns.

``build_world(town_code, seed)`` reads the town's row in
``manifests.catalog.TOWNS`` and builds, deterministically from the seed:

* a grid of streets (blocks of about ``Town.block_m``, ``Town.lanes`` lanes per
  direction) sized so the drivable centre-line length matches ``Town.road_km``;
* per-feature extras switched on by the row: a freeway (dual carriageway with
  turn-around loops, connectors to the grid, guard rails and a tunnel), mini
  roundabouts, a railway, a river crossed by bridges;
* the street furniture and frontage (sidewalks, buildings, walls, fences,
  trees, lamps, traffic lights and signs, props), or, for countryside towns
  (``Town.sidewalks`` False), verges, fields, farms, hedges and woods.

Lanes are closed loops that never cross each other: each block (or group of
blocks) is circled clockwise on its inner lanes (right turns only), the town's
perimeter counter-clockwise on its outer lanes, the freeway as a stadium. So
traffic that keeps one speed per loop can never collide.

Static geometry is merged into one Part per (200 m tile, class, material).
``layout(town_code, seed)`` exposes the plan (loops, parking spans, building
footprints, zebra crossings) that ``render_workers.traffic`` and the tests use.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from manifests.catalog import LABELS, TOWNS, Town, town as town_row
from render_workers import meshes as M
from render_workers.scene import Path, World

ID = {label.name: label.id for label in LABELS}

CURB_H = 0.15  # sidewalk height above the road
OUTER_Z = -0.25  # terrain level outside the street grid
MARK_Z = 0.02  # lane markings above the road
LANE_W_URBAN, LANE_W_RURAL = 3.5, 3.0
PARKING_W = 2.2  # parking strip between the outer lane and the kerb (urban)
FREEWAY_LANE_W = 3.6
FREEWAY_MEDIAN = 30.0  # wide, planted median: lets buses take the turn-around loops
ZEBRA_FROM, ZEBRA_LEN = 0.6, 3.0  # zebra stripes: distance of their near end from the kerb line, length


# --------------------------------------------------------------------------
# The plan
# --------------------------------------------------------------------------
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


@dataclass(frozen=True, eq=False)
class Layout:
    """Everything about a town except its meshes."""

    town: Town
    seed: int
    xs: np.ndarray  # x of the north-south streets
    ys: np.ndarray  # y of the east-west streets
    lane_w: float
    parking_w: float
    sidewalk_w: float  # 0 for countryside (verges instead)
    verge_w: float
    hw: float  # half width of a street
    signals: frozenset  # signalised junctions (i, j)
    roundabouts: frozenset  # junctions with a central island
    groups: tuple  # block groups (i0, i1, j0, j1) circled by one loop
    river: tuple | None  # (y_centre, width) of the river, or None
    freeway: dict | None  # y, x0, x1, lanes, carriageway width, tunnel span
    railway_y: float | None
    bounds: tuple[float, float, float, float]

    @property
    def rect(self) -> tuple[float, float, float, float]:
        """Outer edge of the street grid incl. the outer sidewalk/verge."""
        e = self.hw + max(self.sidewalk_w, self.verge_w)
        return (self.xs[0] - e, self.ys[0] - e, self.xs[-1] + e, self.ys[-1] + e)

    @property
    def road_length_m(self) -> float:
        """Drivable centre-line length: grid streets, freeway and connectors."""
        grid = len(self.ys) * (self.xs[-1] - self.xs[0]) + len(self.xs) * (self.ys[-1] - self.ys[0])
        return float(grid + _freeway_length(self.freeway))


def _split_segment(p0, p1, max_len: float) -> list:
    """Cut a 2D segment into pieces no longer than max_len."""
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    n = max(1, int(np.ceil(np.linalg.norm(p1 - p0) / max_len)))
    t = np.linspace(0.0, 1.0, n + 1)
    pts = p0[None] + t[:, None] * (p1 - p0)[None]
    return [(pts[k], pts[k + 1]) for k in range(n)]


def _line_pieces(p0, p1):
    """Pieces of a wall, fence or hedge line as (p0, p1, length, yaw): lines over
    45 m are cut into pieces of at most 40 m, and pieces under 1 m are dropped."""
    long = np.linalg.norm(np.asarray(p1) - np.asarray(p0)) > 45.0
    for a, b in _split_segment(p0, p1, 40.0) if long else [(p0, p1)]:
        d = b - a
        length = float(np.linalg.norm(d))
        if length >= 1:
            yield a, b, length, float(np.arctan2(d[1], d[0]))


def _freeway_length(fw: dict | None) -> float:
    if fw is None:
        return 0.0
    return (fw["x1"] - fw["x0"]) + 2 * fw["connector_len"]


def _grid_counts(target_m: float, block: float) -> tuple[int, int, float]:
    """Blocks (nx, ny) and spacing whose grid length best matches the target."""
    best = None
    for nx in range(1, 14):
        for ny in range(max(1, nx - 1), nx + 2):
            length = ((ny + 1) * nx + (nx + 1) * ny) * block
            scale = target_m / length
            score = abs(np.log(scale))
            if best is None or score < best[0]:
                best = (score, nx, ny, block * scale)
    return best[1], best[2], best[3]


def _spacings(n: int, block: float, rng) -> np.ndarray:
    gaps = block * rng.uniform(0.85, 1.15, n)
    gaps *= n * block / gaps.sum()
    return np.concatenate([[0.0], np.cumsum(gaps)])


@lru_cache(maxsize=16)
def layout(town_code: str, seed: int) -> Layout:
    """The town's plan: street grid, features and loops' geometry inputs."""
    t = town_row(town_code)
    rng = np.random.default_rng([seed, TOWNS.index(t), 1])
    urban = t.sidewalks
    lane_w = LANE_W_URBAN if urban else LANE_W_RURAL
    parking_w = PARKING_W if urban else 0.0
    hw = t.lanes * lane_w + parking_w
    sidewalk_w = (5.0 + 1.0 * (t.lanes - 1)) if urban else 0.0
    verge_w = 0.0 if urban else 2.5

    fw_lanes = t.lanes + 1
    cw = 1.0 + fw_lanes * FREEWAY_LANE_W + 2.0  # carriageway width incl. shoulders
    # The freeway spans the grid plus 60 m each side; guess the grid width from
    # the target to split the length budget, then size the grid.
    target = t.road_km * 1000.0
    fw_guess = 0.0
    if t.freeway:
        side = np.sqrt(target / 2.4)
        fw_guess = side + 120 + 2 * 45
    nx, ny, block = _grid_counts(target - fw_guess, t.block_m)
    xs = _spacings(nx, block, rng)
    ys = _spacings(ny, block, rng)
    xs -= xs[-1] / 2
    ys -= ys[-1] / 2

    junctions = [(i, j) for i in range(nx + 1) for j in range(ny + 1)]
    degree = {(i, j): 4 - (i in (0, nx)) - (j in (0, ny)) for i, j in junctions}
    signals = frozenset(q for q in junctions if degree[q] >= 3 and rng.random() < t.traffic_light_share)
    interior = [q for q in junctions if degree[q] == 4 and q not in signals]
    roundabouts = frozenset()
    if t.roundabouts and interior:
        pick = rng.choice(len(interior), size=min(2, len(interior)), replace=False)
        roundabouts = frozenset(interior[k] for k in pick)

    groups = _group_blocks(nx, ny, rng)

    river = None
    if t.bridges and ny >= 1:
        j = ny // 2
        inner_h = (ys[j + 1] - ys[j]) - 2 * (hw + max(sidewalk_w, verge_w))
        width = float(np.clip(0.25 * inner_h, 8.0, 18.0))
        if inner_h - width - 8 > 2 * 10:
            river = (float((ys[j] + ys[j + 1]) / 2 + rng.uniform(-3, 3)), width)

    e = hw + max(sidewalk_w, verge_w)
    freeway = None
    if t.freeway:
        y = ys[0] - e - 30.0 - (FREEWAY_MEDIAN / 2 + cw)
        x0, x1 = xs[0] - 60.0, xs[-1] + 60.0
        span = xs[-1] - xs[0]
        tunnel = None
        if t.tunnels and span > 120:
            half = min(70.0, 0.25 * span)
            mid = 0.5 * (xs[0] + xs[-1])
            tunnel = (mid - half, mid + half)
        freeway = dict(y=float(y), x0=float(x0), x1=float(x1), lanes=fw_lanes, cw=cw,
                       tunnel=tunnel, connector_len=float(ys[0] - hw - (y + FREEWAY_MEDIAN / 2 + cw)))
    railway_y = float(ys[-1] + e + 22.0) if t.railway else None

    margin = 140.0 if urban else 170.0
    x0, y0, x1, y1 = xs[0] - e, ys[0] - e, xs[-1] + e, ys[-1] + e
    if freeway:
        y0 = min(y0, freeway["y"] - FREEWAY_MEDIAN / 2 - cw - 20)
        x0, x1 = min(x0, freeway["x0"] - 25), max(x1, freeway["x1"] + 25)
    bounds = (float(x0 - margin), float(y0 - margin), float(x1 + margin), float(y1 + margin))
    return Layout(t, seed, xs, ys, lane_w, parking_w, sidewalk_w, verge_w, hw, signals,
                  roundabouts, groups, river, freeway, railway_y, bounds)


def _group_blocks(nx: int, ny: int, rng) -> tuple:
    """Partition the blocks into rectangles of 1-2 blocks a side."""
    def runs(n):
        cuts, k = [0], 0
        while k < n:
            step = 2 if (n - k >= 2 and rng.random() < 0.35) else 1
            k += step
            cuts.append(k)
        return cuts

    cx, cy = runs(nx), runs(ny)
    return tuple((cx[a], cx[a + 1], cy[b], cy[b + 1]) for a in range(len(cx) - 1) for b in range(len(cy) - 1))


# --------------------------------------------------------------------------
# Lane loops
# --------------------------------------------------------------------------
def rounded_rect(x0, y0, x1, y1, r, clockwise: bool, arc_step_deg: float = 10.0) -> np.ndarray:
    """Closed polyline around a rectangle with rounded corners, z = 0."""
    r = float(min(r, 0.5 * (x1 - x0), 0.5 * (y1 - y0)))
    n = max(2, int(np.ceil(90.0 / arc_step_deg)))
    pts = []
    # counter-clockwise: start on the south side heading east
    corners = [((x1 - r, y0 + r), -90.0), ((x1 - r, y1 - r), 0.0), ((x0 + r, y1 - r), 90.0), ((x0 + r, y0 + r), 180.0)]
    for (cx, cy), a0 in corners:
        ang = np.radians(np.linspace(a0, a0 + 90.0, n + 1))
        pts.append(np.stack([cx + r * np.cos(ang), cy + r * np.sin(ang)], 1))
    p = np.concatenate(pts)
    if clockwise:
        p = p[::-1]
    return np.concatenate([p, np.zeros((len(p), 1))], 1)


def _parking_spans(points: np.ndarray, junction_xy: np.ndarray, clear: float) -> tuple:
    """Arc-length spans on long straight segments, away from junctions."""
    loop = np.vstack([points, points[:1]])
    seg = np.diff(loop, axis=0)
    length = np.linalg.norm(seg, axis=1)
    cum = np.concatenate([[0.0], np.cumsum(length)])
    spans = []
    for k in np.flatnonzero(length > 2 * clear + 6):
        a, d = loop[k, :2], seg[k, :2] / length[k]
        t = (junction_xy - a) @ d
        lat = np.abs((junction_xy - a) @ np.array([-d[1], d[0]]))
        hits = np.sort(t[(lat < clear + 10) & (t > -clear) & (t < length[k] + clear)])
        lo = 8.0
        for h in list(hits) + [length[k] + 1e9]:
            hi = min(h - clear, length[k] - 8.0)
            if hi - lo > 6:
                spans.append((cum[k] + lo, cum[k] + hi))
            lo = max(lo, h + clear)
    return tuple(spans)


def _corner_offset(lay: "Layout") -> float:
    """Offset of the right-turn arc centres from the junction centre.

    All lanes of a block loop turn around the same centre (so they stay
    concentric); it is the farthest one that keeps the outermost lane's
    centre 1.6 m off the kerb corner, and never inside the junction.
    """
    hw, d_max = lay.hw, (lay.town.lanes - 0.5) * lay.lane_w
    return float(max(hw, (np.sqrt(2) * hw - d_max - 1.6) / (np.sqrt(2) - 1)))


def _loops(lay: Layout) -> tuple[Loop, ...]:
    t, hw, lw = lay.town, lay.hw, lay.lane_w
    xs, ys = lay.xs, lay.ys
    jxy = np.array([(x, y) for x in xs for y in ys])
    loops = []
    urban = lay.parking_w > 0
    c = _corner_offset(lay)
    clear = c + 6.0
    for k in range(t.lanes):
        d = (k + 0.5) * lw
        outer = k == t.lanes - 1
        park_lat = -(lw / 2 + lay.parking_w / 2) if (outer and urban) else 0.0
        kerb_lat = -(lw / 2 - 0.9) if outer else 0.0
        r = c - d
        for i0, i1, j0, j1 in lay.groups:
            pts = rounded_rect(xs[i0] + d, ys[j0] + d, xs[i1] - d, ys[j1] - d, r, clockwise=True)
            spans = _parking_spans(pts, jxy, clear) if park_lat else ()
            loops.append(Loop(Path(pts, closed=True), "block", k, r, spans, park_lat, kerb_lat, lw))
        r = hw + d
        pts = rounded_rect(xs[0] - d, ys[0] - d, xs[-1] + d, ys[-1] + d, r, clockwise=False)
        spans = _parking_spans(pts, jxy, hw + 6.0) if park_lat else ()
        loops.append(Loop(Path(pts, closed=True), "perimeter", k, r, spans, park_lat, kerb_lat, lw))
    fw = lay.freeway
    if fw:
        for k in range(fw["lanes"]):
            e = FREEWAY_MEDIAN / 2 + 1.0 + (k + 0.5) * FREEWAY_LANE_W
            pts = rounded_rect(fw["x0"] - e, fw["y"] - e, fw["x1"] + e, fw["y"] + e, e, clockwise=False)
            loops.append(Loop(Path(pts, closed=True), "freeway", k, e, (), 0.0,
                              -(FREEWAY_LANE_W / 2 - 0.9) if k == fw["lanes"] - 1 else 0.0, FREEWAY_LANE_W))
    return tuple(loops)


@lru_cache(maxsize=16)
def loops(town_code: str, seed: int) -> tuple[Loop, ...]:
    """The town's lane loops (the same paths as ``World.lanes``, in order)."""
    return _loops(layout(town_code, seed))


def _crosswalks(lay: Layout) -> tuple[Crosswalk, ...]:
    """Every zebra crossing: one per junction approach, where there are sidewalks."""
    if not lay.sidewalk_w:
        return ()
    xs, ys, hw, w = lay.xs, lay.ys, lay.hw, lay.sidewalk_w
    out = []
    for i, x in enumerate(xs):
        for j, y in enumerate(ys):
            c = np.array([x, y])
            # the streets leaving this junction: direction -> distance to the next junction
            streets = {}
            if j + 1 < len(ys):
                streets[(0, 1)] = ys[j + 1] - y
            if j > 0:
                streets[(0, -1)] = y - ys[j - 1]
            if i + 1 < len(xs):
                streets[(1, 0)] = xs[i + 1] - x
            if i > 0:
                streets[(-1, 0)] = x - xs[i - 1]
            for d in streets:
                n = (-d[1], d[0])
                # beyond a kerb the crossing line runs down the sidewalk of the
                # cross street, if there is one; else only across the sidewalk
                reach = tuple(float(streets[e] - 2 * hw - 4.0) if e in streets else float(w - 1.0)
                              for e in ((-n[0], -n[1]), n))
                centre = c + np.array(d, float) * (hw + ZEBRA_FROM + ZEBRA_LEN / 2)
                out.append(Crosswalk(centre, np.array(n, float), float(hw), reach))
    return tuple(out)


@lru_cache(maxsize=16)
def crosswalks(town_code: str, seed: int) -> tuple[Crosswalk, ...]:
    """The town's zebra crossings (empty for countryside towns)."""
    return _crosswalks(layout(town_code, seed))


def walkway_loops(lay: Layout, inset: float = 0.0) -> tuple[Path, ...]:
    """The closed walkways along the middle of the sidewalks (verges), one per
    block plus the town's outer edge, moved ``inset`` metres away from the road
    (towards the buildings). Each loop keeps the road on its left."""
    xs, ys, hw = lay.xs, lay.ys, lay.hw
    e = hw + (lay.sidewalk_w or lay.verge_w) / 2 + inset
    out = []
    for i in range(len(xs) - 1):
        for j in range(len(ys) - 1):
            pts = rounded_rect(xs[i] + e, ys[j] + e, xs[i + 1] - e, ys[j + 1] - e, 0.5, clockwise=True)
            out.append(Path(pts, closed=True))
    out.append(Path(rounded_rect(xs[0] - e, ys[0] - e, xs[-1] + e, ys[-1] + e, 0.5, clockwise=False), closed=True))
    return tuple(out)


def _walkways(lay: Layout) -> tuple[Path, ...]:
    hw = lay.hw
    out = list(walkway_loops(lay))
    for cw in _crosswalks(lay):  # zebra crossings, kerb to kerb plus half a metre
        ends = [cw.centre - cw.across * (hw + 0.5), cw.centre + cw.across * (hw + 0.5)]
        out.append(Path(np.array([[*p, 0.0] for p in ends]), closed=False))
    return tuple(out)


# --------------------------------------------------------------------------
# Geometry
# --------------------------------------------------------------------------
PALETTE = {
    "asphalt": (66, 66, 70), "asphalt_fw": (80, 80, 84), "marking": (225, 225, 220),
    "marking_y": (215, 180, 60), "paving": (150, 146, 140), "paving_red": (160, 120, 110),
    "curb": (178, 176, 170), "grass": (72, 112, 44), "dry_grass": (125, 130, 70),
    "dirt": (112, 92, 64), "ground": (120, 112, 100), "canopy": (58, 96, 38),
    "canopy2": (82, 112, 44), "bark": (84, 64, 44), "hedge": (44, 84, 34),
    "pole": (112, 114, 118), "wood_pole": (96, 76, 56), "sign": (200, 200, 205),
    "signal": (38, 38, 40), "guard": (175, 176, 180), "ballast": (104, 98, 92),
    "rail": (90, 86, 84), "sleeper": (92, 72, 52), "water": (44, 66, 74),
    "roof": (82, 76, 72), "roof_red": (140, 64, 48), "window": (46, 60, 74),
    "door": (70, 52, 40), "lamp": (255, 240, 200),
}
FACADES = {  # look -> base colours; windows are drawn on brick and concrete
    "brick": [(150, 76, 56), (128, 62, 46), (168, 102, 72), (112, 70, 60)],
    "concrete": [(176, 170, 160), (192, 186, 170), (142, 142, 138), (205, 196, 176), (160, 150, 130)],
    "glass": [(72, 92, 112), (60, 78, 86), (96, 112, 122)],
}
WALLS = [(160, 152, 140), (140, 128, 116), (176, 170, 160), (120, 100, 84)]
FENCES = [(92, 96, 100), (120, 92, 62), (70, 84, 70), (150, 150, 150)]


class _Builder:
    """Turns a Layout into merged, tiled Parts."""

    def __init__(self, lay: Layout) -> None:
        self.lay = lay
        self.t = lay.town
        self.rng = np.random.default_rng([lay.seed, TOWNS.index(lay.town), 2])
        self.batch = M.MeshBatch()
        self.buildings: list[tuple[float, float, float, float, float]] = []  # cx, cy, sx, sy, yaw
        self._cseed = 0

    # ---- adding geometry ------------------------------------------------
    def add(self, cls: str, verts, faces, base, material="matte", amount=0.12, scale=3.0,
            tiled=False, fine=0.05):
        self._cseed += 1
        colors = M.noisy_colors(verts, base, amount, scale, seed=self._cseed % 9973, fine=fine)
        self.add_colored(cls, verts, faces, colors, material, tiled)

    def add_colored(self, cls, verts, faces, colors, material="matte", tiled=False):
        if tiled:
            self.batch.add_tiled(ID[cls], material, verts, faces, colors)
        else:
            self.batch.add(ID[cls], material, verts, faces, colors)

    def pick(self, options):
        return options[int(self.rng.integers(len(options)))]

    # ---- streets ---------------------------------------------------------
    def streets(self) -> None:
        lay, hw = self.lay, self.lay.hw
        xs, ys = lay.xs, lay.ys
        cell = 3.0
        for i, x in enumerate(xs):  # north-south segments
            for j in range(len(ys) - 1):
                a, b = ys[j] + hw, ys[j + 1] - hw
                v, f = M.grid((x - hw, a, 0), (2 * hw, 0, 0), (0, b - a, 0), int(2 * hw / cell), int((b - a) / cell))
                self.add("road", v, f, PALETTE["asphalt"], "road", 0.18, 6.0, tiled=True)
                self.markings(np.array([x, a]), np.array([0.0, 1.0]), b - a)
        for j, y in enumerate(ys):  # east-west segments
            for i in range(len(xs) - 1):
                a, b = xs[i] + hw, xs[i + 1] - hw
                v, f = M.grid((a, y - hw, 0), (b - a, 0, 0), (0, 2 * hw, 0), int((b - a) / cell), int(2 * hw / cell))
                self.add("road", v, f, PALETTE["asphalt"], "road", 0.18, 6.0, tiled=True)
                self.markings(np.array([a, y]), np.array([1.0, 0.0]), b - a)
        for i, x in enumerate(xs):
            for j, y in enumerate(ys):
                v, f = M.ground_rect(x - hw, y - hw, x + hw, y + hw, 0.0, cell)
                self.add("road", v, f, PALETTE["asphalt"], "road", 0.18, 6.0)
                if (i, j) in lay.roundabouts:
                    self.roundabout(x, y)
                self.junction_marks(i, j)

    def markings(self, start: np.ndarray, d: np.ndarray, length: float) -> None:
        """Centre, lane and edge lines along one street segment."""
        lay = self.lay
        n = np.array([-d[1], d[0]])
        lines = []  # (lateral, dashed, width, colour)
        if lay.town.lanes > 1:
            lines += [(-0.12, False, 0.12, "marking_y"), (0.12, False, 0.12, "marking_y")]
        else:
            lines.append((0.0, True, 0.14, "marking"))
        for k in range(1, lay.town.lanes):
            lines += [(k * lay.lane_w, True, 0.14, "marking"), (-k * lay.lane_w, True, 0.14, "marking")]
        if lay.parking_w:
            e = lay.town.lanes * lay.lane_w
            lines += [(e, False, 0.16, "marking"), (-e, False, 0.16, "marking")]
        elif lay.verge_w:
            e = lay.town.lanes * lay.lane_w - 0.25
            lines += [(e, False, 0.14, "marking"), (-e, False, 0.14, "marking")]
        p0s, us, vs = [], [], []
        off = 4.5 if lay.sidewalk_w else 0.5
        for lat, dashed, w, _ in lines:
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
        self.road_marks(p0s, us, vs)

    def junction_marks(self, i: int, j: int) -> None:
        """Zebra crossings and stop lines on every approach of a junction."""
        lay, hw = self.lay, self.lay.hw
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
            if (i, j) in lay.signals or (not lay.sidewalk_w and self.rng.random() < 0.5):
                # stop line across the incoming half (right-hand traffic: incoming on -n side)
                p = c + d * (hw + 4.2) - n * (lay.town.lanes * lay.lane_w)
                p0s.append([*p, MARK_Z]); us.append([*(d * 0.4), 0]); vs.append([*(n * lay.town.lanes * lay.lane_w), 0])
        self.road_marks(p0s, us, vs)

    def road_marks(self, p0s: list, us: list, vs: list) -> None:
        """Add painted quads (corner p0, edges u, v) as road line, every quad facing up."""
        if not p0s:
            return
        p0, u, v = np.array(p0s), np.array(us), np.array(vs)
        flip = np.cross(u, v)[:, 2] < 0
        p0[flip] += v[flip]
        v[flip] = -v[flip]
        vv, ff = M.quads(p0, u, v)
        self.add("road line", vv, ff, PALETTE["marking"], "matte", 0.06, 2.0)

    def roundabout(self, x: float, y: float) -> None:
        lay = self.lay
        d0 = 0.5 * lay.lane_w
        c = _corner_offset(lay)
        r = np.sqrt(2) * c - (c - d0) - 2.6
        ang = np.linspace(0, 2 * np.pi, 25)
        ring = np.stack([x + r * np.cos(ang), y + r * np.sin(ang)], 1)
        v, f = M.ribbon(ring, 0.0, 0.35, MARK_Z)
        self.add("road line", v, f, PALETTE["marking"])
        top = np.concatenate([[[x, y, CURB_H + 0.1]], np.c_[ring[:-1] + 0.0, np.full(24, CURB_H)]])
        top[1:, :2] = np.array([x, y]) + (ring[:-1] - np.array([x, y])) * (r - 0.4) / r
        fan = np.stack([np.zeros(24, int), 1 + np.arange(24), 1 + (np.arange(24) + 1) % 24], 1)
        self.add("terrain", top, M.orient_up(top, fan), PALETTE["grass"], amount=0.2, scale=1.0)
        curb_b = np.c_[ring[:-1] * 0 + ring[:-1], np.zeros(24)]
        curb_b[:, :2] = np.array([x, y]) + (ring[:-1] - np.array([x, y])) * (r - 0.4) / r
        curb_t = curb_b.copy()
        curb_t[:, 2] = CURB_H
        nxt = np.roll(np.arange(24), -1)
        p0, u, v = curb_b, curb_b[nxt] - curb_b, curb_t - curb_b
        vv, ff = M.quads(p0, u, v)
        self.add("sidewalk", vv, ff, PALETTE["curb"])
        self.tree(np.array([x, y, CURB_H]), scale=0.8)
        self.props_box("other", [x + 1.2, y, CURB_H], [0.8, 0.8, 2.4], 0.3, (150, 120, 90), "metal")

    # ---- sidewalks, verges and the outer ring ---------------------------
    def sidewalk_ring(self, x0, y0, x1, y1, w, outward: bool, gaps=()) -> None:
        """A sidewalk band of width w inside (or outside) a rectangle, with curbs."""
        z = CURB_H
        bands = []
        if not outward:
            bands = [((x0, y0, x1, y0 + w), "s"), ((x0, y1 - w, x1, y1), "n"),
                     ((x0, y0 + w, x0 + w, y1 - w), "w"), ((x1 - w, y0 + w, x1, y1 - w), "e")]
        else:
            bands = [((x0 - w, y0 - w, x1 + w, y0), "s_out"), ((x0 - w, y1, x1 + w, y1 + w), "n_out"),
                     ((x0 - w, y0, x0, y1), "w_out"), ((x1, y0, x1 + w, y1), "e_out")]
        look = self.pick(["paving", "paving", "paving_red"])
        planting = self.rng.random() < 0.5
        for (a0, b0, a1, b1), side in bands:
            pieces = [(a0, a1)]
            if side == "s_out":
                for g0, g1 in gaps:
                    pieces = [q for p in pieces for q in ((p[0], min(p[1], g0)), (max(p[0], g1), p[1])) if q[1] - q[0] > 0.5]
            for p0_, p1_ in pieces:
                v, f = M.ground_rect(p0_, b0, p1_, b1, z, 2.0)
                self.add("sidewalk", v, f, PALETTE[look], amount=0.1, scale=1.3, fine=0.08, tiled=True)
                self.curb_faces(p0_, b0, p1_, b1, side)
                if side[0] in "sn":  # end faces of the bands that span the corners
                    low = OUTER_Z if side.endswith("_out") else 0.0
                    for xe, sgn in ((p0_, -1), (p1_, 1)):
                        p = np.array([xe, b0 if sgn > 0 else b1, low])
                        vv, ff = M.quads(p, np.array([0, sgn * (b1 - b0), 0]), np.array([0, 0, z - low]))
                        self.add("sidewalk", vv, ff, PALETTE["curb"], amount=0.08)
            if planting and side in ("s", "n", "w", "e"):
                self.planting_strip(a0, b0, a1, b1, side)

    def planting_strip(self, a0, b0, a1, b1, side) -> None:
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
            self.add("terrain", v, f, PALETTE["grass"], amount=0.25, scale=1.0, fine=0.1, tiled=True)

    def curb_faces(self, a0, b0, a1, b1, side) -> None:
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
            self.add("sidewalk", vv, ff, PALETTE["curb"], amount=0.08)

    def sidewalks(self) -> None:
        lay, hw, w = self.lay, self.lay.hw, self.lay.sidewalk_w or self.lay.verge_w
        xs, ys = lay.xs, lay.ys
        gaps = []
        if lay.freeway:
            gaps = [(xs[0] - hw, xs[0] + hw), (xs[-1] - hw, xs[-1] + hw)]
        if lay.sidewalk_w:
            for i in range(len(xs) - 1):
                for j in range(len(ys) - 1):
                    self.sidewalk_ring(xs[i] + hw, ys[j] + hw, xs[i + 1] - hw, ys[j + 1] - hw, w, False)
            self.sidewalk_ring(xs[0] - hw, ys[0] - hw, xs[-1] + hw, ys[-1] + hw, w, True, gaps)
        else:  # verges: grass strips level with the road edge
            for i in range(len(xs) - 1):
                for j in range(len(ys) - 1):
                    self.verge_ring(xs[i] + hw, ys[j] + hw, xs[i + 1] - hw, ys[j + 1] - hw, w)
            e = hw + w
            for (a0, b0, a1, b1) in [(xs[0] - e, ys[0] - e, xs[-1] + e, ys[0] - hw),
                                     (xs[0] - e, ys[-1] + hw, xs[-1] + e, ys[-1] + e),
                                     (xs[0] - e, ys[0] - hw, xs[0] - hw, ys[-1] + hw),
                                     (xs[-1] + hw, ys[0] - hw, xs[-1] + e, ys[-1] + hw)]:
                v, f = M.ground_rect(a0, b0, a1, b1, 0.02, 3.0)
                self.add("terrain", v, f, PALETTE["dry_grass"], amount=0.2, scale=2.0, tiled=True)

    def verge_ring(self, x0, y0, x1, y1, w) -> None:
        for (a0, b0, a1, b1) in [(x0, y0, x1, y0 + w), (x0, y1 - w, x1, y1),
                                 (x0, y0 + w, x0 + w, y1 - w), (x1 - w, y0 + w, x1, y1 - w)]:
            v, f = M.ground_rect(a0, b0, a1, b1, 0.02, 3.0)
            self.add("terrain", v, f, PALETTE["dry_grass"], amount=0.22, scale=2.0, tiled=True)

    # ---- small objects ---------------------------------------------------
    def props_box(self, cls, base, size, yaw, color, material="matte"):
        v, f = M.boxes(np.array([base], float), np.array([size], float), yaw)
        self.add(cls, v, f, color, material, amount=0.08, scale=1.0)

    def tree(self, base: np.ndarray, scale: float = 1.0, conifer: bool = False) -> None:
        rng = self.rng
        h = scale * rng.uniform(2.2, 3.8)
        v, f = M.cylinders(base[None], h + 1.0, scale * rng.uniform(0.14, 0.24), 6)
        self.add("vegetation", v, f, PALETTE["bark"], amount=0.2, scale=0.5)
        r = scale * rng.uniform(2.4, 3.9)
        if conifer:
            radii = np.array([[0.55 * r, 0.55 * r, 1.6 * r]])
            cen = base + np.array([0, 0, h + 1.2 * r])
        else:
            radii = np.array([[r, r * rng.uniform(0.8, 1.1), r * rng.uniform(0.75, 1.0)]])
            cen = base + np.array([0, 0, h + 0.7 * r])
        v, f = M.blobs(cen[None], radii, seed=int(rng.integers(1 << 20)))
        self.add("vegetation", v, f, self.pick([PALETTE["canopy"], PALETTE["canopy2"], (66, 104, 30)]),
                 amount=0.25, scale=1.2, fine=0.1)

    def pole_with(self, base, height, radius=0.08, wood=False):
        v, f = M.cylinders(np.array([base], float), height, radius, 6)
        self.add("pole", v, f, PALETTE["wood_pole" if wood else "pole"], "matte" if wood else "metal", 0.1, 1.0)

    def street_lamp(self, base, yaw):
        """A lamp post with an arm towards the road (yaw points to the road)."""
        self.pole_with(base, 7.5, 0.09)
        d = np.array([np.cos(yaw), np.sin(yaw), 0])
        arm_c = np.asarray(base) + d * 0.9 + np.array([0, 0, 7.4])
        self.props_box("pole", arm_c - np.array([0, 0, 0.05]), [1.8, 0.12, 0.12], yaw, PALETTE["pole"], "metal")
        head = np.asarray(base) + d * 1.7 + np.array([0, 0, 7.25])
        self.props_box("pole", head, [0.6, 0.3, 0.15], yaw, PALETTE["lamp"], "emissive")

    def traffic_sign(self, base, facing):
        """Pole plus a plate facing ``facing`` (radians, towards approaching cars)."""
        self.pole_with(base, 2.9, 0.05)
        face = self.pick([(190, 30, 30), (30, 70, 170), (235, 235, 235), (230, 190, 30)])
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
            self.add("pole", v, f, PALETTE["pole"], "metal", 0.1, 1.0)
            heads.append(base + left * arm * 0.85 + np.array([0, 0, 4.4]) + d * 0.1)
        for h in heads:
            v, f = M.boxes(h[None], np.array([[0.35, 0.4, 1.05]]), facing)
            self.add("traffic light", v, f, PALETTE["signal"], "matte", 0.05, 0.3)
            lamps = np.array([h + d * 0.18 + np.array([0, 0, z]) for z in (0.17, 0.5, 0.83)])
            col = self.pick([(255, 40, 30), (40, 255, 90), (255, 190, 30)])
            vv, ff = M.boxes(lamps - np.array([0, 0, 0.11]), np.array([[0.04, 0.22, 0.22]]), facing)
            self.add("traffic light", vv, ff, col, "emissive", 0.02, 0.3)

    # ---- street furniture ------------------------------------------------
    def furniture(self) -> None:
        """Trees, lamps, signs, traffic lights and props along every street."""
        lay, rng, t = self.lay, self.rng, self.t
        hw, w = lay.hw, lay.sidewalk_w or lay.verge_w
        xs, ys = lay.xs, lay.ys
        urban = bool(lay.sidewalk_w)
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
                    self.street_side(np.array([x, y]), d, length, spacing, kerb, z, urban)
                    self.junction_furniture((i, j), np.array([x, y]), d, kerb, z, urban)

    def street_side(self, c, d, length, spacing, kerb, z, urban) -> None:
        """Furniture along the right-hand side of the street leaving c along d."""
        lay, rng, t = self.lay, self.rng, self.t
        n_right = np.array([d[1], -d[0]])
        s_vals = np.arange(lay.hw + 9.0, length - lay.hw - 5.0, spacing)
        yaw_to_road = float(np.arctan2(-n_right[1], -n_right[0]))
        bridge = self.on_river
        for k, s in enumerate(s_vals):
            p = c + d * (s + rng.uniform(-1.5, 1.5)) + n_right * (lay.hw + kerb)
            if bridge(p[1], 4.0):
                continue
            base = np.array([p[0], p[1], z])
            u = rng.random()
            if k % 3 == 1:
                if urban or rng.random() < 0.5:
                    if urban:
                        self.street_lamp(base, yaw_to_road)
                    else:
                        self.pole_with(base, 8.0, 0.13, wood=True)
                        self.props_box("pole", base + np.array([0, 0, 7.3]), [0.12, 1.6, 0.12], yaw_to_road, PALETTE["wood_pole"])
            elif u < min(0.9, t.vegetation_density * 1.5):
                self.tree(base, scale=rng.uniform(0.85, 1.25))
            elif urban and u < t.vegetation_density + 0.25:
                q = base + np.array([*n_right, 0.0]) * 0.3
                self.static_prop(q, yaw_to_road)
            elif not urban and u < 0.9:
                hb = base + np.array([*n_right, 0.0]) * 1.5
                self.bush(hb)

    def bush(self, base):
        r = self.rng.uniform(0.8, 1.5)
        v, f = M.blobs((base + np.array([0, 0, 0.5 * r]))[None], np.array([[r, r, 0.8 * r]]), int(self.rng.integers(1 << 20)))
        self.add("vegetation", v, f, PALETTE["hedge"], amount=0.25, scale=0.8)

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

    def junction_furniture(self, q, c, d, kerb, z, urban) -> None:
        """Signs and lights where traffic arrives at junction q along -d."""
        lay, rng = self.lay, self.rng
        hw = lay.hw
        # Approaching traffic drives along -d on the right side: the right-hand
        # corner for them is on the +n_left side of d.
        n_left = np.array([-d[1], d[0]])
        facing = float(np.arctan2(d[1], d[0]))  # plate faces the incoming cars
        corner = c + d * (hw + 4.5 if urban else hw + 3.0) + n_left * (hw + kerb)
        deg = 4 - (q[0] in (0, len(lay.xs) - 1)) - (q[1] in (0, len(lay.ys) - 1))
        if deg == 2:
            if rng.random() < 0.4:
                self.traffic_sign(np.array([*corner, z]), facing)
            return
        if q in lay.signals:
            arm = (lay.town.lanes * lay.lane_w + 0.5 * lay.parking_w + kerb) if lay.town.lanes > 1 or rng.random() < 0.5 else 0.0
            self.traffic_light(np.array([*corner, z]), facing, arm)
            if rng.random() < 0.5:
                self.traffic_sign(np.array([*(corner + d * 3.0), z]), facing)
        elif rng.random() < (0.8 if urban else 0.65):
            self.traffic_sign(np.array([*corner, z]), facing)

    # ---- blocks ----------------------------------------------------------
    def on_river(self, y: float, pad: float = 0.0) -> bool:
        r = self.lay.river
        return r is not None and abs(y - r[0]) < r[1] / 2 + 3.0 + pad

    def blocks(self) -> None:
        lay = self.lay
        hw, w = lay.hw, lay.sidewalk_w or lay.verge_w
        z = CURB_H if lay.sidewalk_w else 0.05
        for i in range(len(lay.xs) - 1):
            for j in range(len(lay.ys) - 1):
                x0, y0 = lay.xs[i] + hw + w, lay.ys[j] + hw + w
                x1, y1 = lay.xs[i + 1] - hw - w, lay.ys[j + 1] - hw - w
                if lay.river and y0 < lay.river[0] < y1:
                    yr0 = lay.river[0] - lay.river[1] / 2 - 3.0
                    yr1 = lay.river[0] + lay.river[1] / 2 + 3.0
                    self.river_section(x0, x1, z)
                    self.block((x0, y0, x1, yr0), z, sides="swe", river_side="n")
                    self.block((x0, yr1, x1, y1), z, sides="nwe", river_side="s")
                else:
                    self.block((x0, y0, x1, y1), z, sides="nswe")

    def block(self, rect, z, sides: str, river_side: str = "") -> None:
        x0, y0, x1, y1 = rect
        if x1 - x0 < 4 or y1 - y0 < 4:
            return
        urban = bool(self.lay.sidewalk_w)
        ground = "grass" if (urban and self.rng.random() < 0.8) or not urban else "ground"
        if urban:
            v, f = M.ground_rect(x0, y0, x1, y1, z, 4.0)
            cls = "terrain" if ground == "grass" else "ground"
            self.add(cls, v, f, PALETTE[ground], amount=0.2, scale=3.0, tiled=True)
            self.frontage(rect, z, sides)
        else:
            self.countryside(rect, z, sides)
        if river_side:  # railing along the river bank
            y = y1 if river_side == "n" else y0
            self.fence_line(np.array([x0, y]), np.array([x1, y]), z, 1.1, metal=True)

    def frontage(self, rect, z, sides) -> None:
        """Buildings and fillers along the street sides of a block."""
        x0, y0, x1, y1 = rect
        rng, t = self.rng, self.t
        W, H = x1 - x0, y1 - y0
        dmax_ns = min(rng.uniform(12, 24) * (1.3 if t.building_height_m[1] > 30 else 1.0), H / 2 - 1 if "n" in sides and "s" in sides else H - 2)
        dmax_we = min(rng.uniform(12, 22), W / 2 - 1)
        front = {
            # side: origin, along, inward, length, start trim, end trim
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
            self.lots(o, a, inw, s0, s1, depth, z)

    def lots(self, o, a, inw, s0, s1, depth, z) -> None:
        rng, t = self.rng, self.t
        s = s0
        big = t.building_height_m[1] > 30
        while s1 - s > 6:
            width = min(rng.uniform(14, 34) if big else rng.uniform(10, 24), s1 - s)
            if s1 - s - width < 8:
                width = s1 - s
            if rng.random() < t.building_density and depth > 6:
                gap = rng.uniform(0.0, 1.5)
                setback = rng.uniform(0.5, 6.0) if self.t.sidewalks else rng.uniform(6.0, 12.0)
                dep = depth * rng.uniform(0.75, 1.0) - setback
                self.building(o, a, inw, s + gap, s + width - gap, setback, dep, z)
                if setback > 2.0 and rng.random() < 0.5:
                    self.hedge_line(o + a * (s + gap) + inw * 0.5, o + a * (s + width - gap) + inw * 0.5, z)
            else:
                self.filler(o, a, inw, s, s + width, depth, z)
            s += width

    def building(self, o, a, inw, s0, s1, setback, depth, z) -> None:
        rng, t = self.rng, self.t
        width = s1 - s0
        if width < 5 or depth < 5:
            return
        lo, hi = t.building_height_m
        h = lo + (hi - lo) * rng.random() ** 1.6
        floors = max(1, int(round((h - 0.5) / 3.2)))
        h = floors * 3.2 + 0.6
        look = "glass" if (h > 22 and rng.random() < 0.5) else ("brick" if (h < 18 and rng.random() < 0.5) else "concrete")
        base_col = np.array(self.pick(FACADES[look]), float) * rng.uniform(0.9, 1.1)
        yaw = float(np.arctan2(a[1], a[0]))
        mid = o + a * (s0 + s1) / 2 + inw * (setback + depth / 2)
        self.buildings.append((float(mid[0]), float(mid[1]), float(width), float(depth), yaw))
        # walls as subdivided grids (floors x bays) so the vertex colours can vary
        corners = [o + a * s0 + inw * setback, o + a * s1 + inw * setback,
                   o + a * s1 + inw * (setback + depth), o + a * s0 + inw * (setback + depth)]
        bay = rng.uniform(3.0, 4.2)
        vs, fs, off = [], [], 0
        facade_info = []
        for k in range(4):
            p, q = corners[k], corners[(k + 1) % 4]
            edge = q - p
            L = float(np.linalg.norm(edge))
            # corners go counter-clockwise seen from above when a x inw > 0
            sign = np.sign(a[0] * inw[1] - a[1] * inw[0])
            if sign < 0:
                p, q = q, p
                edge = -edge
            v, f = M.grid((*p, z), (*edge, 0), (0, 0, h), max(1, int(L / 6)), max(1, floors))
            vs.append(v)
            fs.append(f + off)
            off += len(v)
            facade_info.append((p, edge / L, L))
        verts = np.concatenate(vs)
        faces = np.concatenate(fs)
        mat = "glass" if look == "glass" else "matte"
        cols = M.noisy_colors(verts, base_col, 0.1, 4.0, seed=int(rng.integers(1 << 16)), fine=0.04)
        if look != "glass":  # darker plinth and floor bands
            band = (np.abs(((verts[:, 2] - z) % 3.2) - 0.1) < 0.15) | (verts[:, 2] - z < 0.05)
            cols[band, :3] = (cols[band, :3] * 0.8).astype(np.uint8)
        self.add_colored("building", verts, faces, cols, mat)
        roof_col = PALETTE["roof"] if rng.random() < 0.7 else (120, 118, 112)
        rc = np.array([*(o + a * (s0 + s1) / 2 + inw * (setback + depth / 2)), z + h])
        if h < 9 and rng.random() < 0.6:
            v, f = M.prism_roofs(rc[None], np.array([[width, depth, 0]]), min(depth, width) * 0.35, yaw)
            self.add("building", v, f, PALETTE["roof_red"], amount=0.1)
        else:
            v, f = M.ground_rect(-width / 2, -depth / 2, width / 2, depth / 2, 0, 8.0)
            v = M.transform(v, rc, yaw)
            self.add("building", v, M.orient_up(v, f), roof_col, amount=0.1)
            if rng.random() < 0.5:
                self.props_box("building", rc, [min(4, width / 3), min(3, depth / 3), 1.6], yaw, (150, 150, 150))
        self.windows(facade_info, z, floors, bay, look)

    def windows(self, facades, z, floors, bay, look) -> None:
        rng = self.rng
        p0s, us, vs = [], [], []
        door_p, door_u = [], []
        ribbon = look == "glass" or floors > 6
        for p, e, L in facades:
            out = np.array([e[1], -e[0], 0.0]) * 0.06  # outward normal (faces wind outwards)
            n_bays = max(1, int(L / bay))
            margin = (L - n_bays * bay) / 2
            for fl in range(floors):
                zf = z + 0.6 + fl * 3.2
                if fl == 0 and not ribbon:
                    k = int(rng.integers(n_bays))
                    door_p.append([*(p + e * (margin + k * bay + bay / 2 - 0.6)), z]); door_u.append([*(e * 1.2), 0])
                    continue
                if ribbon:
                    if look == "glass" and fl % 2 == 0:
                        continue
                    p0s.append(np.array([*(p + e * 0.4), zf + 0.8]) + out); us.append([*(e * (L - 0.8)), 0]); vs.append([0, 0, 1.4 if look != "glass" else 0.25])
                else:
                    for b in range(n_bays):
                        p0s.append(np.array([*(p + e * (margin + b * bay + 0.35 * bay)), zf + 0.7]) + out)
                        us.append([*(e * 0.35 * bay * 1.0), 0]); vs.append([0, 0, 1.6])
        if p0s:
            v, f = M.quads(np.array(p0s), np.array(us), np.array(vs))
            col = PALETTE["window"] if look != "glass" else (150, 160, 170)
            self.add("building", v, f, col, "glass" if look != "glass" else "matte", 0.2, 2.0)
        if door_p:
            dp = np.array(door_p, float)
            du = np.array(door_u, float)
            nrm = np.stack([du[:, 1], -du[:, 0], 0 * du[:, 0]], 1)
            nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
            v, f = M.quads(dp + nrm * 0.07, du, np.array([[0, 0, 2.3]]))
            self.add("building", v, f, PALETTE["door"], amount=0.1)

    def filler(self, o, a, inw, s0, s1, depth, z) -> None:
        """A lot without a building: garden, parking court or plaza."""
        rng, t = self.rng, self.t
        kind = rng.choice(["garden", "parking", "wall_garden", "plaza"], p=[0.4, 0.2, 0.3, 0.1])
        p0, p1 = o + a * s0, o + a * s1
        if kind in ("garden", "wall_garden"):
            if kind == "wall_garden":
                self.wall_line(p0 + inw * 0.3, p1 + inw * 0.3, z, rng.uniform(1.2, 2.6))
            elif rng.random() < 0.6:
                self.fence_line(p0 + inw * 0.3, p1 + inw * 0.3, z, rng.uniform(1.0, 1.8))
            else:
                self.hedge_line(p0 + inw * 0.6, p1 + inw * 0.6, z)
            for _ in range(int((s1 - s0) / 7 * (0.5 + t.vegetation_density))):
                p = o + a * rng.uniform(s0 + 2, s1 - 2) + inw * rng.uniform(3, max(3.5, depth - 2))
                self.tree(np.array([*p, z]), rng.uniform(0.9, 1.4))
        elif kind == "parking":
            q0 = o + a * s0 + inw * 0.0
            v, f = M.grid((*q0, z + 0.01), (*(a * (s1 - s0)), 0), (*(inw * depth), 0), int((s1 - s0) / 4) + 1, int(depth / 4) + 1)
            v[:, 2] = z + 0.01
            self.add("ground", v, M.orient_up(v, f), PALETTE["ground"], amount=0.15)
            self.fence_line(p0 + inw * depth, p1 + inw * depth, z, 2.0)
            for _ in range(int(rng.integers(1, 4))):
                p = o + a * rng.uniform(s0 + 1, s1 - 1) + inw * rng.uniform(1, depth - 1)
                self.static_prop(np.array([*p, z]), float(rng.uniform(0, np.pi)))
        else:  # plaza with a kiosk or sculpture ("other")
            q0 = o + a * s0
            v, f = M.grid((*q0, z + 0.01), (*(a * (s1 - s0)), 0), (*(inw * depth), 0), int((s1 - s0) / 3) + 1, int(depth / 3) + 1)
            self.add("sidewalk", v, M.orient_up(v, f), PALETTE["paving_red"], amount=0.1)
            p = o + a * (s0 + s1) / 2 + inw * depth / 2
            self.props_box("other", [*p, z], [rng.uniform(2, 4), rng.uniform(2, 4), rng.uniform(2.5, 4.5)], 0.0,
                           self.pick([(140, 110, 80), (110, 120, 140), (160, 150, 120)]))

    def wall_line(self, p0, p1, z, h):
        for p0, p1, L, yaw in _line_pieces(p0, p1):
            mid = (p0 + p1) / 2
            v, f = M.boxes(np.array([[mid[0], mid[1], z]]), np.array([[L, 0.3, h]]), yaw)
            # subdivide visually via colour only (walls are short)
            self.add("wall", v, f, self.pick(WALLS), amount=0.15, scale=1.0)

    def fence_line(self, p0, p1, z, h, metal=False):
        for p0, p1, L, yaw in _line_pieces(p0, p1):
            self._fence_piece(p0, p1, L, yaw, z, h, metal)

    def _fence_piece(self, p0, p1, L, yaw, z, h, metal):
        e = (p1 - p0) / L
        col = PALETTE["pole"] if metal else self.pick(FENCES)
        n_posts = int(L / 2.5) + 1
        s = np.linspace(0, L, n_posts)
        posts = np.c_[p0[None] + s[:, None] * e[None], np.full(n_posts, z)]
        v, f = M.boxes(posts, np.array([[0.1, 0.1, h]]), yaw)
        self.add("fence", v, f, col, "metal" if metal else "matte", 0.1, 1.0)
        mid = (p0 + p1) / 2
        for zz, hh in ((0.15, h * 0.12), (h * 0.75, h * 0.12)) if metal else ((0.1, h * 0.85),):
            v, f = M.boxes(np.array([[mid[0], mid[1], z + zz]]), np.array([[L, 0.04, hh]]), yaw)
            self.add("fence", v, f, col, "metal" if metal else "matte", 0.15, 0.6, fine=0.2)

    def hedge_line(self, p0, p1, z):
        for p0, p1, L, yaw in _line_pieces(p0, p1):
            self._hedge_piece(p0, p1, L, yaw, z)

    def _hedge_piece(self, p0, p1, L, yaw, z):
        mid = (p0 + p1) / 2
        h = self.rng.uniform(0.9, 1.8)
        v, f = M.grid((-L / 2, -0.5, h), (L, 0, 0), (0, 1.0, 0), max(1, int(L / 1.5)), 1)
        f2_v, f2_f = M.boxes(np.array([[0, 0, 0]]), np.array([[L, 1.0, h]]))
        v = np.concatenate([v, f2_v])
        f = np.concatenate([f, f2_f + len(v) - len(f2_v)])
        v = M.transform(v, [mid[0], mid[1], z], yaw)
        self.add("vegetation", v, f, PALETTE["hedge"], amount=0.3, scale=0.7, fine=0.15)

    # ---- countryside -----------------------------------------------------
    def countryside(self, rect, z, sides) -> None:
        """Fields with hedges and tree rows, sometimes a farm, sometimes woods."""
        x0, y0, x1, y1 = rect
        rng, t = self.rng, self.t
        kind = rng.choice(["field", "farm", "wood", "meadow"], p=[0.4, 0.25, 0.15, 0.2])
        stripes = kind == "field"
        v, f = M.ground_rect(x0, y0, x1, y1, z, 5.0)
        if stripes:
            col = M.noisy_colors(v, self.pick([PALETTE["dirt"], (150, 140, 70), (90, 120, 50)]), 0.15, 6.0, int(rng.integers(1 << 16)))
            rows = (np.floor(v[:, 0] / 2.5) % 2 == 0)
            col[rows, :3] = (col[rows, :3] * 0.82).astype(np.uint8)
            self.add_colored("terrain", v, f, col, tiled=True)
        else:
            self.add("terrain", v, f, PALETTE["grass"], amount=0.25, scale=8.0, tiled=True)
        # boundary: hedges, fences, stone walls with gates
        for (p, q) in [((x0, y0), (x1, y0)), ((x1, y1), (x0, y1)), ((x0, y1), (x0, y0)), ((x1, y0), (x1, y1))]:
            p, q = np.array(p) , np.array(q)
            u = rng.random()
            if u < 0.35:
                self.hedge_line(p, q, z)
            elif u < 0.6:
                self.fence_line(p, q, z, 1.2)
            elif u < 0.8:
                self.wall_line(p, q, z, 1.0)
        # tree rows along the block edges
        n_trees = int(t.vegetation_density * (2 * (x1 - x0) + 2 * (y1 - y0)) / 16)
        for _ in range(n_trees):
            side = rng.integers(4)
            if side < 2:
                p = np.array([rng.uniform(x0 + 2, x1 - 2), (y0 + 2.5) if side == 0 else (y1 - 2.5)])
            else:
                p = np.array([(x0 + 2.5) if side == 2 else (x1 - 2.5), rng.uniform(y0 + 2, y1 - 2)])
            self.tree(np.array([*p, z]), rng.uniform(0.9, 1.5), conifer=rng.random() < 0.25)
        if kind == "wood":
            for _ in range(int((x1 - x0) * (y1 - y0) / 140)):
                p = np.array([rng.uniform(x0 + 6, x1 - 6), rng.uniform(y0 + 6, y1 - 6)])
                self.tree(np.array([*p, z]), rng.uniform(1.0, 1.6), conifer=rng.random() < 0.5)
        if kind == "farm":
            self.farm(rect, z)

    def farm(self, rect, z) -> None:
        rng = self.rng
        x0, y0, x1, y1 = rect
        cx = rng.uniform(x0 + 25, max(x0 + 26, x1 - 25))
        cy = y0 + 14 if rng.random() < 0.5 else y1 - 14
        yaw = 0.0
        # farmhouse
        w, d = rng.uniform(9, 14), rng.uniform(8, 11)
        h = rng.uniform(*self.t.building_height_m) * 0.7
        self.simple_house([cx, cy, z], w, d, h, yaw, self.pick(FACADES["concrete"] + FACADES["brick"]))
        # barn
        bx = cx + rng.choice([-1, 1]) * (w / 2 + 14)
        bw, bd, bh = rng.uniform(14, 22), rng.uniform(9, 13), rng.uniform(4, 6)
        bx = float(np.clip(bx, x0 + bw / 2 + 2, x1 - bw / 2 - 2))
        if abs(bx - cx) > (w + bw) / 2 + 1:
            self.simple_house([bx, cy, z], bw, bd, bh, yaw, self.pick([(140, 50, 40), (120, 90, 60), (150, 150, 140)]), roof=(90, 90, 95))
        # silo / water tank ("other")
        v, f = M.cylinders(np.array([[cx, cy + (9 if cy < (y0 + y1) / 2 else -9), z]]), 9.0, 2.0, 8)
        self.add("other", v, f, (170, 170, 165), "metal", 0.1)
        # hay bales and farm boxes
        for _ in range(3):
            p = [rng.uniform(x0 + 4, x1 - 4), rng.uniform(y0 + 4, y1 - 4), z]
            self.props_box("static", p, [1.4, 1.4, 1.2], 0.0, (190, 165, 90))

    def simple_house(self, c, w, d, h, yaw, col, roof=None):
        c = np.asarray(c, float)
        v, f = M.boxes(c[None], np.array([[w, d, h]]), yaw)
        self.add("building", v, f, col, amount=0.1, scale=2.0)
        self.buildings.append((float(c[0]), float(c[1]), float(w), float(d), float(yaw)))
        v, f = M.prism_roofs((c + np.array([0, 0, h]))[None], np.array([[w + 0.6, d + 0.6, 0]]), 0.35 * d, yaw)
        self.add("building", v, f, roof or PALETTE["roof_red"], amount=0.1)
        # a few windows on the long sides
        n = max(1, int(w / 3.5))
        xsw = np.linspace(-w / 2 + 1.5, w / 2 - 2.5, n)
        p0 = np.array([[x, -d / 2 - 0.05, h * 0.4] for x in xsw] + [[x + 1.0, d / 2 + 0.05, h * 0.4] for x in xsw])
        u = np.array([[1.0, 0, 0]] * n + [[-1.0, 0, 0]] * n)
        p0 = M.transform(p0, c, yaw)
        u = M.transform(u, [0, 0, 0], yaw)
        vv, ff = M.quads(p0, u, np.array([[0, 0, 1.2]]))
        self.add("building", vv, ff, PALETTE["window"], "glass", 0.1)

    # ---- terrain, river, freeway, railway -------------------------------
    def outskirts(self) -> None:
        """Terrain around the street grid, with woods and scattered trees."""
        lay, rng, t = self.lay, self.rng, self.t
        bx0, by0, bx1, by1 = lay.bounds
        rx0, ry0, rx1, ry1 = lay.rect
        cell = 12.0

        def breaks(a, b, c, d):
            return np.unique(np.concatenate([np.linspace(a, b, max(2, int((b - a) / cell) + 1)),
                                             np.linspace(b, c, max(2, int((c - b) / cell) + 1)),
                                             np.linspace(c, d, max(2, int((d - c) / cell) + 1))]))
        xb = breaks(bx0, rx0, rx1, bx1)
        if lay.river:
            yc, w = lay.river
            ylo, yhi = yc - w / 2 - 3.0, yc + w / 2 + 3.0
            yb = np.unique(np.concatenate([breaks(by0, ry0, ylo, yhi), breaks(yhi, ry1, ry1 + 1, by1)]))
        else:
            yb = breaks(by0, ry0, ry1, by1)
        X0, Y0 = np.meshgrid(xb[:-1], yb[:-1], indexing="ij")
        X1, Y1 = np.meshgrid(xb[1:], yb[1:], indexing="ij")
        cx, cy = (X0 + X1) / 2, (Y0 + Y1) / 2
        keep = ~((cx > rx0) & (cx < rx1) & (cy > ry0) & (cy < ry1))
        if lay.river:
            keep &= ~(np.abs(cy - lay.river[0]) < lay.river[1] / 2 + 3.0)
        X0, Y0, X1, Y1 = X0[keep], Y0[keep], X1[keep], Y1[keep]
        p0 = np.stack([X0, Y0, np.full_like(X0, OUTER_Z)], 1)
        v, f = M.quads(p0, np.stack([X1 - X0, 0 * X0, 0 * X0], 1), np.stack([0 * X0, Y1 - Y0, 0 * X0], 1))
        col = M.noisy_colors(v, PALETTE["grass"], 0.25, 18.0, seed=lay.seed % 1000, fine=0.08)
        dirt = M.value_noise(v, 40.0, 5) > 0.68
        col[dirt, :3] = np.array(PALETTE["dirt"], np.uint8)
        self.add_colored("terrain", v, f, col, tiled=True)
        # woods: clusters of trees, denser with vegetation_density
        n_clusters = int(6 + 20 * t.vegetation_density)
        for _ in range(n_clusters):
            for _tries in range(20):
                c = np.array([rng.uniform(bx0 + 10, bx1 - 10), rng.uniform(by0 + 10, by1 - 10)])
                if self.free_outside(c, 25.0):
                    break
            else:
                continue
            for _ in range(int(rng.integers(6, 16))):
                p = c + rng.normal(0, 12, 2)
                if self.free_outside(p, 6.0):
                    self.tree(np.array([*p, OUTER_Z]), rng.uniform(1.0, 1.7), conifer=rng.random() < 0.4)

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

    def river_section(self, x0, x1, z) -> None:
        """Water and banks of the river between x0 and x1 (inside a block)."""
        yc, w = self.lay.river
        self.river_channel(x0, x1, z)

    def river_channel(self, x0, x1, ztop) -> None:
        yc, w = self.lay.river
        zw = -1.6
        bank = 3.0
        v, f = M.grid((x0, yc - w / 2, zw), (x1 - x0, 0, 0), (0, w, 0), max(1, int((x1 - x0) / 6)), 3)
        self.add("ground", v, f, PALETTE["water"], "water", 0.1, 5.0, tiled=True)
        for sgn in (-1, 1):  # sloped banks, facing the water
            ya, yb = yc + sgn * w / 2, yc + sgn * (w / 2 + bank)
            v, f = M.grid((x0, ya, zw), (x1 - x0, 0, 0), (0, yb - ya, ztop - zw), max(1, int((x1 - x0) / 5)), 2)
            self.add("terrain", v, M.orient_up(v, f), PALETTE["dirt"], amount=0.25, scale=2.0, tiled=True)

    def river(self) -> None:
        """The river outside the grid, and the bridges' side beams and railings."""
        lay = self.lay
        if not lay.river:
            return
        yc, w = lay.river
        rx0, _, rx1, _ = lay.rect
        bx0, _, bx1, _ = lay.bounds
        self.river_channel(bx0, rx0, OUTER_Z)
        self.river_channel(rx1, bx1, OUTER_Z)
        ylo, yhi = yc - w / 2 - 3.0, yc + w / 2 + 3.0
        hw, sw = lay.hw, lay.sidewalk_w or lay.verge_w
        # each north-south street crosses on a bridge: beams + railings on both edges
        for i, x in enumerate(lay.xs):
            for sgn in (-1, 1):
                edge = x + sgn * (hw + sw)
                self.props_box("other", [edge - sgn * 0.2, (ylo + yhi) / 2, -1.3], [0.5, yhi - ylo, 1.3 + CURB_H], 0.0, (150, 145, 135))
                self.fence_line(np.array([edge - sgn * 0.15, ylo]), np.array([edge - sgn * 0.15, yhi]), CURB_H if lay.sidewalk_w else 0.02, 1.1, metal=True)

    def freeway(self) -> None:
        lay = self.lay
        fw = lay.freeway
        if not fw:
            return
        y, x0, x1, cw = fw["y"], fw["x0"], fw["x1"], fw["cw"]
        m2 = FREEWAY_MEDIAN / 2
        for sgn in (-1, 1):  # two carriageways
            ya, yb = sorted((y + sgn * m2, y + sgn * (m2 + cw)))
            v, f = M.grid((x0, ya, 0), (x1 - x0, 0, 0), (0, yb - ya, 0), int((x1 - x0) / 4), int(cw / 3))
            self.add("road", v, f, PALETTE["asphalt_fw"], "road", 0.15, 8.0, tiled=True)
            self.skirt(np.array([[x0, ya], [x1, ya]]), sgn < 0)
            self.skirt(np.array([[x0, yb], [x1, yb]]), sgn > 0)
            # lane lines
            for k in range(1, fw["lanes"]):
                yy = y + sgn * (m2 + 1.0 + k * FREEWAY_LANE_W)
                s = np.arange(x0 + 2, x1 - 8, 15.0)
                p0 = np.stack([s, np.full_like(s, yy - 0.08), np.full_like(s, MARK_Z)], 1)
                vv, ff = M.quads(p0, np.array([[6.0, 0, 0]]), np.array([[0, 0.16, 0]]))
                self.add("road line", vv, ff, PALETTE["marking"], amount=0.05, tiled=True)
            for yy in (y + sgn * (m2 + 0.7), y + sgn * (m2 + cw - 1.8)):
                vv, ff = M.grid((x0, yy - 0.1, MARK_Z), (x1 - x0, 0, 0), (0, 0.2, 0), int((x1 - x0) / 20), 1)
                self.add("road line", vv, ff, PALETTE["marking"], amount=0.05, tiled=True)
        # the turn-around loops at both ends (half annuli)
        for xe, a0 in ((x1, -90.0), (x0, 90.0)):
            ang = np.radians(np.linspace(a0, a0 + 180.0, 25))
            rmid = m2 + cw / 2
            pts = np.stack([xe + rmid * np.cos(ang), y + rmid * np.sin(ang)], 1)
            v, f = M.ribbon(pts, cw / 2 + m2 * 0.0, cw / 2 + m2, 0.0, 4)
            self.add("road", v, f, PALETTE["asphalt_fw"], "road", 0.15, 8.0)
            outer = np.stack([xe + (m2 + cw) * np.cos(ang), y + (m2 + cw) * np.sin(ang)], 1)
            self.guard_rail(outer[::1] if xe == x1 else outer[::1])
            # two tree rows behind the turn-around, so the view from the loop is not an empty plain
            for rr, step in ((m2 + cw + 8.0, 8.0), (m2 + cw + 16.0, 10.0)):
                for a in np.radians(np.arange(a0 + 8.0, a0 + 173.0, np.degrees(step / rr))):
                    p = np.array([xe + rr * np.cos(a), y + rr * np.sin(a)]) + self.rng.uniform(-1.5, 1.5, 2)
                    self.tree(np.array([*p, OUTER_Z]), self.rng.uniform(1.0, 1.5), conifer=self.rng.random() < 0.3)
        # median: concrete strip with a guard rail; outer guard rails
        v, f = M.grid((x0, y - m2, 0.0), (x1 - x0, 0, 0), (0, 2 * m2, 0), int((x1 - x0) / 6), 4)
        self.add("terrain", v, f, PALETTE["dry_grass"], amount=0.2, tiled=True)
        for x in np.arange(x0 + 6, x1 - 6, 11.0):
            if not (fw["tunnel"] and fw["tunnel"][0] - 5 < x < fw["tunnel"][1] + 5):
                self.tree(np.array([x + self.rng.uniform(-3, 3), y + self.rng.uniform(-m2 + 5, m2 - 5), 0.0]), 1.1)
        tun = fw["tunnel"]
        spans = [(x0, x1)] if not tun else [(x0, tun[0]), (tun[1], x1)]
        for a, b in spans:
            for sgn in (-1, 1):
                self.guard_rail(np.array([[a, y + sgn * (m2 - 0.3)], [b, y + sgn * (m2 - 0.3)]]))
            for sgn in (-1, 1):
                yy = y + sgn * (m2 + cw - 0.3)
                # leave gaps where the connectors join the north carriageway
                if sgn > 0:
                    for ga, gb in self.split_span(a, b, [(lay.xs[0] - lay.hw - 8, lay.xs[0] + lay.hw + 8),
                                                         (lay.xs[-1] - lay.hw - 8, lay.xs[-1] + lay.hw + 8)]):
                        self.guard_rail(np.array([[ga, yy], [gb, yy]]))
                else:
                    self.guard_rail(np.array([[a, yy], [b, yy]]))
        if tun:
            self.tunnel(tun[0], tun[1])
        self.connectors()

    @staticmethod
    def split_span(a, b, gaps):
        pieces = [(a, b)]
        for g0, g1 in gaps:
            pieces = [q for p in pieces for q in ((p[0], min(p[1], g0)), (max(p[0], g1), p[1])) if q[1] - q[0] > 1.0]
        return pieces

    def skirt(self, seg: np.ndarray, facing_neg_y: bool) -> None:
        """Vertical strip from the road edge down to the outer terrain."""
        if np.linalg.norm(seg[1] - seg[0]) > 60.0:
            for a, b in _split_segment(seg[0], seg[1], 50.0):
                self.skirt(np.array([a, b]), facing_neg_y)
            return
        p0 = np.array([*seg[0], OUTER_Z - 0.05])
        u = np.array([*(seg[1] - seg[0]), 0.0])
        if not facing_neg_y:
            p0 = np.array([*seg[1], OUTER_Z - 0.05])
            u = -u
        v, f = M.quads(p0, u, np.array([0, 0, -OUTER_Z + 0.05]))
        self.add("terrain", v, f, PALETTE["dirt"], amount=0.1, tiled=True)

    def guard_rail(self, pts: np.ndarray) -> None:
        """Posts and a double-sided beam along a 2D polyline."""
        pts = np.asarray(pts, float)
        pts = np.concatenate([np.array(_split_segment(p, q, 40.0))[:, 0] for p, q in zip(pts[:-1], pts[1:])] + [pts[-1:]])
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

    def tunnel(self, a: float, b: float) -> None:
        fw = self.lay.freeway
        y, cw = fw["y"], fw["cw"]
        e = FREEWAY_MEDIAN / 2 + cw
        H = 6.0
        for sgn in (-1, 1):  # side walls
            self.props_box("wall", [(a + b) / 2, y + sgn * (e + 0.4), 0], [b - a, 0.8, H], 0.0, (150, 146, 140))
        for sgn in (-1, 1):  # inner walls: one tube per carriageway
            self.props_box("wall", [(a + b) / 2, y + sgn * (FREEWAY_MEDIAN / 2 - 0.4), 0], [b - a, 0.8, H], 0.0, (160, 156, 150))
        self.props_box("building", [(a + b) / 2, y, H], [b - a, 2 * e + 1.6, 0.9], 0.0, (120, 118, 112))
        v, f = M.quads(np.array([a, y + e, H - 0.001]), np.array([b - a, 0, 0]), np.array([0, -2 * e, 0]))
        self.add("building", v, f, (90, 88, 84))
        # earth mound over the tunnel
        for sgn in (-1, 1):
            ya, yb = y + sgn * (e + 0.8), y + sgn * (e + 14)
            v, f = M.grid((a, ya, H + 0.9), (b - a, 0, 0), (0, yb - ya, OUTER_Z - H - 0.9), int((b - a) / 6), 3)
            self.add("terrain", v, M.orient_up(v, f), PALETTE["grass"], amount=0.25, scale=5.0)
        v, f = M.ground_rect(a, y - e - 0.8, b, y + e + 0.8, H + 0.92, 6.0)
        self.add("terrain", v, f, PALETTE["grass"], amount=0.25, scale=5.0)
        for k in range(3):
            self.tree(np.array([a + (k + 0.5) * (b - a) / 3, y + self.rng.uniform(-6, 6), H + 0.9]), 1.1)
        # ceiling lamps
        xs = np.arange(a + 4, b - 4, 8.0)
        for sgn in (-1, 1):
            p = np.stack([xs, np.full_like(xs, y + sgn * (FREEWAY_MEDIAN / 2 + cw / 2)), np.full_like(xs, H - 0.2)], 1)
            v, f = M.boxes(p, np.array([[2.0, 0.4, 0.15]]))
            self.add("other", v, f, PALETTE["lamp"], "emissive", 0.02)

    def connectors(self) -> None:
        """Two-lane connector roads from the grid's south corners to the freeway."""
        lay, fw = self.lay, self.lay.freeway
        y_top = lay.ys[0] - lay.hw
        y_bot = fw["y"] + FREEWAY_MEDIAN / 2 + fw["cw"]
        for x in (lay.xs[0], lay.xs[-1]):
            v, f = M.grid((x - lay.hw, y_bot, 0), (2 * lay.hw, 0, 0), (0, y_top - y_bot, 0), 4, int((y_top - y_bot) / 3) + 1)
            self.add("road", v, f, PALETTE["asphalt"], "road", 0.18, 6.0)
            self.markings(np.array([x, y_bot]), np.array([0.0, 1.0]), y_top - y_bot)
            for sgn in (-1, 1):
                self.skirt(np.array([[x + sgn * lay.hw, y_bot], [x + sgn * lay.hw, y_top]]), False)
                self.guard_rail(np.array([[x + sgn * (lay.hw + 0.4), y_bot + 2], [x + sgn * (lay.hw + 0.4), y_top - 1]]))
            # the sidewalk gap's terrain skirt is the grid ring's job; add a sign
            self.traffic_sign(np.array([x + lay.hw + 1.2, y_bot + 8, OUTER_Z]), np.pi / 2 * -1)

    def railway(self) -> None:
        lay = self.lay
        if lay.railway_y is None:
            return
        y = lay.railway_y
        x0, _, x1, _ = lay.bounds
        x0, x1 = x0 + 5, x1 - 5
        # ballast bed
        v, f = M.grid((x0, y - 2.2, 0.25), (x1 - x0, 0, 0), (0, 4.4, 0), int((x1 - x0) / 5), 3)
        self.add("railway", v, f, PALETTE["ballast"], amount=0.2, scale=1.0, tiled=True)
        for sgn in (-1, 1):
            yy = y + sgn * 2.2
            p0 = np.array([x0, yy, OUTER_Z]) if sgn < 0 else np.array([x1, yy, OUTER_Z])
            u = np.array([x1 - x0, 0, 0]) * (1 if sgn < 0 else -1)
            v, f = M.quads(p0, u, np.array([0, 0, 0.5]))
            self.add("railway", v, f, PALETTE["ballast"], amount=0.2, tiled=True)
            v, f = M.grid((x0, y + sgn * 0.75 - 0.04, 0.25), (x1 - x0, 0, 0), (0, 0.08, 0), int((x1 - x0) / 40), 1)
            cuts = np.linspace(x0, x1, int((x1 - x0) / 40) + 2)
            cen = np.stack([(cuts[:-1] + cuts[1:]) / 2, np.full(len(cuts) - 1, y + sgn * 0.75), np.full(len(cuts) - 1, 0.25)], 1)
            size = np.stack([np.diff(cuts), np.full(len(cuts) - 1, 0.08), np.full(len(cuts) - 1, 0.16)], 1)
            v2, f2 = M.boxes(cen, size)
            self.add("railway", v2, f2, PALETTE["rail"], "metal", 0.05, tiled=True)
            self.fence_line(np.array([x0, y + sgn * 6.0]), np.array([x1, y + sgn * 6.0]), OUTER_Z, 1.8, metal=True)
        s = np.arange(x0 + 1, x1 - 1, 1.5)
        p = np.stack([s, np.full_like(s, y), np.full_like(s, 0.25)], 1)
        v, f = M.boxes(p, np.array([[0.25, 2.4, 0.1]]))
        self.batch.add_tiled(ID["railway"], "matte", v, f, M.noisy_colors(v, PALETTE["sleeper"], 0.1, 1.0, 3))
        # catenary poles
        s = np.arange(x0 + 10, x1 - 10, 45.0)
        for sx in s:
            self.pole_with([sx, y + 3.2, OUTER_Z], 7.0, 0.12)

    # ---- all together ----------------------------------------------------
    def build(self):
        self.streets()
        self.sidewalks()
        self.blocks()
        self.furniture()
        self.river()
        self.freeway()
        self.railway()
        self.outskirts()
        return self.batch.parts()


@lru_cache(maxsize=8)
def _built(town_code: str, seed: int):
    lay = layout(town_code, seed)
    builder = _Builder(lay)
    parts = builder.build()
    return parts, tuple(builder.buildings)


def building_footprints(town_code: str, seed: int) -> np.ndarray:
    """(N, 5) building footprints: centre x, y, size along, size across, yaw."""
    return np.array(_built(town_code, seed)[1], dtype=np.float64).reshape(-1, 5)


def build_world(town_code: str, seed: int) -> World:
    """The town's static geometry and lanes, deterministic from ``seed``."""
    lay = layout(town_code, seed)
    parts, _ = _built(town_code, seed)
    return World(
        town=lay.town.code,
        seed=seed,
        static=parts,
        lanes=tuple(loop.path for loop in loops(town_code, seed)),
        walkways=_walkways(lay),
        bounds=lay.bounds,
    )
