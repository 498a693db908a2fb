"""Renderer and camera: projection, depth, hood coverage, SEG mapping and culling (headless)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import trimesh

from domains.catalog import NUM_CLASSES, VIEWPOINTS, class_id as class_id_of, viewpoint, weather
from render_workers.render import camera
from render_workers.render.renderer import Renderer
from render_workers.render.part_meshes import look
from render_workers.worlds.scene import Actor, EpisodeScene, Part, Path, World

W, H = 160, 90
ROAD, WALL = 7, 11


def _grid(size: float = 400.0, cell: float = 20.0, z: float = 0.0) -> trimesh.Trimesh:
    xs = np.arange(-size, size, cell)
    vertices, faces = [], []
    for x in xs:
        for y in xs:
            base = len(vertices)
            vertices += [[x, y, z], [x + cell, y, z], [x + cell, y + cell, z], [x, y + cell, z]]
            faces += [[base, base + 1, base + 2], [base, base + 2, base + 3]]
    mesh = trimesh.Trimesh(np.array(vertices), np.array(faces), process=False)
    mesh.visual.vertex_colors = np.tile([90, 90, 90, 255], (len(vertices), 1))
    return mesh


def flat_scene(extra: tuple[Part, ...] = ()) -> EpisodeScene:
    """A flat road plane and an ego parked at the origin looking along +x."""
    lane = Path(np.array([[0.0, 0.0, 0.0], [100.0, 0.0, 0.0]]))
    world = World(town="T01", seed=0, static=(Part(ROAD, _grid(), "road"), *extra), lanes=(lane,))
    ego = Actor("test", (), lane, 0.0, 0.0)
    return EpisodeScene(world=world, actors=(), ego=ego, n_vehicles=0, n_pedestrians=0)


@pytest.fixture(scope="module")
def renderer():
    with Renderer() as r:
        yield r


def render(r: Renderer, scene: EpisodeScene, view: str, w: int = W, h: int = H):
    r.load(scene, weather("CN"), viewpoint(view), w, h)
    return r.render(0.0)


@pytest.mark.parametrize("view", ["V", "B"])
def test_flat_road_depth_matches_projection(renderer, view):
    result = render(renderer, flat_scene(), view)
    rig = result.rig
    assert rig.focal_px == pytest.approx(W / 2)  # 90 degree horizontal FoV
    col = W // 2
    for row in range(H // 2 + 2, H):
        expected = rig.focal_px * viewpoint(view).camera_height_m / (row + 0.5 - rig.cy)
        assert result.buffers["depth"][row, col] == pytest.approx(expected, rel=0.01), row
        assert rig.ground_depth(row) == pytest.approx(expected)
    # at and above the horizon there is only sky, at the far limit
    assert (result.buffers["depth"][: H // 2] == 1000.0).all()
    assert (result.buffers["classes"][: H // 2] == 20).all()
    assert (result.buffers["classes"][H // 2 + 1:] == ROAD).all()


def test_higher_camera_moves_the_road_down_in_depth_terms(renderer):
    low = render(renderer, flat_scene(), "V").buffers["depth"]
    high = render(renderer, flat_scene(), "B").buffers["depth"]
    row = H - 10
    ratio = viewpoint("B").camera_height_m / viewpoint("V").camera_height_m
    assert high[row, W // 2] / low[row, W // 2] == pytest.approx(ratio, rel=0.01)


@pytest.mark.parametrize("vp", VIEWPOINTS, ids=lambda v: v.code)
def test_hood_fraction(renderer, vp):
    w, h = 320, 180
    result = render(renderer, flat_scene(), vp.code, w, h)
    measured = camera.measured_hood_fraction(result.hood_mask)
    if not vp.hood_visible:
        assert measured == 0.0 and camera.hood_mesh(vp, w / h) is None
        return
    assert camera.hood_fraction(vp) == pytest.approx(vp.hood_fraction, abs=1e-12)
    tolerance = 1.0 / h  # one pixel row of rasterisation
    assert 0.1108 - tolerance <= measured <= 0.1399 + tolerance
    assert measured == pytest.approx(camera.measured_hood_fraction(camera.hood_mask(vp, w, h)), abs=0.004)
    assert (result.buffers["classes"][result.hood_mask] == 10).all()
    # the hood's top edge is the parabola: highest in the middle
    top = result.hood_mask.argmax(axis=0)
    assert top[w // 2] <= top[2] and top[w // 2] <= top[-3]


@pytest.mark.parametrize("view", ["A", "V"])
def test_a_narrower_field_of_view_magnifies_and_keeps_the_hood_share(renderer, view):
    """A viewpoint's ``hfov_deg`` (90 unless a domain file says otherwise): the focal length, K and the road's
    depth follow it, and the hood covers the same share of the image, so the catalog's hood_fraction still crops it."""
    assert viewpoint(view).hfov_deg == 90.0 and camera.camera_rig(view, W, H).focal_px == pytest.approx(W / 2)
    narrow = dataclasses.replace(viewpoint(view), hfov_deg=60.0)
    renderer.load(flat_scene(), weather("CN"), narrow, W, H)
    result = renderer.render(0.0)
    rig = result.rig
    assert rig.focal_px == pytest.approx(W / 2 / np.tan(np.radians(30.0)))
    assert rig.K[0, 0] == rig.K[1, 1] == pytest.approx(rig.focal_px)
    col = W // 2
    for row in range(H // 2 + 2, H):
        if result.hood_mask[row, col]:
            break
        expected = rig.focal_px * narrow.camera_height_m / (row + 0.5 - rig.cy)
        assert result.buffers["depth"][row, col] == pytest.approx(expected, rel=0.01), row
    wide = render(renderer, flat_scene(), view)
    assert (result.hood_mask == wide.hood_mask).mean() > 0.995  # the hood's outline is the same in the image
    assert camera.measured_hood_fraction(result.hood_mask) == pytest.approx(narrow.hood_fraction, abs=2.0 / H)


def test_a_rigs_mount_camera_takes_the_viewpoints_field_of_view():
    """The stereo rig's left camera is the viewpoint's own (it sees the hood): it follows the viewpoint's hfov_deg;
    the surround rig's cameras keep their own 70 degrees."""
    from domains.rigs import rig_named

    narrow = dataclasses.replace(viewpoint("A"), hfov_deg=60.0)
    left, right = rig_named("stereo").cameras
    assert camera.camera_rig(narrow, W, H, left).hfov_deg == 60.0 and camera.camera_rig(narrow, W, H, left).has_hood
    assert camera.camera_rig(narrow, W, H, right).hfov_deg == 90.0  # a camera of its own: the rig's (default) 90
    assert {camera.camera_rig(narrow, W, H, s).hfov_deg for s in rig_named("surround").cameras} == {70.0}


def test_hood_mask_converges_to_catalog_fraction():
    for vp in VIEWPOINTS:
        mask = camera.hood_mask(vp, 3840, 2160)
        assert camera.measured_hood_fraction(mask) == pytest.approx(vp.hood_fraction, abs=5e-4)


def test_every_pixel_has_a_valid_class_and_hood_follows_camera(renderer):
    result = render(renderer, flat_scene(), "A")
    assert result.buffers["classes"].max() < NUM_CLASSES
    assert result.buffers["rgb"].shape == (H, W, 3) and result.buffers["rgb"].dtype == np.uint8
    assert result.buffers["depth"].dtype == np.float32
    # the hood is part of the camera rig: the same mask wherever the ego is
    renderer.load(flat_scene(), weather("CN"), viewpoint("A"), W, H)
    later = renderer.render(0.0)
    assert (later.hood_mask == result.hood_mask).all()


def _wall(distance: float) -> Part:
    wall = trimesh.creation.box(extents=(1.0, 200.0, 60.0))
    wall.apply_translation((distance, 0.0, 30.0))
    wall.visual.vertex_colors = np.tile([150, 120, 100, 255], (len(wall.vertices), 1))
    return Part(WALL, wall, "matte")


def test_distance_culling(renderer):
    scene = flat_scene((_wall(600.0),))
    culled = render(renderer, scene, "V")
    assert not (culled.buffers["classes"] == WALL).any()
    with Renderer(cull_m=2000.0) as far:
        drawn = render(far, scene, "V")
    assert (drawn.buffers["classes"] == WALL).any()
    assert drawn.buffers["depth"][drawn.buffers["classes"] == WALL].min() == pytest.approx(599.5, rel=0.02)


def test_near_wall_is_drawn_and_lit(renderer):
    result = render(renderer, flat_scene((_wall(30.0),)), "V")
    wall = result.buffers["classes"] == WALL
    assert wall[H // 4, W // 2]
    assert result.buffers["depth"][H // 4, W // 2] == pytest.approx(29.5 - camera.CAMERA_FORWARD_M, rel=0.01)
    assert result.buffers["rgb"][wall].mean() > 10  # not black: ambient + sun


def _back_facing_sheet(distance: float) -> Part:
    """A single-sided quad across the road ``distance`` m ahead, its front face turned away from the camera."""
    corners = np.array([[distance, -50.0, 0.0], [distance, 50.0, 0.0], [distance, 50.0, 40.0], [distance, -50.0, 40.0]])
    sheet = trimesh.Trimesh(corners, np.array([[0, 1, 2], [0, 2, 3]]), process=False)  # normal +x: away
    sheet.visual.vertex_colors = np.tile([150, 120, 100, 255], (4, 1))
    return Part(WALL, sheet, "matte")


def test_labels_and_depth_are_what_the_colour_pass_draws_back_faces_included(renderer):
    """The colour pass draws back faces (SKIP_CULL_FACES), so the labels and depth, drawn in that same
    pass, show them too: a sheet seen from behind is wall, at its distance, not the sky behind it that
    pyrender's SEG pass (which culls back faces) gives. The merged pass, two passes and the class pass
    alone (``render_labels``: LiDAR, rig sensors) agree byte for byte."""
    from render_workers.render import pyrender_setup as compat

    pr = compat.import_pyrender()
    assert renderer.merged
    merged = render(renderer, flat_scene((_back_facing_sheet(30.0),)), "V").buffers
    assert merged["classes"][H // 4, W // 2] == WALL
    assert merged["depth"][H // 4, W // 2] == pytest.approx(30.0 - camera.CAMERA_FORWARD_M, rel=0.01)
    culled, _ = renderer._offscreen.render(renderer._scene, flags=pr.RenderFlags.SEG, seg_node_map=renderer._seg_map)
    assert culled[H // 4, W // 2, 0] != WALL  # pyrender's way: the sheet is not there
    depth, classes, instance, _ = renderer.render_labels(0.0)
    renderer.merged = False
    try:
        two = renderer.render(0.0).buffers
    finally:
        renderer.merged = True
    for name, want in (("depth", depth), ("classes", classes), ("instance", instance)):
        assert merged[name].tobytes() == want.tobytes() == two[name].tobytes(), name
    assert merged["rgb"].tobytes() == two["rgb"].tobytes()


def test_pyrender_is_imported_without_its_viewer():
    """A fresh process that imports pyrender as the renderer does never loads pyglet's windows or GL
    bindings (the viewer's, ~0.15 CPU-s), still renders off-screen, and says so if the viewer is asked for."""
    import subprocess
    import sys

    probe = (
        "import sys\n"
        "from render_workers.render.pyrender_setup import import_pyrender\n"
        "pr = import_pyrender()\n"
        "assert 'pyglet.gl' not in sys.modules and 'pyglet.window' not in sys.modules, sorted(sys.modules)\n"
        "assert 'pyglet' not in sys.modules\n"
        "assert pr.OffscreenRenderer is not None and pr.Scene is not None\n"
        "try:\n"
        "    pr.Viewer(pr.Scene())\n"
        "except RuntimeError as exc:\n"
        "    print(exc)\n"
    )
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "viewer is not loaded" in done.stdout


def test_unknown_material_raises():
    with pytest.raises(ValueError, match="valid"):
        look("chrome")


def test_render_before_load_raises():
    with pytest.raises(RuntimeError, match="load"):
        Renderer().render(0.0)


def test_framebuffer_patch_is_per_renderer_and_multisampling_still_works(renderer):
    from render_workers.render import pyrender_setup as compat

    pr = compat.import_pyrender()
    plain = render(renderer, flat_scene(), "V")
    with Renderer(msaa=4) as multi:
        sampled = render(multi, flat_scene(), "V")
        assert multi._offscreen._renderer._main_fb_ms != multi._offscreen._renderer._main_fb
        colour, depth = multi._offscreen.render(multi._scene, flags=pr.RenderFlags.RGBA)
        assert depth is None and colour.shape == (H, W, 4)  # colour passes skip the depth read-back
    inner = renderer._offscreen._renderer
    assert inner._main_fb_ms == inner._main_fb  # msaa=0 draws straight into the read framebuffer
    assert (sampled.buffers["classes"] == plain.buffers["classes"]).all()
    assert np.isclose(sampled.buffers["depth"], plain.buffers["depth"], rtol=0.01).mean() > 0.99
    assert np.abs(sampled.buffers["rgb"].astype(int) - plain.buffers["rgb"]).mean() < 4
    with pytest.raises(ValueError, match="MSAA"):
        Renderer(msaa=3)


def test_renderers_share_one_shader_copy_and_leave_nothing_per_renderer(tmp_path, monkeypatch):
    """The cheaper mesh.frag lives in one content-keyed directory: renderers (and
    processes) with the same shaders reuse it, and a renderer leaves no directory of
    its own behind (Ray kills workers without running atexit; per-renderer temp
    copies piled up in /tmp)."""
    import os
    import tempfile

    from render_workers.render import passes
    from render_workers.render.shaders import FAST_MESH_FRAG

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    first = passes.shader_dir(FAST_MESH_FRAG)
    assert first.parent == tmp_path / f"idda-shaders-{os.getuid()}"
    assert (first / "mesh.frag").read_text() == FAST_MESH_FRAG and (first / "mesh.vert").is_file()
    other = passes.shader_dir(FAST_MESH_FRAG + "\n// changed\n")
    assert other != first and passes.shader_dir(FAST_MESH_FRAG) == first
    for _ in range(2):
        with Renderer() as r:
            r.load(flat_scene(), weather("CN"), VIEWPOINTS[3], W, H)
            r.render(0.0)
    assert list(tmp_path.iterdir()) == [first.parent]
    assert sorted(p.name for p in first.parent.iterdir()) == sorted([first.name, other.name])  # no staging left


# ------------------------------------------------------------ what a frame costs ----
def test_a_lidar_face_leaves_out_what_lies_beyond_its_range_and_its_points_stay(renderer, monkeypatch):
    """A LiDAR's four face passes leave out nodes wholly beyond ``lidar.cull_distance`` (about 200 m for a
    120 m range, where the renderer draws to 450 m): the wall 400 m behind is not drawn, and the sweep's
    points and labels are the very ones of faces drawn to 450 m (issue 37: a sweep's cost)."""
    from domains.rigs import Sensor
    from render_workers.render import lidar

    sensor = Sensor(name="roof", kind="lidar", z=0.4, beams=16, points=256, range_m=120.0)
    renderer.load(flat_scene((_wall(60.0), _wall(-400.0))), weather("CN"), viewpoint("A"), W, H)
    drawn = []
    labels_pass = renderer.render_labels

    def recorded(t, cull_m=None):
        out = labels_pass(t, cull_m=cull_m)
        drawn.append(out[0][out[1] == WALL].max(initial=0.0))  # the farthest wall pixel of the face
        return out

    monkeypatch.setattr(renderer, "render_labels", recorded)
    near = lidar.lidar_sweep(renderer, sensor, 0.0, W, H)
    assert 150.0 < lidar.cull_distance(sensor) < 250.0 and max(drawn) < 150.0  # the far wall: not drawn
    drawn.clear()
    monkeypatch.setattr(lidar, "cull_distance", lambda s: 1e9)
    whole = lidar.lidar_sweep(renderer, sensor, 0.0, W, H)
    assert max(drawn) > 390.0  # drawn to the renderer's 450 m, it is there
    assert near.points.tobytes() == whole.points.tobytes() and near.labels.tobytes() == whole.labels.tobytes()
    assert ((near.labels & 0xFFFF) == WALL).any()  # the near wall is in the sweep


def test_a_rigs_sensors_pose_the_actors_once_per_instant(renderer, monkeypatch):
    """Every sensor of a rig draws one instant: the actors are posed for it once, not once per sensor
    (a LiDAR sweep's four faces, a surround rig's six cameras)."""
    from domains.rigs import Sensor
    from render_workers.worlds.scene import Actor, Path as LanePath

    box = trimesh.creation.box(extents=(4.0, 2.0, 1.5))
    box.visual.vertex_colors = np.tile([200, 20, 20, 255], (len(box.vertices), 1))
    lane = LanePath(np.array([[0.0, 0.0, 0.0], [100.0, 0.0, 0.0]]))
    car = Actor("sedan", (Part(WALL, box, "matte"),), lane, 20.0, 5.0)
    scene = flat_scene()
    scene = EpisodeScene(world=scene.world, actors=(car,), ego=scene.ego, n_vehicles=1, n_pedestrians=0)
    renderer.load(scene, weather("CN"), viewpoint("A"), W, H)
    posed = []
    pose = Actor.pose
    monkeypatch.setattr(Actor, "pose", lambda self, t: (posed.append(t) if self is car else None, pose(self, t))[1])
    for yaw in (0.0, 90.0, 180.0):
        renderer.use_sensor(Sensor(name="cam", kind="camera", yaw=yaw), W, H)
        renderer.render_labels(1.0)
    assert posed == [1.0]
    renderer.use_sensor(None, W, H)
    seen = renderer.render(2.0).buffers["classes"]  # another instant: posed again, 10 m on, and drawn there
    assert posed == [1.0, 2.0] and (seen == WALL).any()


def _slab(cls: int, x: float, width: float = 4.0) -> Part:
    slab = trimesh.creation.box(extents=(1.0, width, 6.0))
    slab.apply_translation((x, 0.0, 3.0))
    slab.visual.vertex_colors = np.tile([150, 120, 100, 255], (len(slab.vertices), 1))
    return Part(cls, slab, "matte")


def test_nodes_are_drawn_nearest_first_and_the_hood_before_all(renderer):
    """Opaque nodes drawn near first, so what is covered fails the early depth test unshaded: the
    order follows the camera, not the order the scene was built in; the hood (on the camera) first."""
    from domains.catalog import class_id

    near_to_far = [class_id("fence"), class_id("pole"), class_id("wall"), class_id("building")]
    for xs in ((20.0, 40.0, 60.0, 80.0), (80.0, 60.0, 40.0, 20.0)):
        scene = flat_scene(tuple(_slab(cls, x) for cls, x in zip(near_to_far, xs)))
        renderer.load(scene, weather("CN"), viewpoint("A"), W, H)  # A: the hood in view
        renderer.render(0.0)
        order = renderer._draw_order(renderer._scene)
        assert order[0] is renderer._hood_node
        drawn = [int(renderer._seg_map[node][0]) for node in order]
        slabs = [cls for k, cls in enumerate(drawn) if cls in near_to_far and cls not in drawn[:k]]  # a slab may be 2 nodes
        assert slabs == (near_to_far if xs[0] < xs[-1] else near_to_far[::-1])
        assert drawn[-1] == ROAD  # the road's tiles reach farther than any slab


def test_a_base_colour_texture_is_bound_as_pyrender_binds_it(renderer, monkeypatch):
    """A primitive whose only texture is its base colour is drawn without pyrender's per-primitive
    binding, with the same pixels: its texture on the unit after the shadow map's, the lights as set
    for the program's first primitive; pyrender's own binding (forced here) draws the same frame."""
    import pyrender.renderer as pr_renderer

    from render_workers.render import passes
    from render_workers.worlds.textures import TEXTURE_PX

    rng = np.random.default_rng(3)
    textures = {name: rng.integers(60, 255, (TEXTURE_PX, TEXTURE_PX, 3), dtype=np.uint8) for name in ("asphalt", "brick")}
    road = Part(ROAD, _grid(), "road", texture="asphalt")
    wall = _wall(25.0)
    wall = Part(WALL, wall.mesh, "matte", texture="brick")
    base = flat_scene()
    world = dataclasses.replace(base.world, static=(road, wall, _slab(class_id_of("pole"), 12.0)), textures=textures)
    scene = dataclasses.replace(base, world=world)
    drawn = []
    own = pr_renderer.Renderer._bind_and_draw_primitive
    monkeypatch.setattr(pr_renderer.Renderer, "_bind_and_draw_primitive", lambda *a, **k: (drawn.append(1), own(*a, **k))[1])
    with Renderer() as fresh:  # a renderer whose pass binds textures itself
        fast = render(fresh, scene, "A", 320, 180)
        fast_frames = [fast.buffers[k].copy() for k in ("rgb", "classes", "depth")]
    assert drawn == []
    monkeypatch.setattr(passes, "pyrender_binds", lambda flags: flags != 0)
    with Renderer() as fresh:
        slow = render(fresh, scene, "A", 320, 180)
        slow_frames = [slow.buffers[k] for k in ("rgb", "classes", "depth")]
    assert len(drawn) >= 2  # the road's tiles and the wall, through pyrender's binding
    assert all(np.array_equal(a, b) for a, b in zip(fast_frames, slow_frames))
    plain = render(renderer, flat_scene((_wall(25.0), _slab(class_id_of("pole"), 12.0))), "A", 320, 180).buffers["rgb"]
    assert not np.array_equal(plain, fast_frames[0])  # the textures are in the picture


def test_a_pass_asks_gl_for_its_light_limits_once_per_kind_of_pass(renderer, monkeypatch):
    """pyrender derives its per-program light limits from a GL query at every primitive; a renderer asks once
    per set of flags (the context's answer does not change), so a frame makes no such query after the first."""
    import pyrender.renderer as pr_renderer

    renderer.load(flat_scene((_wall(30.0), _wall(60.0))), weather("CN"), viewpoint("A"), W, H)
    renderer.render(0.0)
    asked = []
    query = pr_renderer.glGetIntegerv
    monkeypatch.setattr(pr_renderer, "glGetIntegerv", lambda what: (asked.append(what), query(what))[1])
    again = renderer.render(0.0)
    assert asked == [] and (again.buffers["classes"] == WALL).any()


def test_a_frames_gl_lookups_do_not_grow_with_what_it_draws(renderer, monkeypatch):
    """Uniform locations are asked of GL once per program and pyrender's program lookup runs once per
    kind of primitive in a pass: a frame of twelve cars makes no more of either than a frame of two
    (pyrender asked both again for every primitive: the per-draw Python cost of every pass)."""
    import OpenGL.GL as gl
    import pyrender.renderer as pr_renderer
    import pyrender.shader_program as pr_program
    from render_workers.worlds.scene import Actor, Path as LanePath

    def scene_of(cars: int) -> EpisodeScene:
        lane = LanePath(np.array([[0.0, 0.0, 0.0], [300.0, 0.0, 0.0]]))
        actors = []
        for i in range(cars):
            box = trimesh.creation.box(extents=(4.0, 2.0, 1.5))
            box.visual.vertex_colors = np.tile([200, 20 + 10 * i, 20, 255], (len(box.vertices), 1))
            actors.append(Actor("sedan", (Part(WALL, box, "matte"),), lane, 15.0 + 8.0 * i, 0.0, 0.0))
        base = flat_scene()
        return EpisodeScene(world=base.world, actors=tuple(actors), ego=base.ego, n_vehicles=cars, n_pedestrians=0)

    def lookups(cars: int) -> tuple[int, int, np.ndarray]:
        renderer.load(scene_of(cars), weather("CN"), viewpoint("A"), W, H)
        renderer.render(0.0)  # the first frame: programs compiled, locations learnt
        asked = {"location": 0, "program": 0}
        for module in (gl, pr_program):
            location = module.glGetUniformLocation
            monkeypatch.setattr(module, "glGetUniformLocation",
                                lambda *a, _f=location: (asked.__setitem__("location", asked["location"] + 1), _f(*a))[1])
        inner = renderer._offscreen._renderer
        lookup = inner._get_primitive_program
        monkeypatch.setattr(inner, "_get_primitive_program",
                            lambda *a: (asked.__setitem__("program", asked["program"] + 1), lookup(*a))[1])
        frame = renderer.render(0.0)
        monkeypatch.undo()
        return asked["location"], asked["program"], frame.buffers["classes"]

    few, many = lookups(2), lookups(12)
    assert (few[2] == WALL).sum() < (many[2] == WALL).sum()  # the twelve cars are drawn
    assert many[:2] == few[:2], (few[:2], many[:2])


def test_gl_calls_made_through_ctypes_draw_what_pyopengl_draws(monkeypatch):
    """Uniforms and draws go to GL through bare ctypes entry points (``passes.gl_entry``): the same
    frame, bit for bit, as through PyOpenGL's wrappers, as pyrender calls them (matrices transposed,
    float64 made float32, a name the shader lacks skipped), with shadows, cars and a textured wall."""
    import ctypes

    from OpenGL import GL
    from render_workers.render import passes
    from render_workers.worlds.scene import Actor, Path as LanePath
    from render_workers.worlds.textures import TEXTURE_PX

    lane = LanePath(np.array([[0.0, 0.0, 0.0], [300.0, 0.0, 0.0]]))
    cars = []
    for i in range(3):
        box = trimesh.creation.box(extents=(4.0, 2.0, 1.5))
        box.visual.vertex_colors = np.tile([200, 40 * i, 20, 255], (len(box.vertices), 1))
        cars.append(Actor("sedan", (Part(WALL, box, "matte"),), lane, 12.0 + 9.0 * i, 0.0, 0.0))
    textures = {"brick": np.random.default_rng(5).integers(60, 255, (TEXTURE_PX, TEXTURE_PX, 3), dtype=np.uint8)}
    wall = _wall(40.0)
    base = flat_scene((Part(WALL, wall.mesh, "matte", texture="brick"), _slab(class_id_of("pole"), 20.0)))
    scene = EpisodeScene(world=dataclasses.replace(base.world, textures=textures), actors=tuple(cars), ego=base.ego,
                         n_vehicles=3, n_pedestrians=0)

    def frame() -> list[np.ndarray]:
        with Renderer() as fresh:
            fresh.load(scene, weather("CS"), viewpoint("A"), 320, 180)
            result = fresh.render(0.5)
            return [result.buffers[k].copy() for k in ("rgb", "classes", "depth", "instance")]

    direct = frame()
    calls = []
    entry = passes.gl_entry
    monkeypatch.setattr(passes, "gl_entry", lambda name, *types: (calls.append(name), entry(name, *types))[1])
    assert all(np.array_equal(a, b) for a, b in zip(direct, frame()))
    assert {"glUniformMatrix4fv", "glUniform3fv", "glUniform4fv", "glDrawArraysInstanced"} <= set(calls)

    def wrapped_uniform(program, name, value):  # pyrender's own ShaderProgram.set_uniform, PyOpenGL's calls
        try:
            program.set_uniform(name, value)
        except ValueError:  # pyrender raises for a name the shader lacks; the pass skips it
            pass

    def wrapped_draw(primitive):
        instances = 1 if primitive.poses is None else len(primitive.poses)
        if primitive.indices is not None:
            GL.glDrawElementsInstanced(primitive.mode, primitive.indices.size, GL.GL_UNSIGNED_INT,
                                       ctypes.c_void_p(0), instances)
        else:
            GL.glDrawArraysInstanced(primitive.mode, 0, len(primitive.positions), instances)

    monkeypatch.setattr(passes, "set_uniform", wrapped_uniform)
    monkeypatch.setattr(passes, "draw_primitive", wrapped_draw)
    through_pyopengl = frame()
    assert all(np.array_equal(a, b) for a, b in zip(direct, through_pyopengl))
    assert (through_pyopengl[1] == WALL).sum() > 1000 and (through_pyopengl[3] > 0).sum() > 100  # wall and cars drawn

