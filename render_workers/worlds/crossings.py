"""Crossing pedestrians for ``render_workers.worlds.traffic``: placed on zebra
crossings where and when no vehicle comes near them.

Every vehicle's motion is known, so a crossing pedestrian is only placed if,
sampled every ``CROSSING_DT`` s over ``[0, CROSSING_HORIZON_S]`` (the frames'
times included), it keeps ``CROSSING_CLEAR`` m from every vehicle, rider and
the ego: people cross in the gaps between cars.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from render_workers.worlds.actors import pedestrian_parts
from render_workers.worlds.scene import Actor, Path, World

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


class CrossingPlanner:
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
