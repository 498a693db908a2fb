"""Per-episode traffic: vehicles, parked cars, riders, pedestrians and the ego.

``populate(world, viewpoint_code, episode_seed)`` draws everything from
``np.random.default_rng(episode_seed)``:

* ``n_vehicles`` in [20, 150] (moving, parked, and two-wheelers) and
  ``n_pedestrians`` in [0, 100], as in IDDA;
* moving vehicles ride the world's lane loops. Loops never cross, and every
  actor on a loop keeps the loop's speed, so actors spaced apart at t=0 stay
  apart forever;
* the ego drives a random loop (by length, freeway loops down-weighted by
  ``FREEWAY_EGO_WEIGHT``) from a random spawn point; its loop gets the ego's
  speed, no car within about 40 m ahead, and riders 20-60 m ahead so the rare
  classes show up in frames;
* parked cars (15-30% of the four-wheelers, now and then a van, truck or a
  bus at a stop) sit in the kerbside parking strips;
* pedestrians walk the sidewalks, mostly near the ego's route, in lanes
  ``town_plan.WALK_LANE_M`` apart with one pace per lane, so they never walk through
  one another; 20-40% of them walk back and forth over a zebra crossing
  (again mostly on the ego's route). Every vehicle's motion is known, so a
  crossing pedestrian is only placed if, sampled every ``CROSSING_DT`` s over
  ``[0, CROSSING_HORIZON_S]`` (the frames' times included), it keeps
  ``CROSSING_CLEAR`` m from every vehicle, rider and the ego: people cross in
  the gaps between cars.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from manifests.catalog import viewpoint as viewpoint_row
from render_workers.actors import PAINTS, VEHICLE_KINDS, pedestrian_parts, rider_parts, vehicle_parts
from render_workers.scene import Actor, EpisodeScene, Loop, Path, World

KIND_WEIGHTS = {"sedan": 0.45, "suv": 0.25, "van": 0.15, "truck": 0.08, "bus": 0.07}
# Parked along the kerb: buses wait at stops, trucks deliver. A bus (2.55 m) is
# a little wider than the 2.2 m strip and overhangs lane and kerb by 0.18 m.
PARKED_WEIGHTS = {"sedan": 0.42, "suv": 0.26, "van": 0.16, "truck": 0.06, "bus": 0.10}
EGO_SIZE = {"B": (11.0, 2.55)}  # ego footprint (length, width) by viewpoint
EGO_SIZE_DEFAULT = (4.8, 2.0)
RIDER_SLOT = 2.4  # bicycles and motorcycles occupy this much lane length
EGO_SPEED = {"A": (10.0, 14.0), "M": (10.0, 14.0), "J": (9.0, 13.0), "V": (8.0, 12.0), "B": (8.0, 11.0)}
FREEWAY_EGO_SPEED = (16.0, 20.0)
# The ego starts on a freeway loop less often than the loops' length alone
# would give: freeway frames show no sidewalk, signals or two-wheelers.
FREEWAY_EGO_WEIGHT = 0.4
# Pedestrians on zebra crossings
CROSSING_SHARE = (0.2, 0.4)  # share of the pedestrians that cross streets
CROSSING_SPEED = (1.2, 1.5)  # m/s
CROSSING_APPROACH = (1.0, 25.0)  # sidewalk walked before and after the zebra, m
CROSSING_SHIFT = 0.9  # sideways spread within the 3 m zebra, m
CROSSING_HORIZON_S = 243.0  # checked against traffic over [0, this]: 81 frames at 3 s
CROSSING_DT = 0.125  # check step, s (divides the 3 s frame period)
WALKER_RADIUS = 0.6  # a walker's footprint (and its motion over a check step) fits this disc, m
CROSSING_CLEAR = 0.5  # kept between a crossing pedestrian and any vehicle's box, m
CROSSING_TRIES = 20  # candidate (zebra, walk) draws per crossing pedestrian
OFFSET_BIN = 0.05  # resolution of the free start offsets, m
# Pedestrians on sidewalks keep to the World's walking lanes (town_plan.WALK_LANE_M
# apart, from the middle of the sidewalk towards the buildings), one pace per lane and loop, each holding
# a WALK_SLOT_M stretch of it: they never walk through one another. A walker
# that finds no free stretch in WALK_TRIES draws is left out (none in 11,081
# pedestrians over 210 episodes of the seven towns).
WALK_SLOT_M = 1.0
WALK_TRIES = 10


# --------------------------------------------------------------------------
# Slots along loops
# --------------------------------------------------------------------------
class _LoopSlots:
    """Occupied arc-length intervals of one closed loop."""

    def __init__(self, length: float) -> None:
        self.length = length
        self.taken: list[tuple[float, float]] = []

    def free(self, s: float, half: float, gap: float) -> bool:
        for c, h in self.taken:
            d = abs((s - c + self.length / 2) % self.length - self.length / 2)
            if d < half + h + gap:
                return False
        return True

    def take(self, s: float, half: float) -> None:
        self.taken.append((s % self.length, half))


def _allowed_kinds(loop: Loop) -> list[str]:
    """Long vehicles only where corners are wide enough to keep them in lane."""
    kinds = []
    for name, k in VEHICLE_KINDS.items():
        # on an arc a box's outer corners stick out beyond its lane
        rr = loop.min_radius_m + k.width / 2
        overshoot = np.sqrt(rr**2 + (k.length / 2) ** 2) - rr
        neighbour = 1.275 if k.width > 2.1 else 1.0
        if overshoot + k.width / 2 + neighbour + 0.05 <= loop.lane_sep_m:
            kinds.append(name)
    return kinds or ["sedan"]


def _pick_kind(rng, kinds: list[str], weights: dict = KIND_WEIGHTS) -> str:
    w = np.array([weights[k] for k in kinds])
    return kinds[int(rng.choice(len(kinds), p=w / w.sum()))]


def _min_distance(a: np.ndarray, b: np.ndarray) -> float:
    a, b = a[:, :2][::2], b[:, :2][::2]
    return float(np.sqrt(((a[:, None, :] - b[None, :, :]) ** 2).sum(-1)).min())


# --------------------------------------------------------------------------
# Crossing pedestrians: scheduled in the gaps of the (fully known) traffic
# --------------------------------------------------------------------------
def _along(path: Path, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vectorised ``Path.at``: positions (..., 3) and headings (...) at arc lengths s."""
    pts = np.vstack([path.points, path.points[:1]]) if path.closed else path.points
    cum = path.cumulative
    total = float(cum[-1])
    s = np.asarray(s, np.float64)
    if total <= 0:
        return np.broadcast_to(pts[0], s.shape + (3,)).copy(), np.zeros(s.shape)
    if path.closed:
        s, back = np.mod(s, total), np.zeros(s.shape, bool)
    else:
        period = np.mod(s, 2 * total)
        back = period > total
        s = np.where(back, 2 * total - period, period)
    i = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(pts) - 2)
    seg = pts[i + 1] - pts[i]
    seg_len = cum[i + 1] - cum[i]
    frac = np.where(seg_len > 0, (s - cum[i]) / np.where(seg_len > 0, seg_len, 1.0), 0.0)
    pos = pts[i] + frac[..., None] * seg
    heading = np.arctan2(seg[..., 1], seg[..., 0]) + np.where(back, np.pi, 0.0)
    return pos, heading


def footprint(parts) -> tuple[np.ndarray, np.ndarray]:
    """Centre (2,) and half extents (2,) of the parts' box in the actor frame."""
    verts = np.concatenate([p.mesh.vertices[:, :2] for p in parts])
    lo, hi = verts.min(axis=0), verts.max(axis=0)
    return (lo + hi) / 2, (hi - lo) / 2


@lru_cache(maxsize=16)
def _loop_samples(loops: tuple) -> tuple[np.ndarray, np.ndarray]:
    """Points every metre or so along each lane loop, and their loop index.

    Cached on the loops tuple, not the World, so a cache entry never keeps a
    whole town (meshes, textures) alive after the world cache dropped it."""
    pts, ids = [], []
    for k, lp in enumerate(loops):
        ring = np.vstack([lp.path.points, lp.path.points[:1]])[:, :2]
        for a, b in zip(ring[:-1], ring[1:]):
            n = max(1, int(np.ceil(np.linalg.norm(b - a))))
            pts.append(a + np.linspace(0.0, 1.0, n, endpoint=False)[:, None] * (b - a))
            ids.append(np.full(n, k))
    return np.concatenate(pts), np.concatenate(ids)


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance of points (..., 2) to the segment a-b."""
    ab = b - a
    t = np.clip(((p - a) @ ab) / (ab @ ab), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[..., None] * ab), axis=-1)


class _CrossingPlanner:
    """Places pedestrians on zebras where and when no vehicle comes near them.

    ``vehicles`` are (actor, centre, half extents) of everything that drives or
    parks on the lane loops, the ego included (it has no parts, so its
    footprint is given).
    """

    def __init__(self, world: World, loops, vehicles: list[tuple[Actor, np.ndarray, np.ndarray]]) -> None:
        self.world = world
        self.crosswalks = world.crosswalks
        self.times = np.arange(0.0, CROSSING_HORIZON_S + CROSSING_DT / 2, CROSSING_DT)
        loop_of = {id(lp.path): k for k, lp in enumerate(loops)}
        self.by_loop: dict[int, list[int]] = {}
        for j, (a, _, _) in enumerate(vehicles):
            self.by_loop.setdefault(loop_of[id(a.path)], []).append(j)
        self.vehicles = vehicles
        n, n_t = len(vehicles), len(self.times)
        self.centre = np.array([c for _, c, _ in vehicles]).reshape(n, 2)
        # box half extents grown by the clearance and by how far the vehicle moves in half a step
        speed = np.array([a.speed_mps for a, _, _ in vehicles])
        self.grown = np.array([h for _, _, h in vehicles]).reshape(n, 2) + CROSSING_CLEAR
        self.grown[:, 0] += speed * CROSSING_DT / 2
        # every vehicle's track at the check times, one vectorised call per loop
        self.xy, self.fwd = np.zeros((n, n_t, 2)), np.zeros((n, n_t, 2))
        for k, js in self.by_loop.items():
            js = np.array(js)
            path = vehicles[js[0]][0].path
            off = np.array([vehicles[j][0].offset_m for j in js])
            lat = np.array([vehicles[j][0].lateral_m for j in js])
            pos, heading = _along(path, off[:, None] + speed[js][:, None] * self.times[None])
            fwd = np.stack([np.cos(heading), np.sin(heading)], -1)
            self.fwd[js] = fwd
            self.xy[js] = pos[..., :2] + lat[:, None, None] * np.stack([-fwd[..., 1], fwd[..., 0]], -1)
        self._events: dict[int, tuple] = {}
        self.reach = CROSSING_APPROACH[1]  # longest walk on a sidewalk beyond a kerb

    def near_loops(self, k: int) -> np.ndarray:
        """Loops that pass near crossing k."""
        return _crosswalk_loops(self.world.loops, self.world.crosswalks)[k]

    def events(self, k: int) -> tuple:
        """(time index, position, forward, centre, grown half extents) of every
        vehicle sample whose grown box meets crossing k's corridor (the walking
        line, widened by the sideways shift and a walker)."""
        if k not in self._events:
            cw = self.crosswalks[k]
            u = cw.across
            v = np.array([-u[1], u[0]])
            cu, cv = cw.half_road + self.reach, CROSSING_SHIFT + WALKER_RADIUS
            js = np.array([j for lp in self.near_loops(k) for j in self.by_loop.get(int(lp), [])], int)
            # coarse: centres within reach of the corridor's bounding box
            ext = np.abs(u) * cu + np.abs(v) * cv
            reach = (np.linalg.norm(self.grown[js], axis=1) + np.linalg.norm(self.centre[js], axis=1))[:, None]
            xy = self.xy[js]
            near = (np.abs(xy[..., 0] - cw.centre[0]) <= ext[0] + reach) & (np.abs(xy[..., 1] - cw.centre[1]) <= ext[1] + reach)
            jj, tt = np.nonzero(near)
            j = js[jj]
            xy, fwd, centre, grown = self.xy[j, tt], self.fwd[j, tt], self.centre[j], self.grown[j]
            left = np.stack([-fwd[:, 1], fwd[:, 0]], 1)
            d = xy + centre[:, :1] * fwd + centre[:, 1:] * left - cw.centre
            fu, fv = np.abs(fwd @ u), np.abs(fwd @ v)
            gx, gy = grown[:, 0], grown[:, 1]
            # separating axes: the corridor's two, then the vehicle's two
            meets = np.abs(d @ u) <= cu + gx * fu + gy * fv
            meets &= np.abs(d @ v) <= cv + gx * fv + gy * fu
            meets &= np.abs((d * fwd).sum(1)) <= gx + cu * fu + cv * fv
            meets &= np.abs((d * left).sum(1)) <= gy + cu * fv + cv * fu
            self._events[k] = (tt[meets], xy[meets], fwd[meets], centre[meets], grown[meets])
        return self._events[k]

    def free_offsets(self, k: int, path: Path, shift: float, speed: float, radius: float) -> np.ndarray:
        """Start offsets (m along ``path``) that keep a walker clear of all traffic.

        The walker (a disc of ``radius``) walks the straight ``path`` on crossing
        k, ``shift`` m off the zebra's middle, back and forth at ``speed``. A
        vehicle sample at time t blocks an interval of the walking line; the
        walker is there at t if its phase (offset + speed t, modulo a round trip)
        is in that interval walking out, or its mirror walking back. So every
        sample forbids two offset intervals; what no sample forbids is free.
        """
        if radius + speed * CROSSING_DT / 2 > WALKER_RADIUS:
            raise ValueError(f"walker radius {radius:.2f} m exceeds WALKER_RADIUS {WALKER_RADIUS} m")
        cw = self.crosswalks[k]
        trip = 2 * path.length
        n_bins = int(np.ceil(trip / OFFSET_BIN))
        t_idx, xy, fwd, centre, half = self.events(k)
        if not len(t_idx):
            return (np.arange(n_bins) + 0.5) * OFFSET_BIN
        u_dir = cw.across
        origin = cw.centre + shift * np.array([-u_dir[1], u_dir[0]])
        left = np.stack([-fwd[:, 1], fwd[:, 0]], 1)
        box = xy + centre[:, :1] * fwd + centre[:, 1:] * left
        # the walking line origin + u * u_dir in each box's frame: |x0 + u ax| <= hx and |y0 + u ay| <= hy
        lo, hi = np.full(len(t_idx), -np.inf), np.full(len(t_idx), np.inf)
        for axis, h in ((fwd, half[:, 0]), (left, half[:, 1])):
            x0 = ((origin - box) * axis).sum(1)
            ax = axis @ u_dir
            h = h + radius
            with np.errstate(divide="ignore", invalid="ignore"):
                e0, e1 = (-h - x0) / ax, (h - x0) / ax
            flat = np.abs(ax) < 1e-9
            e0 = np.where(flat, np.where(np.abs(x0) <= h, -np.inf, np.inf), e0)
            e1 = np.where(flat, np.where(np.abs(x0) <= h, np.inf, -np.inf), e1)
            lo, hi = np.maximum(lo, np.minimum(e0, e1)), np.minimum(hi, np.maximum(e0, e1))
        # to arc length along the path (u along the path may run either way)
        u_pts = (path.points[:, :2] - origin) @ u_dir
        sign = 1.0 if u_pts[-1] > u_pts[0] else -1.0
        u_pts, lo, hi = sign * u_pts, np.where(sign > 0, lo, -hi), np.where(sign > 0, hi, -lo)
        keep = (lo <= hi) & (hi >= u_pts[0]) & (lo <= u_pts[-1])
        if not keep.any():
            return (np.arange(n_bins) + 0.5) * OFFSET_BIN
        cum = path.cumulative
        s_lo = np.interp(np.clip(lo[keep], u_pts[0], u_pts[-1]), u_pts, cum)
        s_hi = np.interp(np.clip(hi[keep], u_pts[0], u_pts[-1]), u_pts, cum)
        vt = speed * self.times[t_idx[keep]]
        margin = speed * CROSSING_DT / 2 + OFFSET_BIN
        # phase in [s_lo, s_hi] walking out, or in [trip - s_hi, trip - s_lo] walking back
        starts = np.concatenate([s_lo - vt, trip - s_hi - vt]) - margin
        widths = np.concatenate([s_hi - s_lo, s_hi - s_lo]) + 2 * margin
        if (widths >= trip).any():
            return np.zeros(0)
        starts = np.mod(starts, trip)
        ends = starts + widths
        wrap = ends > trip
        starts = np.concatenate([starts, np.zeros(wrap.sum())])
        ends = np.concatenate([np.minimum(ends, trip), ends[wrap] - trip])
        diff = np.zeros(n_bins + 1, np.int64)
        np.add.at(diff, np.floor(starts / OFFSET_BIN).astype(int), 1)
        np.add.at(diff, np.minimum(np.ceil(ends / OFFSET_BIN).astype(int), n_bins), -1)
        free = np.flatnonzero(np.cumsum(diff)[:n_bins] == 0)
        return (free + 0.5) * OFFSET_BIN

    def path(self, rng, k: int) -> tuple[Path, float]:
        """A straight walk: sidewalk, kerb, zebra, kerb, sidewalk (feet on the
        kerb height), and its sideways shift from the zebra's middle."""
        cw = self.crosswalks[k]
        a0 = float(rng.uniform(CROSSING_APPROACH[0], max(CROSSING_APPROACH[0], min(self.reach, cw.reach[0]))))
        a1 = float(rng.uniform(CROSSING_APPROACH[0], max(CROSSING_APPROACH[0], min(self.reach, cw.reach[1]))))
        along = np.array([-cw.across[1], cw.across[0]])
        shift = float(rng.uniform(-CROSSING_SHIFT, CROSSING_SHIFT))
        c = cw.centre + along * shift
        hw, z = cw.half_road, cw.kerb_h
        stops = [(-hw - a0, z), (-hw, z), (-hw + 0.2, 0.0), (hw - 0.2, 0.0), (hw, z), (hw + a1, z)]
        if rng.random() < 0.5:  # start from either side
            stops = [(-u, h) for u, h in stops[::-1]]
        return Path(np.array([[*(c + cw.across * u), h] for u, h in stops]), closed=False), shift

    def place(self, rng, n: int, weights: np.ndarray) -> list[Actor]:
        """Up to n crossing pedestrians; zebras drawn with ``weights``."""
        out = []
        p = weights / weights.sum()
        for _ in range(n):
            parts = pedestrian_parts(rng)
            centre, half = footprint(parts)
            radius = float(np.linalg.norm(centre) + np.linalg.norm(half))
            for _ in range(CROSSING_TRIES):
                k = int(rng.choice(len(self.crosswalks), p=p))
                path, shift = self.path(rng, k)
                speed = float(rng.uniform(*CROSSING_SPEED))
                free = self.free_offsets(k, path, shift, speed, radius)
                if len(free):
                    offset = float(free[int(rng.integers(len(free)))])
                    out.append(Actor("pedestrian", parts, path, offset, speed, 0.0))
                    break
        return out


@lru_cache(maxsize=16)
def _crosswalk_loops(loops: tuple, crosswalks: tuple) -> tuple[np.ndarray, ...]:
    """For each crossing, the loops whose vehicles can come near a walker on it."""
    pts, ids = _loop_samples(loops)
    out = []
    for cw in crosswalks:
        half = cw.half_road + CROSSING_APPROACH[1]
        a, b = cw.centre - cw.across * half, cw.centre + cw.across * half
        # a vehicle's box reaches at most ~6 m from its centre, parked ones sit 3 m off their loop
        reach = 12.5 + CROSSING_SHIFT
        box = np.flatnonzero(((pts > np.minimum(a, b) - reach) & (pts < np.maximum(a, b) + reach)).all(axis=1))
        out.append(np.unique(ids[box][_segment_distance(pts[box], a, b) < reach]))
    return tuple(out)


# --------------------------------------------------------------------------
# populate
# --------------------------------------------------------------------------
def populate(world: World, viewpoint_code: str, episode_seed: int) -> EpisodeScene:
    """Vehicles, riders, pedestrians and the ego for one episode."""
    vp = viewpoint_row(viewpoint_code)
    rng = np.random.default_rng(episode_seed)
    n_vehicles = int(rng.integers(20, 151))
    n_pedestrians = int(rng.integers(0, 101))
    loops = world.loops
    if not loops or len(loops) != len(world.lanes):
        raise ValueError(f"world {world.town} seed {world.seed} carries no lane loops matching its lanes")
    lengths = np.array([lp.path.length for lp in loops])

    # the ego: a random loop (longer ones more likely) and spawn point
    ego_w = lengths * np.array([FREEWAY_EGO_WEIGHT if lp.kind == "freeway" else 1.0 for lp in loops])
    ego_i = int(rng.choice(len(loops), p=ego_w / ego_w.sum()))
    ego_loop = loops[ego_i]
    lo, hi = FREEWAY_EGO_SPEED if ego_loop.kind == "freeway" else EGO_SPEED[vp.code]
    ego_speed = float(rng.uniform(lo, hi))
    ego_s = float(rng.uniform(0, lengths[ego_i]))
    ego = Actor(vp.vehicle, (), ego_loop.path, ego_s, ego_speed, 0.0)
    ego_size = EGO_SIZE.get(vp.code, EGO_SIZE_DEFAULT)

    speeds = rng.uniform(5.0, 14.0, len(loops))
    speeds[ego_i] = ego_speed
    slots = [_LoopSlots(L) for L in lengths]
    ego_half = ego_size[0] / 2
    actors: list[Actor] = []
    n_two = min(n_vehicles // 3, max(4, int(round(0.12 * n_vehicles))))
    n_parked_target = int(round(rng.uniform(0.15, 0.3) * (n_vehicles - n_two)))

    # riders: some just ahead of the ego, the rest near its route
    near = [i for i in range(len(loops)) if i == ego_i or _min_distance(loops[i].path.points, ego_loop.path.points) < 20]
    ahead = rng.uniform(22, 60, size=min(3, n_two))
    placed_two = 0
    for k in range(n_two):
        motor = bool(k % 2)
        if k < len(ahead):
            i, s = ego_i, ego_s + ego_half + float(ahead[k])
        else:
            i = int(rng.choice(near)) if rng.random() < 0.7 else int(rng.integers(len(loops)))
            s = float(rng.uniform(0, lengths[i]))
        if not slots[i].free(s, RIDER_SLOT / 2, 2.0):
            continue
        slots[i].take(s, RIDER_SLOT / 2)
        lat = loops[i].kerb_lateral_m + float(rng.uniform(-0.2, 0.2))
        actors.append(Actor("motorcyclist" if motor else "cyclist", rider_parts(rng, motor),
                            loops[i].path, s, float(speeds[i]), lat))
        placed_two += 1

    # free space ahead of and behind the ego (riders may ride in it): no car
    # closer than about 40 m ahead, on the same loop and at the same speed
    slots[ego_i].take(ego_s + 12.0, ego_half + 18.0)

    # moving vehicles
    n_moving = n_vehicles - n_two - n_parked_target
    weights = lengths / lengths.sum()
    placed_moving = 0
    for _ in range(8 * max(1, n_moving)):
        if placed_moving >= n_moving:
            break
        i = int(rng.choice(len(loops), p=weights))
        kinds = _allowed_kinds(loops[i])
        kind = _pick_kind(rng, kinds)
        half = VEHICLE_KINDS[kind].length / 2
        s = float(rng.uniform(0, lengths[i]))
        if not slots[i].free(s, half, 3.0 + 0.4 * speeds[i]):
            continue
        slots[i].take(s, half)
        paint = PAINTS[int(rng.integers(len(PAINTS)))]
        actors.append(Actor(kind, vehicle_parts(kind, paint), loops[i].path, s, float(speeds[i]), 0.0))
        placed_moving += 1

    # parked vehicles in the kerbside strips
    parking = [(i, a, b) for i, lp in enumerate(loops) for a, b in lp.parking]
    parked = [_LoopSlots(L) for L in lengths]
    n_parked = 0
    if parking:
        span_len = np.array([b - a for _, a, b in parking])
        for _ in range(6 * max(1, n_parked_target)):
            if n_parked >= n_vehicles - n_two - placed_moving:
                break
            k = int(rng.choice(len(parking), p=span_len / span_len.sum()))
            i, a, b = parking[k]
            kind = _pick_kind(rng, list(PARKED_WEIGHTS), PARKED_WEIGHTS)
            half = VEHICLE_KINDS[kind].length / 2
            if b - a < 2 * half:
                continue
            s = float(rng.uniform(a + half, b - half))
            if not parked[i].free(s, half, 0.8):
                continue
            parked[i].take(s, half)
            paint = PAINTS[int(rng.integers(len(PAINTS)))]
            actors.append(Actor(kind, vehicle_parts(kind, paint), loops[i].path, s, 0.0,
                                loops[i].parking_lateral_m))
            n_parked += 1

    # pedestrians on zebra crossings, in the gaps of the traffic, most of them
    # on the ego's route
    crossing: list[Actor] = []
    cws = world.crosswalks
    if cws and n_pedestrians:
        vehicles = [(a, *footprint(a.parts)) for a in actors]  # no pedestrians yet
        vehicles.append((ego, np.zeros(2), np.array(ego_size) / 2))
        planner = _CrossingPlanner(world, loops, vehicles)
        on_route = np.array([ego_i in planner.near_loops(k) for k in range(len(cws))], float)
        n_cross = int(round(rng.uniform(*CROSSING_SHARE) * n_pedestrians))
        crossing = planner.place(rng, n_cross, 1.0 + 8.0 * on_route)
        actors.extend(crossing)

    # the others on the sidewalks, most of them along the ego's route
    walk_loops = [p for p in world.walkways if p.closed]
    n_sidewalk = n_pedestrians - len(crossing)
    if walk_loops and n_sidewalk:
        near_w = np.array([_min_distance(p.points, ego_loop.path.points) < 25 for p in walk_loops], float)
        wts = np.array([p.length for p in walk_loops]) * (1.0 + 8.0 * near_w)
        wts /= wts.sum()
        lanes = world.walk_lanes
        if not lanes or len(lanes[0]) != len(walk_loops):
            raise RuntimeError("walkway lanes do not match the world's walkways")
        lane_speed: dict[tuple[int, int], float] = {}
        lane_slots: dict[tuple[int, int], _LoopSlots] = {}
        for _ in range(n_sidewalk):
            i = int(rng.choice(len(walk_loops), p=wts))
            key = (i, int(rng.integers(len(lanes))))
            path = lanes[key[1]][i]
            if key not in lane_speed:  # one pace per lane: nobody walks into the back of another
                lane_speed[key] = 0.0 if rng.random() < 0.2 else float(rng.uniform(0.8, 1.6))
                lane_slots[key] = _LoopSlots(path.length)
            parts = pedestrian_parts(rng)
            slots = lane_slots[key]
            for _try in range(WALK_TRIES):
                s = float(rng.uniform(0, slots.length))
                if slots.free(s, WALK_SLOT_M / 2, 0.0):
                    slots.take(s, WALK_SLOT_M / 2)
                    actors.append(Actor("pedestrian", parts, path, s, lane_speed[key], 0.0))
                    break

    return EpisodeScene(
        world=world,
        actors=tuple(actors),
        ego=ego,
        n_vehicles=n_vehicles,
        n_pedestrians=n_pedestrians,
        extras={
            "viewpoint": vp.code,
            "camera_height_m": vp.camera_height_m,
            "ego_loop": ego_i,
            "ego_loop_kind": ego_loop.kind,
            "vehicles_placed": placed_moving + n_parked + placed_two,
            "parked": n_parked,
            "two_wheelers": placed_two,
            "crossing_pedestrians": len(crossing),
            "ego_size_m": ego_size,
        },
    )
