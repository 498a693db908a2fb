"""Post effects of the weathers beyond the paper's: night lights, snow cover and falling snow.

Each is an effect of ``render_workers.render.postfx`` (same signature, same
context) and a no-op when its weather parameter is zero, so the paper's three
weathers render byte for byte as before. They read only the frame's depth,
classes, camera and weather and the static world (its luminaires and lanes);
labels (classes, depth, instances) are never touched, so a frame's labels are
the same under every weather (paired scenes).

* ``night``: below the horizon (``night_level``: 0 with the sun up, 1 from
  ``NIGHT_SUN_DEG`` below) the lit image is scaled down to ``NIGHT_FLOOR`` of
  its daylight value (the colour pass is rendered with the weather's flat
  ambient light, so it holds the albedo), then lit again where lights are:
  the ego's headlights (a cone on what is ahead and low), street lamps (the
  world's luminaires, ``World.lights``: a pool of light on the ground below
  each near one, and a glowing disc where one is seen), lit windows (a
  world-anchored grid on building facades, about a third of them lit) and the
  head- or tail lights of other cars (two spots low on each car; white on cars
  left of the image centre, i.e. oncoming on a right-hand road, red on the
  others).
* ``snow_cover``: snow on surfaces whose normal (from depth) faces up, on every
  class but people and the sky, in world-anchored patches covering the
  weather's share of them (more of the road); on the road the lanes' wheel
  tracks (``track_map``, from the world's lanes) are grey slush; tree crowns
  carry clumps of snow on what faces up or sideways, over darker, duller
  foliage.
* ``snowfall``: flakes (per-frame random dots, bigger near the camera).
"""

from __future__ import annotations

import functools
from statistics import NormalDist

import numpy as np

from domains.catalog import Weather, class_id
from outputs.geometry import CV_FROM_GL, normals_from_depth

NIGHT_SUN_DEG = 12.0  # full night once the sun is this far below the horizon
NIGHT_FLOOR = 0.1  # what remains of the flat-lit image at full night (moonlight)
HEADLIGHT_GAIN = 2.2
HEADLIGHT_RANGE_M = 60.0
LAMP_GAIN = 1.6
LAMP_POOL_M = 7.0  # radius (1/e) of a street lamp's pool of light on the ground
MAX_LAMPS = 48  # nearest luminaires that light the frame
LAMP_RANGE_M = 150.0  # luminaires farther from the camera are left out
LAMP_GLOW_M = 0.35  # radius of a luminaire's glowing disc
WINDOW_CELL_M = (3.0, 3.2)  # facade grid: along the wall, up
WINDOW_LIT_SHARE = 0.35
LAMP_RGB = (1.0, 0.78, 0.5)
HEADLIGHT_RGB = (1.0, 0.96, 0.88)
TAIL_RGB = (1.0, 0.08, 0.04)
WINDOW_RGB = (1.0, 0.75, 0.42)
SNOW_RGB = (0.93, 0.95, 1.0)
SLUSH_RGB = (0.3, 0.3, 0.31)  # added to half the ground's own luminance in wheel tracks
TRACK_GAUGE_M = 1.6  # between a car's left and right wheel tracks
TRACK_CELL_M = 0.25  # raster of a world's wheel tracks: each a line of one cell, softened (about 0.45 m wide)
TRACK_WIDTH_M = 0.45
TRACK_MEAN = 0.25  # share of a lane the tracks darken, seen from far away
CROWN_SNOW_SHARE = 0.7  # of a tree crown's upper and side faces under snow (in clumps) at full cover

SKY_ID = class_id("sky")
VEHICLE_ID = class_id("vehicle")
BUILDING_ID = class_id("building")
VEGETATION_ID = class_id("vegetation")
ROAD_IDS = (class_id("road"), class_id("road line"))
GROUND_IDS = (*ROAD_IDS, class_id("sidewalk"), class_id("terrain"), class_id("ground"), class_id("railway"))
NO_SNOW_IDS = (SKY_ID, class_id("pedestrian"), class_id("rider"), class_id("unlabeled"))


def _lut(ids, value=1.0) -> np.ndarray:
    lut = np.zeros(256, np.float32)
    lut[list(ids)] = value
    return lut


_GROUND_LUT = _lut(GROUND_IDS).astype(bool)
_SNOW_LUT = np.ones(256, bool)
_SNOW_LUT[list(NO_SNOW_IDS)] = False
_ROAD_LUT = _lut(ROAD_IDS).astype(bool)


def night_level(weather: Weather) -> float:
    """0 with the sun above the horizon, rising to 1 at NIGHT_SUN_DEG below it."""
    return float(np.clip(-weather.sun_elevation_deg / NIGHT_SUN_DEG, 0.0, 1.0))


def _camera_points(ctx) -> np.ndarray:
    """HxWx3 points in the GL camera frame (x right, y up, -z ahead) from the planar depth."""
    rig, z = ctx.rig, ctx.depth
    f = rig.focal_px
    x = (np.arange(rig.width, dtype=np.float32) + 0.5 - rig.cx) / f
    y = (rig.cy - np.arange(rig.height, dtype=np.float32) - 0.5) / f
    return np.stack([x[None, :] * z, y[:, None] * z, -z], axis=-1)


def _world(ctx, cam: np.ndarray) -> np.ndarray:
    m = ctx.world_from_camera.astype(np.float32)
    return cam @ m[:3, :3].T + m[:3, 3]


def _headlights(ctx, cam: np.ndarray) -> np.ndarray:
    """HxW gain of the ego's headlights: a cone ahead, on what is below ~2.5 m, fading with distance."""
    x, y, z = cam[..., 0], cam[..., 1], -cam[..., 2]
    height = y + ctx.rig.viewpoint.camera_height_m
    cone = np.exp(-np.square(x / (0.3 * z + 1.0)))
    reach = np.clip(1.0 - z / HEADLIGHT_RANGE_M, 0.0, 1.0) ** 2 / (1.0 + np.square(z / 25.0))
    return cone * reach * (height < 2.5) * (z > 1.0)


def _lamps(ctx) -> np.ndarray:
    """(N, 3) the world's luminaires near the camera (``World.lights``) in the GL camera frame, nearest
    first: at most MAX_LAMPS within LAMP_RANGE_M, ahead or no more than two pools behind."""
    lights = ctx.world.lights if ctx.world is not None else np.zeros((0, 3))
    if not len(lights):
        return np.zeros((0, 3), np.float32)
    m = np.linalg.inv(ctx.world_from_camera)
    cam = np.asarray(lights, np.float64) @ m[:3, :3].T + m[:3, 3]
    dist = np.linalg.norm(cam, axis=1)
    keep = np.nonzero((dist < LAMP_RANGE_M) & (cam[:, 2] < 2.0 * LAMP_POOL_M))[0]
    keep = keep[np.argsort(dist[keep], kind="stable")][:MAX_LAMPS]
    return cam[keep].astype(np.float32)


def _lamp_pools(ctx, world: np.ndarray, lamps_world: np.ndarray) -> np.ndarray:
    """HxW gain of street lamps' pools of light on ground classes (world distance to each luminaire), evaluated on
    every other row and column (the pools are smooth) and interpolated."""
    import cv2

    ground = _GROUND_LUT[ctx.classes] & ~ctx.hood_mask
    if not len(lamps_world) or not ground.any():
        return np.zeros(ctx.depth.shape, np.float32)
    solid = ctx.depth[1::2, 1::2] < 999.0  # not the sky
    scale, origin = np.float32(1.0 / LAMP_POOL_M), ctx.world_from_camera[:2, 3].astype(np.float32)
    xy = (world[1::2, 1::2][solid][:, :2] - origin) * scale  # near the camera: small numbers, precise in float32
    heads = (lamps_world[:, :2].astype(np.float32) - origin) * scale
    d2 = np.square(xy).sum(axis=1)[:, None] - 2.0 * (xy @ heads.T) + np.square(heads).sum(axis=1)[None, :]
    small = np.zeros(solid.shape, np.float32)
    small[solid] = np.exp(-np.maximum(d2, 0.0)).sum(axis=1)
    h, w = ctx.depth.shape
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR) * ground


def _lamp_heads(ctx, emissive: np.ndarray, lamps: np.ndarray, strength: float) -> None:
    """Draw each luminaire seen (in the image, not hidden behind nearer depth) as a glowing disc into ``emissive``."""
    import cv2

    rig, f = ctx.rig, ctx.rig.focal_px
    h, w = ctx.depth.shape
    colour = tuple(1.3 * strength * c for c in LAMP_RGB)
    for x, y, z in lamps:
        ahead = -float(z)
        if ahead < 1.0:
            continue
        col, row = rig.cx + f * x / ahead, rig.cy - f * y / ahead
        if not (0 <= col < w and 0 <= row < h) or ctx.depth[int(row), int(col)] < 0.97 * ahead - 0.3:
            continue
        radius = max(1.0, f * LAMP_GLOW_M / ahead)
        cv2.circle(emissive, (int(round(col * 16 - 8)), int(round(row * 16 - 8))), int(round(radius * 16)), colour, -1,
                   cv2.LINE_AA, 4)


def _windows(ctx, world: np.ndarray) -> np.ndarray:
    """HxW bool: lit window pixels on building facades (a world-anchored grid, some cells lit)."""
    facade = (ctx.classes == BUILDING_ID) & (ctx.depth < 300.0)
    along = (world[..., 0] + world[..., 1]) / WINDOW_CELL_M[0]
    up = world[..., 2] / WINDOW_CELL_M[1]
    cu, cz = np.floor(along).astype(np.int64), np.floor(up).astype(np.int64)
    fu, fz = along - cu, up - cz
    inside = (fu > 0.22) & (fu < 0.78) & (fz > 0.3) & (fz < 0.75) & (cz >= 1)
    hashed = ((cu * 73856093) ^ (cz * 19349663) ^ 0x5BD1E995) & 0xFFFF
    return facade & inside & (hashed < int(WINDOW_LIT_SHARE * 0x10000))


def _car_lights(ctx, emissive: np.ndarray, strength: float) -> None:
    """Draw two light spots low on each car seen (not the ego's hood) into ``emissive``."""
    import cv2

    mask = ((ctx.classes == VEHICLE_ID) & ~ctx.hood_mask).astype(np.uint8)
    count, _, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    for k in range(1, count):
        x, y, w, h, area = stats[k]
        if area < 6 or w < 3:
            continue
        colour = HEADLIGHT_RGB if x + w / 2 < ctx.rig.cx else TAIL_RGB
        radius = max(1, int(round(0.07 * w)))
        for fx in (0.15, 0.85):
            centre = (int(round(x + fx * w)), int(round(y + 0.62 * h)))
            cv2.circle(emissive, centre, radius, tuple(1.2 * strength * c for c in colour), -1)


def night(img: np.ndarray, ctx) -> np.ndarray:
    """Darken towards moonlight as the sun sets below the horizon; light it again where lights are."""
    weather = ctx.weather
    level = night_level(weather)
    if level <= 0.0:
        return img
    cam = _camera_points(ctx)
    world = _world(ctx, cam)
    sky = ctx.classes == SKY_ID
    gain = np.full(ctx.depth.shape, 1.0 - level * (1.0 - NIGHT_FLOOR), np.float32)
    gain[sky] = 1.0  # the sky is drawn with the weather's own (dark) colours
    lit = np.zeros(img.shape, np.float32)
    emissive = np.zeros(img.shape, np.float32)
    cars, street = weather.car_lights * level, weather.street_lights * level
    if cars > 0:
        beam = _headlights(ctx, cam) * ~(sky | ctx.hood_mask) * (HEADLIGHT_GAIN * cars)
        lit += beam[..., None] * np.asarray(HEADLIGHT_RGB, np.float32)
        _car_lights(ctx, emissive, cars)
    if street > 0:
        lamps = _lamps(ctx)
        pools = _lamp_pools(ctx, world, _world(ctx, lamps)) * (LAMP_GAIN * street)
        lit += pools[..., None] * np.asarray(LAMP_RGB, np.float32)
        emissive[_windows(ctx, world)] = np.asarray(WINDOW_RGB, np.float32) * (0.85 * street)
        _lamp_heads(ctx, emissive, lamps, street)
    out = img * (gain[..., None] + lit)
    return np.maximum(out, emissive)


def _waves(points: np.ndarray, wavelengths_m: tuple[float, float], seed: int, stream: int, count: int = 6) -> np.ndarray:
    """Smooth world-anchored noise at ``points`` (N, D) in metres, about standard normal: a sum of ``count`` random
    plane waves of wavelengths in ``wavelengths_m``."""
    rng = np.random.default_rng([seed, stream])
    direction = rng.normal(size=(count, points.shape[1]))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    k = direction * (2.0 * np.pi / rng.uniform(*wavelengths_m, count))[:, None]
    phase = rng.uniform(0.0, 2.0 * np.pi, count)
    return (np.sin(points @ k.T.astype(np.float32) + phase.astype(np.float32)).sum(axis=1)
            * np.float32(1.0 / np.sqrt(count / 2.0)))


def _share(noise: np.ndarray, share: float, soft: float) -> np.ndarray:
    """0-1 weight that is 1 on about ``share`` of the noise's (standard normal) values, with soft edges."""
    threshold = NormalDist().inv_cdf(min(max(1.0 - share, 1e-6), 1.0 - 1e-6))
    return np.clip((noise - np.float32(threshold)) / np.float32(soft) + np.float32(0.5), 0.0, 1.0)


@functools.lru_cache(maxsize=2)
def track_map(world) -> tuple[np.ndarray, float, float]:
    """A world's wheel tracks on a ground raster of TRACK_CELL_M: two lines TRACK_GAUGE_M apart along every lane's
    centre line, about TRACK_WIDTH_M wide; (uint8 raster, 0-255, row r at y0 + r * cell; x0, y0)."""
    import cv2

    lanes = [lane for lane in world.lanes if len(lane.points) > 1]
    if not lanes:
        return np.zeros((1, 1), np.uint8), 0.0, 0.0
    corners = np.concatenate([lane.points[:, :2] for lane in lanes])
    (x0, y0), (x1, y1) = corners.min(axis=0) - 5.0, corners.max(axis=0) + 5.0
    grid = np.zeros((int((y1 - y0) / TRACK_CELL_M) + 1, int((x1 - x0) / TRACK_CELL_M) + 1), np.uint8)
    for lane in lanes:
        p = lane.points[:, :2]
        ahead = np.diff(np.vstack([p, p[:1]]) if lane.closed else p, axis=0)
        ahead /= np.maximum(np.linalg.norm(ahead, axis=1, keepdims=True), 1e-9)
        left = np.stack([-ahead[:, 1], ahead[:, 0]], axis=1)  # per segment
        before = np.roll(left, 1, axis=0) if lane.closed else np.vstack([left[:1], left])
        after = left if lane.closed else np.vstack([left, left[-1:]])
        normal = before + after  # per point: the mean of its segments' normals, mitred to keep the offset at corners
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-9)
        normal /= np.maximum(np.sum(normal * after, axis=1, keepdims=True), 0.5)
        for side in (-0.5, 0.5):
            line = (p + side * TRACK_GAUGE_M * normal - (x0, y0)) / TRACK_CELL_M
            cv2.polylines(grid, [np.round(line * 16 - 8).astype(np.int32)], lane.closed, 255, 1, cv2.LINE_AA, 4)
    return cv2.GaussianBlur(grid, (0, 0), 0.5), float(x0), float(y0)


def _tracks(ctx, xy: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """0-1 wheel tracks at ground points ``xy`` (N, 2) seen at planar ``depth`` (N,): the world's track raster,
    fading to its mean where a pixel is wider than a track (no aliasing far away)."""
    if ctx.world is None:
        return np.zeros(len(xy), np.float32)
    grid, x0, y0 = track_map(ctx.world)
    col = np.floor((xy[:, 0] - x0) / TRACK_CELL_M).astype(np.int64)
    row = np.floor((xy[:, 1] - y0) / TRACK_CELL_M).astype(np.int64)
    inside = (col >= 0) & (col < grid.shape[1]) & (row >= 0) & (row < grid.shape[0])
    track = np.zeros(len(xy), np.float32)
    track[inside] = grid[row[inside], col[inside]] * np.float32(1.0 / 255.0)
    far = np.clip((depth / ctx.rig.focal_px - 0.5 * TRACK_WIDTH_M) / TRACK_WIDTH_M, 0.0, 1.0).astype(np.float32)
    return track * (1.0 - far) + np.float32(TRACK_MEAN) * far


def snow_cover(img: np.ndarray, ctx) -> np.ndarray:
    """Snow on what faces up (normals from depth) by the weather's snow cover, in world-anchored patches; roads
    white but for grey slush in the lanes' wheel tracks; clumps of snow on tree crowns, dark foliage between."""
    import cv2

    amount = ctx.weather.snow_cover
    if amount <= 0.0:
        return img
    normals = normals_from_depth(ctx.depth, ctx.rig.K)  # OpenCV camera frame
    cv_to_world = (ctx.world_from_camera @ CV_FROM_GL)[:3, :3]
    up = normals @ cv_to_world[2].astype(np.float32)  # world z of each normal
    classes = ctx.classes
    veg = (classes == VEGETATION_ID) & ~ctx.hood_mask
    flat = (up > 0.45) & _SNOW_LUT[classes] & ~ctx.hood_mask & ~veg
    world = _world(ctx, _camera_points(ctx))
    luminance = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    shade = _shade(luminance, classes)
    out = img.copy()
    snow_w, slush_w = _ground_snow(ctx, world[flat], up[flat], _ROAD_LUT[classes[flat]], ctx.depth[flat], amount)
    pixels, lum, lit = img[flat], luminance[flat][:, None], shade[flat][:, None]
    slush = lum * np.float32(0.5) + lit * np.asarray(SLUSH_RGB, np.float32)
    pixels += (slush - pixels) * slush_w[:, None]
    out[flat] = pixels + (lit * np.asarray(SNOW_RGB, np.float32) - pixels) * snow_w[:, None]
    # tree crowns: clumps of snow on what faces up or sideways, the foliage between them darker and duller
    lean = np.clip((up[veg] + 0.3) / 0.6, 0.0, 1.0)  # 1 on what faces up or sideways, 0 on the undersides
    clumps = _waves(world[veg], (0.7, 2.6), ctx.episode_seed, 603) + np.float32(1.5) * (lean - np.float32(1.0))
    snow_w = np.float32(0.95) * _share(clumps, CROWN_SNOW_SHARE * amount, 0.5)
    grey, lum, lit = np.float32(0.45 * amount), luminance[veg][:, None], shade[veg][:, None]
    pixels = (img[veg] * (1.0 - grey) + lum * grey) * np.float32(1.0 - 0.3 * amount)
    out[veg] = pixels + (lit * np.asarray(SNOW_RGB, np.float32) - pixels) * snow_w[:, None]
    return out


def _ground_snow(ctx, points: np.ndarray, up: np.ndarray, road: np.ndarray, depth: np.ndarray,
                 amount: float) -> tuple[np.ndarray, np.ndarray]:
    """Shares of snow and of slush on up-facing pixels (world ``points``, normals' ``up``, ``road`` or not):
    world-anchored patches cover ``amount`` of the ground (more of the road), the lanes' wheel tracks on the road
    are slush."""
    facing = np.clip((up - 0.45) / 0.35, 0.0, 1.0)
    xy = points[:, :2]
    patches = _waves(xy, (1.5, 9.0), ctx.episode_seed, 601)
    snow = np.where(road, _share(patches, amount**0.5, 0.6), _share(patches, amount, 0.6)) * facing
    slush = np.zeros_like(snow)
    on_road = xy[road]
    track = _tracks(ctx, on_road, depth[road])
    track *= np.clip(0.9 + 0.3 * _waves(on_road, (0.8, 4.0), ctx.episode_seed, 602), 0.0, 1.0)
    snow[road] *= 1.0 - track
    slush[road] = facing[road] * track
    return snow * np.float32(amount**0.25), slush  # thinner snow lets a little of the ground show through


def _shade(luminance: np.ndarray, classes: np.ndarray) -> np.ndarray:
    """How lit each pixel is against the mean of its class in the frame (shadows, faces turned from the sun)."""
    counts = np.bincount(classes.ravel(), minlength=256)
    sums = np.bincount(classes.ravel(), weights=luminance.ravel(), minlength=256)
    mean = (sums / np.maximum(counts, 1)).astype(np.float32)
    ratio = luminance / np.maximum(mean[classes], np.float32(0.02))
    return np.sqrt(np.clip(ratio, 0.45, 1.1))


def snowfall(img: np.ndarray, ctx) -> np.ndarray:
    """Falling flakes: random soft white dots (per frame), count from the weather's snowfall."""
    import cv2

    amount = ctx.weather.snowfall
    if amount <= 0.0:
        return img
    h, w = img.shape[:2]
    n = int(amount * w * h / 700)
    x = ctx.rng.uniform(0, w, n)
    y = ctx.rng.uniform(0, h, n)
    near = ctx.rng.random(n) ** 3  # few flakes close to the lens, most far
    radius = np.maximum(1, np.round((0.5 + 3.0 * near) * w / 640)).astype(int)
    layer = np.zeros((h, w), np.float32)
    for cx, cy, r, v in zip(x.astype(int), y.astype(int), radius, 0.55 + 0.4 * near):
        cv2.circle(layer, (int(cx), int(cy)), int(r), float(v), -1)
    layer = cv2.GaussianBlur(layer, (0, 0), max(0.5, w / 1600))
    alpha = layer[..., None]
    return img * (1.0 - alpha) + np.float32(0.97) * alpha

