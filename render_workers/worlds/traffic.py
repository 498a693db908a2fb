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

from dataclasses import dataclass, field

import numpy as np

from domains.catalog import viewpoint as viewpoint_row
from render_workers.worlds.actors import PAINTS, VEHICLE_KINDS, pedestrian_parts, rider_parts, vehicle_parts
from render_workers.worlds.crossings import CROSSING_SHARE, CrossingPlanner, footprint
from render_workers.worlds.scene import Actor, EpisodeScene, Loop, World

KIND_WEIGHTS = {"sedan": 0.45, "suv": 0.25, "van": 0.15, "truck": 0.08, "bus": 0.07}
# Parked along the kerb: buses wait at stops, trucks deliver. A bus (2.55 m) is
# a little wider than the 2.2 m strip and overhangs lane and kerb by 0.18 m.
PARKED_WEIGHTS = {"sedan": 0.42, "suv": 0.26, "van": 0.16, "truck": 0.06, "bus": 0.10}
RIDER_SLOT = 2.4  # bicycles and motorcycles occupy this much lane length
FREEWAY_EGO_SPEED = (16.0, 20.0)
# The ego starts on a freeway loop less often than the loops' length alone
# would give: freeway frames show no sidewalk, signals or two-wheelers.
FREEWAY_EGO_WEIGHT = 0.4
# Pedestrians on sidewalks keep to the World's walking lanes (town_plan.WALK_LANE_M
# apart, from the middle of the sidewalk towards the buildings), one pace per lane and loop, each holding
# a WALK_SLOT_M stretch of it: they never walk through one another. A walker
# that finds no free stretch in WALK_TRIES draws is left out (none in 11,081
# pedestrians over 210 episodes of the seven towns).
WALK_SLOT_M = 1.0
WALK_TRIES = 10
# Dense streets (Town.street_density, issue 34): at density 1 the kerbside strips hold a parked car per
# DENSE_PARKING_M of their length (where one fits), and DENSE_WALKERS more people walk the pavements.
# (18 m, not 9: with a car per 9 m ours showed 1.6x CamVid's share of car and half its pavement, and a
# network trained on them kept less on CamVid; docs/realism.md.)
DENSE_PARKING_M = 18.0
DENSE_WALKERS = 150
DENSE_NEAR_M = 25.0  # parked cars fill the strips of the loops this close to the ego's
DENSE_STREAM = 34  # the crowd's generator: default_rng([episode seed, DENSE_STREAM])
# ... and at density 1 this share of episodes follows a car in the ego's lane, its tail DENSE_LEAD_GAP_M
# ahead of the ego's nose (at the loop's speed, so the gap holds), as real drives mostly do.
DENSE_LEAD_SHARE, DENSE_LEAD_GAP_M = 0.8, (5.0, 20.0)
DENSE_LEAD_WEIGHTS = {"sedan": 0.5, "suv": 0.3, "van": 0.2}
DENSE_LEAD_STREAM = 35


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


@dataclass
class _Placement:
    """One episode's placement state, shared by the phases of ``populate`` in draw order."""

    world: World
    rng: np.random.Generator
    loops: list
    lengths: np.ndarray
    ego_i: int
    ego_s: float
    ego: Actor
    ego_size: tuple
    speeds: np.ndarray
    slots: list
    actors: list = field(default_factory=list)
    parked: list = field(default_factory=list)  # per loop: its parking strips' occupied stretches (_LoopSlots)
    walk_speed: dict = field(default_factory=dict)  # (walkway, lane) -> the pace of everyone in it
    walk_slots: dict = field(default_factory=dict)  # (walkway, lane) -> its occupied stretches (_LoopSlots)

    @property
    def ego_loop(self):
        return self.loops[self.ego_i]


def _place_ego(world: World, vp, rng: np.random.Generator) -> _Placement:
    """The ego: a random loop (longer ones more likely) and spawn point; the loops' speeds."""
    loops = world.loops
    if not loops or len(loops) != len(world.lanes):
        raise ValueError(f"world {world.town} seed {world.seed} carries no lane loops matching its lanes")
    lengths = np.array([lp.path.length for lp in loops])
    ego_w = lengths * np.array([FREEWAY_EGO_WEIGHT if lp.kind == "freeway" else 1.0 for lp in loops])
    ego_i = int(rng.choice(len(loops), p=ego_w / ego_w.sum()))
    lo, hi = FREEWAY_EGO_SPEED if loops[ego_i].kind == "freeway" else vp.ego_speed_mps
    ego_speed = float(rng.uniform(lo, hi))
    ego_s = float(rng.uniform(0, lengths[ego_i]))
    ego = Actor(vp.vehicle, (), loops[ego_i].path, ego_s, ego_speed, 0.0)
    speeds = rng.uniform(5.0, 14.0, len(loops))
    speeds[ego_i] = ego_speed
    return _Placement(world, rng, loops, lengths, ego_i, ego_s, ego, vp.ego_size_m, speeds,
                      [_LoopSlots(L) for L in lengths])


def _place_riders(p: _Placement, n_two: int) -> int:
    """Riders: some just ahead of the ego, the rest near its route; returns how many were placed."""
    rng, loops, lengths = p.rng, p.loops, p.lengths
    near = [i for i in range(len(loops))
            if i == p.ego_i or _min_distance(loops[i].path.points, p.ego_loop.path.points) < 20]
    ahead = rng.uniform(22, 60, size=min(3, n_two))
    placed = 0
    for k in range(n_two):
        motor = bool(k % 2)
        if k < len(ahead):
            i, s = p.ego_i, p.ego_s + p.ego_size[0] / 2 + float(ahead[k])
        else:
            i = int(rng.choice(near)) if rng.random() < 0.7 else int(rng.integers(len(loops)))
            s = float(rng.uniform(0, lengths[i]))
        if not p.slots[i].free(s, RIDER_SLOT / 2, 2.0):
            continue
        p.slots[i].take(s, RIDER_SLOT / 2)
        lat = loops[i].kerb_lateral_m + float(rng.uniform(-0.2, 0.2))
        p.actors.append(Actor("motorcyclist" if motor else "cyclist", rider_parts(rng, motor),
                              loops[i].path, s, float(p.speeds[i]), lat))
        placed += 1
    return placed


def _place_moving(p: _Placement, n_moving: int) -> int:
    """Moving vehicles on the lane loops, spaced by their speed; returns how many were placed."""
    rng, loops, lengths = p.rng, p.loops, p.lengths
    weights = lengths / lengths.sum()
    placed = 0
    for _ in range(8 * max(1, n_moving)):
        if placed >= n_moving:
            break
        i = int(rng.choice(len(loops), p=weights))
        kind = _pick_kind(rng, _allowed_kinds(loops[i]))
        half = VEHICLE_KINDS[kind].length / 2
        s = float(rng.uniform(0, lengths[i]))
        if not p.slots[i].free(s, half, 3.0 + 0.4 * p.speeds[i]):
            continue
        p.slots[i].take(s, half)
        paint = PAINTS[int(rng.integers(len(PAINTS)))]
        p.actors.append(Actor(kind, vehicle_parts(kind, paint), loops[i].path, s, float(p.speeds[i]), 0.0))
        placed += 1
    return placed


def _place_parked(p: _Placement, target: int, room: int, only: frozenset | None = None) -> int:
    """Parked vehicles in the kerbside strips (at most ``room``; ``only``: of these loops); returns how many
    were placed."""
    rng, loops = p.rng, p.loops
    parking = [(i, a, b) for i, lp in enumerate(loops) for a, b in lp.parking if only is None or i in only]
    if not p.parked:
        p.parked = [_LoopSlots(L) for L in p.lengths]
    parked = p.parked
    placed = 0
    if not parking:
        return 0
    span_len = np.array([b - a for _, a, b in parking])
    for _ in range(6 * max(1, target)):
        if placed >= room:
            break
        i, a, b = parking[int(rng.choice(len(parking), p=span_len / span_len.sum()))]
        kind = _pick_kind(rng, list(PARKED_WEIGHTS), PARKED_WEIGHTS)
        half = VEHICLE_KINDS[kind].length / 2
        if b - a < 2 * half:
            continue
        s = float(rng.uniform(a + half, b - half))
        if not parked[i].free(s, half, 0.8):
            continue
        parked[i].take(s, half)
        paint = PAINTS[int(rng.integers(len(PAINTS)))]
        p.actors.append(Actor(kind, vehicle_parts(kind, paint), loops[i].path, s, 0.0, loops[i].parking_lateral_m))
        placed += 1
    return placed


def _place_crossing(p: _Placement, n_pedestrians: int) -> list[Actor]:
    """Pedestrians on zebra crossings, in the gaps of the traffic, most of them on the ego's route."""
    if not p.world.crosswalks or not n_pedestrians:
        return []
    vehicles = [(a, *footprint(a.parts)) for a in p.actors]  # no pedestrians yet
    vehicles.append((p.ego, np.zeros(2), np.array(p.ego_size) / 2))
    planner = CrossingPlanner(p.world, p.loops, vehicles)
    on_route = np.array([p.ego_i in planner.near_loops(k) for k in range(len(p.world.crosswalks))], float)
    n_cross = int(round(p.rng.uniform(*CROSSING_SHARE) * n_pedestrians))
    crossing = planner.place(p.rng, n_cross, 1.0 + 8.0 * on_route)
    p.actors.extend(crossing)
    return crossing


def _place_walkers(p: _Placement, n_sidewalk: int) -> None:
    """The other pedestrians on the sidewalks, most of them along the ego's route."""
    rng, world = p.rng, p.world
    walk_loops = [w for w in world.walkways if w.closed]
    if not walk_loops or not n_sidewalk:
        return
    near_w = np.array([_min_distance(w.points, p.ego_loop.path.points) < 25 for w in walk_loops], float)
    wts = np.array([w.length for w in walk_loops]) * (1.0 + 8.0 * near_w)
    wts /= wts.sum()
    lanes = world.walk_lanes
    if not lanes or len(lanes[0]) != len(walk_loops):
        raise RuntimeError("walkway lanes do not match the world's walkways")
    lane_speed, lane_slots = p.walk_speed, p.walk_slots
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
                p.actors.append(Actor("pedestrian", parts, path, s, lane_speed[key], 0.0))
                break


def _lead(p: _Placement, density: float, episode_seed: int) -> int:
    """Dense streets: a car ahead in the ego's lane for ``density`` x DENSE_LEAD_SHARE of the episodes, where the
    riders ahead leave room; drawn from a generator of its own. Returns 1 or 0."""
    if density <= 0:
        return 0
    rng = np.random.default_rng([episode_seed, DENSE_LEAD_STREAM])
    if rng.random() >= density * DENSE_LEAD_SHARE:
        return 0
    kind = _pick_kind(rng, list(DENSE_LEAD_WEIGHTS), DENSE_LEAD_WEIGHTS)
    half = VEHICLE_KINDS[kind].length / 2
    s = (p.ego_s + p.ego_size[0] / 2 + float(rng.uniform(*DENSE_LEAD_GAP_M)) + half) % p.lengths[p.ego_i]
    if not p.slots[p.ego_i].free(s, half, 2.0):
        return 0
    p.slots[p.ego_i].take(s, half)
    paint = PAINTS[int(rng.integers(len(PAINTS)))]
    p.actors.append(Actor(kind, vehicle_parts(kind, paint), p.ego_loop.path, s, float(p.speeds[p.ego_i]), 0.0))
    return 1


def _crowd(p: _Placement, density: float, episode_seed: int) -> tuple[int, int, float]:
    """Dense streets (``World.street_density`` above 0): after everyone IDDA's counts place, cars parked
    along the kerbs until the strips are ``density`` full (a car per ``DENSE_PARKING_M`` of strip) and
    ``density`` x ``DENSE_WALKERS`` more people on the pavements, most along the ego's route. Drawn from a
    generator of their own, after the others: the episode's other actors are the same as without it.
    Returns (cars, people) added and the metres of kerbside strip near the route."""
    if density <= 0:
        return 0, 0, 0.0
    p.rng = np.random.default_rng([episode_seed, DENSE_STREAM])
    # the kerbs the ego passes: strips of the loops beside its own (those out of sight stay as they were)
    near = frozenset(i for i, lp in enumerate(p.loops)
                     if i == p.ego_i or _min_distance(lp.path.points, p.ego_loop.path.points) < DENSE_NEAR_M)
    strips = sum(b - a for i in near for a, b in p.loops[i].parking)
    target = int(round(density * strips / DENSE_PARKING_M))
    cars = _place_parked(p, target, target, near)
    before = len(p.actors)
    _place_walkers(p, int(round(density * DENSE_WALKERS)))
    return cars, len(p.actors) - before, strips


def populate(world: World, viewpoint_code: str, episode_seed: int) -> EpisodeScene:
    """Vehicles, riders, pedestrians and the ego for one episode (the phases draw from one rng, in this order)."""
    vp = viewpoint_row(viewpoint_code)
    rng = np.random.default_rng(episode_seed)
    n_vehicles = int(rng.integers(20, 151))
    n_pedestrians = int(rng.integers(0, 101))
    p = _place_ego(world, vp, rng)
    n_two = min(n_vehicles // 3, max(4, int(round(0.12 * n_vehicles))))
    n_parked_target = int(round(rng.uniform(0.15, 0.3) * (n_vehicles - n_two)))
    placed_two = _place_riders(p, n_two)
    dense_lead = _lead(p, world.street_density, episode_seed)
    # free space ahead of and behind the ego (riders may ride in it): no car
    # closer than about 40 m ahead, on the same loop and at the same speed
    p.slots[p.ego_i].take(p.ego_s + 12.0, p.ego_size[0] / 2 + 18.0)
    placed_moving = _place_moving(p, n_vehicles - n_two - n_parked_target)
    n_parked = _place_parked(p, n_parked_target, n_vehicles - n_two - placed_moving)
    crossing = _place_crossing(p, n_pedestrians)
    _place_walkers(p, n_pedestrians - len(crossing))
    dense_parked, dense_walkers, kerb_m = _crowd(p, world.street_density, episode_seed)
    return EpisodeScene(
        world=world,
        actors=tuple(p.actors),
        ego=p.ego,
        n_vehicles=n_vehicles + dense_parked + dense_lead,
        n_pedestrians=n_pedestrians + dense_walkers,
        extras={
            "viewpoint": vp.code,
            "camera_height_m": vp.camera_height_m,
            "ego_loop": p.ego_i,
            "ego_loop_kind": p.ego_loop.kind,
            "vehicles_placed": placed_moving + n_parked + placed_two,
            "parked": n_parked,
            "two_wheelers": placed_two,
            "crossing_pedestrians": len(crossing),
            "ego_size_m": p.ego_size,
            **({"dense_parked": dense_parked, "dense_walkers": dense_walkers, "dense_lead": dense_lead,
                "dense_kerb_m": kerb_m} if world.street_density > 0 else {}),
        },
    )
