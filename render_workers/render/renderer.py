"""Off-screen pyrender backend: EpisodeScene + time -> lit RGB, planar depth, class ids.

One :class:`Renderer` lives per worker process (the first render compiles
shaders, ~1.5 s). Per episode, :meth:`Renderer.load` builds the pyrender scene
once: static parts are split into ``tile_m`` ground tiles and merged per
(tile, class, material), so a town is a few hundred nodes that can be culled by
distance and view; each actor becomes one node per (class, material), posed
per frame. The hood is a child of the camera node.

Each :meth:`Renderer.render` draws one colour pass (sun as a DirectionalLight
plus ambient light, no multisampling: geometry edges are anti-aliased in post,
``postfx.antialias``), composited over a procedural sky by its alpha coverage.
The same pass writes each node's ``(class_id, instance id low byte, high byte)``
(``render_workers.render.instances``: the hood, actors and static traffic lights
and signs have ids; merged static tiles 0) into a second colour attachment
(``passes.install_forward_pass``, "merged"), so the labels and the metric depth
(background -> sky, 0 and 1000 m) are crisp, never blended, and are exactly the
surfaces the colour shows, back faces included. A renderer with multisampling
or pyrender's own shader (``msaa``, ``pbr``) draws them in a second,
``RenderFlags.SEG`` pass instead, with the same values. That class pass alone is
``render_labels`` (LiDAR, rig sensors).

The render thread only draws and reads back; compositing the sky and decoding
the SEG colours happen when the frame's :class:`RenderResult` is first used.

Lighting: pyrender's PBR fragment shader costs ~1 s per 1920x1080 frame on
llvmpipe, so by default the colour pass swaps in :data:`render_workers.render.shaders.FAST_MESH_FRAG` (Lambert
diffuse + normalised Blinn-Phong specular from the material's roughness and
metallic factors, ambient, emissive, two-sided, gamma 2.2), about 4x cheaper.
``Renderer(pbr=True)`` keeps pyrender's own shader.

Shadows (``Renderer(shadows=True)``, the default): the sun casts shadow-mapped
shadows. Each frame, :func:`fit_shadow_frame` fits an orthographic light
frustum around what the camera sees up to :data:`SHADOW_FAR_M` (a trapezoid on
the ground from :data:`SHADOW_BACK_M` behind the camera, up to
:data:`SHADOW_TOP_M` above the road), aligned with the view direction, so a
:data:`SHADOW_MAP_PX` map has texels of ~0.1-0.15 m, and picks as casters the
nodes whose bounding spheres reach into it (including ones culled from the
view, e.g. a car beside the ego at sunset; the hood casts nothing). The colour
pass samples the map with one hardware PCF tap (2x2 texels, bilinear) and scales
only the sun's term: ambient and emissive light stay. Shadow strength is
``1 - cloudiness`` (CN 0.9, CS 0.85); below :data:`MIN_SHADOW_STRENGTH` (HRN:
0.05, at most ~2 grey levels) the shadow pass is skipped and the light stays
flat. Shadows fade out between :data:`SHADOW_FADE_M` and :data:`SHADOW_FAR_M`
from the camera (receivers farther away stay lit).
Labels and depth take no light (a uniform colour per node; a SEG pass binds
no lights and takes no shadow pass), so they are identical with shadows on or off. See ``render_workers.render.passes`` for
the pyrender internals this overrides.

pyrender rules this module follows are listed in ``render_workers.render.pyrender_setup``.
"""

from __future__ import annotations

import functools
import logging
import math
import threading
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from domains.catalog import Viewpoint, Weather, class_id, lookup
from render_workers.render import pyrender_setup as compat, passes
from render_workers.render.camera import CameraRig, hood_mesh, sun_direction
from render_workers.render.sky import SkyCache, cloud_texture, composite_sky
from render_workers.render.instances import HOOD_ID, episode_instances, split_static
from render_workers.worlds.scene import EpisodeScene
from render_workers.render.shaders import FAST_MESH_FRAG
from render_workers.render.part_meshes import _pyrender_mesh, _Soup, _sphere, _triangles, part_groups, static_groups

log = logging.getLogger(__name__)

ZNEAR_M = 0.1
ZFAR_M = 1000.0  # the dataset's far limit; pyrender's default (100 m) is too short
CULL_M = 450.0  # static tiles and actors farther than this are not drawn
TILE_M = 200.0  # static geometry is split into square tiles of this size
SKY_ID = class_id("sky")
VEHICLE_ID = class_id("vehicle")
SUN_SCALE = 0.55  # exposure: Weather.light_intensity x this keeps noon albedo from clipping
SHADOW_MAP_PX = 2048  # shadow map size (square)
SHADOW_FAR_M = 150.0  # shadows reach this far from the camera ...
SHADOW_FADE_M = 110.0  # ... fading out from this distance
SHADOW_BACK_M = 20.0  # the shadow map also covers this much behind and beside the camera
SHADOW_TOP_M = 30.0  # receivers up to this height above the road
CASTER_TOP_M = 60.0  # casters up to this height (sets how far towards the sun the depth range reaches)
MIN_SHADOW_STRENGTH = 0.1  # fainter shadows (overcast: HRN's would be 0.05) are skipped, saving their cost


# --------------------------------------------------------------------------
# Renderer
# --------------------------------------------------------------------------
class RenderResult:
    """One frame as the GL passes left it; its buffers are resolved on first use.

    Resolving (the sky behind the colour pass, class and instance ids out of
    the SEG colours, the background's depth) is numpy and OpenCV with no GL, so
    the renderer leaves it to whoever first asks for ``buffers`` or
    ``hood_mask``: in production the episode's second thread, while the render
    thread draws the next frame. ``resolve_s`` is the time that took.

    ``buffers``: name -> array: "rgb" (HxWx3 uint8, lit geometry over the sky),
    "depth" (HxW float32 planar metres, background ZFAR_M), "classes" (HxW
    uint8, background sky), "instance" (HxW uint16 instance ids, background 0).
    ``hood_mask``: HxW bool, the pixels drawn by the ego hood.
    """

    def __init__(self, *, rgba: np.ndarray, seg: np.ndarray, depth: np.ndarray, sky: Callable[[], np.ndarray],
                 zfar: float, world_from_camera: np.ndarray, rig: CameraRig,
                 sun_pixel: tuple[float, float] | None, timings: dict, weather: Weather,
                 actor_poses: list | None = None) -> None:
        self.world_from_camera = world_from_camera  # 4x4
        self.weather = weather  # the parameters this frame was lit under (a shift's, at its time)
        self.rig = rig
        self.sun_pixel = sun_pixel  # sun position in pixels when in front of the camera
        self.timings = timings  # stage -> seconds, of the GL passes
        self.actor_poses = actor_poses  # every actor's world-from-actor pose at the frame's time, where posed
        self.resolve_s = 0.0
        self._raw = (rgba, seg, depth, sky, zfar)
        self._buffers: dict | None = None
        self._hood: np.ndarray | None = None
        self._lock = threading.Lock()

    @property
    def buffers(self) -> dict:
        self._resolve()
        return self._buffers

    @property
    def hood_mask(self) -> np.ndarray:
        self._resolve()
        return self._hood

    def _resolve(self) -> None:
        with self._lock:
            if self._buffers is not None:
                return
            start = time.perf_counter()
            rgba, seg, depth, sky, zfar = self._raw
            depth, classes, instance = decode_labels(seg, depth, zfar)
            self._hood = instance == HOOD_ID
            rgb = composite_sky(rgba, sky())
            self._buffers = {"rgb": rgb, "depth": depth, "classes": classes, "instance": instance}
            self._raw = None  # the GL reads are no longer needed
            self.resolve_s = time.perf_counter() - start


def decode_labels(seg: np.ndarray, depth: np.ndarray, zfar: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A pass's SEG colours and linear depth -> (planar depth float32 metres, class ids uint8, instance
    ids uint16); where nothing was drawn (depth 0): ``zfar``, sky and 0."""
    background = depth <= 0.0
    classes = seg[..., 0].copy()
    classes[background] = SKY_ID
    # green low byte, blue high byte: the two adjacent bytes read as one little-endian uint16
    instance = seg[..., 1:3].view("<u2")[..., 0].copy()
    instance[background] = 0
    depth = np.minimum(depth, np.float32(zfar), dtype=np.float32)
    depth[background] = zfar
    return depth, classes, instance


@dataclass
class _NodeSet:
    nodes: list
    centres: np.ndarray  # (N, 3) bounding-sphere centres (world for static, local for actors)
    radii: np.ndarray  # (N,)


def _node_set(items) -> tuple[_NodeSet, list[int]]:
    """One mesh node per (class id, material, triangle soup), with its bounding
    sphere, in the given order; and the class id of each node."""
    pr = compat.import_pyrender()
    nodes, centres, radii, keys = [], [], [], []
    for cls, material, soup, texture in items:
        mesh, positions = _pyrender_mesh(soup, material, texture)
        centre, radius = _sphere(positions)
        nodes.append(pr.Node(mesh=mesh))  # identity, as matrix=np.eye(4) gives, without deriving a quaternion from it
        centres.append(centre)
        radii.append(radius)
        keys.append(cls)
    return _NodeSet(nodes, np.array(centres).reshape(-1, 3), np.array(radii)), keys


def _draws(method):
    """A renderer method that drives GL. Cut short (an exception, or Ray's cancel raising KeyboardInterrupt
    in the task's thread mid-pass), it may leave the context's state half-set (a shadow pass's polygon
    offset stayed on: every later episode without shadows drew its depth shifted) and the renderer's
    caches half-built; ``_cut_short`` stays set then, and the next :meth:`Renderer.load` starts afresh."""

    @functools.wraps(method)
    def drawing(self, *args, **kwargs):
        outer = self._cut_short
        self._cut_short = True
        result = method(self, *args, **kwargs)
        self._cut_short = outer
        return result

    return drawing


class Renderer:
    """A long-lived off-screen renderer; call :meth:`load` per episode, then :meth:`render`.

    A draw cut short (see ``_draws``) costs a fresh GL context at the next :meth:`load`, so the
    episodes after it are drawn as by a new renderer, byte for byte."""

    def __init__(self, *, znear: float = ZNEAR_M, zfar: float = ZFAR_M, cull_m: float = CULL_M,
                 tile_m: float = TILE_M, pbr: bool = False, msaa: int = 0, shadows: bool = True,
                 shadow_map_px: int = SHADOW_MAP_PX) -> None:
        if not 0 < znear < zfar:
            raise ValueError(f"need 0 < znear < zfar, got {znear}, {zfar}")
        self.znear, self.zfar, self.cull_m, self.tile_m = znear, zfar, cull_m, tile_m
        self.pbr = pbr
        self.shadows = shadows  # may be toggled between frames
        self.shadow_map_px = shadow_map_px
        self._shadow_frame: passes.ShadowFrame | None = None
        # 0: no multisampling (half the colour pass on llvmpipe); edges are
        # anti-aliased in post instead (postfx.antialias).
        if msaa not in passes.MSAA_CHOICES:
            raise ValueError(f"MSAA samples must be one of {passes.MSAA_CHOICES}, got {msaa}")
        self.msaa = msaa
        # One pass draws colour, labels and depth (the fast shader's second output) unless
        # multisampled (ids would be blended) or lit by pyrender's own shader (it has no such output).
        self.merged = msaa == 0 and not pbr
        self._offscreen = None
        self._size: tuple[int, int] | None = None
        self._static_world = None  # the World whose static nodes are cached
        self._static: _NodeSet | None = None
        self._scene = None
        self._episode: EpisodeScene | None = None
        self._draw_list: list = []
        self._near_first: list = []  # this frame's draw order (update)
        self._rank: dict = {}
        self._cut_short = False  # a GL call of this renderer was interrupted: load() starts afresh

    # -- lifecycle ---------------------------------------------------------
    def __enter__(self) -> "Renderer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        offscreen, self._offscreen = self._offscreen, None
        self._scene = self._static = self._static_world = self._episode = None
        self._draw_list, self._near_first, self._rank = [], [], {}
        if offscreen is not None:
            compat.delete_offscreen(offscreen)

    def _ensure_context(self, width: int, height: int) -> None:
        if self._offscreen is None:
            self._offscreen = compat.offscreen_renderer(width, height)
            if not self.pbr:
                passes.install_mesh_shader(self._offscreen, FAST_MESH_FRAG)
            passes.install_framebuffer(self._offscreen, self.msaa)
            passes.install_shadow_pass(self._offscreen, lambda: self._shadow_frame, depth_compare=not self.pbr)
            # pyrender sorts nodes by distance and breaks ties in set (id) order,
            # so coplanar faces could resolve differently from run to run: here
            # nearest first with ties in the order load() built them (update()).
            compat.install_draw_order(self._offscreen, self._draw_order)
            passes.install_forward_pass(self._offscreen)
        elif self._size != (width, height):
            self._offscreen.viewport_width, self._offscreen.viewport_height = width, height
        self._size = (width, height)

    # -- per episode -------------------------------------------------------
    def load(self, scene: EpisodeScene, weather: Weather, viewpoint: Viewpoint, width: int, height: int,
             sky_seed: int = 0) -> None:
        """Build the pyrender scene of an episode (static nodes are reused for the same World); after a
        draw cut short, in a fresh GL context."""
        if self._cut_short:
            log.warning("the last draw was cut short: the renderer starts a fresh GL context")
            self._cut_short = False
            self.close()
        self._load(scene, weather, viewpoint, width, height, sky_seed)

    @_draws
    def _load(self, scene: EpisodeScene, weather: Weather, viewpoint: Viewpoint, width: int, height: int,
              sky_seed: int) -> None:
        pr = compat.import_pyrender()
        self._ensure_context(width, height)
        self.rig = CameraRig(viewpoint, width, height)
        self.weather = weather
        self._episode = scene
        self._sky = SkyCache(cloud_texture(sky_seed))  # per episode: its clouds

        if self._static_world is not scene.world:
            self._static = self._build_static(scene.world)
            self._static_world = scene.world
        self._actors, self._actor_of = self._build_actors(scene)
        self._posed_at = None  # (t, the actors' world centres, their poses): the instant last posed for

        prs = pr.Scene(bg_color=[0.0, 0.0, 0.0, 0.0], ambient_light=_ambient(weather))
        self.instances = episode_instances(scene, self._static_objects)
        static_ids = [i.id for i in self.instances if i.actor < 0]
        actor_ids = {(i.actor, i.class_id): i.id for i in self.instances if i.actor >= 0}
        self._seg_map: dict = {}
        for node, key, obj in zip(self._static.nodes, self._static_keys, self._static_object_of):
            prs.add_node(node)
            self._seg_map[node] = _seg_color(key, 0 if obj < 0 else static_ids[obj])
        for node, key, actor in zip(self._actors.nodes, self._actor_keys, self._actor_of):
            prs.add_node(node)
            self._seg_map[node] = _seg_color(key, actor_ids.get((actor, key), 0))

        camera = pr.PerspectiveCamera(yfov=self.rig.yfov, aspectRatio=self.rig.aspect,
                                      znear=self.znear, zfar=self.zfar)
        self._camera = camera
        self._camera_node = prs.add(camera, pose=np.eye(4))
        self._hood_node = None
        hood = hood_mesh(viewpoint, self.rig.aspect)
        if hood is not None:
            soup = _Soup()
            tri, normals, colors = _triangles(hood)
            soup.add(tri.reshape(-1, 3), normals.reshape(-1, 3), colors.reshape(-1, 4))
            mesh, _ = _pyrender_mesh(soup, "glossy")
            hood_node = pr.Node(mesh=mesh, matrix=np.eye(4))
            prs.add_node(hood_node, parent_node=self._camera_node)
            self._hood_node = hood_node
            self._seg_map[hood_node] = _seg_color(VEHICLE_ID, HOOD_ID)
        self._draw_list = list(self._seg_map)  # hood, then actors, then static: the shadow casters' order
        self._draw_list.reverse()
        self._rank = {node: i for i, node in enumerate(self._draw_list)}  # ties of the draw order
        self._near_first = list(self._draw_list)  # until update() sorts the first frame's

        sun = sun_direction(weather.sun_elevation_deg, weather.sun_azimuth_deg)
        light = pr.DirectionalLight(color=np.asarray(weather.light_color),
                                    intensity=weather.light_intensity * SUN_SCALE)
        light.shadow_texture = passes.shadow_texture(self.shadow_map_px)
        self._light = light
        self._light_node = prs.add(light, pose=_look_along(-sun))
        self._sun = sun
        self._shadow_strength = shadow_strength(weather)
        self._scene = prs

    @_draws
    def use_sensor(self, sensor, width: int, height: int, hood: bool | None = None) -> None:
        """Draw the next frames from a rig's sensor (``domains.rigs.Sensor``) at ``width`` x ``height``:
        its mounting and field of view; the hood only for the viewpoint's own camera. The loaded
        episode (world, actors, weather) stays as it is, so every sensor sees the same instant."""
        self._ensure_context(width, height)
        self.rig = CameraRig(self.rig.viewpoint, width, height, sensor)
        self._camera.yfov, self._camera.aspectRatio = self.rig.yfov, self.rig.aspect
        if self._hood_node is not None:
            self._hood_node.mesh.is_visible = self.rig.has_hood if hood is None else hood

    @_draws
    def render_labels(self, t: float, cull_m: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The class pass alone at time ``t`` from the current sensor: (planar depth float32 metres, background
        ZFAR; class ids uint8, background sky; instance ids uint16) and world_from_camera (OpenGL axes).
        ``cull_m``: leave out nodes wholly farther than this from the sensor (default: the renderer's
        ``cull_m``); a LiDAR's faces need nothing beyond its range (``render_workers.render.lidar``)."""
        pr = compat.import_pyrender()
        cam = self.update(t, shadows=False, cull_m=cull_m)
        seg, depth = self._offscreen.render(self._scene, flags=pr.RenderFlags.SEG | pr.RenderFlags.SKIP_CULL_FACES,
                                            seg_node_map=self._seg_map)
        return (*decode_labels(seg, depth, self.zfar), cam)

    def set_weather(self, weather: Weather) -> None:
        """Light the loaded episode by ``weather`` from the next frame on (a shift's frame weather):
        sun colour, strength and direction, ambient light, shadows and sky."""
        if weather == self.weather:
            return
        self.weather = weather
        self._scene.ambient_light = _ambient(weather)
        self._light.color = np.asarray(weather.light_color)
        self._light.intensity = weather.light_intensity * SUN_SCALE
        self._sun = sun_direction(weather.sun_elevation_deg, weather.sun_azimuth_deg)
        self._scene.set_pose(self._light_node, _look_along(-self._sun))
        self._shadow_strength = shadow_strength(weather)

    def _build_static(self, world) -> _NodeSet:
        pr = compat.import_pyrender()
        textures = {}
        for name in sorted({p.texture for p in world.static if p.texture}):
            image = lookup(world.textures, name, "texture")
            textures[name] = pr.Texture(source=image, source_channels="RGB")
        tiled, self._static_objects = split_static(world.static)  # traffic lights and signs: one node set each
        items = [(cls, material, soup, textures.get(tex))
                 for (_, _, cls, material, tex), soup in sorted(static_groups(tiled, self.tile_m).items())]
        self._static_object_of = [-1] * len(items)
        for k, parts in enumerate(self._static_objects):
            for (cls, material), soup in sorted(part_groups(parts).items()):
                items.append((cls, material, soup, None))
                self._static_object_of.append(k)
        node_set, self._static_keys = _node_set(items)
        log.debug("static scene: %d nodes from %d parts, %d objects", len(node_set.nodes), len(world.static),
                  len(self._static_objects))
        return node_set

    def _build_actors(self, scene: EpisodeScene) -> tuple[_NodeSet, list[int]]:
        items, actor_of = [], []
        for index, actor in enumerate(scene.actors):
            for (cls, material), soup in sorted(part_groups(actor.parts).items()):
                items.append((cls, material, soup, None))
                actor_of.append(index)
        node_set, self._actor_keys = _node_set(items)
        return node_set, actor_of

    def _draw_order(self, scene) -> list:
        """Replacement for pyrender's ``_sorted_mesh_nodes``: the frame's visible nodes nearest first
        (:meth:`update` sorts them), the hood before all."""
        return [node for node in self._near_first if node.mesh.is_visible]

    # -- per frame -----------------------------------------------------------
    def _visible(self, centres: np.ndarray, radii: np.ndarray, cam: np.ndarray, cull_m: float | None = None) -> np.ndarray:
        """Distance (``cull_m``, default the renderer's) and horizontal-frustum test of bounding spheres (world frame)."""
        d = centres - cam[:3, 3]
        forward, right = -cam[:3, 2], cam[:3, 0]
        z, x = d @ forward, d @ right
        near = np.linalg.norm(d, axis=1) - radii < (self.cull_m if cull_m is None else cull_m)
        half = math.atan(self.rig.tan_half_h)
        c, s = math.cos(half), math.sin(half)
        inside = (np.abs(x) * c - z * s) < radii
        return near & inside & (z > -radii)

    def update(self, t: float, shadows: bool = True, cull_m: float | None = None) -> np.ndarray:
        """Pose the camera and actors for time ``t`` and cull (and fit the shadow map, unless ``shadows`` is
        False: a class pass alone draws none); returns world_from_camera. ``cull_m``: as ``render_labels``."""
        if self._scene is None or self._episode is None:
            raise RuntimeError("Renderer.load() must be called before rendering")
        cam = self.rig.world_from_camera(self._episode.ego.pose(t))
        self._scene.set_pose(self._camera_node, cam)
        if self._static.nodes:
            for node, on in zip(self._static.nodes, self._visible(self._static.centres, self._static.radii, cam, cull_m)):
                node.mesh.is_visible = bool(on)
        if self._actors.nodes:
            if self._posed_at is None or self._posed_at[0] != t:  # a rig's sensors draw one instant: pose it once
                poses = [actor.pose(t) for actor in self._episode.actors]
                for node, a in zip(self._actors.nodes, self._actor_of):
                    self._scene.set_pose(node, poses[a])
                centres = np.array([poses[a][:3, :3] @ c + poses[a][:3, 3] for c, a in zip(self._actors.centres, self._actor_of)])
                self._posed_at = (t, centres.reshape(self._actors.centres.shape), poses)
            world_centres = self._posed_at[1]
            for node, on in zip(self._actors.nodes, self._visible(world_centres, self._actors.radii, cam, cull_m)):
                node.mesh.is_visible = bool(on)
        else:
            world_centres = np.empty((0, 3))
        self._near_first = self._nearest_first(cam, world_centres)
        if shadows and self._shadows_on():
            self._shadow_frame = self._fit_shadows(cam, world_centres)
        return cam

    def _nearest_first(self, cam: np.ndarray, actor_centres: np.ndarray) -> list:
        """The visible nodes by the distance of their bounding sphere's centre from the camera, nearest
        first, ties in the order :meth:`load` built them; the hood (on the camera) first.

        Opaque nodes only (every material is), so the order decides no pixel but the rare tie of equal
        depths, and those the same way in every run. Drawn near first, a farther surface behind a
        nearer one fails llvmpipe's early depth test and is never shaded; in the order of the build,
        whole tiles of road and buildings were shaded and then covered (docs/bench_render.md)."""
        nodes = [self._hood_node] if self._hood_node is not None else []
        centres = [cam[:3, 3]] if nodes else []
        for node_set, world in ((self._actors, actor_centres), (self._static, self._static.centres)):
            for node, centre in zip(node_set.nodes, world):
                if node.mesh.is_visible:
                    nodes.append(node)
                    centres.append(centre)
        if not nodes:
            return []
        d = np.asarray(centres, np.float64) - cam[:3, 3]
        # squared, by elementwise IEEE operations only: the same order on every CPU path (a reduction's
        # summation order, as in np.linalg.norm, may follow the SIMD width)
        distance = d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2]
        rank = [self._rank[node] for node in nodes]
        return [nodes[i] for i in np.lexsort((rank, distance))]

    def _shadows_on(self) -> bool:
        return self.shadows and self._shadow_strength >= MIN_SHADOW_STRENGTH

    def _fit_shadows(self, cam: np.ndarray, actor_centres: np.ndarray) -> passes.ShadowFrame:
        view, proj, box = fit_shadow_frame(self._sun, cam, self.rig)
        casters = set()
        for nodes, centres, radii in ((self._static.nodes, self._static.centres, self._static.radii),
                                      (self._actors.nodes, actor_centres, self._actors.radii)):
            if nodes:
                hits = _in_light_box(centres, radii, view, box)
                casters.update(node for node, hit in zip(nodes, hits) if hit)
        ordered = [node for node in self._draw_list if node in casters]  # fixed order
        texel = max(box[1] - box[0], box[3] - box[2]) / self.shadow_map_px
        params = np.array([self._shadow_strength, 1.5 * texel, SHADOW_FADE_M, SHADOW_FAR_M], np.float32)
        return passes.ShadowFrame(view=view, proj=proj, casters=ordered, uniforms={"shadow_params": params})

    @_draws
    def render(self, t: float, weather: Weather | None = None) -> RenderResult:
        """Render the loaded episode at simulated time ``t`` (seconds), under ``weather`` if given
        (a shift's weather at that frame; see ``set_weather``), else the episode's."""
        pr = compat.import_pyrender()
        if weather is not None:
            self.set_weather(weather)
        timings = {}
        start = time.perf_counter()
        cam = self.update(t)
        timings["scene_update"] = time.perf_counter() - start

        start = time.perf_counter()
        flags = pr.RenderFlags.RGBA | pr.RenderFlags.SKIP_CULL_FACES
        if self._shadows_on():
            flags |= pr.RenderFlags.SHADOWS_DIRECTIONAL
        if self.merged:  # the labels and depth come out of the colour pass itself
            rgba, seg, depth = self._offscreen.render(self._scene, flags=flags, seg_node_map=self._seg_map)
            timings["color_pass"], timings["class_pass"] = time.perf_counter() - start, 0.0
        else:
            rgba, _ = self._offscreen.render(self._scene, flags=flags)
            timings["color_pass"] = time.perf_counter() - start
            start = time.perf_counter()
            seg_flags = pr.RenderFlags.SEG | pr.RenderFlags.SKIP_CULL_FACES
            seg, depth = self._offscreen.render(self._scene, flags=seg_flags, seg_node_map=self._seg_map)
            timings["class_pass"] = time.perf_counter() - start

        # Fixed for the episode, so the frame may be resolved on another thread later.
        sky = functools.partial(self._sky, self.weather, self.rig, cam)
        posed = self._posed_at
        return RenderResult(
            rgba=rgba, seg=seg, depth=depth, sky=sky, zfar=self.zfar,
            world_from_camera=cam, rig=self.rig, sun_pixel=self._sun_pixel(cam), timings=timings,
            weather=self.weather, actor_poses=posed[2] if posed is not None and posed[0] == t else None,
        )

    def _sun_pixel(self, cam: np.ndarray) -> tuple[float, float] | None:
        sun_cam = cam[:3, :3].T @ self._sun
        if sun_cam[2] >= -1e-6:
            return None
        x, y = self.rig.project(sun_cam[None, :])[0]
        return float(x), float(y)


def _ambient(weather: Weather) -> np.ndarray:
    return weather.ambient * np.asarray(weather.light_color)


def _seg_color(class_id: int, instance_id: int) -> tuple[int, int, int]:
    """SEG pass colour of a node: class id in red, instance id over green (low) and blue (high)."""
    return (class_id, instance_id & 255, instance_id >> 8)


def shadow_strength(weather: Weather) -> float:
    """Share of the sun's light a shadow takes away: clear skies crisp, overcast nearly none."""
    if weather.sun_elevation_deg <= 0.0:
        return 0.0
    return float(np.clip(1.0 - weather.cloudiness, 0.0, 1.0))


def fit_shadow_frame(sun: np.ndarray, cam: np.ndarray, rig: CameraRig) -> tuple[np.ndarray, np.ndarray, tuple]:
    """Light view and orthographic projection covering what the camera sees within SHADOW_FAR_M.

    The light frame looks along ``-sun`` with its y axis along the camera's
    forward direction projected across the sun, so the covered ground
    trapezoid fills the map. Returns (view, proj, box) with box =
    (x0, x1, y0, y1, z0, z1) in light eye coordinates (z towards the sun).
    """
    z = np.asarray(sun, np.float64) / np.linalg.norm(sun)
    forward = -cam[:3, 2].copy()
    forward[2] = 0.0
    if np.linalg.norm(forward) < 1e-6:
        forward = cam[:3, 1].copy()
        forward[2] = 0.0
    forward /= np.linalg.norm(forward)
    y = forward - (forward @ z) * z
    if np.linalg.norm(y) < 1e-6:  # sun straight ahead on the horizon: any axis will do
        y = np.cross(z, [0.0, 0.0, 1.0]) if abs(z[2]) < 0.99 else np.array([0.0, 1.0, 0.0])
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    rot = np.stack([x, y, z], axis=1)  # light -> world
    origin = cam[:3, 3]
    right = np.array([forward[1], -forward[0], 0.0])
    ground = origin[2] - rig.viewpoint.camera_height_m
    far_half = SHADOW_FAR_M * rig.tan_half_h
    ahead = np.array([-SHADOW_BACK_M, -SHADOW_BACK_M, SHADOW_FAR_M, SHADOW_FAR_M])
    across = np.array([-SHADOW_BACK_M, SHADOW_BACK_M, -far_half, far_half])
    xy = origin[:2] + ahead[:, None] * forward[:2] + across[:, None] * right[:2]
    points = np.array([[px, py, ground + h] for px, py in xy for h in (-2.0, SHADOW_TOP_M)])
    q = (points - origin) @ rot
    x0, y0, z0 = q.min(axis=0) - 1.0
    x1, y1, z1 = q.max(axis=0) + 1.0
    z1 += CASTER_TOP_M / max(z[2], 0.05)  # casters sit towards the sun
    view = np.eye(4)
    view[:3, :3] = rot.T
    view[:3, 3] = -rot.T @ origin
    near, far = -z1, -z0  # distances along the light's -z
    proj = np.eye(4)
    proj[0, 0], proj[0, 3] = 2.0 / (x1 - x0), -(x1 + x0) / (x1 - x0)
    proj[1, 1], proj[1, 3] = 2.0 / (y1 - y0), -(y1 + y0) / (y1 - y0)
    proj[2, 2], proj[2, 3] = -2.0 / (far - near), -(far + near) / (far - near)
    return view, proj, (x0, x1, y0, y1, z0, z1)


def _in_light_box(centres: np.ndarray, radii: np.ndarray, view: np.ndarray, box: tuple) -> np.ndarray:
    """Bounding spheres that overlap the light box (they can cast into the shadow map)."""
    q = centres @ view[:3, :3].T + view[:3, 3]
    lo = np.array([box[0], box[2], box[4]])
    hi = np.array([box[1], box[3], box[5]])
    return ((q + radii[:, None] >= lo) & (q - radii[:, None] <= hi)).all(axis=1)


def _look_along(direction: np.ndarray) -> np.ndarray:
    """A pose whose -z axis points along ``direction`` (pyrender lights shine along -z)."""
    z = -np.asarray(direction, dtype=np.float64)
    z /= np.linalg.norm(z)
    up = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.99 else np.array([1.0, 0.0, 0.0])
    x = np.cross(up, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2] = x, y, z
    return m
