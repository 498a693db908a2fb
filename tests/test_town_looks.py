"""Towns that differ in looks, class by class (issue 25 item 5: the city shift).

A segmentation network trained in one town carries over to another as far as
the two share each class's look. ``class_albedo`` measures that look (mean
albedo per class over the static world); these tests hold the towns apart by
it: the paper's city pair (T01 -> T07) in every class the farmland shares with
the old town, and every pair of kerbed towns in their street furniture.
"""

from __future__ import annotations

from dataclasses import replace
from itertools import combinations

import numpy as np
import pytest

from domains.catalog import class_id, town as town_row
from render_workers.worlds import world as W
from render_workers.worlds.styles import FURNITURES, STYLES, look, style

SHARED = ("road", "vegetation", "terrain", "pole", "traffic sign", "traffic light", "fence")
FURNITURE = ("pole", "traffic light")


def distance(a, b) -> float:
    return float(np.linalg.norm(np.asarray(a, float) - np.asarray(b, float)))


@pytest.fixture(scope="module")
def albedo(procedural_worlds):
    return {code: W.class_albedo(procedural_worlds[code]) for code in ("T01", "T03", "T06", "T07")}


def test_the_farmland_looks_unlike_the_old_town_in_every_shared_class(albedo):
    """Road, plants, ground and furniture of T07 are at least 40 sRGB levels away from T01's."""
    old, farm = albedo["T01"], albedo["T07"]
    for name in SHARED:
        c = class_id(name)
        assert c in old and c in farm, name
        assert distance(old[c], farm[c]) > 40.0, (name, old[c], farm[c])
    # the farmland's plants are autumn gold, not green: red at least green, the old town's well below it
    veg = class_id("vegetation")
    assert farm[veg][0] >= farm[veg][1] and old[veg][0] < 0.8 * old[veg][1]


def test_kerbed_towns_keep_their_own_street_furniture(albedo):
    """Poles and signal heads wear each style's furniture row: no two of the measured towns share them."""
    for a, b in combinations(sorted(albedo), 2):
        gaps = [distance(albedo[a][class_id(n)], albedo[b][class_id(n)]) for n in FURNITURE]
        assert max(gaps) > 30.0, (a, b, gaps)


def test_class_albedo_follows_the_furniture_row():
    """The statistic sees a style change: the old town built with the farm's furniture has its timber poles."""
    from render_workers.worlds.builder import Kit
    from render_workers.worlds.scene import World
    from render_workers.worlds.town_plan import plan

    def poles(furniture: str) -> np.ndarray:
        kit = Kit(plan(town_row("T01"), 0))
        kit.style = replace(kit.style, furniture=furniture)
        kit.traffic_light(np.array([0.0, 0.0, 0.0]), 0.0, arm=4.0)
        world = World(town="T01", seed=0, static=kit.batch.parts(), lanes=(), walkways=(), bounds=(0, 0, 1, 1))
        return W.class_albedo(world)[class_id("pole")]

    timber = next(f for f in FURNITURES if f.name == "timber and stone")
    steel = look(town_row("T01")).props
    assert np.allclose(poles("timber and stone"), timber.pole, atol=12)
    assert np.allclose(poles(steel.name), steel.pole, atol=12)


def test_every_style_names_a_furniture_row_and_unknown_ones_are_rejected():
    names = {f.name for f in FURNITURES}
    assert len(names) == len(FURNITURES)
    assert {s.furniture for s in STYLES} <= names
    assert look(town_row("T07")).props.name == "timber and stone"
    assert all(len(f.signs) == len(f.fences) == len(f.walls) == 4 for f in FURNITURES)  # one draw per piece, any row
    with pytest.raises(ValueError, match="unknown furniture 'chrome'; valid furnitures: steel and enamel"):
        replace(style("farmland"), furniture="chrome")
    with pytest.raises(ValueError, match="unknown surface 'kudzu'"):
        replace(style("farmland"), hedge="kudzu")


def test_the_farmland_is_in_late_autumn_no_green_crown_hedge_or_verge_left():
    """Every tree crown, hedge and verge of the farmland is rust, straw, russet, bare twigs or leaf litter
    (red well above green), where the old town's are green, and its trunks are pale grey, not brown: a network
    that learned the old town's plants and verges does not find them there."""
    from render_workers.worlds.styles import surface

    farm, old = look(town_row("T07")), look(town_row("T01"))
    for name in (*farm.canopies, farm.hedge, farm.verge):
        r, g, _ = surface(name).color
        assert r >= 1.15 * g, name
    for name in (*old.canopies, old.hedge, old.verge):
        r, g, _ = surface(name).color
        assert g > r, name
    assert distance(surface(farm.bark).color, surface(old.bark).color) > 60.0


def _street_world(code: str, **style_change):
    from render_workers.worlds import streets
    from render_workers.worlds.builder import Kit
    from render_workers.worlds.scene import World
    from render_workers.worlds.town_plan import plan

    kit = Kit(plan(town_row(code), 0))
    kit.style = replace(kit.style, **style_change)
    streets.streets(kit)
    tracks = streets.track_segments(kit)
    return tracks, W.class_albedo(World(town=code, seed=0, static=kit.batch.parts(), lanes=(), walkways=(),
                                        bounds=(0, 0, 1, 1)))


def test_the_farmland_has_unpaved_farm_tracks_with_a_grass_crown():
    """About the style's share of the farmland's street segments are gravel tracks (road) with a grass crown
    (terrain) and ruts; the kerbed towns' streets are all paved, and so are the farmland's without the share."""
    from render_workers.worlds.styles import surface

    farm = look(town_row("T07"))
    tracks, albedo = _street_world("T07")
    lay = W.layout("T07", 0)
    segments = len(lay.xs) * (len(lay.ys) - 1) + len(lay.ys) * (len(lay.xs) - 1)
    assert 0.5 * farm.track_share < len(tracks) / segments < 1.5 * farm.track_share
    assert class_id("terrain") in albedo  # the crowns
    paved_tracks, paved = _street_world("T07", track="", track_share=0.0)
    assert not paved_tracks and class_id("terrain") not in paved
    road = class_id("road")
    track = np.array(surface(farm.track).color, float)
    assert distance(albedo[road], track) < distance(paved[road], track) - 5.0
    assert not _street_world("T01")[0]
    with pytest.raises(ValueError, match="track_share must be in"):
        replace(farm, track="")
