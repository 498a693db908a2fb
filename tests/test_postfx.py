"""Post effects on a small synthetic frame: each does what it says, only where
and when it should, and the chain is deterministic."""

import numpy as np
import pytest

from domains.catalog import class_id, weather
from render_workers.render import postfx
from render_workers.render.camera import camera_rig

W, H = 96, 54
ROAD, SKY, BUILDING = class_id("road"), class_id("sky"), class_id("building")


def context(weather_code="CN", speed=10.0, sun=None, seed=0):
    classes = np.full((H, W), SKY, np.uint8)
    classes[H // 2 :, :] = ROAD
    classes[H // 4 : H // 2, W // 3 : W // 2] = BUILDING
    depth = np.full((H, W), 1000.0, np.float32)
    rows = np.arange(H // 2, H)
    depth[H // 2 :, :] = (4.0 * H / (rows - H / 2 + 0.5))[:, None].astype(np.float32)
    depth[H // 4 : H // 2, W // 3 : W // 2] = 30.0
    rig = camera_rig("V", W, H)
    return postfx.FxContext(
        depth=depth, classes=classes, hood_mask=np.zeros((H, W), bool), rig=rig,
        world_from_camera=rig.world_from_camera(np.eye(4)), weather=weather(weather_code),
        ego_speed_mps=speed, sun_pixel=sun, rng=np.random.default_rng(seed), episode_seed=seed,
    )


def image():
    rng = np.random.default_rng(1)
    return rng.uniform(0.2, 0.6, (H, W, 3)).astype(np.float32)


def test_grading_warms_the_sunset_and_leaves_noon():
    img = image()
    assert np.array_equal(postfx.grading(img, context("CN")), img)
    graded = postfx.grading(img, context("CS"))
    assert graded[..., 0].mean() > img[..., 0].mean() and graded[..., 2].mean() < img[..., 2].mean()


def test_bloom_spreads_only_from_bright_areas():
    dark = np.full((H, W, 3), 0.3, np.float32)
    assert np.array_equal(postfx.bloom(dark, context()), dark)
    bright = dark.copy()
    bright[20:24, 40:44] = 1.0
    out = postfx.bloom(bright, context())
    assert out[22, 50].mean() > dark[22, 50].mean()  # glow beside the bright patch
    assert abs(out[2, 2].mean() - 0.3) < 1e-3  # far corner untouched


def test_lens_flare_needs_the_sun_in_view():
    img = image()
    assert np.array_equal(postfx.lens_flare(img, context("CS", sun=None)), img)
    flared = postfx.lens_flare(img, context("CS", sun=(10.0, 5.0)))
    assert flared.sum() > img.sum()


def test_motion_blur_grows_with_speed_and_spares_a_parked_car():
    img = image()
    assert np.array_equal(postfx.motion_blur(img, context(speed=0.0)), img)
    slow = np.abs(postfx.motion_blur(img, context(speed=5.0)) - img).mean()
    fast = np.abs(postfx.motion_blur(img, context(speed=20.0)) - img).mean()
    assert fast > slow > 0


def test_motion_blur_equals_all_five_samples_warped():
    """The blur's first sample (zoom 1) is taken as it is, not warped: the same values as warping
    it too, as the blur was written (a sum of five warps from zero), at a frame's real size."""
    import cv2

    h, w = 216, 384
    rng = np.random.default_rng(5)
    img = rng.uniform(0.0, 1.0, (h, w, 3)).astype(np.float32)
    ctx = context(speed=14.0)
    rig = camera_rig("V", w, h)
    depth = rng.uniform(0.5, 80.0, (h, w)).astype(np.float32)
    ctx = postfx.FxContext(**{**ctx.__dict__, "depth": depth, "classes": np.zeros((h, w), np.uint8),
                              "hood_mask": np.zeros((h, w), bool), "rig": rig})
    travel = 14.0 * postfx.EXPOSURE_S
    zoom = min(0.08, travel / postfx.BLUR_REF_M)
    small = cv2.resize(img, (w // 2, h // 2), interpolation=cv2.INTER_AREA)
    acc = np.zeros_like(small)
    for k in range(5):
        s = 1.0 - zoom * k / 4
        m = np.array([[s, 0, (1 - s) * rig.cx / 2], [0, s, (1 - s) * rig.cy / 2]], np.float32)
        acc += cv2.warpAffine(small, m, (w // 2, h // 2), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                              borderMode=cv2.BORDER_REFLECT)
    blurred = cv2.resize(acc * np.float32(0.2), (w, h), interpolation=cv2.INTER_LINEAR)
    weight = cv2.min(cv2.divide(float(travel / zoom), cv2.max(depth, 0.1)), 1.0)
    expected = cv2.blendLinear(img, blurred, 1.0 - weight, weight)
    assert np.array_equal(postfx.motion_blur(img, ctx), expected)


def test_rain_and_wet_road_only_in_hard_rain():
    img = image()
    for name in ("rain", "wet_road", "puddles"):
        assert np.array_equal(postfx.EFFECTS[name](img, context("CN")), img), name
    rainy = postfx.rain(img, context("HRN"))
    assert not np.array_equal(rainy, img)
    wet = postfx.wet_road(img, context("HRN"))
    road = context().classes == ROAD
    assert not np.allclose(wet[road], img[road])  # the road looks different when wet
    assert np.allclose(wet[~road], img[~road], atol=1e-4)  # elsewhere only float rounding


def test_fog_pulls_far_pixels_towards_the_horizon_colour():
    img = image()
    foggy = postfx.fog(img, context("HRN"))
    horizon = np.asarray(weather("HRN").sky_horizon, np.float32) / 255
    far, near = (0, 0), (H - 1, W // 2)
    assert np.abs(foggy[far] - horizon).sum() < np.abs(img[far] - horizon).sum()
    assert np.abs(foggy[near] - img[near]).sum() < np.abs(foggy[far] - img[far]).sum()


def test_fog_keeps_its_horizon_image_for_the_next_frame_unchanged():
    """The horizon colour's image is filled once per size and colour and shared, read-only: fog on
    frames of one weather, another and the first again gives what a fresh fill gives each time."""
    import cv2

    img = image()

    def fresh(code):
        horizon = np.asarray(weather(code).sky_horizon, np.float32) / 255
        transmittance = cv2.exp(context(code).depth * np.float32(-postfx.extinction(weather(code).visibility_m)))
        return postfx._lerp(np.ascontiguousarray(np.broadcast_to(horizon, img.shape)), img, transmittance)

    for code in ("HRN", "CS", "HRN", "CS"):
        assert np.array_equal(postfx.fog(img, context(code)), fresh(code)), code
    horizon = np.asarray(weather("HRN").sky_horizon, np.float32) / 255
    flat = postfx._flat(img.shape, horizon)
    assert not flat.flags.writeable and flat is postfx._flat(img.shape, horizon)


def test_antialias_touches_only_geometry_edges():
    import cv2

    img = image()
    before = img.copy()
    out = postfx.antialias(img, context())
    assert np.array_equal(img, before)  # a new image; the input stays as it was
    changed = np.any(out != img, axis=2)
    assert changed.any()
    assert np.array_equal(out[changed], cv2.blur(img, (3, 3))[changed])  # edges: the 3x3 box blur
    assert not changed[5:10, 5:20].any()  # inside the sky, far from any edge
    assert changed[H // 4 + 2, W // 3 - 1] or changed[H // 4 + 2, W // 3]  # the building's left edge


def test_chain_is_deterministic_and_registry_checked():
    frame = (image() * 255).astype(np.uint8)
    a = postfx.apply(frame, context("HRN", seed=3))
    b = postfx.apply(frame, context("HRN", seed=3))
    c = postfx.apply(frame, context("HRN", seed=4))
    assert a.dtype == np.uint8 and np.array_equal(a, b) and not np.array_equal(a, c)
    with pytest.raises(ValueError, match="antialias"):
        postfx.apply(frame, context(), order=("sparkles",))


def _saturation(img):
    return float((img.max(axis=2) - img.min(axis=2)).mean())


def camera(seed, share=1.0):
    """A context whose weather asks for a real camera's look (``camera``, opt-in)."""
    from dataclasses import replace

    ctx = context(seed=seed)
    return replace(ctx, weather=replace(ctx.weather, camera=share))


def test_camera_look_is_opt_in_and_blends_by_its_share():
    img = image()
    for effect in (postfx.tone, postfx.sensor):
        ctx = context(seed=1)
        assert effect(img, ctx) is img  # built-in weathers: the frame as before
        assert np.array_equal(ctx.rng.random(3), np.random.default_rng(1).random(3))  # no draw taken either
        full, half = effect(img, camera(1)), effect(img, camera(1, 0.5))
        assert np.allclose(half, 0.5 * img + 0.5 * full, atol=1e-5)


def test_tone_mutes_colour_and_compresses_highlights_like_a_camera():
    vivid = np.zeros((H, W, 3), np.float32)
    vivid[..., 0], vivid[..., 1] = 0.9, 0.2  # saturated orange
    vivid[:4] = 1.0  # a white sky row
    out = postfx.tone(vivid, camera(1))
    assert _saturation(out[4:]) < 0.6 * _saturation(vivid[4:])  # muted colour
    assert out.min() >= 0.0 and out.max() <= 1.0
    again = postfx.tone(vivid, camera(1))
    other = postfx.tone(vivid, camera(2))
    assert np.array_equal(out, again) and not np.array_equal(out, other)  # exposure and white balance per episode


def test_sensor_darkens_corners_adds_grain_and_keeps_the_middle():
    flat = np.full((H, W, 3), 0.5, np.float32)
    out = postfx.sensor(flat, camera(1))
    assert out[:4, :4].mean() < out[H // 2 - 2: H // 2 + 2, W // 2 - 2: W // 2 + 2].mean()  # vignetting
    assert out[H // 3: 2 * H // 3, W // 3: 2 * W // 3].std() > 0.003  # noise survives the JPEG round trip
    assert abs(out[H // 3: 2 * H // 3, W // 3: 2 * W // 3].mean() - 0.5) < 0.03  # no shift in the middle
    assert np.array_equal(out, postfx.sensor(flat, camera(1)))


def test_randomize_is_opt_in_and_recolours_each_class_once_per_episode():
    from dataclasses import replace

    img = np.full((H, W, 3), 0.5, np.float32)
    assert np.array_equal(postfx.randomize(img, context()), img)  # the built-in weathers leave it off

    def recoloured(seed):
        ctx = context(seed=seed)
        return postfx.randomize(img, replace(ctx, weather=replace(ctx.weather, randomize=1.0))), ctx.classes

    out, classes = recoloured(seed=3)
    for cls in np.unique(classes):  # one colour per class: the structure stays
        assert np.ptp(out[classes == cls], axis=0).max() == 0.0
    sky, road = out[classes == SKY][0], out[classes == ROAD][0]
    assert not np.allclose(sky, road) and not np.allclose(sky, 0.5)
    assert np.array_equal(recoloured(seed=3)[0], out) and not np.array_equal(recoloured(seed=4)[0], out)


def test_randomize_above_1_spreads_the_colours_wider():
    """``randomize`` is the spread of the gains: 1 within 1 +- 0.45 per channel (times a level within
    1 +- 0.3), up to 2 (1 +- 0.9 and 1 +- 0.6; at 1.8 a CamVid network kept the most, docs/realism.md)."""
    from dataclasses import replace

    img = np.full((H, W, 3), 0.5, np.float32)

    def spread(strength):
        gains = []
        for seed in range(40):
            ctx = context(seed=seed)
            out = postfx.randomize(img, replace(ctx, weather=replace(ctx.weather, randomize=strength)))
            gains.append(out[ctx.classes == SKY][0] / 0.5)
        return np.ptp(np.array(gains), axis=0).min(), np.array(gains).min()

    one, two = spread(1.0), spread(2.0)
    assert two[0] > 1.5 * one[0]  # about twice as wide
    assert one[1] > 0.3 and 0.0 <= two[1] < 0.3  # darker colours come in; clipped at 0, never negative


def test_frame_looks_draw_the_camera_and_colours_anew_for_their_share_of_frames():
    """Issue 34: a look drawn per frame taught a CamVid network more than one per episode (docs/realism.md).
    At 0 (every built-in weather) every frame of an episode gets the episode's look; at 1 each frame its own,
    the same on every render; in between, that share of frames."""
    from dataclasses import replace

    img = image()

    def looks(share, frame, seed=3):
        ctx = context(seed=seed)
        ctx = replace(ctx, frame=frame, weather=replace(ctx.weather, camera=1.0, randomize=1.0, frame_looks=share))
        return postfx.tone(img, ctx), postfx.randomize(img, ctx)

    assert context().weather.frame_looks == 0.0
    for effect in range(2):
        episode = looks(0.0, 0)[effect]
        assert all(np.array_equal(looks(0.0, f)[effect], episode) for f in (1, 7))  # one look per episode
        own = [looks(1.0, f)[effect] for f in (0, 1, 7)]
        assert not any(np.array_equal(a, b) for i, a in enumerate(own) for b in own[i + 1:])  # each frame its own
        assert np.array_equal(looks(1.0, 7)[effect], own[2])  # and the same on every render
        assert not np.array_equal(looks(1.0, 7, seed=4)[effect], own[2])
        kept = sum(np.array_equal(looks(0.5, f)[effect], episode) for f in range(40))
        assert 8 <= kept <= 32  # about half the frames keep the episode's look
