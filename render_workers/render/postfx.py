"""RGB post effects: a registry of cheap, vectorised, deterministic image operations.

Each effect takes a float32 HxWx3 image in [0, 1] (sRGB) and an :class:`FxContext`
(the frame's depth, classes, camera, weather, ego speed and rng) and returns a
new image. :data:`ORDER` applies them scene first (puddles, wet road, fog), then
atmosphere (rain), then lens and camera (bloom, flare, motion blur), then the
weather's colour grading, the opt-in per-episode class textures (``retexture``, in
``render_workers.render.texturefx``) and colours (``randomize``),
and last a real camera's look (issue 34): ``tone`` (exposure and white balance
per episode, a filmic curve, muted colour) and ``sensor`` (vignetting, lens
blur, chromatic aberration, noise, JPEG-like compression). An effect whose weather strength is zero is a no-op. Snow cover,
night lights and snowfall live in ``render_workers.render.weatherfx``.

Randomness comes only from ``FxContext.rng`` (per frame) and
``FxContext.episode_seed`` (world-anchored puddles), so a frame is reproducible.
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from domains.catalog import Weather, class_id
from domains.fog import extinction
from render_workers.render import texturefx, weatherfx
from render_workers.render.camera import CameraRig
from render_workers.worlds.scene import World

ROAD_IDS = np.array([class_id("road"), class_id("road line")])
WET_IDS = np.array([class_id("road"), class_id("road line"), class_id("sidewalk")])
SKY_ID = class_id("sky")
EXPOSURE_S = 1.0 / 30.0  # shutter time for motion blur
BLUR_REF_M = 3.0  # objects this close get the full radial blur
BLOOM_THRESHOLD = 0.72


@dataclass(frozen=True, eq=False)
class FxContext:
    """Everything an effect may read besides the image."""

    depth: np.ndarray  # HxW float32 planar metres (sky = 1000)
    classes: np.ndarray  # HxW uint8 class ids
    hood_mask: np.ndarray  # HxW bool
    rig: CameraRig
    world_from_camera: np.ndarray  # 4x4
    weather: Weather
    ego_speed_mps: float
    sun_pixel: tuple[float, float] | None
    rng: np.random.Generator  # per-frame randomness (rain streaks)
    episode_seed: int  # world-anchored patterns (puddles) stay put between frames
    world: World | None = None  # the static world (its street lamps' luminaires, its lanes' wheel tracks)
    frame: int = 0  # the frame's index in its episode (the looks a weather draws per frame: _look_rng)


Effect = Callable[[np.ndarray, FxContext], np.ndarray]


def _resize(image: np.ndarray, width: int, height: int) -> np.ndarray:
    import cv2

    interp = cv2.INTER_AREA if width < image.shape[1] else cv2.INTER_LINEAR
    return cv2.resize(image, (width, height), interpolation=interp)


@functools.lru_cache(maxsize=2)
def _flat_cached(size: tuple[int, int], colour: tuple) -> np.ndarray:
    import cv2

    flat = cv2.merge([np.full(size, np.float32(c), np.float32) for c in colour])
    flat.flags.writeable = False  # shared by every frame of the size and colour
    return flat


def _flat(shape: tuple, colour) -> np.ndarray:
    """An HxWx3 float32 image of one colour, read-only: kept for the next frame of the same size and colour
    (fog's horizon colour is the weather's: 3-5 ms per full-HD frame to fill again)."""
    return _flat_cached(tuple(shape[:2]), tuple(np.asarray(colour, np.float32).tolist()))


def _add_scaled(img: np.ndarray, layer: np.ndarray, scale: float) -> np.ndarray:
    """img + scale * layer (both HxWx3 float32) in one pass."""
    import cv2

    return cv2.scaleAdd(layer, float(scale), img)


def _class_lut(ids) -> np.ndarray:
    lut = np.zeros(256, dtype=bool)
    lut[np.asarray(ids)] = True
    return lut


_ROAD_LUT = _class_lut(ROAD_IDS)
_WET_LUT = _class_lut(WET_IDS)


def _mirror_rows(height: int, cy: float) -> np.ndarray:
    """Row seen in a flat mirror at each row (about the horizon ``cy`` of a level camera)."""
    return np.clip(np.round(2.0 * cy - np.arange(height) - 1.0), 0, height - 1).astype(np.intp)


def _lerp(a: np.ndarray, b: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """a * (1 - weight) + b * weight with an HxW weight, in one cv2 pass."""
    import cv2

    weight = weight.astype(np.float32, copy=False)
    return cv2.blendLinear(a, b, 1.0 - weight, weight)


def _ground_points(ctx: FxContext, rows: np.ndarray, cols: np.ndarray, z: np.ndarray) -> np.ndarray:
    """World (x, y) of pixels (full-resolution row/col centres) at planar depth ``z``."""
    f = ctx.rig.focal_px
    cam = np.stack([(cols + 0.5 - ctx.rig.cx) / f * z, (ctx.rig.cy - rows - 0.5) / f * z, -z], axis=1)
    return cam @ ctx.world_from_camera[:3, :3].T[:, :2] + ctx.world_from_camera[:2, 3]


def _puddle_waves(seed: int, count: int = 6) -> tuple[np.ndarray, np.ndarray, float]:
    """Random plane waves (metres) whose sum thresholds into puddle shapes."""
    rng = np.random.default_rng([seed, 303])
    angle = rng.uniform(0, 2 * math.pi, count)
    wavelength = rng.uniform(2.5, 9.0, count)
    k = np.stack([np.cos(angle), np.sin(angle)], axis=1) * (2 * math.pi / wavelength)[:, None]
    phase = rng.uniform(0, 2 * math.pi, count)
    return k, phase, math.sqrt(count / 2.0)  # std of a sum of unit sines


def puddles(img: np.ndarray, ctx: FxContext) -> np.ndarray:
    """Mirror the scene about the horizon inside world-anchored puddles on the road.

    The puddle pattern is a thresholded sum of plane waves on the ground (world
    x, y from depth), evaluated at 1/4 resolution and upsampled; the threshold
    makes about ``weather.puddles`` of the road reflective.
    """
    amount = ctx.weather.puddles
    if amount <= 0:
        return img
    import cv2

    h, w = ctx.rig.height, ctx.rig.width
    road = _ROAD_LUT[ctx.classes] & ~ctx.hood_mask & (ctx.depth < 150.0)
    step = 4
    rows, cols = np.nonzero(road[step // 2::step, step // 2::step])
    if rows.size == 0:
        return img
    full_rows, full_cols = rows * step + step // 2, cols * step + step // 2
    k, phase, std = _puddle_waves(ctx.episode_seed)
    xy = _ground_points(ctx, full_rows, full_cols, ctx.depth[full_rows, full_cols].astype(np.float64))
    noise = np.sin(xy @ k.T + phase).sum(axis=1) / std
    small = np.zeros(((h + step - 1 - step // 2) // step, (w + step - 1 - step // 2) // step), np.float32)
    small[rows, cols] = np.clip((noise - _normal_quantile(1.0 - amount)) / 0.35, 0.0, 1.0)
    weight = cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR) * (0.85 * road)
    mirrored = img[_mirror_rows(h, ctx.rig.cy)] * np.float32(0.85)
    return _lerp(img, mirrored, weight)


def _normal_quantile(p: float) -> float:
    """Inverse standard normal CDF (Abramowitz & Stegun 26.2.23, |error| < 4.5e-4)."""
    p = min(max(p, 1e-6), 1 - 1e-6)
    t = math.sqrt(-2.0 * math.log(min(p, 1 - p)))
    q = t - (2.515517 + 0.802853 * t + 0.010328 * t * t) / (1 + 1.432788 * t + 0.189269 * t * t + 0.001308 * t**3)
    return q if p > 0.5 else -q


def wet_road(img: np.ndarray, ctx: FxContext) -> np.ndarray:
    """Darken wet ground and add a blurred mirror sheen, strongest at grazing angles."""
    wet = ctx.weather.wetness
    if wet <= 0:
        return img
    import cv2

    h, w = ctx.rig.height, ctx.rig.width
    mask = _WET_LUT[ctx.classes] & ~ctx.hood_mask
    sw, sh = max(1, w // 4), max(1, h // 4)
    small = _resize(img, sw, sh)[_mirror_rows(sh, ctx.rig.cy * sh / h)]
    sheen = _resize(cv2.GaussianBlur(small, (0, 0), 2.0), w, h)
    below = np.clip((np.arange(h) + 0.5 - ctx.rig.cy) / max(1.0, h - ctx.rig.cy), 0.0, 1.0)
    fresnel = ((0.08 + 0.5 * (1.0 - below) ** 4) * wet).astype(np.float32)  # per row
    darkened = img * (1.0 - np.float32(0.35 * wet) * mask)[..., None]
    return _lerp(darkened, sheen, mask * fresnel[:, None])


def fog(img: np.ndarray, ctx: FxContext) -> np.ndarray:
    """Blend towards the horizon colour with transmittance exp(-beta * depth), beta = ln(20) / visibility
    (domains.fog; a weather declared as a share per km before renders as it did)."""
    beta = extinction(ctx.weather.visibility_m)
    if beta <= 0:
        return img
    import cv2

    transmittance = cv2.exp(ctx.depth * np.float32(-beta))
    return _lerp(_flat(img.shape, np.asarray(ctx.weather.sky_horizon, np.float32) / 255.0), img, transmittance)


def rain(img: np.ndarray, ctx: FxContext) -> np.ndarray:
    """Bright slanted streaks (count and length follow rain and speed) and a grey veil."""
    amount = ctx.weather.rain
    if amount <= 0:
        return img
    import cv2

    h, w = ctx.rig.height, ctx.rig.width
    n = int(amount * w * h / 1800)
    x = ctx.rng.uniform(0, w, n)
    y = ctx.rng.uniform(-0.1 * h, h, n)
    length = ctx.rng.uniform(0.03, 0.09, n) * h * (1.0 + ctx.ego_speed_mps / 20.0)
    slant = 0.12 + ctx.rng.normal(0.0, 0.03, n)
    x1, y1 = x + slant * length, y + length
    lines = np.stack([np.stack([x, y], 1), np.stack([x1, y1], 1)], 1).round().astype(np.int32)
    layer = np.zeros((h, w), np.uint8)
    thickness = max(1, int(round(w / 1400)))
    cv2.polylines(layer, list(lines), False, 255, thickness, cv2.LINE_AA)
    streaks = cv2.GaussianBlur(layer, (0, 0), max(0.6, w / 2400)).astype(np.float32) * (0.22 * amount / 255.0)
    veil = 0.1 * amount
    grey = float(img.mean())
    veiled = cv2.addWeighted(img, 1.0 - veil, img, 0.0, grey * veil)
    return cv2.add(veiled, cv2.merge([streaks, streaks, streaks]))


def bloom(img: np.ndarray, ctx: FxContext) -> np.ndarray:
    """Glow around bright areas: threshold at 1/4 size, blur at two scales, upsample and add back."""
    import cv2

    h, w = img.shape[:2]
    strength = 0.55 * (1.0 - 0.6 * ctx.weather.cloudiness)
    small = _resize(img, max(1, w // 4), max(1, h // 4))
    bright = np.maximum(small - BLOOM_THRESHOLD, 0.0)
    if not bright.any():
        return img
    sigma = max(1.0, w / 400.0)
    sh, sw = bright.shape[:2]
    # the wide glow (4 sigma) is blurred at a further quarter size: same look, 1/16 of the pixels
    wide = cv2.GaussianBlur(_resize(bright, max(1, sw // 4), max(1, sh // 4)), (0, 0), sigma)
    glow = cv2.GaussianBlur(bright, (0, 0), sigma) + _resize(wide, sw, sh)
    return _add_scaled(img, _resize(glow, w, h), strength)


def lens_flare(img: np.ndarray, ctx: FxContext) -> np.ndarray:
    """Halo and ghost discs along the sun-centre line when the sun is in (or near) view."""
    if ctx.sun_pixel is None:
        return img
    import cv2

    h, w = img.shape[:2]
    sx, sy = ctx.sun_pixel
    outside = max(0.0, -sx, sx - w, -sy, sy - h) / (0.15 * w)
    if outside >= 1.0:
        return img
    visibility = 1.0 - outside
    if 0 <= sx < w and 0 <= sy < h:  # how much of the sun's surroundings is open sky
        r = max(2, w // 80)
        patch = ctx.classes[max(0, int(sy) - r): int(sy) + r + 1, max(0, int(sx) - r): int(sx) + r + 1]
        visibility *= float(np.mean(patch == SKY_ID))
    strength = visibility * (1.0 - 0.9 * ctx.weather.cloudiness)
    if strength <= 0.01:
        return img
    scale = 4
    lw, lh = max(1, w // scale), max(1, h // scale)
    layer = np.zeros((lh, lw, 3), np.float32)
    tint = np.asarray(ctx.weather.light_color, np.float32)
    sun = np.array([sx, sy]) / scale
    centre = np.array([lw / 2, lh / 2])
    cv2.circle(layer, tuple(int(v) for v in sun.round()), max(1, lw // 25), tuple(float(c) * 0.9 for c in tint), -1)
    cv2.line(layer, (int(sun[0] - lw * 0.3), int(sun[1])), (int(sun[0] + lw * 0.3), int(sun[1])),
             tuple(float(c) * 0.35 for c in tint), max(1, lh // 200))
    ghosts = ((0.55, 0.035, (0.35, 0.55, 1.0)), (0.85, 0.02, (0.5, 1.0, 0.6)),
              (1.25, 0.05, (1.0, 0.6, 0.3)), (1.6, 0.08, (0.4, 0.4, 1.0)), (1.95, 0.03, (1.0, 0.9, 0.5)))
    for t, radius, colour in ghosts:
        p = sun + (centre - sun) * t
        cv2.circle(layer, tuple(int(v) for v in p.round()), max(1, int(radius * lw)),
                   tuple(0.12 * c for c in colour), -1)
    layer = cv2.GaussianBlur(layer, (0, 0), max(1.0, lw / 200))
    return _add_scaled(img, _resize(layer, w, h), strength)


def motion_blur(img: np.ndarray, ctx: FxContext) -> np.ndarray:
    """Radial blur from the focus of expansion, weighted by speed / depth (hood stays sharp)."""
    if ctx.ego_speed_mps <= 0:
        return img
    import cv2

    h, w = img.shape[:2]
    travel = ctx.ego_speed_mps * EXPOSURE_S  # metres moved during the exposure
    max_zoom = min(0.08, travel / BLUR_REF_M)
    if max_zoom * max(w, h) / 2 < 0.5:  # under half a pixel at the image corners
        return img
    sw, sh = max(1, w // 2), max(1, h // 2)
    small = _resize(img, sw, sh)
    cx, cy = ctx.rig.cx / 2, ctx.rig.cy / 2
    steps = 5
    acc = small.copy()  # k = 0 samples at the pixel itself: that warp gives ``small`` exactly
    for k in range(1, steps):
        s = 1.0 - max_zoom * k / (steps - 1)  # sample towards the focus of expansion
        m = np.array([[s, 0, (1 - s) * cx], [0, s, (1 - s) * cy]], np.float32)
        acc += cv2.warpAffine(small, m, (sw, sh), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                              borderMode=cv2.BORDER_REFLECT)
    blurred = _resize(acc * np.float32(1.0 / steps), w, h)
    weight = cv2.min(cv2.divide(float(travel / max_zoom), cv2.max(ctx.depth, 0.1)), 1.0)
    np.copyto(weight, np.float32(0.0), where=ctx.hood_mask)
    return _lerp(img, blurred, weight)


def grading(img: np.ndarray, ctx: FxContext) -> np.ndarray:
    """Per-channel colour gain of the weather (sunset warmth, rainy blue-grey)."""
    import cv2

    gain = np.asarray(ctx.weather.grading, np.float32)
    if np.all(gain == 1.0):
        return img
    return cv2.multiply(img, (*map(float, gain), 0.0))


def antialias(img: np.ndarray, ctx: FxContext) -> np.ndarray:
    """Soften geometry edges (class or depth discontinuities) with a 3x3 blur.

    Stands in for multisampling, which costs half the colour pass on llvmpipe.
    """
    import cv2

    cls, depth = ctx.classes, ctx.depth
    edge = np.zeros(cls.shape, dtype=np.uint8)
    for here, there, out in ((np.s_[:, 1:], np.s_[:, :-1], edge[:, 1:]), (np.s_[1:, :], np.s_[:-1, :], edge[1:, :])):
        a, b = depth[here], depth[there]
        jump = cv2.compare(cv2.absdiff(a, b), cv2.min(a, b) * np.float32(0.05) + np.float32(0.05), cv2.CMP_GT)
        out |= jump | cv2.compare(cls[here], cls[there], cv2.CMP_NE)
    edge = cv2.dilate(edge, np.ones((2, 2), np.uint8))
    # the blurred image with the original put back off the edges: the same pixels as copying the
    # blur onto a copy of the original along the edges, without that copy (11 ms, not 20-28 ms, full HD)
    return cv2.copyTo(img, cv2.compare(edge, 0, cv2.CMP_EQ), cv2.blur(img, (3, 3)))


# A camera's look (issue 34): what a real street camera does to a scene that the renderer draws
# clean, saturated and noiseless. Strengths are for the whole frame; blur and chromatic
# aberration scale with the width (pixels at CAMERA_REF_WIDTH).
CAMERA_REF_WIDTH = 320
CAMERA_SATURATION = 0.4  # colour kept around each pixel's grey (real street footage is muted)
CAMERA_CONTRAST = 1.15  # gain about mid-grey after the curve (deep shadows, blown skies)
CAMERA_EXPOSURE = (0.7, 1.15)  # exposure range (one per episode), linear light
CAMERA_WHITE_BALANCE = 0.06  # channel gains (one set per episode) within 1 +- this
CAMERA_STREAM = 34  # the episode's camera settings: np.random.default_rng([episode_seed, CAMERA_STREAM])
CAMERA_VIGNETTE = 0.3  # light lost at the corners
CAMERA_BLUR_PX = 0.5  # lens blur sigma
CAMERA_ABERRATION_PX = 0.5  # red and blue shifted apart by this at the frame's edge
CAMERA_NOISE = (0.008, 0.02)  # sensor noise sigma: floor and signal-proportional part
CAMERA_JPEG_QUALITY = 75


def _filmic(x: np.ndarray) -> np.ndarray:
    """ACES-like filmic tone curve (Narkowicz's fit) of linear light, into [0, 1]."""
    f = np.float32
    return np.clip(x * (f(2.51) * x + f(0.03)) / (x * (f(2.43) * x + f(0.59)) + f(0.14)), f(0.0), f(1.0))


OCCLUSION_RADIUS = 0.03  # screen-space ambient occlusion: the neighbourhood, as a share of the frame's width
OCCLUSION_GAIN = 6.0  # darkening per unit of relative disparity excess ...
OCCLUSION_MAX = 0.45  # ... up to this share of the light, at full strength


def occlusion(img: np.ndarray, ctx: FxContext) -> np.ndarray:
    """Screen-space ambient occlusion from depth (the weather's ``occlusion`` strength, opt-in): a pixel whose
    neighbourhood is nearer than itself (a corner, a kerb, the ground under a car, the wall behind a tree) is
    darkened by how much nearer, the unsharp mask of disparity (Luft et al. 2006). The sky is left alone."""
    strength = ctx.weather.occlusion
    if strength <= 0.0:
        return img
    import cv2

    f = np.float32
    # Disparity (1 / depth) is affine in the pixel's position on any plane, so its local mean equals it there:
    # only creases and nearer things in front make the excess. The sky and the ego's hood are no surfaces of
    # the scene: the mean is taken over the rest.
    disparity = f(1.0) / np.maximum(ctx.depth, f(0.1))
    sigma = max(1.0, OCCLUSION_RADIUS * ctx.rig.width)
    sky = ctx.classes == SKY_ID
    scene = (~(ctx.hood_mask | sky)).astype(np.float32)
    near = cv2.GaussianBlur(disparity * scene, (0, 0), sigma) / np.maximum(cv2.GaussianBlur(scene, (0, 0), sigma),
                                                                          f(1e-3))
    excess = (near - disparity) / disparity
    dark = np.clip(excess * f(OCCLUSION_GAIN), f(0.0), f(OCCLUSION_MAX)) * f(strength)
    dark[sky | ctx.hood_mask] = 0.0
    return cv2.multiply(img, cv2.merge([f(1.0) - dark] * 3))


RANDOMIZE_GAIN = 0.45  # at full strength each class's channel gains lie within 1 +- this ...
RANDOMIZE_LEVEL = 0.3  # ... times one brightness gain within 1 +- this
RANDOMIZE_STREAM = 35  # the episode's colours: np.random.default_rng([episode_seed, RANDOMIZE_STREAM])


def _look_rng(ctx: FxContext, stream: int) -> np.random.Generator:
    """The generator of a drawn look (the camera's exposure and white balance, the random colours): the
    episode's, or the frame's own for the share of frames the weather's ``frame_looks`` asks (issue 34: a new
    look every frame taught a network more than one per episode). Which frames draw their own is itself drawn
    per frame, from a stream of its own, so at 1 every frame does and at 0 (the default) none. (Frame 0's own
    look is the episode's: numpy's seed sequences ignore a trailing zero.)"""
    share = ctx.weather.frame_looks
    if share >= 1.0 or (share > 0.0 and np.random.default_rng([ctx.episode_seed, stream, ctx.frame, 1]).random() < share):
        return np.random.default_rng([ctx.episode_seed, stream, ctx.frame])
    return np.random.default_rng([ctx.episode_seed, stream])


def randomize(img: np.ndarray, ctx: FxContext) -> np.ndarray:
    """Structured domain randomization (the weather's ``randomize`` strength, opt-in): every class's
    colour scaled per channel by gains drawn once per episode (or per frame: ``frame_looks``), so the scene
    keeps its structure."""
    strength = ctx.weather.randomize
    if strength <= 0.0:
        return img
    rng = _look_rng(ctx, RANDOMIZE_STREAM)
    gains = 1.0 + strength * RANDOMIZE_GAIN * rng.uniform(-1.0, 1.0, (256, 3))
    gains *= 1.0 + strength * RANDOMIZE_LEVEL * rng.uniform(-1.0, 1.0, (256, 1))
    return np.clip(img * gains.astype(np.float32)[ctx.classes], np.float32(0.0), np.float32(1.0))


def _camera_look(effect: Effect) -> Effect:
    """``effect`` as the weather's ``camera`` share asks: a no-op at 0 (no draw from the frame's rng, so
    frames without the look keep their bytes), the effect itself at 1, a blend between them."""

    def blended(img: np.ndarray, ctx: FxContext) -> np.ndarray:
        share = ctx.weather.camera
        if share <= 0.0:
            return img
        out = effect(img, ctx)
        if share >= 1.0:
            return out
        import cv2

        return cv2.addWeighted(img, 1.0 - share, out, share, 0.0)

    blended.__name__, blended.__doc__ = effect.__name__, effect.__doc__
    return blended


@_camera_look
def tone(img: np.ndarray, ctx: FxContext) -> np.ndarray:
    """Exposure and white balance (per episode, or per frame: ``frame_looks``), a filmic curve in linear light, then muted colour and contrast."""
    import cv2

    camera = _look_rng(ctx, CAMERA_STREAM)  # one camera setting per episode (or per frame)
    exposure = camera.uniform(*CAMERA_EXPOSURE)
    gains = exposure * (1.0 + camera.uniform(-CAMERA_WHITE_BALANCE, CAMERA_WHITE_BALANCE, 3))
    linear = cv2.multiply(cv2.pow(np.maximum(img, np.float32(0.0)), 2.2), (*map(float, gains), 0.0))
    out = cv2.pow(_filmic(linear), 1 / 2.2)
    grey = cv2.cvtColor(out, cv2.COLOR_RGB2GRAY)
    out = cv2.addWeighted(out, CAMERA_SATURATION, cv2.merge([grey] * 3), 1.0 - CAMERA_SATURATION, 0.0)
    f = np.float32
    return np.clip((out - f(0.5)) * f(CAMERA_CONTRAST) + f(0.5), f(0.0), f(1.0))


def vignette(height: int, width: int) -> np.ndarray:
    """The share of light the lens lets through at each pixel (1 at the centre, 1 - CAMERA_VIGNETTE at the corners)."""
    ys, xs = np.ogrid[-1.0:1.0:height * 1j, -1.0:1.0:width * 1j]
    return (1.0 - CAMERA_VIGNETTE * 0.5 * (xs * xs + ys * ys)).astype(np.float32)


@_camera_look
def sensor(img: np.ndarray, ctx: FxContext) -> np.ndarray:
    """Vignetting, lens blur, chromatic aberration, sensor noise and JPEG-like compression."""
    import cv2

    h, w = img.shape[:2]
    scale = w / CAMERA_REF_WIDTH
    out = cv2.multiply(img, cv2.merge([vignette(h, w)] * 3))
    out = cv2.GaussianBlur(out, (0, 0), CAMERA_BLUR_PX * scale)
    shift = CAMERA_ABERRATION_PX * scale
    if shift > 0.05:  # red magnified, blue shrunk about the centre
        r, g, b = cv2.split(out)
        for i, k in ((0, 1.0 + 2 * shift / w), (2, 1.0 - 2 * shift / w)):
            m = np.float32([[k, 0, (1 - k) * (w - 1) / 2], [0, k, (1 - k) * (h - 1) / 2]])
            (r, g, b)[i][...] = cv2.warpAffine((r, g, b)[i], m, (w, h), borderMode=cv2.BORDER_REFLECT)
        out = cv2.merge([r, g, b])
    sigma = np.float32(CAMERA_NOISE[0]) + np.float32(CAMERA_NOISE[1]) * np.sqrt(np.maximum(out, np.float32(0.0)))
    out = out + ctx.rng.standard_normal(out.shape, dtype=np.float32) * sigma
    q = cv2.multiply(out, (255.0, 255.0, 255.0, 0.0), dtype=cv2.CV_8U)
    ok, data = cv2.imencode(".jpg", q, [cv2.IMWRITE_JPEG_QUALITY, CAMERA_JPEG_QUALITY])
    return np.multiply(cv2.imdecode(data, cv2.IMREAD_UNCHANGED), np.float32(1.0 / 255.0), dtype=np.float32)


EFFECTS: dict[str, Effect] = {
    "antialias": antialias,
    "foliage": texturefx.foliage,
    "occlusion": occlusion,
    "reflections": texturefx.reflections,
    "puddles": puddles,
    "wet_road": wet_road,
    "snow_cover": weatherfx.snow_cover,
    "night": weatherfx.night,
    "fog": fog,
    "rain": rain,
    "snowfall": weatherfx.snowfall,
    "bloom": bloom,
    "lens_flare": lens_flare,
    "motion_blur": motion_blur,
    "grading": grading,
    "retexture": texturefx.retexture,
    "randomize": randomize,
    "tone": tone,
    "sensor": sensor,
}
ORDER: tuple[str, ...] = tuple(EFFECTS)


_UNIT = np.arange(256, dtype=np.float32) * np.float32(1.0 / 255.0)  # uint8 level -> [0, 1], float32


def apply(rgb: np.ndarray, ctx: FxContext, order: tuple[str, ...] = ORDER,
          timings: dict | None = None) -> np.ndarray:
    """Run effects in ``order`` on an HxWx3 uint8 image; returns uint8. Unknown names raise."""
    unknown = [name for name in order if name not in EFFECTS]
    if unknown:
        raise ValueError(f"unknown post effect(s) {unknown}; valid: {', '.join(EFFECTS)}")
    if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"rgb: expected HxWx3 uint8, got {rgb.dtype} {rgb.shape}")
    import cv2

    img = cv2.LUT(rgb, _UNIT)  # rgb / 255 in float32, as np.multiply(rgb, float32(1 / 255)) gives it, in half the time
    for name in order:
        start = time.perf_counter()
        img = EFFECTS[name](img, ctx)
        if timings is not None:
            timings[name] = timings.get(name, 0.0) + time.perf_counter() - start
    return cv2.multiply(img, (255.0, 255.0, 255.0, 0.0), dtype=cv2.CV_8U)  # rounded, saturated
