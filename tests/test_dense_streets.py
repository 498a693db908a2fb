"""Dense streets (issue 34): a town's ``street_density`` above 0 fills its streets the way real ones are
(buildings at the pavement, parked cars, people, poles and signs); at 0 the town is as designed."""

from __future__ import annotations

import hashlib
from dataclasses import replace

import numpy as np
import pytest

from domains import catalog
from domains.catalog import class_id, town as town_row
from domains.catalog_file import CatalogError, with_file
from render_workers.worlds import world as W
from render_workers.worlds.traffic import populate

EPISODES = (0, 3)  # populate seeds the fingerprints cover


def _fingerprint(world, scenes) -> dict:
    """What a change of the default's draws would move: triangles per class, lights, buildings, the
    vertices' extent and every actor's kind and place (rounded, so the figures hold across machines)."""
    tris: dict[int, int] = {}
    for part in world.static:
        tris[part.class_id] = tris.get(part.class_id, 0) + len(part.mesh.faces)
    verts = np.concatenate([p.mesh.vertices for p in world.static])
    actors = repr([(a.kind, round(a.offset_m, 2), round(a.speed_mps, 2), round(a.lateral_m, 2))
                   for s in scenes for a in s.actors]).encode()
    return {"triangles": dict(sorted(tris.items())), "lights": len(world.lights),
            "vertex_sum_m": int(round(float(np.abs(verts).sum()))),
            "actors": hashlib.sha256(actors).hexdigest()[:16],
            "counts": [(s.n_vehicles, s.n_pedestrians) for s in scenes]}


# T02 at seed 0, episodes 0 and 3 from viewpoint V, as the code before street_density built them.
DEFAULT_T02 = {
    "triangles": {1: 4000, 2: 2170, 3: 90, 5: 2502, 6: 1224, 7: 2696, 8: 7206, 9: 21016, 11: 60, 12: 300, 13: 1240,
                  15: 50, 19: 4472, 22: 862, 23: 102},
    "lights": 56, "vertex_sum_m": 6851982, "actors": "281d8dce38c141a1", "counts": [(131, 64), (126, 8)],
}


@pytest.fixture(scope="module")
def t02():
    return W.build_town(town_row("T02"), 0)


@pytest.fixture(scope="module")
def t02_dense():
    return W.build_town(replace(town_row("T02"), street_density=1.0), 0)


def test_density_zero_builds_and_populates_the_town_as_before(t02):
    """The default (street_density 0) draws exactly what the town drew before the parameter: same
    triangles, lights, vertices and actors (the frames then stay byte for byte, docs/realism.md)."""
    assert t02.street_density == 0.0
    got = _fingerprint(t02, [populate(t02, "V", s) for s in EPISODES])
    assert got == DEFAULT_T02


def test_dense_streets_are_denser_and_deterministic(t02, t02_dense):
    def tris(world):
        out: dict[int, int] = {}
        for part in world.static:
            out[part.class_id] = out.get(part.class_id, 0) + len(part.mesh.faces)
        return out

    base, dense = tris(t02), tris(t02_dense)
    for name in ("building", "pole", "traffic sign"):
        assert dense[class_id(name)] > 1.2 * base[class_id(name)], name
    assert len(W.building_footprints("T02", 0)) < len(W._built(replace(town_row("T02"), street_density=1.0), 0)[1])
    again = W.build_town(replace(town_row("T02"), street_density=1.0), 0)
    assert _fingerprint(again, []) == _fingerprint(t02_dense, [])
    for seed in EPISODES:
        plain, crowded = populate(t02, "V", seed), populate(t02_dense, "V", seed)
        assert crowded.extras["dense_parked"] > 0 and crowded.extras["dense_walkers"] > 0
        # a car per 18 m of the kerbs near the route at most (9 m lowered what CamVid keeps; docs/realism.md)
        assert crowded.extras["dense_parked"] <= round(crowded.extras["dense_kerb_m"] / 18.0)
        assert crowded.n_vehicles == plain.n_vehicles + crowded.extras["dense_parked"] + crowded.extras["dense_lead"]
        assert crowded.n_pedestrians == plain.n_pedestrians + crowded.extras["dense_walkers"]
        parked = [a for a in crowded.actors if a.speed_mps == 0 and a.kind != "pedestrian"]
        assert len(parked) > len([a for a in plain.actors if a.speed_mps == 0 and a.kind != "pedestrian"])
        assert "dense_parked" not in plain.extras
        assert _fingerprint(t02_dense, [populate(t02_dense, "V", seed)]) == _fingerprint(t02_dense, [crowded])


def test_dense_streets_follow_a_car_in_the_ego_lane(t02, t02_dense):
    """Most dense episodes have a car ahead in the ego's lane, its tail 5-20 m from the ego's nose, at the ego's
    speed (so the gap holds over the episode); episodes without dense streets keep the free road ahead."""
    from render_workers.worlds import traffic
    from render_workers.worlds.actors import VEHICLE_KINDS

    def ahead_in_lane(world, seed):
        scene = populate(world, "V", seed)
        ego = scene.ego
        cars = sorted(((a.offset_m - ego.offset_m) % ego.path.length, a) for a in scene.actors
                      if a.path is ego.path and a.kind in VEHICLE_KINDS and a.lateral_m == 0.0)
        return scene, cars

    followed = 0
    for seed in range(10):
        scene, cars = ahead_in_lane(t02_dense, seed)
        n = scene.extras["dense_lead"]
        assert n in (0, 1)
        if n:
            ahead, car = cars[0]
            gap = ahead - VEHICLE_KINDS[car.kind].length / 2 - scene.extras["ego_size_m"][0] / 2
            lo, hi = traffic.DENSE_LEAD_GAP_M
            assert lo - 1e-6 <= gap <= hi + 1e-6 and car.speed_mps == scene.ego.speed_mps, (seed, gap)
        assert all(ahead > 28.0 for ahead, _ in cars[n:])  # the others keep clear of the road just ahead
        followed += n
        assert all(ahead > 28.0 for ahead, _ in ahead_in_lane(t02, seed)[1])  # the default: free road ahead
    assert followed >= 5  # DENSE_LEAD_SHARE 0.8 of ten episodes, less where riders ahead leave no room


def test_street_density_is_a_town_parameter_of_domain_files():
    dense = with_file(catalog.BUILTIN, '[[town]]\ncode = "T01D"\nlike = "T01"\nstreet_density = 0.7\n', "dense.toml")
    assert dense.by_code("town")["T01D"].street_density == 0.7
    assert catalog.BUILTIN.by_code("town")["T01"].street_density == 0.0
    with pytest.raises(CatalogError, match="street_density"):
        with_file(catalog.BUILTIN, '[[town]]\ncode = "T01D"\nlike = "T01"\nstreet_density = 1.5\n', "bad.toml")


def test_the_crowd_keeps_clear_of_everyone(t02_dense):
    """The cars and people dense streets add share the strips' and walking lanes' slots with the others:
    no two vehicles overlap, no two walkers meet (the checks of tests/test_world.py)."""
    from tests.test_world import _boxes_at, _movers, _overlap, _box

    scene = populate(t02_dense, "V", 0)
    movers = _movers(scene)
    for t in (0.0, 30.0, 60.0):
        boxes = [_box(a, t) for a in movers]
        centres = np.array([b[0] for b in boxes])
        for i in range(len(boxes)):
            for j in np.flatnonzero(np.linalg.norm(centres[i + 1:] - centres[i], axis=1) < 14.0) + i + 1:
                assert not _overlap(boxes[i], boxes[j]), f"{movers[i].kind} / {movers[j].kind} overlap at t={t}"
    walkers = [a for a in scene.actors if a.kind == "pedestrian" and a.path.closed]
    local = []
    for a in walkers:
        verts = np.concatenate([p.mesh.vertices[:, :2] for p in a.parts])
        lo, hi = verts.min(axis=0), verts.max(axis=0)
        local.append(((lo + hi) / 2, (hi - lo) / 2))
    for t in (0.0, 30.0, 60.0):
        boxes = _boxes_at(walkers, t, local)
        centres = np.array([b[0] for b in boxes])
        for i in range(len(walkers)):
            for j in np.flatnonzero(np.linalg.norm(centres[i + 1:] - centres[i], axis=1) < 3.0) + i + 1:
                assert not _overlap(boxes[i], boxes[j], shrink=0.0), f"two pedestrians meet at t={t}"
