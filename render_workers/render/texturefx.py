"""Random textures per class (issue 34): structured domain randomization of surface detail, opt-in.

``retexture`` is an effect of ``render_workers.render.postfx`` (same signature, same context). With the
weather's ``textures`` above 0 every class gets, once per episode, a procedural pattern of its own and a
second colour: a sum of random plane waves over the surface's world position (from the depth and the
camera's pose, so the pattern stays on the world between frames), shaped into one of ``KINDS`` (smooth
clouds, blotches, veins, stripes), at a scale drawn per class, mixing the class's own colour towards the
second by up to ``MAX_MIX`` at full strength. The sky's pattern is laid on the view direction instead
(clouds). A network trained on such frames cannot rely on our surfaces being clean and uniform (and real
ones are not), and learns from layout and shape. Labels are untouched; at 0 it draws nothing, so the
frames are byte for byte as before.

Waves shorter than a few pixels' footprint fade out (``_footprint_fade``), so far surfaces do not alias
into moire.
"""

from __future__ import annotations

import numpy as np

from domains.catalog import class_id
from outputs.geometry import CV_FROM_GL, normals_from_depth
from render_workers.render.weatherfx import _camera_points, _world

TEXTURE_STREAM = 36  # a class's pattern: np.random.default_rng([episode_seed, TEXTURE_STREAM, class id])
WAVES = 8  # plane waves per pattern, over OCTAVES octaves
OCTAVES = 3
WAVELENGTH_M = (0.4, 8.0)  # a class's coarsest wavelength, drawn log-uniform
SKY_WAVELENGTH_RAD = (0.08, 0.6)  # the sky's, on the view direction
MAX_MIX = 0.7  # share of the second colour at a pattern's peak, at full strength
SECOND_GAIN = (0.25, 1.75)  # the second colour: the class's colour times per-channel gains in this range
SKY_ID = class_id("sky")


def _smooth(n: np.ndarray) -> np.ndarray:
    return np.clip(0.5 + 0.3 * n, 0.0, 1.0)


def _blotches(n: np.ndarray) -> np.ndarray:
    return np.clip(1.5 * n + 0.5, 0.0, 1.0)


def _veins(n: np.ndarray) -> np.ndarray:
    return np.clip(1.0 - 2.0 * np.abs(n), 0.0, 1.0)


def _stripes(n: np.ndarray) -> np.ndarray:
    return (n > 0.0).astype(np.float32)


# a pattern's shape: standard-normal-ish noise -> a 0-1 weight of the second colour
KINDS = {"smooth": _smooth, "blotches": _blotches, "veins": _veins, "stripes": _stripes}


def _footprint_fade(wavelength: np.ndarray, footprint: np.ndarray) -> np.ndarray:
    """(N, waves) weight of each wave at each pixel: 1 above 3 pixels a period, 0 below 1.5."""
    return np.clip(wavelength[None, :] / (1.5 * footprint[:, None]) - 1.0, 0.0, 1.0).astype(np.float32)


def _pattern(rng: np.random.Generator, points: np.ndarray, footprint: np.ndarray,
             span: tuple[float, float]) -> np.ndarray:
    """A class's 0-1 weight at ``points`` (N, 3): its kind, scale and waves drawn from ``rng``."""
    kind = list(KINDS.values())[int(rng.integers(len(KINDS)))]
    coarse = float(np.exp(rng.uniform(np.log(span[0]), np.log(span[1]))))
    octave = np.arange(WAVES) % OCTAVES
    wavelength = coarse * np.exp2(-octave.astype(np.float64)) * rng.uniform(0.8, 1.25, WAVES)
    if kind is _stripes:  # one dominant direction
        wavelength[:] = coarse
    direction = rng.normal(size=(WAVES, 3))
    if kind is _stripes:
        direction[:] = direction[0]
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    k = (direction * (2.0 * np.pi / wavelength)[:, None]).astype(np.float32)
    phase = rng.uniform(0.0, 2.0 * np.pi, WAVES).astype(np.float32)
    gain = np.float32(0.7) ** octave.astype(np.float32)
    weight = gain[None, :] * _footprint_fade(wavelength, footprint)
    noise = (np.sin(points @ k.T + phase) * weight).sum(axis=1) / np.sqrt(0.5 * (gain**2).sum())
    return kind(noise.astype(np.float32))


def retexture(img: np.ndarray, ctx) -> np.ndarray:
    """Per-episode random textures per class (the weather's ``textures`` strength; 0: a no-op)."""
    strength = ctx.weather.textures
    if strength <= 0.0:
        return img
    cam = _camera_points(ctx)
    world = _world(ctx, cam)
    footprint = ctx.depth / np.float32(ctx.rig.focal_px)  # metres per pixel on a surface facing the camera
    seen = ~ctx.hood_mask  # the ego's hood keeps its paint
    out = img.copy()
    for cid in np.unique(ctx.classes[seen]):
        mask = (ctx.classes == cid) & seen
        rng = np.random.default_rng([ctx.episode_seed, TEXTURE_STREAM, int(cid)])
        second = rng.uniform(*SECOND_GAIN, 3).astype(np.float32)
        mix = np.float32(strength * MAX_MIX * rng.uniform(0.4, 1.0))
        if cid == SKY_ID:  # a pattern on the view direction: clouds that stay put as the camera moves on
            rays = cam[mask] / np.linalg.norm(cam[mask], axis=1, keepdims=True)
            rays = rays @ ctx.world_from_camera[:3, :3].T.astype(np.float32)
            w = _pattern(rng, rays, np.full(len(rays), 1.0 / ctx.rig.focal_px, np.float32), SKY_WAVELENGTH_RAD)
        else:
            w = _pattern(rng, world[mask], footprint[mask], WAVELENGTH_M)
        pixels = img[mask]
        out[mask] = pixels * (np.float32(1.0) + (mix * w)[:, None] * (second - np.float32(1.0)))
    return np.clip(out, np.float32(0.0), np.float32(1.0))


VEGETATION_ID = class_id("vegetation")
FOLIAGE_STREAM = 37  # the crowns' leaf clusters: np.random.default_rng([episode_seed, FOLIAGE_STREAM])
LEAF_CLUSTER_M = (0.35, 1.2)  # wavelengths of the clusters of leaves ...
LEAF_M = (0.08, 0.3)  # ... and of the leaves in them
FOLIAGE_GAP_SHARE = 0.3  # share of a crown seen as dark gaps between clusters
FOLIAGE_SHADE = (0.35, 1.35)  # light on a gap's floor, on a cluster's sunlit top


def _noise(rng: np.random.Generator, points: np.ndarray, footprint: np.ndarray, span: tuple[float, float],
           count: int = 16) -> np.ndarray:
    """About standard normal world-anchored noise at ``points`` (N, 3): ``count`` random plane waves in ``span``
    (metres), each fading out below a few pixels' footprint (the mean of what is left stays 0)."""
    direction = rng.normal(size=(count, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    wavelength = np.exp(rng.uniform(np.log(span[0]), np.log(span[1]), count))
    k = (direction * (2.0 * np.pi / wavelength)[:, None]).astype(np.float32)
    phase = rng.uniform(0.0, 2.0 * np.pi, count).astype(np.float32)
    weight = _footprint_fade(wavelength, footprint)
    return (np.sin(points @ k.T + phase) * weight).sum(axis=1) * np.float32(1.0 / np.sqrt(count / 2.0))


def _lever_pixels(ctx, strength: float, cid: int) -> np.ndarray | None:
    """The pixels of class ``cid`` a lever of ``strength`` repaints (the ego's hood keeps its paint); None
    when the lever is off or the class is not in view."""
    if strength <= 0.0:
        return None
    mask = (ctx.classes == cid) & ~ctx.hood_mask
    return mask if mask.any() else None


def foliage(img: np.ndarray, ctx) -> np.ndarray:
    """Leaf clusters on tree crowns and hedges (the weather's ``foliage`` strength; 0: a no-op): world-anchored
    clusters lit on top, dark gaps between them, single leaves within, where the renderer draws a smooth blob."""
    strength = ctx.weather.foliage
    veg = _lever_pixels(ctx, strength, VEGETATION_ID)
    if veg is None:
        return img
    rng = np.random.default_rng([ctx.episode_seed, FOLIAGE_STREAM])
    cam = _camera_points(ctx)[veg]
    points = _world(ctx, cam)
    footprint = ctx.depth[veg] / np.float32(ctx.rig.focal_px)
    clusters = _noise(rng, points, footprint, LEAF_CLUSTER_M)
    leaves = _noise(rng, points, footprint, LEAF_M)
    lit = np.clip(0.5 + 0.35 * clusters + 0.2 * leaves, 0.0, 1.0)  # 0 in the gaps, 1 on the clusters' tops
    from statistics import NormalDist

    gap = NormalDist().inv_cdf(FOLIAGE_GAP_SHARE)
    lit = np.where(clusters < gap, lit * np.float32(0.4), lit)
    shade = np.float32(FOLIAGE_SHADE[0]) + np.float32(FOLIAGE_SHADE[1] - FOLIAGE_SHADE[0]) * lit
    out = img.copy()
    out[veg] = img[veg] * (np.float32(1.0) + np.float32(strength) * (shade - np.float32(1.0)))[:, None]
    return np.clip(out, np.float32(0.0), np.float32(1.0))


VEHICLE_ID = class_id("vehicle")
REFLECT_STREAM = 38  # the mirrored street: np.random.default_rng([episode_seed, REFLECT_STREAM])
REFLECT_F0 = 0.2  # share of the light a surface facing the camera mirrors (Schlick: 1 at grazing angles)
SKY_RADIANCE = 1.6  # the mirrored sky against the paint (brighter than white: clipped after the mix)
SKYLINE_BLOCKS = 36  # facades around the horizon, each of its own height and shade
SKYLINE_TOP = (0.05, 0.5)  # sine of a facade's top above the horizon
FACADE_SHADE = (0.12, 0.5)
GROUND_SHADE = (0.06, 0.2)
WINDOW_ROWS = 40.0  # window rows per unit of sine elevation on a mirrored facade ...
WINDOW_COLUMNS = 5  # ... and columns per facade
SHOULDER_M = 0.9  # height of a car's shoulder line: panels above it lean towards the sky, below it the road ...
BULGE = 0.8  # ... by up to this much of a unit normal


def _normals_within(ctx, mask: np.ndarray) -> np.ndarray:
    """(N, 3) ``normals_from_depth`` at ``mask``'s pixels, in their order, computed over each connected
    region's bounding box and one pixel around it (a pixel's normal reads its four neighbours only), not
    over the whole frame: the same values at a small share of the cost."""
    import cv2

    count, _, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    normals = np.zeros(mask.shape + (3,), np.float64)
    K = np.array(ctx.rig.K, np.float64)
    for x, y, w, h, _ in stats[1:count]:
        r0, r1 = max(y - 1, 0), min(y + h + 1, mask.shape[0])
        c0, c1 = max(x - 1, 0), min(x + w + 1, mask.shape[1])
        box = K.copy()
        box[0, 2] -= c0
        box[1, 2] -= r0
        inside = mask[r0:r1, c0:c1]
        normals[r0:r1, c0:c1][inside] = normals_from_depth(ctx.depth[r0:r1, c0:c1], box)[inside]
    return normals[mask]


def reflections(img: np.ndarray, ctx) -> np.ndarray:
    """Reflections on vehicles (the weather's ``reflections`` strength; 0: a no-op): each pixel of a car's
    paint or glass mirrors, by Schlick's approximation of Fresnel's law, what lies along the view direction
    reflected about the surface's normal (from the depth) in a street drawn once per episode and fixed to
    the world's axes: the weather's sky, a skyline of facades with rows of windows, and the road below the
    horizon. Flat-shaded boxes then carry the sweeping highlights and mirrored edges of real paint."""
    strength = ctx.weather.reflections
    mask = _lever_pixels(ctx, strength, VEHICLE_ID)
    if mask is None:
        return img
    f = np.float32
    rng = np.random.default_rng([ctx.episode_seed, REFLECT_STREAM])
    tops = rng.uniform(*SKYLINE_TOP, SKYLINE_BLOCKS).astype(f)
    shades = (rng.uniform(*FACADE_SHADE, (SKYLINE_BLOCKS, 1)) * rng.uniform(0.8, 1.2, (SKYLINE_BLOCKS, 3))).astype(f)
    ground, turn = f(rng.uniform(*GROUND_SHADE)), rng.uniform(0.0, 2.0 * np.pi)
    zenith, horizon = (np.asarray(c, f) / f(255.0) for c in (ctx.weather.sky_zenith, ctx.weather.sky_horizon))

    cam = _camera_points(ctx)[mask]
    view = cam / np.linalg.norm(cam, axis=1, keepdims=True)
    normal = (_normals_within(ctx, mask) * np.diag(CV_FROM_GL)[:3]).astype(f)  # OpenCV -> GL axes
    rotation = ctx.world_from_camera[:3, :3].astype(f)
    view, normal = view @ rotation.T, normal @ rotation.T  # world axes from here on (z up)
    # Car bodies are convex where ours are flat boxes: above the shoulder line a panel turns to the sky,
    # below it to the road. The normal leans so by the point's height above the road under the camera.
    height = cam @ rotation[2] + f(ctx.rig.viewpoint.camera_height_m)
    normal[:, 2] += np.clip((height - f(SHOULDER_M)) / f(0.4), f(-1.0), f(1.0)) * f(BULGE)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    facing = np.clip(-(view * normal).sum(axis=1), f(0.0), f(1.0))
    mirrored = view + f(2.0) * facing[:, None] * normal
    up = mirrored[:, 2]
    around = (np.arctan2(mirrored[:, 1], mirrored[:, 0]) + turn) / (2.0 * np.pi) % 1.0 * SKYLINE_BLOCKS
    block = np.minimum(around.astype(np.int64), SKYLINE_BLOCKS - 1)

    sky = np.clip(up, 0.0, 1.0)[:, None] ** f(0.5)
    env = (horizon + (zenith - horizon) * sky) * f(SKY_RADIANCE)
    facade = (up > 0.0) & (up < tops[block])
    windows = (np.sin(up * f(WINDOW_ROWS * np.pi)) > 0.3) & (np.sin(around * f(WINDOW_COLUMNS * np.pi)) > -0.4)
    env[facade] = shades[block[facade]] * np.where(windows[facade], f(0.55), f(1.0))[:, None]
    env[up <= 0.0] = ground
    fresnel = f(REFLECT_F0) + f(1.0 - REFLECT_F0) * (f(1.0) - facing) ** 5
    w = np.minimum(f(strength) * fresnel, f(1.0))[:, None]
    out = img.copy()
    out[mask] = np.clip(img[mask] * (f(1.0) - w) + env.astype(f) * w, f(0.0), f(1.0))
    return out
