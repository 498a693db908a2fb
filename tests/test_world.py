"""Procedural towns and per-episode traffic (render_workers.worlds.world / traffic)."""

from __future__ import annotations

import numpy as np
import pytest

from domains.catalog import TOWNS, VIEWPOINTS, class_id, town as town_row, viewpoint
from render_workers.worlds import world as W
from render_workers.worlds.scene import MATERIALS
from render_workers.worlds.styles import is_urban
from render_workers.worlds.traffic import populate

TOWN_CODES = [t.code for t in TOWNS]
MOVING_CLASSES = {class_id("vehicle"), class_id("bicycle"), class_id("motorcycle")}


@pytest.fixture(scope="module")
def worlds(procedural_worlds):
    return procedural_worlds


def _tri_counts(world) -> dict[int, int]:
    out: dict[int, int] = {}
    for part in world.static:
        out[part.class_id] = out.get(part.class_id, 0) + len(part.mesh.faces)
    return out


# --------------------------------------------------------------------------
# Determinism
# --------------------------------------------------------------------------
def test_layout_is_deterministic_and_seed_dependent():
    for code in TOWN_CODES:
        a, b = W.plan.__wrapped__(town_row(code), 3), W.plan.__wrapped__(town_row(code), 3)
        assert np.array_equal(a.xs, b.xs) and np.array_equal(a.ys, b.ys)
        assert a.signals == b.signals and a.groups == b.groups
        c = W.plan.__wrapped__(town_row(code), 4)
        assert not np.array_equal(a.xs, c.xs)


def test_geometry_is_deterministic_and_seed_dependent():
    a, _, lights_a = W._built(town_row("T02"), 5)
    b, _, lights_b = W._built(town_row("T02"), 5)
    assert len(a) == len(b) and np.array_equal(lights_a, lights_b)
    for pa, pb in zip(a, b):
        assert pa.class_id == pb.class_id and pa.material == pb.material
        assert np.array_equal(pa.mesh.vertices, pb.mesh.vertices)
        assert np.array_equal(pa.mesh.faces, pb.mesh.faces)
        assert np.array_equal(pa.mesh.visual.vertex_colors, pb.mesh.visual.vertex_colors)
    c, *_ = W._built(town_row("T02"), 6)
    va = np.concatenate([p.mesh.vertices for p in a])
    vc = np.concatenate([p.mesh.vertices for p in c])
    assert va.shape != vc.shape or not np.array_equal(va, vc)


# --------------------------------------------------------------------------
# Content
# --------------------------------------------------------------------------
@pytest.mark.parametrize("code", TOWN_CODES)
def test_town_contains_its_classes(worlds, code):
    t = town_row(code)
    present = set(_tri_counts(worlds[code]))
    need = ["road", "road line", "building", "vegetation", "terrain", "pole", "traffic sign",
            "traffic light", "fence", "wall"]
    if is_urban(t):
        need.append("sidewalk")
    if t.railway:
        need.append("railway")
    if t.freeway:
        need.append("guard rail")
    missing = [name for name in need if class_id(name) not in present]
    assert not missing, f"{code} lacks {missing}"
    if not t.railway:
        assert class_id("railway") not in present
    if not is_urban(t):
        assert class_id("sidewalk") not in present


@pytest.mark.parametrize("code", TOWN_CODES)
def test_parts_are_merged_tiled_and_coloured(worlds, code):
    world = worlds[code]
    keys = set()
    for part in world.static:
        assert part.material in MATERIALS
        colors = part.mesh.visual.vertex_colors
        assert colors.dtype == np.uint8 and len(colors) == len(part.mesh.vertices)
        # a part holds one 200 m tile's pieces, which may overhang it a little
        c = part.mesh.triangles_center[:, :2]
        assert (np.ptp(c, axis=0) <= 200.0 + 2 * 90.0).all()
        key = (tuple(np.floor(c.mean(axis=0) / 200.0)), part.class_id, part.material)
        keys.add(key)
    assert len(keys) > 20
    # large classes are never one flat colour
    for name in ("road", "building", "vegetation", "terrain"):
        cols = np.concatenate([p.mesh.visual.vertex_colors[:, :3] for p in world.static
                               if p.class_id == class_id(name)])
        assert cols.std(axis=0).max() > 3.0, name


@pytest.mark.parametrize("code", TOWN_CODES)
def test_triangle_budget(worlds, code):
    world = worlds[code]
    total = sum(len(p.mesh.faces) for p in world.static)
    assert total < 1_500_000
    centres = np.concatenate([p.mesh.triangles_center[:, :2] for p in world.static])
    probe = world.loops[-1].path.points[0, :2]  # a point on the perimeter / freeway
    near = np.linalg.norm(centres - probe, axis=1) < 450.0
    assert near.sum() < 300_000


@pytest.mark.parametrize("code", TOWN_CODES)
def test_road_length_matches_catalog(code):
    lay = W.layout(code, 0)
    target = town_row(code).road_km * 1000.0
    assert abs(lay.road_length_m - target) / target < 0.15


def test_towns_differ():
    a, b = W.layout("T07", 0), W.layout("T05", 0)
    assert a.sidewalk_w == 0 and b.sidewalk_w > 0
    assert b.town.building_height_m[1] > 3 * a.town.building_height_m[1]


# --------------------------------------------------------------------------
# Traffic
# --------------------------------------------------------------------------
def _box(actor, t):
    """2D oriented box (centre, half extents, axes) of an actor's parts at time t."""
    verts = np.concatenate([p.mesh.vertices for p in actor.parts])
    lo, hi = verts[:, :2].min(axis=0), verts[:, :2].max(axis=0)
    pose = actor.pose(t)
    centre_local = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, 0.0, 1.0])
    centre = (pose @ centre_local)[:2]
    return centre, (hi - lo) / 2, pose[:2, :2]


def _overlap(a, b, shrink=0.05) -> bool:
    """Separating-axis test for two 2D oriented boxes."""
    (ca, ha, ra), (cb, hb, rb) = a, b
    ha, hb = ha - shrink, hb - shrink
    d = cb - ca
    for axis in (ra[:, 0], ra[:, 1], rb[:, 0], rb[:, 1]):
        pa = abs(ra[:, 0] @ axis) * ha[0] + abs(ra[:, 1] @ axis) * ha[1]
        pb = abs(rb[:, 0] @ axis) * hb[0] + abs(rb[:, 1] @ axis) * hb[1]
        if abs(d @ axis) > pa + pb:
            return False
    return True


def _movers(scene):
    return [a for a in scene.actors if any(p.class_id in MOVING_CLASSES for p in a.parts)]


@pytest.mark.parametrize("code,seed", [("T01", 0), ("T03", 1), ("T05", 2), ("T07", 3), ("T02", 4)])
def test_no_vehicle_overlaps(worlds, code, seed):
    scene = populate(worlds[code], "A", seed)
    movers = _movers(scene)
    assert len(movers) >= 20
    fp = W.building_footprints(code, 0)
    bld = [(f[:2], f[2:4] / 2, np.array([[np.cos(f[4]), -np.sin(f[4])], [np.sin(f[4]), np.cos(f[4])]])) for f in fp]
    for t in (0.0, 3.0, 17.0, 61.0, 149.0):
        boxes = [_box(a, t) for a in movers]
        centres = np.array([b[0] for b in boxes])
        radius = np.array([np.linalg.norm(b[1]) for b in boxes])
        dist = np.linalg.norm(centres[:, None] - centres[None], axis=2)
        close = np.argwhere(np.triu(dist < radius[:, None] + radius[None], 1))
        for i, j in close:
            assert not _overlap(boxes[i], boxes[j]), f"{movers[i].kind} / {movers[j].kind} overlap at t={t}"
        if t == 0.0:
            for b in boxes:
                for f in bld:
                    if np.linalg.norm(f[0] - b[0]) < np.linalg.norm(f[1]) + np.linalg.norm(b[1]):
                        assert not _overlap(b, f), "vehicle inside a building"


def _road_triangles(world):
    tris = [p.mesh.triangles[:, :, :2] for p in world.static if p.class_id == class_id("road")]
    return np.concatenate(tris)


def _on_triangles(points, tris):
    """For each 2D point, whether some triangle contains it (barycentric test)."""
    a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
    v0, v1 = b - a, c - a
    den = v0[:, 0] * v1[:, 1] - v0[:, 1] * v1[:, 0]
    out = np.zeros(len(points), bool)
    for k, p in enumerate(points):
        w = p - a
        u = (w[:, 0] * v1[:, 1] - w[:, 1] * v1[:, 0]) / den
        v = (v0[:, 0] * w[:, 1] - v0[:, 1] * w[:, 0]) / den
        out[k] = bool(((u >= -1e-6) & (v >= -1e-6) & (u + v <= 1 + 1e-6)).any())
    return out


@pytest.mark.parametrize("code,seed", [("T01", 0), ("T03", 5), ("T06", 7), ("T07", 2)])
def test_ego_stays_on_road(worlds, code, seed):
    world = worlds[code]
    scene = populate(world, "J", seed)
    ego = scene.ego
    assert ego.parts == ()
    pts = np.array([ego.pose(t)[:2, 3] for t in np.arange(0.0, 240.0, 1.5)])
    tris = _road_triangles(world)
    inside = _on_triangles(pts, tris)
    assert inside.all(), f"ego off the road at {pts[~inside][:3]}"


def test_populate_counts_determinism_and_viewpoints(worlds):
    world = worlds["T01"]
    seen_ego = set()
    for seed in range(4):
        scene = populate(world, "A", seed)
        assert 20 <= scene.n_vehicles <= 150 and 0 <= scene.n_pedestrians <= 100
        peds = [a for a in scene.actors if a.kind == "pedestrian"]
        assert len(peds) == scene.n_pedestrians
        seen_ego.add(round(scene.ego.offset_m, 3))
        again = populate(world, "A", seed)
        assert [a.kind for a in again.actors] == [a.kind for a in scene.actors]
        assert [a.offset_m for a in again.actors] == [a.offset_m for a in scene.actors]
    assert len(seen_ego) == 4  # a new spawn point every episode
    for vp in VIEWPOINTS:
        scene = populate(world, vp.code, 11)
        assert scene.extras["camera_height_m"] == vp.camera_height_m
        assert 1.2 <= scene.extras["camera_height_m"] <= 2.5
        assert 7.0 <= scene.ego.speed_mps <= 20.0


def test_rare_classes_are_placed_near_the_ego(worlds):
    scene = populate(worlds["T03"], "M", 1)
    kinds = {a.kind for a in scene.actors}
    assert {"cyclist", "motorcyclist", "sedan"} <= kinds
    ego_lane = [a for a in scene.actors if a.path is scene.ego.path]
    assert any(a.kind in ("cyclist", "motorcyclist") for a in ego_lane)
    assert all(a.speed_mps == scene.ego.speed_mps for a in ego_lane)


def test_no_car_right_ahead_of_the_ego(worlds):
    """Cars on the ego's loop keep its speed, so one close ahead would fill every frame."""
    for code, seed in (("T01", 3), ("T03", 8), ("T07", 5)):
        scene = populate(worlds[code], "V", seed)
        ego, length = scene.ego, scene.ego.path.length
        for a in scene.actors:
            if a.path is not ego.path or a.kind in ("cyclist", "motorcyclist") or a.speed_mps == 0:  # parked at the kerb
                continue
            ahead = (a.offset_m - ego.offset_m) % length
            assert ahead > 25.0, f"{code}: {a.kind} {ahead:.1f} m ahead of the ego"


def test_ego_prefers_streets_to_the_freeway(worlds):
    from render_workers.worlds.traffic import FREEWAY_EGO_WEIGHT, _place_ego

    loops = worlds["T04"].loops
    lengths = np.array([lp.path.length for lp in loops])
    is_fw = np.array([lp.kind == "freeway" for lp in loops])
    by_length = lengths[is_fw].sum() / lengths.sum()  # the ego's share if it picked by length only
    # the ego's draw alone (populate's first placement), over many more seeds than whole episodes afford
    vp = viewpoint("A")
    on_fw = np.mean([_place_ego(worlds["T04"], vp, np.random.default_rng(s)).ego_loop.kind == "freeway"
                     for s in range(400)])
    assert FREEWAY_EGO_WEIGHT < 1.0 and 0.0 < on_fw < by_length
    scene = populate(worlds["T04"], "A", 0)  # and what an episode reports is the loop it drove
    assert scene.extras["ego_loop_kind"] == loops[scene.extras["ego_loop"]].kind


def _boxes_at(actors, t, local):
    """Like _box, with each actor's local footprint (centre, half extents) given."""
    out = []
    for a, (c, h) in zip(actors, local):
        pose = a.pose(t)
        out.append(((pose @ np.array([c[0], c[1], 0.0, 1.0]))[:2], h, pose[:2, :2]))
    return out


@pytest.mark.parametrize("code,seed", [("T01", 0), ("T02", 4), ("T06", 3)])
def test_crossing_pedestrians_keep_clear_of_traffic(worlds, code, seed):
    """Pedestrians walk over zebras in the gaps: no vehicle, rider or the ego meets one in any frame."""
    for vp in ("A", "B"):
        scene = populate(worlds[code], vp, seed)
        crossing = [a for a in scene.actors if a.kind == "pedestrian" and not a.path.closed]
        assert len(crossing) == scene.extras["crossing_pedestrians"]
        if scene.n_pedestrians >= 20:
            assert crossing, "no one crosses the street"
        movers = [a for a in scene.actors if a.kind != "pedestrian"] + [scene.ego]
        local = []
        for a in movers + crossing:
            if a.parts:
                verts = np.concatenate([p.mesh.vertices[:, :2] for p in a.parts])
                lo, hi = verts.min(axis=0), verts.max(axis=0)
                local.append(((lo + hi) / 2, (hi - lo) / 2))
            else:  # the ego: not drawn, but it has a size
                local.append((np.zeros(2), np.array(scene.extras["ego_size_m"]) / 2))
        on_road = 0
        for t in np.arange(0.0, 240.0 + 1e-9, 3.0):
            boxes = _boxes_at(movers, t, local[:len(movers)])
            centres = np.array([b[0] for b in boxes])
            for pb, p in zip(_boxes_at(crossing, t, local[len(movers):]), crossing):
                on_road += abs(p.pose(t)[2, 3]) < 1e-9
                for i in np.flatnonzero(np.linalg.norm(centres - pb[0], axis=1) < 8.0):
                    assert not _overlap(pb, boxes[i], shrink=-0.2), f"{movers[i].kind} meets a pedestrian at t={t}"
        assert not crossing or on_road > 0  # they do step onto the road


@pytest.mark.parametrize("code,seed", [("T01", 0), ("T02", 1), ("T05", 2), ("T07", 3)])
def test_sidewalk_pedestrians_never_walk_through_each_other(worlds, code, seed):
    """One pace per sidewalk lane, lanes apart, corners included: no two walkers' footprints meet."""
    scene = populate(worlds[code], "A", seed)
    walkers = [a for a in scene.actors if a.kind == "pedestrian" and a.path.closed]
    assert len(walkers) >= 2
    local = []
    for a in walkers:
        verts = np.concatenate([p.mesh.vertices[:, :2] for p in a.parts])
        lo, hi = verts.min(axis=0), verts.max(axis=0)
        local.append(((lo + hi) / 2, (hi - lo) / 2))
    assert any(a.speed_mps > 0 for a in walkers) and len({round(a.speed_mps, 6) for a in walkers}) > 1
    for t in np.arange(0.0, 240.0 + 1e-9, 1.5):
        boxes = _boxes_at(walkers, t, local)
        centres = np.array([b[0] for b in boxes])
        for i in range(len(walkers)):
            for j in np.flatnonzero(np.linalg.norm(centres[i + 1:] - centres[i], axis=1) < 3.0) + i + 1:
                assert not _overlap(boxes[i], boxes[j], shrink=0.0), f"two pedestrians meet at t={t}"


def test_town_traffic_has_buses(worlds):
    """Buses stop at the kerb in towns whose corners are too tight for them to drive."""
    for code in ("T01", "T02"):
        kinds = [a.kind for s in range(6) for a in populate(worlds[code], "A", s).actors]
        assert "bus" in kinds and "truck" in kinds, code


# --------------------------------------------------------------------------
# Styles: town identity as data
# --------------------------------------------------------------------------
def test_every_town_has_a_style_and_styles_differ():
    from render_workers.worlds.styles import STYLES, look, style, is_urban

    for t in TOWNS:
        assert style(t.style) is look(t)
    assert len({t.style for t in TOWNS}) == len(TOWNS)
    assert len({s.name for s in STYLES}) == len(STYLES)
    assert look(town_row("T07")).markings == "none" and not is_urban(town_row("T07"))
    assert look(town_row("T07")).lane_w_m < look(town_row("T01")).lane_w_m


def test_farmland_reads_as_farmland_not_as_a_town(worlds):
    """The country town's own look (issue 9, the city shift): a chip-seal road, not any kerbed town's asphalt,
    and golden ground and crops where the towns have green lawns; its built road wears that surface."""
    from render_workers.worlds.styles import STYLES, look, surface

    farm = look(town_row("T07"))
    urban = [s for s in STYLES if s.sidewalks]
    road = surface(farm.asphalt)
    assert all(road.texture != surface(s.asphalt).texture and road.color != surface(s.asphalt).color for s in urban)
    assert min(road.color) > max(max(surface(s.asphalt).color) for s in urban) + 20  # pale aggregate, not black top

    def golden(name):  # yellow to orange (red at least green) and saturated (red well above blue)
        r, g, b = surface(name).color
        return r >= g and r > 1.8 * b

    assert golden(farm.ground) and any(golden(c) for c in farm.crops) and any(golden(c) for c in farm.tall_crops)
    assert not any(golden(s.ground) for s in urban)  # lawns and dry grass: green or grey
    roads = [p for p in worlds["T07"].static if p.class_id == class_id("road")]
    assert roads and {p.texture for p in roads} == {road.texture}


def test_field_boundaries_follow_the_style():
    """Each countryside block edge is one draw against the style's field_bounds: hedgerow
    (vegetation), fence or dry-stone wall by their shares, open past their sum; the
    farmland lines most of its fields with hedgerows."""
    from dataclasses import replace

    from render_workers.worlds.countryside import boundary
    from render_workers.worlds.builder import Kit
    from render_workers.worlds.styles import look
    from render_workers.worlds.town_plan import plan

    assert dict(look(town_row("T07")).field_bounds)["hedge"] >= 0.5

    def drawn(bounds, u):
        kit = Kit(plan(town_row("T07"), 0))
        kit.style = replace(kit.style, field_bounds=bounds)
        boundary(kit, np.array([0.0, 0.0]), np.array([30.0, 0.0]), 0.0, u)
        return {p.class_id for p in kit.batch.parts()}

    mix = (("wall", 0.2), ("hedge", 0.5), ("fence", 0.1))
    assert drawn(mix, 0.1) == {class_id("wall")}
    assert drawn(mix, 0.6) == {class_id("vegetation")}
    assert drawn(mix, 0.75) == {class_id("fence")}
    assert drawn(mix, 0.85) == set()
    assert drawn((), 0.0) == set()


def test_unknown_surface_style_and_kit_are_rejected():
    from dataclasses import replace

    from domains.catalog import Town
    from render_workers.worlds.styles import STYLES, look, style, surface

    with pytest.raises(ValueError, match="unknown surface 'marble'; valid surfaces: asphalt dark, "):
        replace(STYLES[0], facades=("brick red", "marble"))
    with pytest.raises(ValueError, match="unknown architecture 'gothic'; valid architectures: european"):
        replace(STYLES[0], architecture="gothic")
    with pytest.raises(ValueError, match="unknown tree species 'palm'"):
        replace(STYLES[0], trees=(("palm", 1.0),))
    with pytest.raises(ValueError, match="unknown surface"):
        surface("chrome")
    with pytest.raises(ValueError, match="tall_crop_share must be in"):
        replace(STYLES[0], tall_crops=("maize",))  # tall crops but none sown
    with pytest.raises(ValueError, match="unknown surface 'bamboo'"):
        replace(style("farmland"), tall_crops=("bamboo",))
    with pytest.raises(ValueError, match="unknown field boundary 'moat'; valid field boundaries: hedge, fence, wall"):
        replace(style("farmland"), field_bounds=(("moat", 0.2),))
    with pytest.raises(ValueError, match="field_bounds shares must be >= 0 and sum to at most 1"):
        replace(style("farmland"), field_bounds=(("hedge", 0.7), ("wall", 0.4)))
    with pytest.raises(ValueError, match="unknown style 'gothic town'; valid styles: european old town"):
        look(replace(town_row("T01"), style="gothic town"))
    assert isinstance(town_row("T01"), Town) and style("farmland").architecture == "farm"


def test_builder_never_reads_town_codes():
    """Features see the plan and the style only: no town code appears in the world's modules."""
    import re
    from pathlib import Path

    root = Path(W.__file__).parent
    modules = ["world", "town_plan", "builder", "roadway", "streets", "buildings", "countryside", "freeway", "river", "railway"]
    for name in modules:
        text = (root / f"{name}.py").read_text()
        assert not re.search(r"T0\d", text), f"{name}.py mentions a town code"
        assert ".code" not in text.replace("t.code,", ""), f"{name}.py reads a town's code"


def test_a_style_row_changes_the_world():
    """The same town with another style row: other surfaces, other buildings, other roadside."""
    from dataclasses import replace

    t01 = town_row("T01")
    base = W.build_town(t01, 0)
    restyled = W.build_town(replace(t01, style="glass city"), 0)

    def colours(world, name):
        return np.concatenate([p.mesh.visual.vertex_colors[:, :3] for p in world.static if p.class_id == class_id(name)])

    assert not np.array_equal(colours(base, "road").mean(axis=0), colours(restyled, "road").mean(axis=0))
    assert any(p.material == "glass" and p.class_id == class_id("building") and len(p.mesh.faces) > 500
               for p in restyled.static)
    farm = W.build_town(replace(t01, style="farmland"), 0)
    assert class_id("sidewalk") not in _tri_counts(farm) and class_id("sidewalk") in _tri_counts(base)


def test_roofs_and_tall_crops_wear_their_textures(worlds):
    """House roofs are painted in their surface (terracotta tiles, concrete), and the
    farmland's maize stands are vegetation textured with stalks."""
    from render_workers.worlds.styles import surface

    tiles = [p for p in worlds["T01"].static
             if p.class_id == class_id("building") and p.texture == surface("roof terracotta").texture]
    slope = np.concatenate([np.abs(p.mesh.face_normals[:, 2]) for p in tiles])
    assert ((slope > 0.3) & (slope < 0.95)).sum() > 100  # pitched roof faces, not only brick walls
    t07 = worlds["T07"].static
    maize = [p for p in t07 if p.texture == "stalks"]
    assert maize and {p.class_id for p in maize} == {class_id("vegetation")}
    tops = np.concatenate([p.mesh.vertices[:, 2] for p in maize])
    assert 1.8 < tops.max() < 3.5  # taller than a person, lower than the trees


def test_a_path_measures_itself_once_and_answers_as_before():
    """Arc lengths are made once per path (``Path.at`` ran for every actor at every frame) and
    shared read-only; positions and headings are those of measuring afresh each time."""
    from render_workers.worlds.scene import Path

    rng = np.random.default_rng(7)
    for closed in (True, False):
        pts = np.cumsum(rng.normal(size=(9, 3)), axis=0)
        path = Path(pts, closed=closed)
        loop = np.vstack([pts, pts[:1]]) if closed else pts
        cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(loop, axis=0), axis=1))])
        assert np.array_equal(path.cumulative, cum) and path.length == cum[-1]
        assert path.cumulative is path.cumulative  # measured once
        assert not path.cumulative.flags.writeable and not path._loop().flags.writeable
        for s in np.linspace(-3 * cum[-1], 3 * cum[-1], 41):
            pos, heading = path.at(float(s))
            fresh = Path(pts.copy(), closed=closed)  # a path never asked before
            pos2, heading2 = fresh.at(float(s))
            assert np.array_equal(pos, pos2) and heading == heading2
            pos[:] = 0.0  # the caller's own array: the path is untouched
        assert np.array_equal(path.points, pts) and np.array_equal(path.cumulative, cum)


def test_value_noise_hashes_the_eight_corners_at_once_with_the_same_floats():
    """The corners' hashes come from one pass over all eight (world builds spent a third of their
    time in eight small passes); the noise is the corner-by-corner sum, bit for bit."""
    from render_workers.worlds.meshes import _hash01, value_noise

    rng = np.random.default_rng(11)
    points = rng.uniform(-500.0, 500.0, (2000, 3))
    for scale, seed in ((3.0, 0), (0.69, 7), (40.0, 12345)):
        p = points / scale
        i0 = np.floor(p).astype(np.int64)
        f = p - i0
        f = f * f * (3 - 2 * f)
        expected = np.zeros(len(p))
        for dx in (0, 1):
            wx = f[:, 0] if dx else 1 - f[:, 0]
            for dy in (0, 1):
                wy = f[:, 1] if dy else 1 - f[:, 1]
                for dz in (0, 1):
                    wz = f[:, 2] if dz else 1 - f[:, 2]
                    expected += wx * wy * wz * _hash01(i0[:, 0] + dx, i0[:, 1] + dy, i0[:, 2] + dz, seed)
        assert np.array_equal(value_noise(points, scale, seed), expected)


def test_quads_write_their_corners_in_place_with_the_same_floats():
    """``quads`` writes its corners into one array (world builds make ~7,000 calls): the corners,
    faces and floats of stacking broadcast copies, for one or many of each of p0, u and v."""
    from render_workers.worlds.meshes import quads

    rng = np.random.default_rng(8)
    many = lambda: rng.uniform(-300.0, 300.0, (4, 3))  # noqa: E731
    one = lambda: rng.uniform(-300.0, 300.0, 3)  # noqa: E731
    for p0, u, v in ((one(), one(), one()), (many(), one(), many()), (one(), many(), one()),
                     (one()[None], many(), one()), (many(), many(), many()), (one().tolist(), one(), one()[None])):
        a, b, c = (np.atleast_2d(np.asarray(x, np.float64)) for x in (p0, u, v))
        n = max(len(a), len(b), len(c))
        a, b, c = (np.broadcast_to(x, (n, 3)) for x in (a, b, c))
        verts, faces = quads(p0, u, v)
        assert np.array_equal(verts, np.stack([a, a + b, a + b + c, a + c], axis=1).reshape(-1, 3))
        assert np.array_equal(faces, (np.array([[0, 1, 2], [0, 2, 3]])[None] + 4 * np.arange(n)[:, None, None]).reshape(-1, 3))


def test_noisy_colours_take_both_octaves_in_one_pass_with_the_same_floats():
    """Both octaves of a mesh's colour noise come from one pass over its points stacked twice (world
    builds call it thousands of times for a few dozen vertices): bit for bit the two separate passes."""
    from render_workers.worlds.meshes import noisy_colors, value_noise

    rng = np.random.default_rng(5)
    for n, scale, seed in ((0, 3.0, 0), (1, 0.7, 96), (37, 3.0, 9972), (500, 18.0, 65535), (20, 1.0, np.int64(41))):
        verts = rng.uniform(-400.0, 400.0, (n, 3))
        base, amount, fine = (141, 120, 98), 0.2, 0.06
        n1 = value_noise(verts, scale, seed) - 0.5
        n2 = value_noise(verts, scale * 0.23, seed + 7) - 0.5
        gain = 1.0 + 2 * amount * n1 + 2 * fine * n2
        expected = np.full((n, 4), 255, np.uint8)
        expected[:, :3] = np.clip(np.asarray(base, np.float64)[None] * gain[:, None], 0, 255).astype(np.uint8)
        assert np.array_equal(noisy_colors(verts, base, amount, scale, seed, fine), expected)


def test_colours_asked_of_a_batch_are_made_together_as_each_piece_s_own_bytes(monkeypatch):
    """A world builder's pieces ask for their noisy colours when added (``NoiseColors``) and get them when
    the batch merges, in a few passes for all (~3,000 calls of a few dozen points were a quarter of a
    town's build): bit for bit ``noisy_colors`` of each piece, of any subset of its points, across passes."""
    import render_workers.worlds.meshes as M

    monkeypatch.setattr(M, "NOISE_POINTS_PER_PASS", 64)  # several passes, and a piece larger than one
    rng = np.random.default_rng(3)
    asked, expected = [], []
    for n, scale, seed, base in ((0, 3.0, 0, (90, 91, 92)), (1, 0.7, 96, (10, 200, 30, 255)),
                                 (37, 3.0, 9972, np.array([141.5, 120.0, 98.25])), (200, 18.0, 65535, (255, 0, 7)),
                                 (20, 1.0, np.int64(41), (5, 6, 7)), (3, 2.5, 8, (250, 250, 250))):
        verts = rng.uniform(-400.0, 400.0, (n, 3))
        amount, fine = float(rng.uniform(0.0, 0.3)), float(rng.uniform(0.0, 0.1))
        piece = M.NoiseColors(verts, base, amount, scale, seed, fine)
        asked.append(piece)
        expected.append(M.noisy_colors(verts, base, amount, scale, seed, fine))
        some = rng.permutation(n)[: n // 2]  # what add_tiled keeps of a piece for one tile
        asked.append(piece[some])
        expected.append(expected[-1][some])
        verts[:] = 0.0  # the caller's array changed after adding: the colours are of the points as added
    made = M.made_colors(asked)
    assert len(made) == len(expected)
    for got, want in zip(made, expected):
        assert got.dtype == np.uint8 and np.array_equal(got, want)
    assert all(np.array_equal(piece.made(), want) for piece, want in zip(asked, expected))


def test_a_batch_merges_asked_colours_as_if_made_when_added():
    """``MeshBatch.parts`` of pieces added with colours to make (whole, or split between tiles by
    ``add_tiled``) and of pieces added with their colours: the same parts, vertex for vertex."""
    import render_workers.worlds.meshes as M

    rng = np.random.default_rng(4)
    pieces = []
    for k in range(12):
        verts, faces = M.boxes(rng.uniform(-300.0, 300.0, (3, 3)), rng.uniform(0.5, 40.0, (3, 3)))
        pieces.append((k % 3, verts, faces, (rng.integers(0, 256, 3)), 0.1 + 0.01 * k, 1.0 + k, k, 0.05))
    batches = []
    for asked in (True, False):
        batch = M.MeshBatch(tile_m=50.0)
        for cls, verts, faces, base, amount, scale, seed, fine in pieces:
            colors = (M.NoiseColors(verts, base, amount, scale, seed, fine) if asked
                      else M.noisy_colors(verts, base, amount, scale, seed, fine))
            if cls == 2:
                batch.add_tiled(cls, "matte", verts, faces, colors)
            else:
                batch.add(cls, "matte", verts, faces, colors)
        batches.append(batch.parts())
    asked, made = batches
    assert len(asked) == len(made) > 3
    for a, b in zip(asked, made):
        assert (a.class_id, a.material) == (b.class_id, b.material)
        assert np.array_equal(a.mesh.vertices, b.mesh.vertices) and np.array_equal(a.mesh.faces, b.mesh.faces)
        assert np.array_equal(a.mesh.visual.vertex_colors, b.mesh.visual.vertex_colors)


def test_static_groups_put_each_face_in_its_centroid_s_tile():
    """A part wholly in one tile goes to it without sorting its tiles; one across tiles is split face by
    face: the groups hold the faces of each (tile, class, material) in the parts' and faces' order."""
    import trimesh

    from render_workers.render.part_meshes import _triangles, static_groups
    from render_workers.worlds.scene import Part

    rng = np.random.default_rng(6)
    parts = []
    for k, (lo, hi) in enumerate(((5.0, 45.0), (-90.0, 90.0), (120.0, 130.0), (-30.0, 70.0))):
        verts = rng.uniform(lo, hi, (30, 3))
        faces = rng.integers(0, 30, (20, 3))
        colors = rng.integers(0, 256, (30, 4)).astype(np.uint8)
        mesh = trimesh.Trimesh(vertices=verts, faces=faces, vertex_colors=colors, process=False)
        parts.append(Part(class_id=k % 2, mesh=mesh, material="matte"))
    groups = static_groups(tuple(parts), 50.0)
    expected: dict = {}
    for part in parts:
        tri, normals, colors = _triangles(part.mesh)
        for f in range(len(tri)):
            tx, ty = np.floor(tri[f].mean(axis=0)[:2] / 50.0).astype(np.int64)
            got = expected.setdefault((int(tx), int(ty), part.class_id, part.material, part.texture), ([], [], []))
            got[0].append(tri[f])
            got[1].append(normals[f])
            got[2].append(colors[f])
    assert set(groups) == set(expected) and len(groups) > 4
    for key, soup in groups.items():
        positions, normals, colors, uvs = soup.arrays()
        tri, nor, col = (np.concatenate(x).astype(np.float32) for x in expected[key])
        assert np.array_equal(positions, tri) and np.array_equal(normals, nor) and np.array_equal(colors, col)
        assert uvs is None


def test_boxes_make_every_side_in_one_pass_with_the_same_floats():
    """``boxes`` makes all sides of all its boxes in one ``quads`` call (world builds make ~1,600 calls):
    the vertices, faces and floats of one call per side, concatenated side by side."""
    from render_workers.worlds.meshes import _concat, boxes, quads

    rng = np.random.default_rng(9)
    for n, yaws, bottom in ((1, 0.0, False), (1, 0.7, True), (5, None, False), (5, None, True), (3, 1.3, False)):
        centers, sizes = rng.uniform(-300.0, 300.0, (n, 3)), rng.uniform(0.1, 30.0, (n, 3))
        yaw = rng.uniform(-np.pi, np.pi, n) if yaws is None else yaws
        cs, sn = np.cos(np.broadcast_to(yaw, (n,))), np.sin(np.broadcast_to(yaw, (n,)))
        ex = np.stack([cs, sn, np.zeros(n)], 1) * sizes[:, :1]
        ey = np.stack([-sn, cs, np.zeros(n)], 1) * sizes[:, 1:2]
        ez = np.zeros((n, 3))
        ez[:, 2] = sizes[:, 2]
        base = centers - 0.5 * ex - 0.5 * ey
        sides = [(base + ex, ey, ez), (base + ey, -ey, ez), (base + ex + ey, -ex, ez), (base, ex, ez), (base + ez, ex, ey)]
        if bottom:
            sides.append((base + ey, ex, -ey))
        want_v, want_f = _concat([quads(p, u, v) for p, u, v in sides])
        got_v, got_f = boxes(centers[0] if n == 1 else centers, sizes, yaw, bottom=bottom)
        assert np.array_equal(got_v, want_v) and np.array_equal(got_f, want_f)
