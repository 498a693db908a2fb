"""The sky behind the colour pass: one image per camera orientation, kept while the ego keeps it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from domains.catalog import viewpoint, weather
from render_workers.render import sky as sky_module
from render_workers.render.camera import CameraRig
from render_workers.render.sky import SkyCache, cloud_texture, sky_image


def _camera(yaw: float, x: float = 0.0) -> np.ndarray:
    """world_from_camera (OpenGL axes: -z forward, y up) of a level camera at (x, 0, 1.5) turned by ``yaw``."""
    c, s = math.cos(yaw), math.sin(yaw)
    cam = np.eye(4)
    cam[:3, :3] = np.array([[-s, 0.0, -c], [c, 0.0, -s], [0.0, 1.0, 0.0]])
    cam[:3, 3] = (x, 0.0, 1.5)
    return cam


@pytest.fixture
def counted(monkeypatch):
    calls = []
    real = sky_module.sky_image

    def sky(*args):
        calls.append(args[2][:3, :3].copy())
        return real(*args)

    monkeypatch.setattr(sky_module, "sky_image", sky)
    return calls


def test_a_kept_sky_is_the_sky_to_the_byte_and_made_once_per_orientation(counted):
    clouds = cloud_texture(3)
    rig = CameraRig(viewpoint("A"), 96, 54)
    cache = SkyCache(clouds)
    for code in ("CN", "HRN"):
        for cam in (_camera(0.3), _camera(0.3, x=40.0), _camera(1.2), _camera(0.3)):
            got = cache(weather(code), rig, cam)
            assert got.tobytes() == sky_image(weather(code), rig, cam, clouds).tobytes()
            assert not got.flags.writeable  # shared between frames: nobody may paint on it
    # per weather: two orientations, each made once (moving along the road changes nothing)
    assert len(counted) == 2 * 2  # the cache's (the reference images above call the real function)
    assert cache(weather("CN"), CameraRig(viewpoint("A"), 48, 27), _camera(0.3)).shape == (27, 48, 3)


def test_the_cache_keeps_the_last_few_orientations_only(counted):
    cache = SkyCache(cloud_texture(0), size=2)
    rig, cn = CameraRig(viewpoint("A"), 32, 18), weather("CN")
    for yaw in (0.1, 0.2, 0.3, 0.1):  # 0.1 was pushed out by 0.3
        cache(cn, rig, _camera(yaw))
    assert len(counted) == 4
    cache(cn, rig, _camera(0.3))
    assert len(counted) == 4
