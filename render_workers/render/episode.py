"""Render one episode: spec -> world -> traffic -> frames handed to a sink. No Ray here.

Reads top to bottom like a worker script: look up the scenario, build (or reuse)
the town's world, populate it from the episode seed, load it into the
process's renderer, then for each frame (one every ``spec.frame_interval_s`` simulated
seconds, 3 by default) render the named buffers, post-process the colour, add the ``objects``
table when asked and call ``sink(frame)``; encoding the spec's outputs and
writing them is the sink's business (``pipeline.episode_job``). Only the drawing (``Renderer.render``) runs on the calling
thread; the rest of a frame (resolving the GL reads, post effects, outputs,
then the sink) runs on one background thread, in frame order, so finishing
and writing frame i (numpy, OpenCV, PNG deflate, hashing and file writes
release the GIL) overlaps drawing frame i + 1; at most ``SINK_AHEAD`` frames
wait for it.

Every random draw derives from ``spec.seed`` (traffic, sky, puddles, rain) or
from the town seed (world), so the same spec gives byte-identical PNGs.
"""

from __future__ import annotations

import atexit
import functools
import logging
import time
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from domains.catalog import NUM_CLASSES, scenario as lookup_scenario, town_variant, using, weather as lookup_weather
from domains.ramps import weather_at
from domains.conditions import frame_conditions
from domains.rigs import rig_from_json
from outputs.geometry import CV_FROM_GL, normals_from_depth, pose_cells
from outputs.objects import label_counts, object_counts
from manifests.schema import NEW_RULES
from outputs.table import BUFFERS
from roots.episode_spec import DrawSpec, check_frame_interval, check_rules, town_seed
from render_workers.render import postfx
from render_workers.worlds import testworld, traffic, worldcache, world as procedural_world
from render_workers.render.camera import measured_hood_fraction
from render_workers.render.flow import episode_flow
from render_workers.render.instances import frame_objects, instance_classes
from render_workers.render.lidar import LidarSweep, lidar_frame, lidar_sweep
from render_workers.render.memory import keep_freed_memory, scene_frozen
from render_workers.render.renderer import Renderer, RenderResult
from render_workers.worlds.scene import EpisodeScene, Frame, World
from render_workers.worlds.registry import DEFAULT_WORLD, WORLDS, check_world  # noqa: F401 (re-exported: the API since before the registry)

log = logging.getLogger(__name__)

_FX_STREAM = 404  # rng stream id of per-frame post effects

# outputs: the objects table and the counts; encoding the outputs into files is part of the sink.
FRAME_STAGES = ("scene_update", "color_pass", "class_pass", "resolve", "post_fx", "outputs", "sink", "sink_wait")
SINK_AHEAD = 2  # frames handed to the sink thread and not yet written


@dataclass(frozen=True)
class WorldBuilder:
    """The two functions a world provides."""

    build_world: Callable[[str, int], World]
    populate: Callable[[World, str, int], EpisodeScene]


# The worlds by name (render_workers.worlds.registry.WORLDS names the same ones).
BUILDERS: dict[str, WorldBuilder] = {
    "procedural": WorldBuilder(procedural_world.build_world, traffic.populate),
    "test": WorldBuilder(testworld.build_world, testworld.populate),
}


def world_builder(name: str) -> WorldBuilder:
    """The world registered as ``name``; ValueError naming the valid ones for unknown names."""
    check_world(name)
    return BUILDERS[name]


@functools.lru_cache(maxsize=8)
def cached_world(world: str, town_code: str, seed: int, variant: str = "") -> World:
    """A town's static world, loaded (or built) once per process and reused across its episodes.

    ``variant`` (``domains.catalog.town_variant``) tells a town a domain file
    declares or changes from the built-in town of its code; the catalog that
    declares it must be in force while it is built.

    The process's one world cache; behind it, built worlds are kept on disk
    (``render_workers.worlds.worldcache``), so a new worker loads instead of building."""
    return worldcache.load_or_build(world, town_code, seed, world_builder(world).build_world, variant)


@functools.lru_cache(maxsize=1)
def process_renderer() -> Renderer:
    """The worker process's long-lived renderer (its first frame compiles shaders).

    It is closed at interpreter exit, while PyOpenGL can still free it cleanly.
    """
    renderer = Renderer()
    atexit.register(renderer.close)
    return renderer


@dataclass(frozen=True)
class EpisodeInfo:
    """What rendering an episode reports back (small and serialisable)."""

    n_vehicles: int
    n_pedestrians: int
    frames: int
    timings: dict = field(default_factory=dict)  # stage -> total seconds over the episode


def validate_spec(spec: DrawSpec) -> None:
    """Raise ValueError for a spec no frame could be rendered from."""
    lookup_scenario(spec.scenario)
    if spec.frames < 1:
        raise ValueError(f"{spec.key}: frames must be at least 1, got {spec.frames}")
    if spec.width < 1 or spec.height < 1:
        raise ValueError(f"{spec.key}: image size must be positive, got {spec.width}x{spec.height}")
    if spec.seed < 0 or spec.run_seed < 0:
        raise ValueError(f"{spec.key}: seeds must be non-negative")
    if unknown := sorted(set(spec.buffers) - set(BUFFERS)):
        raise ValueError(f"{spec.key}: unknown buffers {', '.join(unknown)}; valid buffers: {', '.join(BUFFERS)}")
    check_frame_interval(spec.frame_interval_s)
    check_rules(spec.rules)


def load_episode(spec: DrawSpec, renderer: Renderer, world: str = DEFAULT_WORLD) -> tuple[EpisodeScene, dict]:
    """Build/reuse the world, populate it and load it into ``renderer``; returns scene and timings.

    The spec's user domain entries (``spec.catalog``) are in force meanwhile:
    the lookups by code below, and the world builders', see them."""
    with using(spec.catalog):
        return _load_episode(spec, renderer, world)


def _load_episode(spec: DrawSpec, renderer: Renderer, world: str) -> tuple[EpisodeScene, dict]:
    validate_spec(spec)
    scen = lookup_scenario(spec.scenario)
    timings = {}
    start = time.perf_counter()
    static = cached_world(world, scen.town.code, town_seed(spec.run_seed, scen.town), town_variant(scen.town))
    timings["world"] = time.perf_counter() - start
    start = time.perf_counter()
    scene = world_builder(world).populate(static, scen.viewpoint.code, spec.seed)
    timings["populate"] = time.perf_counter() - start
    start = time.perf_counter()
    renderer.load(scene, scen.weather, scen.viewpoint, spec.width, spec.height, sky_seed=spec.seed)
    timings["load"] = time.perf_counter() - start
    return scene, timings


def frame_weathers(spec: DrawSpec) -> list:
    """The weather each frame of ``spec`` is rendered under: its scenario's, or a shift's at that frame."""
    with using(spec.catalog):
        row = lookup_scenario(spec.scenario).weather
        return [weather_at(row, i, spec.frames, lookup_weather, spec.rules < NEW_RULES) for i in range(spec.frames)]


def render_frame(renderer: Renderer, scene: EpisodeScene, spec: DrawSpec, index: int) -> tuple[Frame, dict]:
    """Render frame ``index`` of a loaded episode; returns the frame and its stage timings."""
    result = renderer.render(spec.frame_time(index), frame_weathers(spec)[index])
    frame, timings = finish_frame(result, renderer, scene, spec, index)
    return frame, {**result.timings, **timings}


def finish_frame(result: RenderResult, renderer: Renderer, scene: EpisodeScene, spec: DrawSpec,
                 index: int, sensor: int = 0) -> tuple[Frame, dict]:
    """Frame ``index`` from its rendered buffers: post effects, the objects table (when asked), counts.

    No GL here: it reads only the episode's fixed state (weather, rig,
    instances, actors' paths), so it may run on another thread while the
    renderer draws the next frame."""
    t = spec.frame_time(index)
    buffers = dict(result.buffers)  # the GL reads are resolved here, off the render thread
    timings = {"resolve": result.resolve_s}
    start = time.perf_counter()
    ctx = postfx.FxContext(
        depth=buffers["depth"], classes=buffers["classes"], hood_mask=result.hood_mask, rig=result.rig,
        world_from_camera=result.world_from_camera, weather=result.weather,
        ego_speed_mps=scene.ego.speed_mps, sun_pixel=result.sun_pixel,
        rng=np.random.default_rng([spec.seed, _FX_STREAM, index] + ([sensor] if sensor else [])),
        episode_seed=spec.seed, world=scene.world, frame=index,
    )
    buffers["rgb"] = postfx.apply(buffers["rgb"], ctx)
    timings["post_fx"] = time.perf_counter() - start
    start = time.perf_counter()
    pixels = label_counts(buffers["instance"])  # per instance id: the objects table's and counts'
    if "objects" in spec.buffers:
        poses = result.actor_poses  # as the renderer posed them for this instant
        if poses is None:
            poses = [actor.pose(t) for actor in scene.actors]
        buffers["objects"] = frame_objects(buffers["instance"], renderer.instances, poses,
                                           result.world_from_camera, result.rig.focal_px, pixels)
    if "normals" in spec.buffers:  # opt-in: from the planar depth and the rig's intrinsics
        buffers["normals"] = normals_from_depth(buffers["depth"], result.rig.K)
    if "flow" in spec.buffers:  # opt-in: to the next frame; none after the last
        buffers["flow"] = (episode_flow(buffers["depth"], buffers["instance"], result.rig, scene, renderer.instances,
                                        t, spec.frame_time(index + 1)) if index + 1 < spec.frames
                           else np.zeros(buffers["depth"].shape + (3,), np.float32))
    counts = label_counts(buffers["classes"], NUM_CLASSES)
    objects = object_counts(buffers["instance"], instance_classes(renderer.instances), pixels)
    timings["outputs"] = time.perf_counter() - start
    ego_to_world = scene.ego.pose(t)
    frame = Frame(
        index=index, sim_time_s=t, buffers=buffers, class_counts=counts, object_counts=objects,
        camera_height_m=float(result.rig.cam_to_ego[2, 3]),
        hood_fraction=measured_hood_fraction(result.hood_mask), ego_speed_mps=float(scene.ego.speed_mps),
        n_vehicles=scene.n_vehicles, n_pedestrians=scene.n_pedestrians,
        conditions=frame_conditions(result.weather),
        **pose_cells(result.rig.K, result.world_from_camera @ CV_FROM_GL, ego_to_world, result.rig.cam_to_ego),
        sensor=rig_from_json(spec.rig).sensor_name(sensor),
    )
    return frame, timings


def _finish_and_sink(sink: Callable[[Frame], None], result, renderer: Renderer, scene: EpisodeScene,
                     spec: DrawSpec, index: int, sensor: int = 0) -> dict:
    """The back half of a frame, on the sink thread: finish it, then hand it to ``sink``; returns its timings.
    ``sensor``: the rig's sensor (its place in the rig); a LiDAR's ``result`` is its sweep."""
    if isinstance(result, LidarSweep):
        frame, timings = lidar_frame(result, scene, spec, index, sensor, frame_weathers(spec)[index]), {}
    else:
        frame, timings = finish_frame(result, renderer, scene, spec, index, sensor)
    start = time.perf_counter()
    sink(frame)
    timings["sink"] = time.perf_counter() - start
    return timings


def render_episode(spec: DrawSpec, sink: Callable[[Frame], None], *, world: str = DEFAULT_WORLD,
                   renderer: Renderer | None = None) -> EpisodeInfo:
    """Render every frame of ``spec`` and pass each to ``sink``; returns counts and timings.

    This thread draws (the GL passes); one background thread finishes each
    frame (resolves its GL reads, post effects, outputs) and calls ``sink``
    with it, in frame order, while the next frame is drawn. So a worker alone
    on the machine (the last episode of a run) keeps two cores busy. An error
    in either stops the episode and is raised here. Timings: ``sink`` is the
    time spent in it, ``sink_wait`` the time drawing waited for the background
    thread. A process that renders keeps the memory it frees, and the loaded scene stays out of
    Python's cyclic garbage collection while the frames render (``render_workers.render.memory``)."""
    keep_freed_memory()
    renderer = renderer if renderer is not None else process_renderer()
    scene, timings = load_episode(spec, renderer, world)
    weathers = frame_weathers(spec)
    for stage in FRAME_STAGES:
        timings[stage] = 0.0
    pending: deque[Future] = deque()

    def collect(future: Future) -> None:
        for stage, seconds in future.result().items():
            timings[stage] += seconds

    def settle(limit: int) -> None:
        start = time.perf_counter()
        while len(pending) > limit:
            collect(pending.popleft())
        timings["sink_wait"] += time.perf_counter() - start

    rig = rig_from_json(spec.rig)
    with scene_frozen(), ThreadPoolExecutor(max_workers=1, thread_name_prefix="idda-sink") as pool:
        try:
            for index in range(spec.frames):
                for k, sensor in enumerate(rig.sensors):  # every sensor at the frame's instant, in rig order
                    if sensor.kind == "lidar":
                        start, cpu = time.perf_counter(), time.thread_time()
                        result = lidar_sweep(renderer, sensor, spec.frame_time(index), spec.width, spec.height)
                        timings["lidar"] = timings.get("lidar", 0.0) + time.perf_counter() - start
                        timings["lidar_cpu"] = timings.get("lidar_cpu", 0.0) + time.thread_time() - cpu  # this thread's
                    else:
                        if not rig.is_default:
                            renderer.use_sensor(sensor, *sensor.size(spec.width, spec.height))
                        result = renderer.render(spec.frame_time(index), weathers[index])
                        for stage, seconds in result.timings.items():
                            timings[stage] += seconds
                    while pending and pending[0].done():  # surface a sink error early
                        collect(pending.popleft())
                    settle(SINK_AHEAD - 1)
                    pending.append(pool.submit(_finish_and_sink, sink, result, renderer, scene, spec, index, k))
            settle(0)
        finally:
            for future in pending:  # after an error: drop frames not yet started
                future.cancel()
    if not rig.is_default:
        renderer.use_sensor(None, spec.width, spec.height)  # the next episode starts from the viewpoint's camera
    log.debug("%s: %d frames, timings %s", spec.key, spec.frames, timings)
    return EpisodeInfo(n_vehicles=scene.n_vehicles, n_pedestrians=scene.n_pedestrians,
                       frames=spec.frames, timings=timings)
