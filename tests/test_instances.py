"""Instance masks and the objects sidecar, on small episodes of the procedural and test worlds."""

from __future__ import annotations

import numpy as np
import pytest

from domains.catalog import INSTANCE_LABELS, LABELS, class_id
from outputs.objects import box_corners, object_counts
from roots.episode_spec import FRAME_PERIOD_S, EpisodeSpec
from pipeline.episode_job import frame_outputs
from render_workers.render import episode
from render_workers.render.camera import CameraRig
from render_workers.render.instances import CV_FROM_GL, HOOD_ID, instance_classes
from render_workers.render.renderer import Renderer

W, H = 192, 108
INSTANCE_IDS = {label.id for label in INSTANCE_LABELS}


@pytest.fixture(scope="module")
def renderer():
    with Renderer() as r:
        yield r


@pytest.fixture(scope="module")
def town(renderer):
    """Four frames of a procedural town (traffic, lights and signs), and the renderer's instances."""
    spec = EpisodeSpec("T01_CN_A", 0, 5, 4, W, H, "train", 0)
    frames = []
    scene, _ = episode.load_episode(spec.drawing, renderer)
    for index in range(spec.frames):
        frames.append(episode.render_frame(renderer, scene, spec.drawing, index)[0])
    return spec, scene, list(renderer.instances), frames


def test_every_object_class_gets_ids_and_static_geometry_none(town):
    spec, _, instances, frames = town
    ids = [i.id for i in instances]
    assert ids == list(range(HOOD_ID + 1, HOOD_ID + 1 + len(ids)))  # dense, the hood first
    assert {i.class_id for i in instances} == INSTANCE_IDS  # traffic lights and signs too
    classes = instance_classes(instances)
    for frame in frames:
        inst, cls = frame_outputs(spec, frame)["instance"], frame_outputs(spec, frame)["semantic_raw"][..., 0]
        assert inst.dtype == np.uint16
        objects = inst > HOOD_ID
        assert (classes[inst[objects]] == cls[objects]).all()  # an id always sits on its own class
        assert not np.isin(cls[inst == 0], list(INSTANCE_IDS)).any()  # every object pixel has an id
        assert (cls[inst == HOOD_ID] == class_id("vehicle")).all()
        assert frame.object_counts == object_counts(inst, classes)
        table = frame_outputs(spec, frame)["objects"]
        for label in INSTANCE_LABELS:
            assert frame.object_counts[label.object_column] == table.column("class_id").to_pylist().count(label.id)


def test_instance_ids_are_stable_across_the_episode(town):
    """An actor keeps its id: the 3D box the sidecar gives for an id, taken back to
    the world, is that actor's box at each frame's time; ids seen in several frames abound."""
    spec, scene, instances, frames = town
    by_id = {i.id: i for i in instances}
    rig = CameraRig(scene_viewpoint(spec), W, H)
    seen: dict[int, int] = {}
    for frame in frames:
        t = frame.index * FRAME_PERIOD_S
        cam = rig.world_from_camera(scene.ego.pose(t))
        rows = frame_outputs(spec, frame)["objects"].to_pylist()
        for row in rows:
            inst = by_id[row["instance_id"]]
            assert row["class_id"] == inst.class_id
            world = np.eye(4) if inst.actor < 0 else scene.actors[inst.actor].pose(t)
            expected = world[:3, :3] @ inst.centre + world[:3, 3]
            centre_gl = CV_FROM_GL @ np.array([row["cx"], row["cy"], row["cz"]])
            got = cam[:3, :3] @ centre_gl + cam[:3, 3]
            assert np.allclose(got, expected, atol=1e-3 * max(1.0, np.linalg.norm(expected - cam[:3, 3])))
            seen[row["instance_id"]] = seen.get(row["instance_id"], 0) + 1
    assert sum(1 for n in seen.values() if n >= 2) >= 3


def scene_viewpoint(spec):
    from domains.catalog import scenario

    return scenario(spec.scenario).viewpoint


def test_2d_boxes_are_tight_against_the_mask(town):
    spec, _, _, frames = town
    for frame in frames:
        inst = frame_outputs(spec, frame)["instance"]
        for row in frame_outputs(spec, frame)["objects"].to_pylist():
            ys, xs = np.nonzero(inst == row["instance_id"])
            assert row["pixels"] == len(xs) > 0
            assert (row["x0"], row["y0"], row["x1"], row["y1"]) == (xs.min(), ys.min(), xs.max() + 1, ys.max() + 1)
            assert 0.0 <= row["occlusion"] < 1.0 and 0.0 <= row["truncation"] <= 1.0
            assert LABELS[row["class_id"]].name == row["class_name"]


def test_3d_box_projects_inside_the_2d_box(town):
    """The projected 3D box encloses the visible 2D box, and for objects well in view
    its projected centre lies inside the 2D box."""
    spec, _, _, frames = town
    focal = W / 2.0  # 90 degree horizontal field of view
    checked = 0
    for frame in frames:
        for row in frame_outputs(spec, frame)["objects"].to_pylist():
            corners = box_corners((row["cx"], row["cy"], row["cz"]), (row["length"], row["width"], row["height"]), row["yaw"])
            if (corners[:, 2] <= 0.1).any():
                continue
            px = np.stack([W / 2 + focal * corners[:, 0] / corners[:, 2], H / 2 + focal * corners[:, 1] / corners[:, 2]], 1)
            (u0, v0), (u1, v1) = px.min(axis=0), px.max(axis=0)
            assert u0 - 1 <= row["x0"] and row["x1"] <= u1 + 1 and v0 - 1 <= row["y0"] and row["y1"] <= v1 + 1, row
            if row["pixels"] >= 30 and row["truncation"] == 0.0 and row["occlusion"] < 0.3:
                cu = W / 2 + focal * row["cx"] / row["cz"]
                cv = H / 2 + focal * row["cy"] / row["cz"]
                assert row["x0"] - 1 <= cu <= row["x1"] + 1 and row["y0"] - 1 <= cv <= row["y1"] + 1, row
                checked += 1
    assert checked >= 2


def test_silhouette_fills_every_triangle_and_clips_at_the_near_plane():
    """An amodal silhouette is the union of its triangles' projections: a square of two triangles at
    10 m fills the square (each triangle is half of it), and a triangle the near plane cuts still fills
    its visible part."""
    from render_workers.render.instances import _silhouette

    focal, cx, cy, shape = 100.0, 50.0, 50.0, (100, 100)
    a, b, c, d = ([x, y, 10.0] for x, y in ((-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)))
    square = np.array([[a, b, c], [a, c, d]])  # 20 x 20 pixels about the centre
    window = (slice(45, 55), slice(45, 55))
    for tris in (square, square[:1], square[1:]):
        (ys, xs), mask = _silhouette(tris, window, shape, focal, cx, cy)
        filled = np.zeros(shape, bool)
        filled[ys, xs] = mask
        share = filled[40:60, 40:60].mean()
        assert (share == 1.0) if len(tris) == 2 else (0.5 <= share < 0.6)
        assert filled.sum() == filled[39:61, 39:61].sum()  # nothing outside the square's pixels
    cut = np.array([[[-1.0, -1.0, 10.0], [1.0, -1.0, 10.0], [0.0, 1.0, -1.0]]])  # a vertex behind the camera
    (ys, xs), mask = _silhouette(cut, (slice(40, 41), slice(40, 60)), shape, focal, cx, cy)
    filled = np.zeros(shape, bool)
    filled[ys, xs] = mask
    assert filled[40, 41:59].all() and filled[60:].any()  # its far edge, and up to the image's edge
    assert not filled[:39].any()  # the part behind the near plane (z < NEAR_M) is not drawn
