"""Calibration and poses in the manifest: the convention holds, and depth reprojects between frames."""

from __future__ import annotations

import numpy as np
import pytest

from domains.catalog import class_id
from outputs.encoding import decode_depth_raw, decode_png
from outputs.geometry import CV_FROM_GL, HFOV_DEG, as_matrix, depth_to_world, intrinsics, project, world_to_camera
from roots.episode_spec import EpisodeSpec
from manifests.reader import read_part
from render_workers.render.camera import camera_rig

W, H = 160, 90
# Classes that can move, and the sky (no surface): the rest is the static world.
NOT_STATIC = tuple(class_id(name) for name in ("vehicle", "pedestrian", "rider", "bicycle", "motorcycle", "sky"))
# A flat road looks the same from anywhere along it: these say nothing about the ego's position on it.
FLAT = tuple(class_id(name) for name in ("road", "road line", "sidewalk", "terrain", "ground", "railway"))


def test_intrinsics_project_as_the_renderer_does():
    """K in OpenCV's convention (pixel centres at integers) puts a point where the
    renderer's own projection (centres at +0.5, OpenGL axes) does, half a pixel apart."""
    rig = camera_rig("M", W, H)
    K = rig.K
    assert K[0, 0] == K[1, 1] == pytest.approx(W / 2 / np.tan(np.radians(HFOV_DEG / 2)))
    assert (K[0, 2], K[1, 2]) == ((W - 1) / 2, (H - 1) / 2)
    points_gl = np.array([[1.0, 0.5, -10.0], [-3.0, -1.2, -4.0], [0.0, 0.0, -100.0]])
    points_cv = points_gl @ CV_FROM_GL[:3, :3]
    assert np.allclose(project(points_cv, K) + 0.5, rig.project(points_gl))
    assert np.allclose(intrinsics(1920, 1080, 90.0)[:2, 2], (959.5, 539.5))


def test_camera_axes_in_the_ego_frame():
    """OpenCV camera axes: x right (ego -y), y down (ego -z), z forward (ego +x), at the mirror's height."""
    rig = camera_rig("B", W, H)
    R, t = rig.cam_to_ego[:3, :3], rig.cam_to_ego[:3, 3]
    assert np.allclose(R @ [1, 0, 0], [0, -1, 0]) and np.allclose(R @ [0, 1, 0], [0, 0, -1])
    assert np.allclose(R @ [0, 0, 1], [1, 0, 0])
    assert t[2] == pytest.approx(rig.viewpoint.camera_height_m) and t[0] > 0


def test_depth_to_world_round_trip():
    """The docs' snippet: pixels back-projected with K and the pose project back onto themselves."""
    K = intrinsics(W, H, HFOV_DEG)
    pose = np.eye(4)
    pose[:3, :3] = [[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]  # looking along world +x
    pose[:3, 3] = (5.0, -2.0, 1.5)
    depth = np.full((H, W), 1000.0, np.float32)
    depth[50:, :] = 12.5
    points = depth_to_world(depth, list(K.ravel()), list(pose.ravel()))
    assert points.shape == ((H - 50) * W, 3)
    assert np.allclose(points[:, 0], 5.0 + 12.5)  # 12.5 m ahead along world +x
    cam = world_to_camera(points, pose)
    v, u = np.nonzero(depth < 999)
    assert np.allclose(project(cam, K), np.stack([u, v], axis=1)) and np.allclose(cam[:, 2], 12.5)


def reprojection_errors(depth_a, depth_b, classes_a, classes_b, row_a, row_b, skip=NOT_STATIC) -> np.ndarray:
    """Relative depth errors of frame a's static pixels moved into frame b, where b sees static world
    (``skip``: the classes left out). Frame b's depth is read between pixel centres by bilinear
    interpolation of 1/z (exact on a plane), where all four neighbours are static."""
    static_a = ~np.isin(classes_a, skip)
    points = depth_to_world(np.where(static_a, depth_a, 1000.0), row_a["K"], row_a["cam_to_world"])
    cam = world_to_camera(points, row_b["cam_to_world"])
    cam = cam[cam[:, 2] > 0.5]
    uv = project(cam, row_b["K"])
    inside = (uv[:, 0] >= 0) & (uv[:, 0] <= W - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= H - 1)
    cam, uv = cam[inside], uv[inside]
    u0 = np.minimum(np.floor(uv[:, 0]).astype(int), W - 2)
    v0 = np.minimum(np.floor(uv[:, 1]).astype(int), H - 2)
    fu, fv = uv[:, 0] - u0, uv[:, 1] - v0
    corners = [(v0, u0), (v0, u0 + 1), (v0 + 1, u0), (v0 + 1, u0 + 1)]
    weights = [(1 - fu) * (1 - fv), fu * (1 - fv), (1 - fu) * fv, fu * fv]
    keep = np.all([~np.isin(classes_b[v, u], skip) for v, u in corners], axis=0)
    inverse = sum(w / depth_b[v, u] for w, (v, u) in zip(weights, corners))
    seen = 1.0 / inverse[keep]
    return np.abs(cam[keep, 2] - seen) / seen


@pytest.mark.parametrize("interval", [3.0, 0.1])
def test_depth_reprojects_between_frames_with_the_manifest_poses(tmp_path, interval):
    """The proof of issue 24: frame t's planar depth, back-projected with the row's K and
    cam_to_world and moved into frame t+1, matches frame t+1's depth on static classes,
    at the paper's 3 s and at a 10 Hz camera's 0.1 s."""
    from pipeline.episode_job import run_episode
    from storage import Storage

    storage = Storage.from_uri(str(tmp_path / "root"))
    spec = EpisodeSpec("T01_CN_M", 0, 11, 3, W, H, "train", 0, frame_interval_s=interval)
    run_episode(spec, storage, world="test")
    rows = read_part(storage, spec.scenario, spec.episode).to_pylist()
    assert [r["sim_time_s"] for r in rows] == pytest.approx([0.0, interval, 2 * interval])
    depth = [decode_depth_raw(decode_png(storage.read_bytes(r["depth_raw_path"]), "depth")) for r in rows]
    classes = [decode_png(storage.read_bytes(r["semantic_raw_path"]), "semantic")[..., 0] for r in rows]
    for r in rows:
        assert len(r["K"]) == 9 and len(r["cam_to_world"]) == len(r["ego_to_world"]) == len(r["cam_to_ego"]) == 16
        assert np.allclose(as_matrix(r["cam_to_world"], 4), as_matrix(r["ego_to_world"], 4) @ as_matrix(r["cam_to_ego"], 4))
    moved = np.linalg.norm(as_matrix(rows[1]["cam_to_world"], 4)[:3, 3] - as_matrix(rows[0]["cam_to_world"], 4)[:3, 3])
    assert moved == pytest.approx(interval * rows[0]["ego_speed_mps"], rel=1e-3)  # straight along its lane
    for a in range(len(rows) - 1):
        errors = reprojection_errors(depth[a], depth[a + 1], classes[a], classes[a + 1], rows[a], rows[a + 1])
        # 3 s apart the ego drove ~30 m: most of frame a's near road is behind it, the far world still in view
        assert errors.size > (100 if interval > 1 else 0.2 * W * H)
        assert np.median(errors) <= 0.01, (a, np.median(errors))
        # Off the flat ground (buildings, poles, walls...) too; and there frame a's pose in place of
        # frame a+1's is far off, so a wrong pose fails the test.
        upright = reprojection_errors(depth[a], depth[a + 1], classes[a], classes[a + 1], rows[a], rows[a + 1],
                                      NOT_STATIC + FLAT)
        assert upright.size > 50 and np.median(upright) <= 0.01, (a, np.median(upright))
        still = reprojection_errors(depth[a], depth[a + 1], classes[a], classes[a + 1], rows[a], rows[a],
                                    NOT_STATIC + FLAT)
        assert np.median(still) > (0.05 if interval > 1 else 0.002)


def test_the_docs_depth_snippet_gives_the_world_points(tmp_path):
    """docs/conventions.md's numpy snippet, run as written on a rendered frame and its manifest row,
    gives outputs.geometry.depth_to_world's points; and they are where the renderer put the road."""
    import re
    from pathlib import Path

    from pipeline.episode_job import run_episode
    from storage import Storage

    doc = (Path(__file__).resolve().parents[1] / "docs" / "conventions.md").read_text()
    section = doc[doc.index("## Depth PNG to world points"):]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    namespace: dict = {}
    exec(compile(code, "docs/conventions.md", "exec"), namespace)
    storage = Storage.from_uri(str(tmp_path / "root"))
    spec = EpisodeSpec("T02_CN_B", 0, 5, 1, 64, 36, "train", 0)
    run_episode(spec, storage, world="test")
    row = read_part(storage, spec.scenario, spec.episode).to_pylist()[0]
    points = namespace["depth_png_to_world"](storage.path(row["depth_raw_path"]), row["K"], row["cam_to_world"])
    depth = decode_depth_raw(decode_png(storage.read_bytes(row["depth_raw_path"]), "depth"))
    assert points.shape[0] > 0.3 * 64 * 36
    assert np.allclose(points, depth_to_world(depth, row["K"], row["cam_to_world"]))
    classes = decode_png(storage.read_bytes(row["semantic_raw_path"]), "semantic")[..., 0]
    road = classes[depth < 999.0] == class_id("road")
    ego_z = as_matrix(row["ego_to_world"], 4)[2, 3]
    assert road.sum() > 50 and np.median(np.abs(points[road, 2] - ego_z)) < 0.05  # the road is at the ego's feet


def test_normals_face_up_on_the_road_and_sideways_on_walls(tmp_path):
    """The opt-in normals output, taken to the world with cam_to_world: the road's point up,
    buildings' and walls' lie flat; unit length wherever there is a surface, zero in the sky."""
    from outputs.table import output, read_output
    from pipeline.episode_job import run_episode
    from storage import Storage

    storage = Storage.from_uri(str(tmp_path / "root"))
    spec = EpisodeSpec("T01_CN_A", 0, 7, 1, W, H, "train", 0, outputs=("semantic_raw", "normals"))
    run_episode(spec, storage, world="test")
    row = read_part(storage, spec.scenario, spec.episode).to_pylist()[0]
    normals = output("normals").decode(read_output("normals", storage.read_bytes(row["normals_path"])))
    classes = decode_png(storage.read_bytes(row["semantic_raw_path"]), "semantic")[..., 0]
    sky = classes == class_id("sky")
    assert not normals[sky].any()
    assert np.allclose(np.linalg.norm(normals[~sky], axis=-1), 1.0, atol=1e-3)
    world = normals @ as_matrix(row["cam_to_world"], 4)[:3, :3].T
    road = classes == class_id("road")
    assert road.sum() > 200 and np.median(world[road, 2]) > np.cos(np.radians(2))
    upright = np.isin(classes, [class_id("building"), class_id("wall")])
    assert upright.sum() > 50 and np.median(np.abs(world[upright, 2])) < np.sin(np.radians(5))


def test_flow_is_the_reprojection_on_static_pixels_and_follows_moving_objects(tmp_path):
    """The opt-in flow output (KITTI encoding) at 0.1 s: on static pixels it equals the
    reprojection of depth with the manifest's K and poses (median end-point error <= 0.5 px);
    on vehicles, following it into frame t+1 finds the same object more often than zero flow;
    the last frame's flow is all invalid."""
    from outputs.table import output, read_output
    from pipeline.episode_job import run_episode
    from storage import Storage

    storage = Storage.from_uri(str(tmp_path / "root"))
    spec = EpisodeSpec("T01_CN_M", 0, 11, 2, W, H, "train", 0, frame_interval_s=0.1,
                       outputs=("depth_raw", "semantic_raw", "instance", "flow"))
    run_episode(spec, storage, world="test")
    rows = read_part(storage, spec.scenario, spec.episode).to_pylist()

    def read(row, name):
        return output(name).decode(read_output(name, storage.read_bytes(row[f"{name}_path"]), row[f"{name}_path"]))

    flow, last = read(rows[0], "flow"), read(rows[1], "flow")
    assert not last[..., 2].any()
    depth, classes = read(rows[0], "depth_raw"), read(rows[0], "semantic_raw")
    v, u = np.nonzero(depth < 999.0)
    cam = world_to_camera(depth_to_world(depth, rows[0]["K"], rows[0]["cam_to_world"]), rows[1]["cam_to_world"])
    expected = project(cam, rows[1]["K"]) - np.stack([u, v], axis=1)
    static = ~np.isin(classes[v, u], NOT_STATIC) & (flow[v, u, 2] > 0)
    assert static.sum() > 0.3 * W * H
    epe = np.linalg.norm(flow[v, u, :2][static] - expected[static], axis=1)
    assert np.median(epe) <= 0.5 and np.percentile(epe, 90) <= 0.05
    ids_now, ids_next = read(rows[0], "instance"), read(rows[1], "instance")
    movers = (classes == class_id("vehicle")) & (ids_now > 1) & (flow[..., 2] > 0)
    mv, mu = np.nonzero(movers)
    tu = np.clip(np.rint(mu + flow[mv, mu, 0]).astype(int), 0, W - 1)
    tv = np.clip(np.rint(mv + flow[mv, mu, 1]).astype(int), 0, H - 1)
    followed = np.mean(ids_next[tv, tu] == ids_now[mv, mu])
    still = np.mean(ids_next[mv, mu] == ids_now[mv, mu])
    assert movers.sum() > 20 and followed > still and followed > 0.9, (followed, still)


def test_flow_beyond_the_encodings_range_is_invalid_in_a_full_hd_wide_render(tmp_path):
    """Issue 32: 1920 px wide and 3 s between frames, static pixels near the sides move beyond KITTI's
    +-512 px: they are stored invalid (a root made before rules clamps them, and keeps doing so); every
    other pixel is stored as before, and what is valid is the reprojection."""
    from dataclasses import replace

    from outputs.table import output, read_output
    from manifests.schema import OLD_RULES
    from pipeline.episode_job import run_episode
    from storage import Storage

    spec = EpisodeSpec("T01_CN_V", 0, 11, 2, 1920, 36, "train", 0, outputs=("depth_raw", "flow"))
    flows = {}
    for rules in (spec.rules, OLD_RULES):
        storage = Storage.from_uri(str(tmp_path / f"rules{rules}"))
        run_episode(replace(spec, rules=rules), storage, world="test")
        rows = read_part(storage, spec.scenario, spec.episode).to_pylist()
        flows[rules] = read_output("flow", storage.read_bytes(rows[0]["flow_path"]))
    new, old = flows[spec.rules], flows[OLD_RULES]
    clamped = (old[..., 2] > 0) & ((old[..., :2] == 0) | (old[..., :2] == 65535)).any(axis=-1)
    assert clamped.sum() > 20  # the scene has motion beyond the range
    assert not (new[clamped]).any() and np.array_equal(new[~clamped], old[~clamped])
    depth = output("depth_raw").decode(read_output("depth_raw", storage.read_bytes(rows[0]["depth_raw_path"])))
    v, u = np.nonzero(depth < 999.0)
    cam = world_to_camera(depth_to_world(depth, rows[0]["K"], rows[0]["cam_to_world"]), rows[1]["cam_to_world"])
    expected = project(cam, rows[0]["K"]) - np.stack([u, v], axis=1)
    flow = output("flow").decode(new)
    valid = flow[v, u, 2] > 0
    assert np.median(np.linalg.norm(flow[v, u, :2][valid] - expected[valid], axis=1)) <= 0.5
    assert (np.abs(expected[clamped[v, u]]).max(axis=1) > 511).all()
