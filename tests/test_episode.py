"""End to end: a small episode of the test world renders headless, deterministically."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from domains.catalog import NUM_CLASSES, PALETTE
from outputs.table import DEFAULT_OUTPUTS as OUTPUTS, IMAGE_OUTPUTS, read_output
from roots.episode_spec import FRAME_PERIOD_S, DrawSpec, EpisodeSpec
from pipeline.episode_job import frame_files, frame_outputs
from render_workers.render import episode
from render_workers.worlds.registry import WORLDS
from render_workers.worlds import testworld
from outputs.encoding import decode_depth_raw
from render_workers.render.renderer import Renderer

W, H = 160, 90


def spec(scenario: str = "T01_CN_A", seed: int = 3, frames: int = 2, width: int = W, height: int = H) -> EpisodeSpec:
    return EpisodeSpec(scenario, 0, seed, frames, width, height, "train", 0)


@pytest.fixture(scope="module")
def renderer():
    with Renderer() as r:
        yield r


def run(s: EpisodeSpec, renderer: Renderer):
    frames = []
    info = episode.render_episode(s.drawing, frames.append, world="test", renderer=renderer)
    return info, frames


def test_small_episode_renders_headless(renderer):
    info, frames = run(spec(), renderer)
    assert info.frames == len(frames) == 2
    assert 20 <= info.n_vehicles <= 150 and 0 <= info.n_pedestrians <= 100
    for stage in episode.FRAME_STAGES + ("world", "populate", "load"):
        assert info.timings[stage] >= 0.0
    for index, frame in enumerate(frames):
        assert frame.index == index and frame.sim_time_s == index * FRAME_PERIOD_S
        outputs = frame_outputs(spec(), frame)
        assert tuple(outputs) == OUTPUTS
        for name in (n for n in IMAGE_OUTPUTS if n in outputs):
            image = outputs[name]
            assert image.shape[:2] == (H, W) and image.dtype == (np.uint16 if name == "instance" else np.uint8), name
        assert frame.class_counts.shape == (NUM_CLASSES,)
        assert frame.class_counts.sum() == W * H
        ids = outputs["semantic_raw"][..., 0]
        assert ids.max() < NUM_CLASSES and not outputs["semantic_raw"][..., 1:].any()
        assert (outputs["semantic_color"] == PALETTE[ids]).all()
        assert (np.bincount(ids.ravel(), minlength=NUM_CLASSES) == frame.class_counts).all()
        assert frame.camera_height_m == 1.20 and frame.ego_speed_mps > 0
        assert 0.1108 - 1 / H <= frame.hood_fraction <= 0.1399 + 1 / H


def test_depth_outputs_agree(renderer):
    _, frames = run(spec(frames=1), renderer)
    images = frame_outputs(spec(frames=1), frames[0])
    depth = decode_depth_raw(images["depth_raw"])
    assert depth.max() <= 1000.0 and depth.min() > 0.0
    sky = images["semantic_raw"][..., 0] == 20
    assert np.allclose(depth[sky], 1000.0)
    gray = np.rint(depth / 1000.0 * 255.0)
    assert np.abs(gray - images["depth_gray"][..., 0]).max() <= 1


def test_no_hood_for_van_and_bus(renderer):
    for view in ("V", "B"):
        _, frames = run(spec(f"T01_CN_{view}", frames=1), renderer)
        assert frames[0].hood_fraction == 0.0


def test_every_class_is_visible_in_the_test_world(renderer):
    _, frames = run(spec("T01_CN_V", seed=1, width=480, height=270), renderer)
    seen = sum(f.class_counts for f in frames)
    assert [c for c in range(1, 23) if seen[c] == 0] == []


def test_same_spec_gives_identical_pngs(renderer):
    s = spec("T02_HRN_M", seed=11)
    _, first = run(s, renderer)
    with Renderer() as fresh:  # a fresh process-like renderer: no cached static nodes
        _, second = run(s, fresh)
    for a, b in zip(first, second):
        assert frame_files(s, a) == frame_files(s, b)
    _, other = run(spec("T02_HRN_M", seed=12), renderer)
    assert frame_files(s, other[0])["rgb"] != frame_files(s, first[0])["rgb"]


def test_encode_frame_round_trips(renderer):
    _, frames = run(spec(frames=1), renderer)
    data = frame_files(spec(frames=1), frames[0])
    outputs = frame_outputs(spec(frames=1), frames[0])
    assert tuple(data) == OUTPUTS
    for name, blob in data.items():
        if name in IMAGE_OUTPUTS:
            assert (read_output(name, blob) == outputs[name]).all()
        else:
            assert read_output(name, blob).equals(outputs[name])


def test_populate_counts_follow_idda():
    world = testworld.build_world("T01", 0)
    for seed in range(6):
        scene = testworld.populate(world, "A", seed)
        assert 20 <= scene.n_vehicles <= 150
        assert 0 <= scene.n_pedestrians <= 100
        assert len(scene.actors) == scene.n_vehicles + scene.n_pedestrians
    same = testworld.populate(world, "A", 4), testworld.populate(world, "A", 4)
    assert same[0].n_vehicles == same[1].n_vehicles and same[0].ego.offset_m == same[1].ego.offset_m


def test_world_registry_is_lazy_and_validated():
    with pytest.raises(ValueError, match="valid worlds"):
        episode.world_builder("nope")
    builder = episode.world_builder("test")
    assert builder.build_world is testworld.build_world and builder.populate is testworld.populate
    assert tuple(episode.BUILDERS) == WORLDS  # the light registry (driver, CLI) names the builders bound here
    assert episode.cached_world("test", "T01", 5) is episode.cached_world("test", "T01", 5)


def test_bad_spec_raises_before_rendering(renderer):
    with pytest.raises(ValueError, match="frames"):
        episode.render_episode(spec(frames=0).drawing, lambda f: None, world="test", renderer=renderer)
    with pytest.raises(ValueError, match="unknown town"):
        episode.render_episode(spec("T99_CN_A").drawing, lambda f: None, world="test", renderer=renderer)


# what only the writer needs of a job: how frames are encoded and where they are filed
WRITER_FIELDS = {"outputs", "rgb_format", "layout", "png_deflater", "split"}


def test_the_renderer_takes_only_what_it_draws():
    """Issue 36: the render functions take a DrawSpec, which holds none of the writer's fields; every
    other field of the job reaches the renderer (a new job field must be placed on one side)."""
    import dataclasses
    import inspect

    drawn = {f.name for f in dataclasses.fields(DrawSpec)}
    assert not drawn & WRITER_FIELDS
    assert {f.name for f in dataclasses.fields(EpisodeSpec)} - WRITER_FIELDS == drawn - {"buffers"}
    for function in (episode.render_episode, episode.load_episode, episode.render_frame, episode.finish_frame,
                     episode.frame_weathers, episode.validate_spec):
        assert inspect.signature(function).parameters["spec"].annotation == "DrawSpec", function.__name__
    job = spec(frames=3)
    assert job.drawing == DrawSpec(job.scenario, 0, job.seed, 3, W, H, 0, job.buffers)
    with pytest.raises(ValueError, match="unknown buffers"):
        episode.validate_spec(dataclasses.replace(job.drawing, buffers=frozenset({"rgb", "sparkle"})))


def test_sink_runs_in_frame_order_off_the_render_thread(renderer):
    import threading

    seen = []
    episode.render_episode(spec(frames=4).drawing, lambda f: seen.append((f.index, threading.current_thread())),
                           world="test", renderer=renderer)
    assert [i for i, _ in seen] == [0, 1, 2, 3]
    assert all(t is not threading.main_thread() for _, t in seen)


def test_each_actor_is_posed_once_per_frame_and_the_objects_match_posing_afresh(renderer, monkeypatch):
    """The renderer's poses of a frame are the ones its objects table is made from: each actor
    posed once per frame (131 actors cost ~1 ms a posing), the same table as posing them again."""
    from render_workers.render import renderer as renderer_module
    from render_workers.worlds.scene import Actor

    job = spec(frames=3).drawing
    shared = [frame.buffers["objects"] for frame in run(spec(frames=3), renderer)[1]]
    posed = []
    pose = Actor.pose
    monkeypatch.setattr(Actor, "pose", lambda self, t: (posed.append((bool(self.parts), t)), pose(self, t))[1])
    frames = run(spec(frames=3), renderer)[1]
    actors = len(episode.load_episode(job, renderer, "test")[0].actors)
    assert len([t for drawn, t in posed if drawn]) == 3 * actors  # the ego (no parts) poses the camera
    monkeypatch.setattr(renderer_module.RenderResult, "actor_poses", property(lambda self: None, lambda self, v: None), raising=False)
    fresh = [frame.buffers["objects"] for frame in run(spec(frames=3), renderer)[1]]
    assert all(a.equals(b) and a.equals(c.buffers["objects"]) for a, b, c in zip(shared, fresh, frames))
    assert shared[0].num_rows > 0


def test_the_render_thread_only_draws(renderer, monkeypatch):
    """The sky and the decoding of the class pass run where the frame is finished,
    off the render thread, and give the same frame as resolving it at once."""
    import threading

    from render_workers.render import sky as sky_module

    real = sky_module.SkyCache.__call__
    skies = []

    def sky_image(*args):
        skies.append(threading.current_thread())
        return real(*args)

    monkeypatch.setattr(sky_module.SkyCache, "__call__", sky_image)
    _, frames = run(spec(frames=3), renderer)
    assert len(skies) == 3 and all(t is not threading.main_thread() for t in skies)
    scene, _ = episode.load_episode(spec(frames=3).drawing, renderer, "test")
    result = renderer.render(0.0)
    assert len(skies) == 3  # drawn, not resolved yet
    frame, _ = episode.finish_frame(result, renderer, scene, spec(frames=3).drawing, 0)
    assert result.buffers is result.buffers and len(skies) == 4  # resolved once, then kept
    assert frame_files(spec(frames=3), frame) == frame_files(spec(frames=3), frames[0])


def test_a_sink_error_stops_the_episode_and_is_raised(renderer):
    seen = []

    def sink(frame):
        seen.append(frame.index)
        if frame.index == 1:
            raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        episode.render_episode(spec(frames=6).drawing, sink, world="test", renderer=renderer)
    assert seen[:2] == [0, 1] and len(seen) <= 1 + episode.SINK_AHEAD + 1


def test_the_test_worlds_fast_box_is_trimeshs_box_to_the_bit():
    """testworld._box skips trimesh's Trimesh per box (most of an episode's population time); its
    numbers must stay those of trimesh.creation.box(extents) moved by apply_transform, or every
    test-world frame would change."""
    rng = np.random.default_rng(7)
    for k in range(200):
        extents, centre = rng.uniform(0.05, 40.0, 3), rng.uniform(-500.0, 500.0, 3)
        yaw = float(rng.uniform(-math.pi, math.pi)) if k % 2 else 0.0
        want = trimesh.creation.box(extents=extents)
        want.apply_transform(testworld._transform(centre, yaw))
        got = testworld._box(extents, centre, yaw)
        assert got.vertices.tobytes() == want.vertices.tobytes() and got.faces.tobytes() == want.faces.tobytes()
