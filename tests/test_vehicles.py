"""Vehicles as a camera behind them sees them: red tail lamps, a light plate, and a dark underbody where
the road used to show through under the car (issue 34: cars were the class real frames missed most)."""

from __future__ import annotations

import numpy as np
import pytest

from domains.catalog import class_id, viewpoint, weather
from render_workers.render.renderer import Renderer
from render_workers.worlds.actors import VEHICLE_KINDS, _vehicle_geometry, vehicle_parts
from render_workers.worlds.scene import Actor, EpisodeScene, Path
from tests.test_renderer import flat_scene

W, H = 320, 180
GREY = (130, 130, 135)  # a paint neither red nor bright: what is red or bright on the car is a lamp or the plate


@pytest.fixture(scope="module")
def behind():
    """A grey sedan 7 m ahead of viewpoint V's camera, its rear to the camera, under ClearNoon:
    (rgb, class ids, planar depth)."""
    lane = Path(np.array([[0.0, 0.0, 0.0], [100.0, 0.0, 0.0]]))
    base = flat_scene()
    car = Actor("sedan", vehicle_parts("sedan", GREY), lane, 7.0 + VEHICLE_KINDS["sedan"].length / 2, 0.0)
    scene = EpisodeScene(world=base.world, actors=(car,), ego=base.ego, n_vehicles=1, n_pedestrians=0)
    with Renderer() as r:
        r.load(scene, weather("CN"), viewpoint("V"), W, H)
        buffers = r.render(0.0).buffers
    return buffers["rgb"].astype(int), buffers["classes"], buffers["depth"]


def test_a_car_from_behind_shows_red_tail_lamps_and_a_light_plate(behind):
    rgb, classes, _ = behind
    car = classes == class_id("vehicle")
    assert car.sum() > 500, "the car is not in view"
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    red = car & (r > 90) & (r > 2 * g) & (r > 2 * b)
    paint = np.median(rgb[car].min(axis=-1))  # the body's, lit as the rear is
    bright = car & (rgb.min(axis=-1) > paint + 25)
    assert red.sum() >= 10, f"{red.sum()} red pixels on the car: no tail lamps"
    assert bright.sum() >= 6, f"{bright.sum()} bright pixels on the car: no plate"
    cols = np.nonzero(red.any(axis=0))[0]  # one lamp at each side of the car's centre column
    centre = np.nonzero(car.any(axis=0))[0].mean()
    assert cols.min() < centre < cols.max()


def test_under_a_car_is_its_dark_underbody_not_the_road(behind):
    rgb, classes, depth = behind
    car = classes == class_id("vehicle")
    rows = np.nonzero(car.any(axis=1))[0]
    bottom = rows.max()  # the car's lowest rows, between its wheels, are the underbody's
    cols = np.nonzero(car[bottom - 2])[0]
    middle = slice(int(np.percentile(cols, 35)), int(np.percentile(cols, 65)) + 1)
    assert car[bottom - 2, middle].all(), "the road shows through under the car"
    assert rgb[bottom - 2, middle].mean() < 60


@pytest.mark.parametrize("name", sorted(VEHICLE_KINDS))
def test_every_kind_keeps_its_size_and_a_sedan_cabin_slopes(name):
    """What is added stays within the body and its bumpers (the kind's length plus 3 cm a side), and
    a sedan's glass narrows to its roof while a bus's stays upright."""
    kind = VEHICLE_KINDS[name]
    geometry = _vehicle_geometry(name)
    vertices = np.concatenate([v for v, _ in geometry])
    assert vertices[:, 0].max() <= kind.length / 2 + 0.03 + 1e-9 and vertices[:, 0].min() >= -kind.length / 2 - 0.03 - 1e-9
    assert np.abs(vertices[:, 1]).max() <= kind.width / 2 + 0.01  # the wheels stand out 5 mm and vertices[:, 2].max() <= kind.height + 1e-9
    glass = geometry[1][0]
    top, bottom = glass[:, 2].max(), glass[:, 2].min()
    span = {z: np.ptp(glass[np.isclose(glass[:, 2], z), 0]) for z in (top, bottom)}
    if name == "sedan":
        assert span[top] < 0.7 * span[bottom]
    if name == "bus":
        assert span[top] == pytest.approx(span[bottom])
