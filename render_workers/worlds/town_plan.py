"""A town's plan: its street grid, features and the paths traffic uses; no meshes.

``plan(town, seed)`` reads the town's row (and its style's lane width and road
edge) from ``domains.catalog`` and lays out, deterministically from the seed:

* a grid of streets (blocks of about ``Town.block_m``, ``Town.lanes`` lanes per
  direction) sized so the drivable centre-line length matches ``Town.road_km``;
* the features the row switches on: a freeway (dual carriageway with
  turn-around loops and connectors to the grid, maybe a tunnel), mini
  roundabouts, a railway, a river crossed by bridges.

Lanes are closed loops that never cross each other: each block (or group of
blocks) is circled clockwise on its inner lanes (right turns only), the town's
perimeter counter-clockwise on its outer lanes, the freeway as a stadium. So
traffic that keeps one speed per loop can never collide. ``loops``,
``crosswalks`` and ``walk_lanes`` are what ``render_workers.worlds.world`` hands to
traffic on the ``World``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from domains.catalog import Town, town as town_row
from render_workers.worlds.scene import Crosswalk, Loop, Path
from render_workers.worlds.styles import look, is_urban

CURB_H = 0.15  # sidewalk height above the road
OUTER_Z = -0.25  # terrain level outside the street grid
MARK_Z = 0.02  # lane markings above the road
PARKING_W = 2.2  # parking strip between the outer lane and the kerb (urban)
VERGE_W = 2.5  # verge width beside countryside roads
FREEWAY_LANE_W = 3.6
FREEWAY_MEDIAN = 30.0  # wide, planted median: lets buses take the turn-around loops
ZEBRA_FROM, ZEBRA_LEN = 0.6, 3.0  # zebra stripes: distance of their near end from the kerb line, length
WALK_LANE_M = 0.7  # sidewalk walking lanes lie this far apart
RIVER_BANK_M = 3.0  # sloped bank on each side of the river's water


# --------------------------------------------------------------------------
# The plan
# --------------------------------------------------------------------------
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
    def river_band(self) -> tuple[float, float] | None:
        """(y min, y max) of the river with its banks, or None without a river."""
        if self.river is None:
            return None
        yc, w = self.river
        return (yc - w / 2 - RIVER_BANK_M, yc + w / 2 + RIVER_BANK_M)

    @property
    def road_length_m(self) -> float:
        """Drivable centre-line length: grid streets, freeway and connectors."""
        grid = len(self.ys) * (self.xs[-1] - self.xs[0]) + len(self.xs) * (self.ys[-1] - self.ys[0])
        return float(grid + _freeway_length(self.freeway))


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


def layout(town_code: str, seed: int) -> Layout:
    """The plan of the catalog's town ``town_code``."""
    return plan(town_row(town_code), seed)


@lru_cache(maxsize=16)
def plan(t: Town, seed: int) -> Layout:
    """The town's plan: street grid, features and loops' geometry inputs."""
    rng = np.random.default_rng([seed, t.stream, 1])
    urban = is_urban(t)
    lane_w = look(t).lane_w_m
    parking_w = PARKING_W if urban else 0.0
    hw = t.lanes * lane_w + parking_w
    sidewalk_w = (5.0 + 1.0 * (t.lanes - 1)) if urban else 0.0
    verge_w = 0.0 if urban else VERGE_W

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


def corner_offset(lay: Layout) -> float:
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
    urban = is_urban(t)
    c = corner_offset(lay)
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


def loops(lay: Layout) -> tuple[Loop, ...]:
    """The town's lane loops (the same paths as ``World.lanes``, in order)."""
    return _loops(lay)


def crosswalks(lay: Layout) -> tuple[Crosswalk, ...]:
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
                out.append(Crosswalk(centre, np.array(n, float), float(hw), reach, CURB_H))
    return tuple(out)


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


def walk_lanes(lay: Layout) -> tuple[tuple[Path, ...], ...]:
    """The walkways moved 0, 1, 2... lanes of ``WALK_LANE_M`` towards the buildings,
    as many as the sidewalk (or verge) holds."""
    half_w = 0.5 * (lay.sidewalk_w or 2 * 1.25)
    return tuple(walkway_loops(lay, k * WALK_LANE_M) for k in range(1 + int(max(0.0, half_w - 0.5) // WALK_LANE_M)))


def walkways(lay: Layout) -> tuple[Path, ...]:
    """Closed walkways plus one open path over every zebra."""
    hw = lay.hw
    out = list(walkway_loops(lay))
    for cw in crosswalks(lay):  # zebra crossings, kerb to kerb plus half a metre
        ends = [cw.centre - cw.across * (hw + 0.5), cw.centre + cw.across * (hw + 0.5)]
        out.append(Path(np.array([[*p, 0.0] for p in ends]), closed=False))
    return tuple(out)
