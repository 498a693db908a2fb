"""``idda view`` (analysis.viewer): a rerun recording of an episode, read back
through rerun's own reader (rerun.chunk.RrdReader): frames, entity paths, the
camera pose equal to the manifest's, labels, point cloud, boxes and series."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from outputs.geometry import as_matrix, depth_to_world
from tests.test_export import cli_app, make_tiny_root

SCENARIO = "T01_CS_A"


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    return make_tiny_root(tmp_path_factory)


@pytest.fixture(scope="module")
def rows(root):
    from analysis.viewer import episode_rows
    from storage import Storage

    return episode_rows(Storage.from_uri(str(root)), SCENARIO, 0)


@pytest.fixture(scope="module")
def recording(root, tmp_path_factory) -> dict:
    """{entity path: {column: [(frame or None, value)]}} of the recording `idda view` writes."""
    from analysis.view_picture import read_recording

    out = tmp_path_factory.mktemp("view") / "episode.rrd"
    done = CliRunner().invoke(cli_app(), ["view", str(root), "--scenario", SCENARIO, "--episode", "0",
                                          "--out", str(out), "--stride", "1"])
    assert done.exit_code == 0, done.output
    assert "recorded 2 frames" in done.output
    return read_recording(str(out))


def test_every_frame_and_entity_is_recorded(recording, rows):
    frames = [r["frame"] for r in rows]
    for entity in ("world/camera", "world/camera/image", "world/camera/image/rgb", "world/camera/image/semantic",
                   "world/camera/image/depth", "world/depth", "world/camera/boxes", "world/camera/image/boxes",
                   "conditions/sun_altitude_deg", "conditions/cloudiness", "conditions/ego_speed_mps"):
        columns = recording["/" + entity]
        logged = sorted({f for values in columns.values() for f, v in values if v is not None})
        assert logged == frames, entity
    assert "/world/trajectory" in recording and "/world" in recording


def test_the_camera_pose_and_pinhole_are_the_manifests(recording, rows):
    poses = recording["/world/camera"]
    for row, (_, t), (_, m) in zip(rows, poses["Transform3D:translation"], poses["Transform3D:mat3x3"]):
        T = as_matrix(row["cam_to_world"], 4)
        np.testing.assert_allclose(t[0], T[:3, 3], rtol=1e-6)
        np.testing.assert_allclose(np.reshape(m[0], (3, 3)).T, T[:3, :3], atol=1e-6)  # rerun's mat3x3: columns
    pinholes = recording["/world/camera/image"]["Pinhole:image_from_camera"]
    for row, (_, k) in zip(rows, pinholes):
        np.testing.assert_allclose(np.reshape(k[0], (3, 3)).T, as_matrix(row["K"], 3), rtol=1e-6)


def test_labels_depth_points_boxes_and_series(recording, rows, root):
    from domains.catalog import LABELS
    from outputs.encoding import decode_depth_raw
    from outputs.objects import read_objects
    from outputs.table import read_output

    context = recording["/world"]["AnnotationContext:context"][0][1][0]
    got = [(c["class_id"], c["class_description"]["info"]["label"], c["class_description"]["info"]["color"])
           for c in context]
    rgba = [(r << 24) | (g << 16) | (b << 8) | 255 for r, g, b in (label.color for label in LABELS)]
    assert got == [(label.id, label.name, colour) for label, colour in zip(LABELS, rgba)]
    for i, row in enumerate(rows):
        labels = read_output("semantic_raw", (root / row["semantic_raw_path"]).read_bytes())[..., 0]
        got = recording["/world/camera/image/semantic"]["SegmentationImage:buffer"][i][1][0]
        assert bytes(got) == labels.tobytes()
        depth = decode_depth_raw(read_output("depth_raw", (root / row["depth_raw_path"]).read_bytes()))
        points = np.array(recording["/world/depth"]["Points3D:positions"][i][1])
        np.testing.assert_allclose(points, depth_to_world(depth, row["K"], row["cam_to_world"]), rtol=1e-5, atol=1e-3)
        objects = read_objects((root / row["objects_path"]).read_bytes())
        centers = np.array(recording["/world/camera/boxes"]["Boxes3D:centers"][i][1]).reshape(-1, 3)
        assert len(centers) == objects.num_rows
        np.testing.assert_allclose(centers[:, 2], objects.column("cz").to_numpy(), rtol=1e-6)
        for column in ("sun_altitude_deg", "cloudiness", "ego_speed_mps"):
            frame, value = recording[f"/conditions/{column}"]["Scalars:scalars"][i]
            assert frame == row["frame"] and value[0] == pytest.approx(row[column], rel=1e-6)


def test_box_rotation_matches_the_objects_corners():
    from analysis.viewer import box_rotation
    from outputs.objects import box_corners

    for yaw in (0.0, 0.7, -np.pi / 2, 3.0):
        R = box_rotation(yaw)
        assert np.linalg.det(R) == pytest.approx(1.0)
        size = np.array([4.0, 2.0, 1.5])
        signs = np.array([[a, b, d] for a in (-1, 1) for b in (-1, 1) for d in (-1, 1)], float)
        np.testing.assert_allclose((signs * size / 2) @ R.T, box_corners((0, 0, 0), size, yaw), atol=1e-12)


def test_view_errors_are_one_line(root, tmp_path):
    runner = CliRunner()
    for args, message in (
        ([str(root), "--scenario", SCENARIO, "--episode", "7", "--out", str(tmp_path / "a.rrd")], "no episode 7"),
        ([str(root), "--scenario", SCENARIO, "--episode", "0"], "--out FILE.rrd, --spawn"),
        ([str(root), "--scenario", SCENARIO, "--episode", "0", "--out", str(tmp_path / "a.txt")], ".rrd"),
        ([str(tmp_path / "nowhere"), "--scenario", SCENARIO, "--episode", "0", "--out", str(tmp_path / "a.rrd")],
         "is not an output root"),
    ):
        result = runner.invoke(cli_app(), ["view", *args])
        assert result.exit_code == 2 and message in result.output and result.output.count("\n") == 1, result.output
    assert not list(tmp_path.glob("*.rrd"))


def test_without_rerun_it_names_the_install_line(root, tmp_path, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "rerun", None)  # as if rerun-sdk were not installed
    result = CliRunner().invoke(cli_app(), ["view", str(root), "--scenario", SCENARIO, "--episode", "0",
                                            "--out", str(tmp_path / "a.rrd")])
    assert result.exit_code == 2 and result.output.count("\n") == 1
    assert "pip install -e '.[view]'" in result.output


def test_a_picture_of_a_frame_is_drawn_from_the_recording(root, rows, tmp_path):
    """``--picture`` draws the chosen frame of the recording it wrote (read back through rerun's reader)."""
    import cv2

    from analysis.view_picture import frames_of, picture_png, read_recording

    runner, app = CliRunner(), cli_app()
    out, picture = tmp_path / "ep.rrd", tmp_path / "ep.png"
    args = ["view", str(root), "--scenario", SCENARIO, "--episode", "0", "--out", str(out)]
    done = runner.invoke(app, [*args, "--picture", str(picture), "--frame", str(rows[-1]["frame"])])
    assert done.exit_code == 0, done.output
    image = cv2.imread(str(picture))
    assert image is not None and image.shape[0] > 400 and image.std() > 10
    recording = read_recording(str(out))
    assert frames_of(recording) == [r["frame"] for r in rows]
    assert picture.read_bytes() == picture_png(recording, rows[-1]["frame"])  # drawn from the recording, same bytes
    assert picture_png(recording, rows[0]["frame"]) != picture.read_bytes()  # another frame, another picture
    bad = runner.invoke(app, [*args, "--picture", str(picture), "--frame", "99"])
    assert bad.exit_code == 2 and "frame 99 is not in the recording" in bad.output
    without = runner.invoke(app, ["view", str(root), "--scenario", SCENARIO, "--episode", "0", "--spawn",
                                  "--picture", str(tmp_path / "x.png")])
    assert without.exit_code == 2 and "give --out" in without.output
