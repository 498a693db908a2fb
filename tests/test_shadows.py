"""Sun shadows: direction and length follow the sun, overcast stays flat, labels and depth never change."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from domains.catalog import weather
from roots.episode_spec import EpisodeSpec
from pipeline.episode_job import frame_files
from render_workers.render import episode
from render_workers.render.camera import CameraRig, sun_direction
from render_workers.render.renderer import (
    MIN_SHADOW_STRENGTH, SHADOW_FAR_M, Renderer, fit_shadow_frame, shadow_strength,
)
from render_workers.worlds.scene import Part
from tests.test_renderer import flat_scene
from domains.catalog import viewpoint

W, H = 480, 270
WALL = 11
BOX_HEIGHT_M = 6.0


def _box(x: float, y: float) -> Part:
    mesh = trimesh.creation.box((4.0, 4.0, BOX_HEIGHT_M))
    mesh.apply_translation((x, y, BOX_HEIGHT_M / 2))
    mesh.visual.vertex_colors = np.tile([200, 60, 60, 255], (len(mesh.vertices), 1))
    return Part(WALL, mesh, "matte")


@pytest.fixture(scope="module")
def renderer():
    with Renderer() as r:
        yield r


def _render(r: Renderer, scene, code: str, shadows: bool):
    r.shadows = shadows
    r.load(scene, weather(code), viewpoint("V"), W, H)
    return r.render(0.0)


def _patch(result, world_xy: tuple[float, float], half: int = 2) -> np.ndarray:
    """Mean RGB around the pixel where a ground point (z = 0) appears."""
    cam_from_world = np.linalg.inv(result.world_from_camera)
    p = cam_from_world @ np.array([world_xy[0], world_xy[1], 0.0, 1.0])
    x, y = result.rig.project(p[None, :3])[0]
    col, row = int(x), int(y)
    assert half <= col < W - half and half <= row < H - half, (col, row)
    return result.buffers["rgb"][row - half:row + half + 1, col - half:col + half + 1].reshape(-1, 3).mean(axis=0)


def _away_from_sun(code: str) -> np.ndarray:
    """Horizontal unit vector pointing where the sun's shadows fall."""
    sun = sun_direction(weather(code).sun_elevation_deg, weather(code).sun_azimuth_deg)
    return -sun[:2] / np.linalg.norm(sun[:2])


def test_noon_box_shadow_falls_away_from_the_sun(renderer):
    centre = np.array([20.0, 0.0])
    scene = flat_scene((_box(*centre),))
    on = _render(renderer, scene, "CN", True)
    off = _render(renderer, scene, "CN", False)
    away = _away_from_sun("CN")  # CN sun: ahead-left, so the shadow falls back-right, towards the camera
    length = BOX_HEIGHT_M / math.tan(math.radians(weather("CN").sun_elevation_deg))  # ~2.8 m
    shadowed = centre + away * (2.6 + 0.5 * length)  # 2.6 m: leaving the 4 m box along that direction
    lit = shadowed * [1.0, -1.0]  # mirrored across the view axis: same distance, beside the box
    assert _patch(on, shadowed).sum() < 0.6 * _patch(on, lit).sum()
    assert _patch(off, shadowed).sum() == pytest.approx(_patch(off, lit).sum(), rel=0.03)
    beyond = centre + away * (2.6 + length + 2.0)  # past the shadow's tip: lit again
    assert _patch(on, beyond).sum() == pytest.approx(_patch(off, beyond).sum(), abs=3)


def test_sunset_shadows_are_long(renderer):
    centre = np.array([15.0, -4.0])
    scene = flat_scene((_box(*centre),))
    away = _away_from_sun("CS")  # CS sun behind-right: the shadow runs forward-left
    far_point = centre + away * 25.0  # ~4 box heights away: only a low sun reaches it
    cs_on, cs_off = _render(renderer, scene, "CS", True), _render(renderer, scene, "CS", False)
    cn_on, cn_off = _render(renderer, scene, "CN", True), _render(renderer, scene, "CN", False)
    assert _patch(cs_on, far_point).sum() < _patch(cs_off, far_point).sum() - 6
    assert _patch(cn_on, far_point).sum() == pytest.approx(_patch(cn_off, far_point).sum(), abs=3)


def test_overcast_light_stays_flat(renderer):
    assert shadow_strength(weather("HRN")) < MIN_SHADOW_STRENGTH <= shadow_strength(weather("CS"))
    scene = flat_scene((_box(20.0, 0.0),))
    on, off = _render(renderer, scene, "HRN", True), _render(renderer, scene, "HRN", False)
    assert np.abs(on.buffers["rgb"].astype(int) - off.buffers["rgb"].astype(int)).max() <= 2


@pytest.mark.parametrize("code", ["CN", "CS", "HRN"])
def test_classes_and_depth_do_not_change(renderer, code):
    scene = flat_scene((_box(20.0, 0.0), _box(12.0, 6.0)))
    on, off = _render(renderer, scene, code, True), _render(renderer, scene, code, False)
    assert np.array_equal(on.buffers["classes"], off.buffers["classes"])
    assert np.array_equal(on.buffers["depth"], off.buffers["depth"])
    assert np.array_equal(on.hood_mask, off.hood_mask)
    if code != "HRN":
        assert not np.array_equal(on.buffers["rgb"], off.buffers["rgb"])


@pytest.mark.parametrize("code", ["CN", "CS"])
def test_light_frustum_covers_the_view(code):
    """Ground the camera sees within SHADOW_FAR_M lands inside the shadow map."""
    rig = CameraRig(viewpoint("A"), 1920, 1080)
    sun = sun_direction(weather(code).sun_elevation_deg, weather(code).sun_azimuth_deg)
    rng = np.random.default_rng(0)
    for heading in np.linspace(0.0, 2 * math.pi, 7, endpoint=False):
        ego = np.eye(4)
        ego[:2, :2] = [[math.cos(heading), -math.sin(heading)], [math.sin(heading), math.cos(heading)]]
        ego[:3, 3] = rng.uniform(-500, 500, 3) * [1, 1, 0.02]
        cam = rig.world_from_camera(ego)
        view, proj, _ = fit_shadow_frame(sun, cam, rig)
        forward, right = ego[:3, 0], -ego[:3, 1]
        ahead = rng.uniform(0.0, SHADOW_FAR_M, 200)
        across = rng.uniform(-1.0, 1.0, 200) * ahead * rig.tan_half_h
        heights = rng.uniform(0.0, 20.0, 200)
        points = ego[:3, 3] + ahead[:, None] * forward + across[:, None] * right + heights[:, None] * [0, 0, 1]
        ndc = (proj @ view @ np.c_[points, np.ones(len(points))].T).T
        assert (np.abs(ndc[:, :3]) <= 1.0).all()


def test_same_spec_gives_identical_pngs_with_shadows(renderer):
    spec = EpisodeSpec("T01_CS_A", 0, 5, 2, 160, 90, "train", 0)
    renderer.shadows = True  # the other tests toggle it
    runs = []
    for r in (renderer, None):
        frames: list = []
        if r is None:
            with Renderer() as fresh:
                episode.render_episode(spec.drawing, frames.append, world="test", renderer=fresh)
        else:
            episode.render_episode(spec.drawing, frames.append, world="test", renderer=r)
        runs.append([frame_files(spec, f) for f in frames])
    assert runs[0] == runs[1]


def test_closing_one_renderer_leaves_another_intact():
    """A closed renderer's leftovers, collected later, must not free GL objects of the renderer in use.

    pyrender's inner renderer frees its buffers again from ``__del__``, in
    whatever context is current then; CI once lost the shadow framebuffer of a
    live renderer that way (GLError on glBindFramebuffer) when the garbage
    collector ran mid-test.
    """
    import gc

    scene = flat_scene((_box(20.0, 0.0),))
    with Renderer() as kept:
        before = _render(kept, scene, "CN", True).buffers["rgb"]
        with Renderer() as other:
            _render(other, scene, "CN", True)
        _render(kept, scene, "CN", True)  # the kept renderer's context is current again
        gc.collect()  # the closed renderer's leftovers go now, while that context is current
        after = _render(kept, scene, "CN", True).buffers["rgb"]
    assert np.array_equal(before, after)


@pytest.mark.parametrize("code", ["CN", "HRN"])
def test_forward_pass_patch_draws_pyrenders_pixels(code):
    """passes.install_forward_pass sets per-pass uniforms once per program, and draws the labels and
    depth in the colour pass itself; colour, classes, instances and depth stay byte for byte what
    pyrender's own colour and SEG passes draw (test world, actors and traffic lights included,
    shadows on where the weather has them; it shows no back faces, where pyrender's SEG pass, which
    culls them, would differ)."""
    spec = EpisodeSpec(f"T01_{code}_A", 0, 5, 1, 320, 180, "train", 0).drawing
    with Renderer() as r:
        scene, _ = episode.load_episode(spec, r, world="test")
        assert r.merged
        patched = r.render(3.0)
        inner = r._offscreen._renderer
        del inner._forward_pass  # back to pyrender's method, which has no merged pass: two passes
        r.merged = False
        plain = r.render(3.0)
    for name, buffer in patched.buffers.items():
        assert buffer.dtype == plain.buffers[name].dtype and buffer.tobytes() == plain.buffers[name].tobytes(), name
