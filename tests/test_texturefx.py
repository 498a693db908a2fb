"""The opt-in surface and light levers of issue 34 (random textures per class, leaf clusters on tree crowns,
ambient occlusion): off they leave a frame's bytes alone and draw nothing; on they do what they say, only
where they should, anchored on the world, and the same in two processes."""

import hashlib
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest

from domains.catalog import class_id
from render_workers.render import postfx, texturefx
from tests.test_postfx import BUILDING, H, ROAD, SKY, W, context

VEGETATION = class_id("vegetation")


def scene(seed=0, **levers):
    """The test frame of test_postfx with a tree crown (vegetation at 6 m) in front of the building."""
    ctx = context(seed=seed)
    classes, depth = ctx.classes.copy(), ctx.depth.copy()
    classes[H // 8: H // 2, 2: W // 3 + 4] = VEGETATION  # partly in front of the building (30 m)
    depth[H // 8: H // 2, 2: W // 3 + 4] = 6.0
    return replace(ctx, classes=classes, depth=depth, weather=replace(ctx.weather, **levers))


def grey():
    return np.full((H, W, 3), 0.5, np.float32)


LEVERS = {"textures": "retexture", "foliage": "foliage", "occlusion": "occlusion",  # weather parameter: effect
          "reflections": "reflections"}


@pytest.mark.parametrize("lever", sorted(LEVERS))
def test_a_lever_at_zero_is_a_no_op_that_draws_nothing(lever):
    ctx = scene()
    state = ctx.rng.bit_generator.state
    img = np.random.default_rng(2).uniform(0.1, 0.9, (H, W, 3)).astype(np.float32)
    assert getattr(ctx.weather, lever) == 0.0  # the built-in weathers leave it off
    assert np.array_equal(postfx.EFFECTS[LEVERS[lever]](img, ctx), img)
    assert ctx.rng.bit_generator.state == state
    rgb = (img * 255).astype(np.uint8)  # and the whole chain keeps the frame's bytes
    assert np.array_equal(postfx.apply(rgb, ctx, order=(LEVERS[lever],)), rgb)


def test_textures_pattern_every_class_per_episode_and_keep_the_hood():
    ctx = scene(seed=3, textures=1.0)
    hood = np.zeros((H, W), bool)
    hood[-4:, :] = True
    out = texturefx.retexture(grey(), replace(ctx, hood_mask=hood))
    assert np.array_equal(out[hood], grey()[hood])  # the ego's paint is no surface of the world
    for cls in (SKY, ROAD, VEGETATION):  # a pattern inside each class, not one flat colour
        assert out[(ctx.classes == cls) & ~hood].std(axis=0).max() > 0.002, cls
    again = texturefx.retexture(grey(), replace(ctx, hood_mask=hood, rng=np.random.default_rng(99)))
    assert np.array_equal(again, out)  # one pattern per episode: not drawn from the frame's rng
    other = texturefx.retexture(grey(), replace(scene(seed=4, textures=1.0), hood_mask=hood))
    assert not np.array_equal(other, out)


def test_textures_stay_on_the_world_when_the_camera_moves():
    """The camera moved sideways by one pixel's footprint on the building's wall (30 m): each wall pixel
    now shows what its right-hand neighbour showed, pattern included."""
    ctx = scene(seed=5, textures=1.0)
    a = texturefx.retexture(grey(), ctx)
    moved = ctx.world_from_camera.copy()
    moved[:3, 3] += moved[:3, 0] * (30.0 / ctx.rig.focal_px)
    b = texturefx.retexture(grey(), replace(ctx, world_from_camera=moved))
    wall = ctx.classes == BUILDING
    both = wall[:, :-1] & wall[:, 1:]
    assert a[:, :-1][both].std() > 0.005  # there is a pattern to follow
    np.testing.assert_allclose(b[:, :-1][both], a[:, 1:][both], atol=2e-3)


def test_foliage_puts_clusters_and_gaps_on_tree_crowns_only():
    ctx = scene(seed=1, foliage=1.0)
    out = texturefx.foliage(grey(), ctx)
    veg = ctx.classes == VEGETATION
    assert np.array_equal(out[~veg], grey()[~veg])
    shade = out[veg][:, 0] / 0.5
    assert shade.min() < 0.6 and shade.max() > 1.1  # dark gaps and lit clusters
    assert np.array_equal(texturefx.foliage(grey(), replace(ctx, rng=np.random.default_rng(7))), out)


def test_occlusion_darkens_what_nearer_things_surround_and_leaves_planes():
    ctx = scene(occlusion=1.0)
    out = postfx.occlusion(grey(), ctx)
    assert np.array_equal(out[ctx.classes == SKY], grey()[ctx.classes == SKY])
    # the building (30 m) right beside the tree crown (6 m) is darkened; the open road far below it is not
    beside = out[H // 4: H // 2, W // 3 + 4: W // 3 + 6, 0]
    assert (ctx.classes[H // 4: H // 2, W // 3 + 4: W // 3 + 6] == BUILDING).all()
    assert beside.max() < 0.45
    road = out[H - 8:, W // 2:, 0]
    assert np.abs(road - 0.5).max() < 0.02  # a plane's disparity is affine: its local mean is itself


VEHICLE = class_id("vehicle")
CAR_Z, CAR_ROOF_M, CAR_LENGTH = 8.0, 1.45, 4.5  # a car ahead: its rear face this far, this tall, then its roof


def car_ahead(seed=0, **levers):
    """The tree crown's scene with a car ahead in the middle: its vertical rear face at CAR_Z from the
    road up to CAR_ROOF_M, and its flat roof (seen at a grazing angle from viewpoint V's 2.1 m) behind."""
    ctx = scene(seed=seed, **levers)
    classes, depth = ctx.classes.copy(), ctx.depth.copy()
    f, cy, eye = ctx.rig.focal_px, ctx.rig.cy, ctx.rig.viewpoint.camera_height_m
    row = lambda height, z: int(round(cy + f * (eye - height) / z - 0.5))  # noqa: E731
    cols = slice(W // 2, W // 2 + 14)
    face = slice(row(CAR_ROOF_M, CAR_Z) + 1, row(0.3, CAR_Z) + 1)
    classes[face, cols], depth[face, cols] = VEHICLE, CAR_Z
    roof = np.arange(row(CAR_ROOF_M, CAR_Z + CAR_LENGTH), face.start)
    classes[roof, cols] = VEHICLE
    depth[roof, cols] = (f * (eye - CAR_ROOF_M) / (roof + 0.5 - cy))[:, None]
    return replace(ctx, classes=classes, depth=depth)


def test_reflections_mirror_the_street_on_vehicles_only():
    ctx = car_ahead(seed=2, reflections=1.0)
    out = texturefx.reflections(grey(), ctx)
    car = ctx.classes == VEHICLE
    assert np.array_equal(out[~car], grey()[~car])
    rows = np.flatnonzero(car.any(axis=1))
    face = rows[ctx.depth[rows, W // 2] == CAR_Z]
    roof = rows[ctx.depth[rows, W // 2] > CAR_Z]
    assert len(face) >= 6 and len(roof) >= 2
    light = out[:, W // 2: W // 2 + 14].mean(axis=(1, 2))
    # the rear face mirrors the sky above its shoulder line and the road below; the roof, seen at a grazing
    # angle, mirrors most (Fresnel)
    assert light[face[:2]].mean() > 0.5 > light[face[-2:]].mean() + 0.05
    assert np.abs(light[roof] - 0.5).mean() > 2 * np.abs(light[face] - 0.5).mean()
    assert np.array_equal(texturefx.reflections(grey(), replace(ctx, rng=np.random.default_rng(5))), out)
    hood = np.zeros((H, W), bool)
    hood[face[-3]:, :] = True  # the ego's hood over the car's bottom rows: it keeps its paint
    hooded = texturefx.reflections(grey(), replace(ctx, hood_mask=hood))
    assert np.array_equal(hooded[hood], grey()[hood]) and np.array_equal(hooded[~hood], out[~hood])


def test_reflections_read_the_normals_the_whole_frame_gives():
    """The normals are computed around each car only: the same values as over the whole frame, cars at the
    image's edges and cars that touch one another included. The cars' sides curve away from the camera (depth
    quadratic across the columns), so a normal's x and a box's edge both matter."""
    from outputs.geometry import normals_from_depth

    ctx = car_ahead(seed=4)
    classes, depth = ctx.classes.copy(), ctx.depth.copy()
    for rows, cols, z in ((slice(30, H), slice(0, 9), 3.0), (slice(26, 33), slice(W - 7, W), 12.0),
                          (slice(28, 31), slice(W // 2 + 13, W // 2 + 20), 7.5), (slice(29, 33), slice(30, 37), 9.0)):
        classes[rows, cols] = VEHICLE
        side = np.arange(cols.stop - cols.start, dtype=np.float32)
        depth[rows, cols] = z + 0.03 * side[None, :] ** 2
    # the last car leans back too, and beside it what is not a car lies nearly at its depth: the whole
    # frame's normals read that
    depth[29:33, 30:37] += 0.05 * np.arange(4, dtype=np.float32)[:, None]
    depth[29:33, 29] = depth[29:33, 30] - 0.001
    depth[28, 30:37] = depth[29, 30:37] - 0.001
    ctx = replace(ctx, classes=classes, depth=depth)
    car = classes == VEHICLE
    np.testing.assert_array_equal(texturefx._normals_within(ctx, car), normals_from_depth(depth, ctx.rig.K)[car])


def test_reflections_above_one_mirror_more_and_stay_in_range():
    one = texturefx.reflections(grey(), car_ahead(seed=2, reflections=1.0))
    two = texturefx.reflections(grey(), car_ahead(seed=2, reflections=2.0))
    assert np.abs(two - 0.5).sum() > 1.5 * np.abs(one - 0.5).sum()
    assert two.min() >= 0.0 and two.max() <= 1.0


CHILD = """
import hashlib, sys

import numpy as np
from tests.test_texturefx import car_ahead
from render_workers.render import postfx
ctx = car_ahead(seed=11, textures=1.0, foliage=1.0, occlusion=1.0, reflections=1.0)
rgb = (np.random.default_rng(2).uniform(0.1, 0.9, (ctx.rig.height, ctx.rig.width, 3)) * 255).astype(np.uint8)
print(hashlib.sha256(postfx.apply(rgb, ctx).tobytes()).hexdigest())
"""


def test_the_levers_give_the_same_bytes_in_two_processes():
    got = {subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True, check=True).stdout.strip()
           for _ in range(2)}
    assert len(got) == 1 and len(got.pop()) == 64
