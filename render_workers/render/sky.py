"""The procedural sky behind the colour pass: gradient, clouds and sun glow."""

from __future__ import annotations

import math
import threading

import numpy as np

from domains.catalog import Weather
from render_workers.render.camera import CameraRig, sun_direction

SKY_DOWNSCALE = 4  # the sky is smooth: compute it at 1/4 size and upscale


# --------------------------------------------------------------------------
def cloud_texture(seed: int, size: tuple[int, int] = (64, 256)) -> np.ndarray:
    """Periodic (in azimuth) fractal noise in [0, 1], rows = elevation 0..90 deg."""
    import cv2

    rng = np.random.default_rng([seed, 17])
    h, w = size
    out = np.zeros((h, w), dtype=np.float32)
    amplitude, total = 1.0, 0.0
    for cells in (4, 8, 16, 32):
        coarse = rng.random((max(2, cells * h // w), cells)).astype(np.float32)
        wrapped = np.concatenate([coarse, coarse[:, :1]], axis=1)  # wrap in azimuth
        big = cv2.resize(wrapped, (w + w // cells, h), interpolation=cv2.INTER_CUBIC)[:, :w]
        out += amplitude * big
        total += amplitude
        amplitude *= 0.5
    out /= total
    return np.clip((out - out.min()) / max(1e-6, float(out.max() - out.min())), 0.0, 1.0)





def sky_image(
    weather: Weather, rig: CameraRig, world_from_camera: np.ndarray, clouds: np.ndarray
) -> np.ndarray:
    """HxWx3 uint8 sRGB sky seen by the camera: gradient, clouds and sun glow.

    Computed at 1/SKY_DOWNSCALE size in float and upscaled as uint8 (a quarter
    of the memory traffic of a float upscale)."""
    import cv2

    h, w = max(2, rig.height // SKY_DOWNSCALE), max(2, rig.width // SKY_DOWNSCALE)
    xs = (np.arange(w) + 0.5) / w * 2 * rig.tan_half_h - rig.tan_half_h  # right
    ys = rig.tan_half_v - (np.arange(h) + 0.5) / h * 2 * rig.tan_half_v  # up
    # world directions of the rays: R @ (x, y, -1)
    rot = world_from_camera[:3, :3]
    dirs = (xs[None, :, None] * rot[:, 0] + ys[:, None, None] * rot[:, 1] - rot[:, 2])
    dirs /= np.linalg.norm(dirs, axis=2, keepdims=True)
    elevation = np.arcsin(np.clip(dirs[..., 2], -1, 1))
    azimuth = np.arctan2(dirs[..., 1], dirs[..., 0])

    t = np.clip(elevation / math.radians(55.0), 0.0, 1.0)[..., None] ** 0.6
    zenith = np.asarray(weather.sky_zenith, np.float32) / 255.0
    horizon = np.asarray(weather.sky_horizon, np.float32) / 255.0
    sky = horizon + (zenith - horizon) * t
    sky = np.where((elevation < 0)[..., None], horizon * 0.92, sky)

    if weather.cloudiness > 0:
        ch, cw = clouds.shape
        row = np.clip(elevation / (math.pi / 2), 0, 1) * (ch - 1)
        col = (azimuth / (2 * math.pi) % 1.0) * cw
        # clouds thin out towards the horizon by perspective: stretch rows
        noise = cv2.remap(clouds, col.astype(np.float32), row.astype(np.float32), cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_WRAP)
        cover = np.clip((noise - (1.0 - weather.cloudiness)) / 0.25 + weather.cloudiness * 0.5, 0.0, 1.0)
        cloud_rgb = np.clip(horizon * 0.6 + 0.45 * (1 - weather.cloudiness) + 0.1, 0, 1)
        sky = sky + (cloud_rgb - sky) * (cover * 0.9)[..., None]

    sun = sun_direction(weather.sun_elevation_deg, weather.sun_azimuth_deg)
    cos_angle = np.clip(dirs @ sun, -1.0, 1.0)
    angle = np.degrees(np.arccos(cos_angle))
    light = np.asarray(weather.light_color, np.float32)
    glow = (np.exp(-np.square(angle / 12.0)) * 0.35 + np.exp(-np.square(angle / 1.2)) * 1.5)
    glow *= (1.0 - 0.85 * weather.cloudiness)
    sky = sky + glow[..., None] * light
    small = (np.clip(sky, 0, 1) * 255.0 + 0.5).astype(np.uint8)
    return cv2.resize(small, (rig.width, rig.height), interpolation=cv2.INTER_LINEAR)


class SkyCache:
    """:func:`sky_image` under one episode's ``clouds``, kept for the last ``size`` (weather, rig,
    camera orientation) asked.

    The sky depends on the camera's rotation only, and an ego on a straight road keeps its rotation
    bit for bit from frame to frame (5-9 rotations in 60 frames of T01, T03 and T05): those frames
    take the image already made (~35 ms of CPU per full-HD frame), the same bytes. Images are
    read-only, shared between the frames that use them; safe to call from any thread."""

    def __init__(self, clouds: np.ndarray, size: int = 4) -> None:
        from collections import OrderedDict

        self.clouds = clouds
        self.size = size
        self._images: OrderedDict = OrderedDict()
        self._lock = threading.Lock()

    def __call__(self, weather: Weather, rig: CameraRig, world_from_camera: np.ndarray) -> np.ndarray:
        key = (weather, rig, np.ascontiguousarray(world_from_camera[:3, :3], dtype=np.float64).tobytes())
        with self._lock:
            image = self._images.get(key)
            if image is not None:
                self._images.move_to_end(key)
                return image
        image = sky_image(weather, rig, world_from_camera, self.clouds)
        image.flags.writeable = False
        with self._lock:
            self._images[key] = image
            while len(self._images) > self.size:
                self._images.popitem(last=False)
        return image


def composite_sky(rgba: np.ndarray, sky: np.ndarray) -> np.ndarray:
    """The colour pass (premultiplied RGBA, alpha 0 where nothing was drawn) over the uint8 sky.

    ``rgb + sky * (255 - alpha) / 255`` per pixel, rounded and saturated, as
    whole-image uint8 OpenCV passes (no per-pixel masks)."""
    import cv2

    rgba = np.ascontiguousarray(rgba)
    uncovered = cv2.subtract(np.full(rgba.shape[:2], 255, np.uint8), cv2.extractChannel(rgba, 3))
    behind = cv2.multiply(sky, cv2.cvtColor(uncovered, cv2.COLOR_GRAY2RGB), scale=1.0 / 255.0)
    return cv2.add(cv2.cvtColor(rgba, cv2.COLOR_RGBA2RGB), behind)
