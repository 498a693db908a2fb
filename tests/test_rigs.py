"""Sensor rigs (issue 37): the rig table, one world state per frame for every sensor, the layout,
the manifest's sensor rows, resume and verify, and the geometric proofs (stereo disparity, surround
neighbours, LiDAR against the front camera)."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest
from typer.testing import CliRunner

from domains.catalog import class_id
from domains.conditions import CONDITION_COLUMNS
from domains.rigs import DEFAULT_RIG, RigError, builtin_rigs, rig_from_entry, rig_named, rigs_from_text
from manifests.layout import EPISODE_DIRS, match_frame_file, frame_path
from outputs.encoding import decode_depth_raw, decode_kitti_labels, decode_kitti_points, decode_png
from outputs.geometry import as_matrix, project, world_to_camera
from outputs.table import read_output
from pipeline.planner import PlanConfig, make_plan
from pipeline.settings import RunConfig
from render_workers.render.instances import HOOD_ID
from tests.roots import render_root

SKY = class_id("sky")


def _rows(root) -> list[dict]:
    from manifests.reader import read_manifest

    return read_manifest(str(root)).to_pylist()


def _depth(root, row) -> np.ndarray:
    return decode_depth_raw(decode_png((root / row["depth_raw_path"]).read_bytes())).astype(np.float64)


def _classes(root, row) -> np.ndarray:
    return decode_png((root / row["semantic_raw_path"]).read_bytes())[..., 0]


def _plan(rig: str, frames: int = 1, width: int = 160, height: int = 90, domains: str = "T01_CN_A") -> PlanConfig:
    return PlanConfig(domains=domains, frames_per_scenario=frames, width=width, height=height, rig=rig)


# ------------------------------------------------------------------ the table ----
def test_built_in_rigs():
    rigs = builtin_rigs()
    assert list(rigs) == ["front", "stereo", "surround", "lidar64"]
    assert rigs[DEFAULT_RIG].is_default and len(rigs["front"].sensors) == 1 and rigs["front"].sensors[0].is_mount_camera
    left, right = rigs["stereo"].sensors
    assert left.is_mount_camera and (right.y - left.y) == pytest.approx(-0.54)  # right is 0.54 m to the right
    assert len(rigs["surround"].cameras) == 6
    yaws = sorted(s.yaw % 360 for s in rigs["surround"].sensors)
    gaps = np.diff(yaws + [yaws[0] + 360])
    assert all(g < s.hfov_deg for g, s in zip(gaps, rigs["surround"].sensors))  # neighbours overlap: all round
    lidar = [s for s in rigs["lidar64"].sensors if s.kind == "lidar"]
    assert len(lidar) == 1 and lidar[0].beams == 64


@pytest.mark.parametrize("entry, message", [
    ({"name": "x", "sensor": []}, "at least one sensor"),
    ({"name": "x", "sensor": [{"name": "a", "kind": "radar"}]}, "'kind'"),
    ({"name": "x", "sensor": [{"name": "A b", "kind": "camera"}]}, "lower-case"),
    ({"name": "x", "sensor": [{"name": "a", "kind": "camera", "hfov_deg": 500}]}, "out of range"),
    ({"name": "x", "sensor": [{"name": "a", "kind": "camera", "colour": 1}]}, "'colour': unknown"),
    ({"name": "x", "sensor": [{"name": "a", "kind": "camera"}, {"name": "a", "kind": "camera"}]}, "twice"),
    ({"name": "x", "sensor": [{"name": "a", "kind": "lidar"}]}, "at least one camera"),
    ({"name": "x", "sensor": [{"name": "a", "kind": "camera"}, {"name": "l", "kind": "lidar", "pitch": 5}]}, "level"),
    ({"name": "x", "sensor": [{"name": "a", "kind": "camera", "width": 9}]}, r"'width': 9 is out of range \[32, 8192\]"),
    ({"name": "x", "sensor": [{"name": "a", "kind": "camera", "height": 64.5}]}, "'height': expected a whole number"),
    ({"name": "x", "sensor": [{"name": "a", "kind": "camera"}, {"name": "l", "kind": "lidar", "height": 64}]},
     "'height': a camera's"),
])
def test_a_bad_rig_is_refused_naming_what(entry, message):
    with pytest.raises(RigError, match=message):
        rig_from_entry(entry, "f.toml")
    with pytest.raises(RigError, match="valid rigs: front, stereo"):
        rig_named("nope")
    assert list(rigs_from_text('[[rig]]\nname = "mono"\nsensor = [{ name = "cam", kind = "camera" }]\n', "f")) == ["mono"]


def test_a_bad_rig_is_one_line_and_exit_2(tmp_path):
    from pipeline.cli import app

    result = CliRunner().invoke(app, ["produce", "--domains", "T01_CN_A", "--frames-per-scenario", "1", "--width", "64",
                                      "--height", "36", "--world", "test", "--rig", "wide", "--out", str(tmp_path / "o")])
    assert result.exit_code == 2
    assert result.output.strip().splitlines() == ["error: unknown rig 'wide'; valid rigs: front, stereo, surround, lidar64"]
    assert not (tmp_path / "o").exists()


def test_plan_takes_a_rig_and_counts_sensor_frames(tmp_path):
    """``idda plan --rig``: the rig's sensors and the frames as sensor frames; a bad rig as produce's (one line, exit 2)."""
    from pipeline.cli import app
    from pipeline.plan_file import read_plan

    runner = CliRunner()
    out = tmp_path / "plan.parquet"
    args = ["plan", "--domains", "T01_CN_A", "--frames-per-scenario", "3", "--out", str(out)]
    result = runner.invoke(app, [*args, "--rig", "surround"])
    assert result.exit_code == 0, result.output
    assert ("rig surround: 6 sensors, front (camera), frontleft (camera), backleft (camera), back (camera), "
            "backright (camera), frontright (camera); 3 frames = 18 sensor frames") in result.output.splitlines()
    assert read_plan(out).config.rig == "surround"
    assert "rig front: 1 sensor, front (camera); 3 frames = 3 sensor frames" in runner.invoke(app, args).output
    out.unlink()
    result = runner.invoke(app, [*args, "--rig", "wide"])
    assert result.exit_code == 2
    assert result.output.strip().splitlines() == ["error: unknown rig 'wide'; valid rigs: front, stereo, surround, lidar64"]
    assert not out.exists()
    domain = tmp_path / "rear.toml"
    domain.write_text('[[rig]]\nname = "rear"\nsensor = [{ name = "back", kind = "camera", yaw = 180.0 }, '
                      '{ name = "roof", kind = "lidar", z = 0.4 }]\n')
    result = runner.invoke(app, [*args, "--rig", "rear", "--catalog", str(domain)])
    assert result.exit_code == 0, result.output
    assert "rig rear: 2 sensors, back (camera), roof (lidar); 3 frames = 6 sensor frames" in result.output
    assert json.loads(read_plan(out).config.rig)["name"] == "rear"


def test_the_default_rig_leaves_specs_and_paths_as_before():
    plan = make_plan(_plan("front"))
    assert {spec.rig for spec in plan.episodes} == {""} and plan.episodes[0].sensors == ("",)
    assert frame_path("T01_CN_A", "rgb", "0000_001", "png", EPISODE_DIRS) == "T01_CN_A/e0000/rgb/0000_001_T01_CN_A.png"
    stereo = make_plan(_plan("stereo")).episodes[0]
    assert stereo.sensors == ("left", "right") and json.loads(stereo.rig)["name"] == "stereo"
    path = frame_path("T01_CN_A", "rgb", "0000_001", "png", EPISODE_DIRS, "left")
    assert path == "T01_CN_A/e0000/left/rgb/0000_001_T01_CN_A_left.png"
    match = match_frame_file(path)
    assert match and match["sensor"] == "left" and match["output"] == "rgb" and match["frame"] == "001"
    assert match_frame_file("T01_CN_A/e0000/rgb/0000_001_T01_CN_A.png")["sensor"] is None
    assert match_frame_file("T01_CN_A/e0000/left/rgb/0000_001_T01_CN_A_right.png") is None  # the stem names its sensor
    with pytest.raises(ValueError, match="written by a rig's LiDAR"):
        replace(_plan("front"), outputs=("rgb", "lidar_points")).validate()


# ------------------------------------------------------------------ stereo ----
@pytest.fixture(scope="module")
def stereo_root(tmp_path_factory):
    root = tmp_path_factory.mktemp("stereo")
    render_root(root, RunConfig(plan=_plan("stereo", frames=2), world="test"))
    return root


def test_stereo_rows_one_per_sensor_frame_same_instant(stereo_root):
    rows = _rows(stereo_root)
    assert [(r["frame"], r["sensor"]) for r in rows] == [(0, "left"), (0, "right"), (1, "left"), (1, "right")]
    assert len({r["uid"] for r in rows}) == 4
    for left, right in zip(rows[::2], rows[1::2]):
        assert left["sim_time_s"] == right["sim_time_s"] and left["ego_to_world"] == right["ego_to_world"]
        assert left["n_vehicles"] == right["n_vehicles"]
        assert all(left[c] == right[c] for c in CONDITION_COLUMNS)  # the same weather
        lc, rc = as_matrix(left["cam_to_ego"], 4), as_matrix(right["cam_to_ego"], 4)
        assert np.allclose(np.linalg.inv(lc) @ rc[:, 3], [0.54, 0, 0, 1])  # the right camera, 0.54 m along camera x
        assert left["hood_fraction"] > 0 and right["hood_fraction"] == 0  # the hood: the viewpoint's camera only


def test_stereo_disparity_is_f_b_over_z(stereo_root):
    """For static pixels of the right image on surfaces whose depth changes along the row, the
    left image's matching position (where the left depth, interpolated in 1/Z, equals the right pixel's
    depth) is f * B / Z to the right: measured from the two depth renders, not from the poses."""
    rows = _rows(stereo_root)
    errors = []
    for left, right in zip(rows[::2], rows[1::2]):
        zl, zr = _depth(stereo_root, left), _depth(stereo_root, right)
        cl, cr = _classes(stereo_root, left), _classes(stereo_root, right)
        inst = read_output("instance", (stereo_root / right["instance_path"]).read_bytes())
        f = as_matrix(right["K"], 3)[0, 0]
        for v, u in zip(*np.nonzero((zr < 200) & (inst == 0) & (cr != SKY))):
            z = zr[v, u]
            pred = u + f * 0.54 / z
            best = None
            for k in range(int(pred) - 2, int(pred) + 3):
                if not 0 <= k < zl.shape[1] - 1 or cl[v, k] != cr[v, u] or cl[v, k + 1] != cr[v, u]:
                    continue
                a, b = 1 / zl[v, k], 1 / zl[v, k + 1]
                if abs(b - a) < 1e-3 / z or abs(zl[v, k + 1] - zl[v, k]) > 0.05 * z:  # flat along the row, or an edge
                    continue
                t = (1 / z - a) / (b - a)
                if 0 <= t <= 1 and (best is None or abs(k + t - pred) < abs(best - pred)):
                    best = k + t
            if best is not None:
                errors.append(best - u - f * 0.54 / z)
    print(f"stereo: {len(errors)} matches, median |disparity - f*B/Z| {np.median(np.abs(errors)):.4f} px")
    assert len(errors) > 200
    assert np.median(np.abs(errors)) <= 0.1


def test_stereo_resumes_and_verifies_byte_identically(stereo_root, tmp_path):
    """A rig's part holds frames x sensors rows: resume must count frames, not rows (without that a done
    stereo episode read as 'holds 4 frames, the plan asks for 2' and the run stopped)."""
    import shutil

    from manifests.reader import episode_frames
    from pipeline.driver import pending_episodes
    from pipeline.status import root_status
    from roots.verify import verify as verify_root
    from storage import Storage

    root = tmp_path / "copy"
    shutil.copytree(stereo_root, root)
    storage = Storage.from_uri(str(root))
    plan = make_plan(_plan("stereo", frames=2))
    assert pending_episodes(plan, episode_frames(storage)) == []
    status = root_status(storage)
    assert (status.frames_done, status.frames_total) == (2, 2)
    assert verify_root(storage).ok
    before = {p.relative_to(root): p.read_bytes() for p in root.rglob("*.png")}
    # lose the part and one right-camera file: the episode is pending, and re-rendered to the same bytes
    part = next(root.glob("manifest/**/*.parquet"))
    part.unlink()
    (root / "T01_CN_A/e0000/right/rgb/0000_001_T01_CN_A_right.png").unlink()
    assert [s.key for s in pending_episodes(plan, episode_frames(storage))] == ["T01_CN_A/e0000"]
    render_root(root, RunConfig(plan=_plan("stereo", frames=2), world="test"))
    assert {p.relative_to(root): p.read_bytes() for p in root.rglob("*.png")} == before
    assert verify_root(storage).ok
    damaged = root / "T01_CN_A/e0000/right/depth_raw/0000_000_T01_CN_A_right.png"
    damaged.write_bytes(damaged.read_bytes()[:-1] + b"x")
    problems = verify_root(storage).problems
    assert [p.path for p in problems] == ["T01_CN_A/e0000/right/depth_raw/0000_000_T01_CN_A_right.png"]


def test_query_by_sensor(stereo_root):
    from manifests.query import Query, run_query
    from manifests.reader import read_manifest

    table = read_manifest(str(stereo_root))
    picked = run_query(table, Query(sensors=("right",))).table
    assert picked.column("sensor").to_pylist() == ["right", "right"]
    with pytest.raises(ValueError, match="not a sensor name"):
        Query(sensors=("Right side",)).validate()


def test_card_and_stats_count_frames_not_sensor_frames(stereo_root, tmp_path):
    """A stereo root of 2 frames holds 4 manifest rows: the card and ``idda stats`` say 2 frames (and 4 sensor frames)."""
    import shutil

    from exports.card import split_counts
    from manifests.query import count_frames, rig_sensors
    from manifests.reader import read_manifest
    from pipeline.cli import app

    root = tmp_path / "stereo"
    shutil.copytree(stereo_root, root)
    table = read_manifest(str(root))
    assert (len(table), count_frames(table), rig_sensors(table)) == (4, 2, ("left", "right"))
    assert sum(sum(row.values()) for row in split_counts(table).values()) == 2
    runner = CliRunner()
    result = runner.invoke(app, ["card", str(root)])
    assert result.exit_code == 0, result.output
    assert "(2 of the 2 frames the root holds)" in result.output
    card = (root / "README.md").read_text()
    assert "2 frames in 1 episodes over 1 scenarios (town x weather x viewpoint), each seen by the 2 sensor(s) of its " \
           "rig (left, right; 4 sensor frames, one manifest row each), at 160x90" in card
    assert "| **total** (1 scenarios) | | | |" in card and "| **2** |" in card
    result = runner.invoke(app, ["stats", str(root), "--chart", str(tmp_path / "shares.png")])
    assert result.exit_code == 0, result.output
    assert "(2 of the 2 frames the root holds, 4 sensor frames of its 4)" in result.output


def test_query_and_export_count_frames_not_sensor_frames(stereo_root, tmp_path):
    """``idda query`` and ``idda export`` count a rig's root in frames (2), its manifest rows (4) as sensor frames;
    a sample draws frames, each with every sensor of the rig, never one sensor's row of a frame."""
    import csv

    from pipeline.cli import app

    runner = CliRunner()
    result = runner.invoke(app, ["query", str(stereo_root)])
    assert result.exit_code == 0, result.output
    assert result.output.splitlines()[-2:] == [
        "T01_CN_A          2",
        "2 frames selected of 2 matching the filters (2 of the 2 frames the root holds, 4 sensor frames of its 4)"]
    result = runner.invoke(app, ["query", str(stereo_root), "--sensor", "right"])
    assert result.output.splitlines()[-1] == ("2 frames selected of 2 matching the filters "
                                              "(2 of the 2 frames the root holds, 2 sensor frames of its 4)")
    for seed in (0, 1, 2):
        out = tmp_path / f"one{seed}.csv"
        result = runner.invoke(app, ["query", str(stereo_root), "--per-scenario", "1", "--seed", str(seed),
                                     "--out", str(out)])
        assert result.exit_code == 0, result.output
        assert result.output.splitlines()[-1].startswith("1 frames selected of 2 matching the filters "
                                                         "(1 of the 2 frames the root holds, 2 sensor frames of its 4)")
        rows = list(csv.DictReader(out.open()))
        assert [r["sensor"] for r in rows] == ["left", "right"] and rows[0]["frame"] == rows[1]["frame"]
    result = runner.invoke(app, ["query", str(stereo_root), "--per-scenario", "3"])
    assert "warning: T01_CN_A has 1 frame(s) fewer than asked for" in result.output
    result = runner.invoke(app, ["query", str(stereo_root), "--sensor", "back"])
    assert result.exit_code == 2 and "(0 of the 2 frames the root holds match the filters)" in result.output
    result = runner.invoke(app, ["export", str(stereo_root), "--format", "cityscapes", "--sensor", "left",
                                 "--to", str(tmp_path / "cs")])
    assert result.exit_code == 0, result.output
    assert "exported 2 of the 2 frames the root holds, 2 sensor frames of its 4 (2 " in result.output
    result = runner.invoke(app, ["export", str(stereo_root), "--format", "webdataset", "--to", str(tmp_path / "wds")])
    assert result.exit_code == 0, result.output
    assert "exported 2 of the 2 frames the root holds, 4 sensor frames of its 4 (2 " in result.output
    marker = json.loads((tmp_path / "wds" / "EXPORT.json").read_text())  # a sample per sensor frame
    assert (marker["frames"], marker["sensor_frames"], marker["per_scenario"]) == (2, 4, {"T01_CN_A": 2})


def test_distances_sample_frames_of_one_camera(stereo_root, monkeypatch):
    """``idda distances`` samples the first N frames per domain: in a stereo root, N frames of its left
    camera (the rig's first), not N rows (a frame's left and right images as two 'frames')."""
    from analysis import distances

    seen = {}
    features = distances.domain_features

    def spy(storage, paths, bank, threads=4):
        seen.update(paths)
        return features(storage, paths, bank, threads)

    monkeypatch.setattr(distances, "domain_features", spy)
    report = distances.domain_distances(distances.DistanceConfig(root=str(stereo_root), samples=2))
    assert seen == {"T01_CN_A": ["T01_CN_A/e0000/left/rgb/0000_000_T01_CN_A_left.png",
                                 "T01_CN_A/e0000/left/rgb/0000_001_T01_CN_A_left.png"]}
    assert report.sensor == "left" and "2 frames each (the rig's left camera)" in distances.format_distance_table(report)


# ------------------------------------------------------------------ surround ----
def test_surround_neighbours_agree_on_what_they_both_see(tmp_path):
    root = tmp_path / "surround"
    render_root(root, RunConfig(plan=_plan("surround", width=192, height=108), world="test"))
    rows = _rows(root)
    assert [r["sensor"] for r in rows] == ["front", "frontleft", "backleft", "back", "backright", "frontright"]
    agree = total = 0
    for a, b in zip(rows, rows[1:] + rows[:1]):  # every pair of neighbours, all round
        za, zb, ca, cb = _depth(root, a), _depth(root, b), _classes(root, a), _classes(root, b)
        Ka, Kb = as_matrix(a["K"], 3), as_matrix(b["K"], 3)
        v, u = np.nonzero(za < 200)
        z = za[v, u]
        cam = np.stack([(u - Ka[0, 2]) * z / Ka[0, 0], (v - Ka[1, 2]) * z / Ka[1, 1], z], axis=1)
        T = as_matrix(a["cam_to_world"], 4)
        world = cam @ T[:3, :3].T + T[:3, 3]
        in_b = world_to_camera(world, b["cam_to_world"])
        front = in_b[:, 2] > 0.5
        uv = np.rint(project(in_b[front], Kb)).astype(int)
        inside = (uv[:, 0] >= 0) & (uv[:, 0] < zb.shape[1]) & (uv[:, 1] >= 0) & (uv[:, 1] < zb.shape[0])
        ub, vb = uv[inside, 0], uv[inside, 1]
        seen = np.abs(zb[vb, ub] - in_b[front][inside, 2]) < 0.02 * in_b[front][inside, 2]  # not occluded in b
        src = ca[v[front][inside], u[front][inside]]
        agree += int(np.count_nonzero(src[seen] == cb[vb[seen], ub[seen]]))
        total += int(np.count_nonzero(seen))
    print(f"surround: {total} shared points, class agreement {agree / total:.4f}")
    assert total > 500  # the 10-degree overlaps hold many points
    assert agree / total >= 0.98


# ------------------------------------------------------------------ LiDAR ----
def test_lidar_points_land_on_the_front_camera_pixels_of_their_depth_and_class(tmp_path):
    root = tmp_path / "lidar"
    render_root(root, RunConfig(plan=_plan("lidar64", width=320, height=180), world="test"))
    front, lidar = _rows(root)
    assert (front["sensor"], lidar["sensor"]) == ("front", "lidar") and lidar["K"] is None
    assert lidar["rgb_path"] is None and lidar["lidar_points_path"].endswith("/lidar/lidar_points/0000_000_T01_CN_A_lidar.bin")
    points = decode_kitti_points((root / lidar["lidar_points_path"]).read_bytes())
    labels = decode_kitti_labels((root / lidar["lidar_labels_path"]).read_bytes())
    assert len(points) == len(labels) > 10_000 and points.dtype == np.float32
    world = points[:, :3].astype(np.float64) @ as_matrix(lidar["cam_to_world"], 4)[:3, :3].T \
        + as_matrix(lidar["cam_to_world"], 4)[:3, 3]
    cam = world_to_camera(world, front["cam_to_world"])
    ahead = cam[:, 2] > 1.0
    uv = np.rint(project(cam[ahead], front["K"])).astype(int)
    depth, classes = _depth(root, front), _classes(root, front)
    h, w = depth.shape
    inside = (uv[:, 0] >= 1) & (uv[:, 0] < w - 1) & (uv[:, 1] >= 1) & (uv[:, 1] < h - 1)
    u, v = uv[inside, 0], uv[inside, 1]
    z = cam[ahead][inside, 2]
    cls = (labels[ahead][inside] & 0xFFFF).astype(np.uint8)
    assert len(z) > 1000
    rel = np.abs(depth[v, u] - z) / z
    assert np.median(rel) <= 0.01
    # class, edges aside: pixels whose 3x3 neighbourhood is one class and one surface (no depth jump)
    window = [(dv, du) for dv in (-1, 0, 1) for du in (-1, 0, 1)]
    same = np.all([classes[v + dv, u + du] == classes[v, u] for dv, du in window], axis=0)
    smooth = np.all([np.abs(depth[v + dv, u + du] - depth[v, u]) < 0.05 * depth[v, u] for dv, du in window], axis=0)
    hood = read_output("instance", (root / front["instance_path"]).read_bytes())[v, u] == HOOD_ID  # the ego: the camera's alone
    keep = same & smooth & (rel < 0.05) & ~hood
    print(f"lidar: {len(points)} points, {len(z)} in view, median relative depth error {np.median(rel):.5f}, "
          f"class agreement {np.mean(cls[keep] == classes[v, u][keep]):.4f} over {np.count_nonzero(keep)} points")
    assert np.count_nonzero(keep) > 500
    assert np.mean(cls[keep] == classes[v, u][keep]) >= 0.98
    # the ranges stay inside the sensor's limit, and the instance ids ride in the high 16 bits
    assert np.linalg.norm(points[:, :3], axis=1).max() <= 120.0 + 1e-3
    assert set(np.unique(labels >> 16)) <= set(range(2**16))


def test_a_domain_file_declares_a_rig_that_travels_in_run_json(tmp_path):
    """A [[rig]] of a --catalog file: recorded whole in run.json, so resume, verify and workers need no file."""
    from domains.catalog import BUILTIN
    from domains.catalog_file import CatalogError, with_file
    from domains.rigs import run_rig
    from roots.run_file import read_record
    from storage import Storage

    text = ('[[rig]]\nname = "rear"\nsensor = [{ name = "back", kind = "camera", yaw = 180.0, hfov_deg = 60.0 }]\n'
            '[[weather]]\ncode = "FG1"\nlike = "CN"\n')
    assert with_file(BUILTIN, text, "f.toml").weathers[-1].code == "FG1"  # the domain tables still load
    with pytest.raises(CatalogError, match="valid tables: .*\\[\\[rig\\]\\]"):
        with_file(BUILTIN, "[[bogus]]\n", "f.toml")
    assert run_rig("stereo", text, "f.toml") == "stereo"
    recorded = run_rig("rear", text, "f.toml")
    assert json.loads(recorded)["name"] == "rear"
    root = tmp_path / "rear"
    render_root(root, RunConfig(plan=_plan(recorded, width=64, height=36), world="test"))
    (row,) = _rows(root)
    assert row["sensor"] == "back" and row["rgb_path"].startswith("T01_CN_A/e0000/back/rgb/")
    assert as_matrix(row["K"], 3)[0, 0] == pytest.approx(32 / math.tan(math.radians(30)))
    assert read_record(Storage.from_uri(str(root)))["config"]["rig"] == recorded


def test_a_camera_of_its_own_size_renders_at_it_and_its_rows_say_so(tmp_path):
    """A rig's camera may declare width and height (default the run's): its files and K are at its size, its rows
    carry it, and verify and resume accept it (the run's size is not every row's); the built-in rigs' JSON is unchanged."""
    from pipeline.provenance import RunConfigError, check_rows
    from roots.verify import verify as verify_root
    from storage import Storage

    text = ('[[rig]]\nname = "mixed"\nsensor = [{ name = "main", kind = "camera" }, '
            '{ name = "wide", kind = "camera", yaw = 90.0, hfov_deg = 120.0, width = 96, height = 48 }]\n')
    rig = rigs_from_text(text, "f.toml")["mixed"]
    assert rig.sizes(64, 36) == {"main": (64, 36), "wide": (96, 48)}
    assert all("width" not in json.dumps(json.loads(r.as_json())["sensors"]) for r in builtin_rigs().values())
    assert rig_from_entry(json.loads(rig.as_json()), "spec") == rig  # the JSON a spec carries keeps the size
    config = RunConfig(plan=_plan(rig.as_json(), frames=2, width=64, height=36), world="test")
    root = tmp_path / "mixed"
    storage = render_root(root, config)
    rows = _rows(root)
    assert [(r["sensor"], r["width"], r["height"]) for r in rows] == [("main", 64, 36), ("wide", 96, 48)] * 2
    for row in rows:
        for output in ("rgb", "depth_raw", "semantic_raw"):
            assert decode_png((root / row[f"{output}_path"]).read_bytes()).shape[:2] == (row["height"], row["width"])
        assert sum(row[label] for label in row if label.startswith("px_")) == row["width"] * row["height"]
    K = as_matrix(rows[1]["K"], 3)
    assert K[0, 0] == pytest.approx(48 / math.tan(math.radians(60))) and (K[0, 2], K[1, 2]) == (47.5, 23.5)  # pixel centres: (W - 1) / 2
    assert verify_root(storage).ok
    before = {p.relative_to(root): p.read_bytes() for p in root.rglob("*.png")}
    render_root(root, config)  # a resume checks the rows' sizes against the run's (check_rows)
    assert {p.relative_to(root): p.read_bytes() for p in root.rglob("*.png")} == before
    with pytest.raises(RunConfigError, match="holds frames at 64x36, 96x48, this run asks for 80x36, 96x48"):
        check_rows(storage, RunConfig(plan=_plan(rig.as_json(), frames=2, width=80, height=36), world="test"))
    # verify holds each sensor's rows to its own size: a camera at the run's size where its rig gives another is a conflict
    from roots.run_file import read_record
    from roots.verify import config_conflict

    recorded = read_record(storage)["config"]
    seed = rows[0]["seed"]
    assert config_conflict({"main": (64, 36), "wide": (96, 48)}, seed, "T01_CN_A", 0, recorded) is None
    assert config_conflict({"main": (64, 36), "wide": (64, 36)}, seed, "T01_CN_A", 0, recorded) \
        == "wide frames are 64x36, run.json says 96x48"


def test_a_front_root_has_no_rig_columns_in_its_parts_or_indexes(tmp_path):
    """The default rig writes the parts and indexes it wrote before rigs, byte for byte: no sensor column
    and no LiDAR columns (without leaving them out, every new front root's index changed)."""
    import pyarrow.parquet as pq

    from manifests.schema import RULE_PART_SCHEMA

    root = tmp_path / "front"
    render_root(root, RunConfig(plan=_plan("front", width=64, height=36), world="test"), compact=True)
    (part,) = root.glob("manifest/**/*.parquet")
    assert pq.read_schema(part).names == RULE_PART_SCHEMA.names
    (index,) = root.glob("_index/*.parquet")
    names = pq.read_schema(index).names
    assert "sensor" not in names and not any(n.startswith("lidar_") for n in names)
    (row,) = _rows(root)
    assert row["sensor"] is None and row["uid"] == "0000_000_T01_CN_A"
    assert row["rgb_path"] == "T01_CN_A/e0000/rgb/0000_000_T01_CN_A.png"


def test_an_export_takes_one_sensor_at_a_time(stereo_root, tmp_path):
    """Export layouts name files per frame: the left and right frames of a stereo root would overwrite each
    other, so an export of both is refused in one line, and --sensor picks one."""
    from pipeline.cli import app

    runner = CliRunner()
    both = runner.invoke(app, ["export", str(stereo_root), "--format", "cityscapes", "--to", str(tmp_path / "cs")])
    assert both.exit_code == 2 and "export one sensor at a time (--sensor NAME)" in both.output
    left = runner.invoke(app, ["export", str(stereo_root), "--format", "cityscapes", "--to", str(tmp_path / "cs"),
                               "--sensor", "left"])
    assert left.exit_code == 0, left.output
    assert len(list((tmp_path / "cs").rglob("*_leftImg8bit.png"))) == 2


def test_the_rig_bench_measures(tmp_path):
    """``benchmarks.bench_rigs`` (make bench BENCH=rigs) runs: small, on the test world (it had stopped running
    when episodes came to be drawn from a DrawSpec, and nothing noticed)."""
    from benchmarks.bench_rigs import measure

    row = measure("lidar64", 64, 36, frames=3, world="test")
    # cpu_s is a difference of two episodes' CPU: at this size a loaded machine's noise can make it either sign
    assert row["rig"] == "lidar64" and row["sensors"] == 2 and isinstance(row["cpu_s"], float)
    assert row["lidar_wall_s"] > 0 < row["lidar_cpu_s"]  # means of the sweeps, never a difference


def test_the_rig_bench_counts_every_draw(monkeypatch):
    """The bench's per-frame CPU holds every camera draw of the frames it measures. Each draw made to cost
    0.25 CPU-s more, and each sink made slower (sleeping, so the drawing thread runs ahead of it as at full
    HD): stereo's frame must cost at least its two draws' 0.5. The window between two frames' sinks it once
    took held none of front's draws and half of stereo's, which read as an overhead per extra sensor."""
    import time as clock

    from benchmarks import bench_rigs
    from render_workers.render.renderer import Renderer

    draw, encode = Renderer.render, bench_rigs.frame_files

    def costly_draw(self, *args, **kwargs):
        start = clock.thread_time()
        while clock.thread_time() - start < 0.25:
            pass
        return draw(self, *args, **kwargs)

    def slow_sink(spec, frame):
        clock.sleep(0.6)
        return encode(spec, frame)

    monkeypatch.setattr(Renderer, "render", costly_draw)
    monkeypatch.setattr(bench_rigs, "frame_files", slow_sink)
    row = bench_rigs.measure("stereo", 64, 36, frames=4, world="test")  # two frames measured: a one-off halves
    assert row["cpu_s"] >= 0.49, row


def test_semantickitti_files_round_trip():
    from outputs.encoding import encode_kitti_bin, encode_lidar_labels, encode_lidar_points

    points = np.array([[1.5, -2.0, 0.25, 0.0], [10.0, 0.0, -1.0, 0.0]], np.float32)
    labels = np.array([7 | (3 << 16), 11], np.uint32)
    data = encode_kitti_bin(encode_lidar_points((points, labels)))
    assert len(data) == 32 and np.array_equal(decode_kitti_points(data), points)
    assert np.array_equal(decode_kitti_labels(encode_kitti_bin(encode_lidar_labels((points, labels)))), labels)
    with pytest.raises(ValueError, match="lidar_points"):
        encode_lidar_points((points[:, :3].copy(), labels))
    with pytest.raises(ValueError, match="16-byte"):
        decode_kitti_points(data[:-1])


def test_the_rig_pictures_draw(tmp_path):
    """reports.rig_pictures (docs/images/rig_surround.png and rig_lidar64.png at full size), tiny."""
    from reports import rig_pictures

    root = str(tmp_path / "s")
    png = rig_pictures.surround_png(root, rig_pictures.render_rig("surround", 64, 36, root, world="test"))
    assert png.startswith(b"\x89PNG")
    root = str(tmp_path / "l")
    png = rig_pictures.lidar_png(root, rig_pictures.render_rig("lidar64", 96, 54, root, world="test"))
    assert png.startswith(b"\x89PNG")


def test_a_paired_query_pairs_a_rigs_frames_sensor_by_sensor(tmp_path):
    """`idda query --paired` in a rig's root: a paired scene has a row per sensor under each weather, so
    pairs were looked for among rows keyed without the sensor, none had exactly one row per weather, and
    the query matched nothing. Each sensor's frame pairs with the same sensor's under the other weather;
    the counts are of frames."""
    import pyarrow.csv as pv

    from pipeline.cli import app

    root = tmp_path / "root"
    render_root(root, RunConfig(plan=_plan("stereo", frames=2, width=64, height=36, domains="T01_CN_A,T01_CS_A"),
                                world="test"))
    out = tmp_path / "pairs.csv"
    result = CliRunner().invoke(app, ["query", str(root), "--paired", "CS,CN", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "4 frames selected of 4 matching the filters (4 of the 4 frames the root holds, 8 sensor frames of its 8)" \
        in result.output, result.output
    assert [line.split() for line in result.output.splitlines()[:2]] == [["T01_CN_A", "2"], ["T01_CS_A", "2"]]
    back = pv.read_csv(out)
    assert list(zip(*(back.column(c).to_pylist() for c in ("frame", "sensor", "weather")))) == [
        (f, s, w) for f in (0, 1) for s in ("left", "right") for w in ("CS", "CN")]
