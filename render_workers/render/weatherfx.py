"""Post effects of the weathers beyond the paper's: night lights, snow cover and falling snow.

Each is an effect of ``render_workers.render.postfx`` (same signature, same
context) and a no-op when its weather parameter is zero, so the paper's three
weathers render byte for byte as before. They read only the frame's depth,
classes, camera and weather; labels (classes, depth, instances) are never
touched, so a frame's labels are the same under every weather (paired scenes).

* ``night``: below the horizon (``night_level``: 0 with the sun up, 1 from
  ``NIGHT_SUN_DEG`` below) the lit image is scaled down to ``NIGHT_FLOOR`` of
  its daylight value (the colour pass is rendered with the weather's flat
  ambient light, so it holds the albedo), then lit again where lights are:
  the ego's headlights (a cone on what is ahead and low), street lamps on the
  tops of poles (a glowing head and a pool of light on the ground around its
  world position), lit windows (a world-anchored grid on building facades,
  about a third of them lit) and the head- or tail lights of other cars (two
  spots low on each car; white on cars left of the image centre, i.e.
  oncoming on a right-hand road, red on the others).
* ``snow_cover``: surfaces whose normal (from depth) faces up whiten, on every
  class but people and the sky; vegetation catches snow on any face; roads
  keep tyre-darkened snow (half the cover).
* ``snowfall``: flakes (per-frame random dots, bigger near the camera).
"""

from __future__ import annotations

import numpy as np

from manifests.catalog import Weather, class_id
from manifests.geometry import CV_FROM_GL, normals_from_depth

NIGHT_SUN_DEG = 12.0  # full night once the sun is this far below the horizon
NIGHT_FLOOR = 0.1  # what remains of the flat-lit image at full night (moonlight)
HEADLIGHT_GAIN = 2.2
HEADLIGHT_RANGE_M = 60.0
LAMP_GAIN = 1.6
LAMP_POOL_M = 7.0  # radius (1/e) of a street lamp's pool of light on the ground
MAX_LAMPS = 48  # nearest pole tops that carry a lamp
WINDOW_CELL_M = (3.0, 3.2)  # facade grid: along the wall, up
WINDOW_LIT_SHARE = 0.35
LAMP_RGB = (1.0, 0.78, 0.5)
HEADLIGHT_RGB = (1.0, 0.96, 0.88)
TAIL_RGB = (1.0, 0.08, 0.04)
WINDOW_RGB = (1.0, 0.75, 0.42)
SNOW_RGB = (0.93, 0.95, 1.0)

SKY_ID = class_id("sky")
POLE_ID = class_id("pole")
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
_SNOW_LUT = np.ones(256, np.float32)
_SNOW_LUT[list(NO_SNOW_IDS)] = 0.0
_SNOW_LUT[list(ROAD_IDS)] = 0.5


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


def _lamps(ctx) -> list[tuple[int, int, float]]:
    """(column, row, depth) of the top of each pole seen, nearest first, at most MAX_LAMPS."""
    import cv2

    mask = (ctx.classes == POLE_ID).astype(np.uint8)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    lamps = []
    for k in range(1, count):
        x, y, w, h, area = stats[k]
        if h < 3 or h < 1.5 * w:
            continue
        cols = np.nonzero(labels[y] == k)[0]
        col = int(cols[len(cols) // 2])
        lamps.append((col, int(y), float(ctx.depth[y, col])))
    lamps.sort(key=lambda lamp: (lamp[2], lamp[0], lamp[1]))
    return lamps[:MAX_LAMPS]


def _lamp_pools(ctx, world: np.ndarray, lamps) -> np.ndarray:
    """HxW gain of street lamps' pools of light on ground classes (world distance to each lamp)."""
    ground = _GROUND_LUT[ctx.classes] & ~ctx.hood_mask
    out = np.zeros(ctx.depth.shape, np.float32)
    if not lamps or not ground.any():
        return out
    heads = np.array([world[r, c, :2] for c, r, _ in lamps], np.float32)
    xy = world[ground][:, :2]
    d2 = np.square(xy[:, None, :] - heads[None, :, :]).sum(axis=2)
    out[ground] = np.exp(-d2 / LAMP_POOL_M**2).sum(axis=1)
    return out


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
    import cv2

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
        pools = _lamp_pools(ctx, world, lamps) * (LAMP_GAIN * street)
        lit += pools[..., None] * np.asarray(LAMP_RGB, np.float32)
        emissive[_windows(ctx, world)] = np.asarray(WINDOW_RGB, np.float32) * (0.85 * street)
        f = ctx.rig.focal_px
        for col, row, depth in lamps:
            radius = max(1, int(round(f * 0.35 / max(depth, 1.0))))
            cv2.circle(emissive, (col, max(0, row - radius)), radius, tuple(1.3 * street * c for c in LAMP_RGB), -1)
    out = img * (gain[..., None] + lit)
    return np.maximum(out, emissive)


def snow_cover(img: np.ndarray, ctx) -> np.ndarray:
    """Whiten up-facing surfaces (normals from depth) and vegetation by the weather's snow cover."""
    import cv2

    amount = ctx.weather.snow_cover
    if amount <= 0.0:
        return img
    normals = normals_from_depth(ctx.depth, ctx.rig.K)  # OpenCV camera frame
    cv_to_world = (ctx.world_from_camera @ CV_FROM_GL)[:3, :3]
    up = normals @ cv_to_world[2].astype(np.float32)  # world z of each normal
    facing = np.clip((up - 0.45) / 0.35, 0.0, 1.0)
    facing = np.maximum(facing, 0.7 * (ctx.classes == VEGETATION_ID))
    weight = facing * _SNOW_LUT[ctx.classes] * ~ctx.hood_mask * np.float32(amount)
    luminance = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    shade = np.clip(0.6 + 0.8 * luminance, 0.6, 1.0)
    snow = shade[..., None] * np.asarray(SNOW_RGB, np.float32)
    w3 = weight.astype(np.float32)[..., None]
    return img * (1.0 - w3) + snow * w3


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

