"""Calibration in the exports: HF rows carry K and cam_to_world, the Cityscapes
export writes Cityscapes' camera JSON, and the bird's-eye picture of
docs/conventions.md is drawn from a rendered episode.

One small rendered root (one scenario, 3 frames, 64x36, world "test") is shared by the module.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from exports import cityscapes as cs_layout
from exports import export as ex
from outputs.geometry import project, unflat
from manifests.reader import read_manifest

DOMAINS = "T01_CS_A"
FRAMES = 3


@pytest.fixture(scope="module")
def root(tmp_path_factory) -> Path:
    from pipeline.settings import PlanConfig, RunConfig
    from tests.roots import render_root

    path = tmp_path_factory.mktemp("geometry_exports") / "run"
    plan = PlanConfig(domains=DOMAINS, frames_per_scenario=FRAMES, width=64, height=36, seed=5)
    config = RunConfig(plan, world="test")
    render_root(path, config)
    return path


@pytest.fixture(scope="module")
def rows(root) -> list[dict]:
    return read_manifest(str(root)).to_pylist()


def test_hf_rows_carry_k_and_cam_to_world(root, rows, tmp_path):
    ex.export(ex.ExportConfig(root=str(root), to=str(tmp_path / "hf"), format="hf"))
    table = pq.read_table(sorted((tmp_path / "hf" / "data").glob("*.parquet")))
    by_uid = {r["uid"]: r for r in rows}
    assert table.num_rows == len(rows)
    for sample in table.select(["uid", "K", "cam_to_world"]).to_pylist():
        row = by_uid[sample["uid"]]
        assert sample["K"] == row["K"] and len(sample["K"]) == 9
        assert sample["cam_to_world"] == row["cam_to_world"] and len(sample["cam_to_world"]) == 16
    features = json.loads(table.schema.metadata[b"huggingface"])["info"]["features"]
    assert features["K"] == {"feature": {"dtype": "float64", "_type": "Value"}, "_type": "List"}


def _rotation(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """Cityscapes' (csCalibration.pdf) camera-to-vehicle rotation Rz(yaw) Ry(pitch) Rx(roll)."""
    cy, sy, cp, sp = math.cos(yaw), math.sin(yaw), math.cos(pitch), math.sin(pitch)
    cr, sr = math.cos(roll), math.sin(roll)
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    return rz @ ry @ rx


def test_cityscapes_camera_json_per_image(root, rows, tmp_path):
    target = tmp_path / "cs"
    ex.export(ex.ExportConfig(root=str(root), to=str(target), format="cityscapes"))
    for row in rows:
        name = cs_layout.cityscapes_name(row["scenario"], row["episode"], row["frame"])
        city = cs_layout.cityscapes_city(row["scenario"])
        camera = json.loads((target / "camera" / row["split"] / city / f"{name}_camera.json").read_text())
        K, cam_to_ego = unflat(row["K"], 3), unflat(row["cam_to_ego"], 4)
        assert camera["intrinsic"] == {"fx": K[0, 0], "fy": K[1, 1], "u0": K[0, 2], "v0": K[1, 2]}
        ext = camera["extrinsic"]
        assert set(ext) == {"baseline", "pitch", "roll", "yaw", "x", "y", "z"} and ext["baseline"] == 0.0
        # Position: our ego frame has Cityscapes' vehicle axes (x forward, y left, z up).
        assert (ext["x"], ext["y"], ext["z"]) == tuple(cam_to_ego[:3, 3])
        assert ext["x"] > 0 and ext["z"] > 0.5
        # Angles: the vehicle-axes camera's rotation; its forward (x) axis is the optical axis (OpenCV z).
        R = _rotation(ext["yaw"], ext["pitch"], ext["roll"])
        assert np.allclose(R[:, 0], cam_to_ego[:3, 2]) and np.allclose(R[:, 1], -cam_to_ego[:3, 0])
        assert np.allclose(R[:, 2], -cam_to_ego[:3, 1])
        # csCalibration.pdf eq. (1), (6): a vehicle-frame point lands on the pixel our K and cam_to_ego give.
        p_vehicle = np.array([12.0, 1.5, 0.4])
        cs_K = np.array([[camera["intrinsic"]["fx"], 0, camera["intrinsic"]["u0"]],
                         [0, camera["intrinsic"]["fy"], camera["intrinsic"]["v0"]], [0, 0, 1]])
        uvw = cs_K @ cs_layout.CV_FROM_VEHICLE_AXES @ R.T @ (p_vehicle - [ext["x"], ext["y"], ext["z"]])
        p_cam = np.linalg.inv(cam_to_ego) @ np.append(p_vehicle, 1.0)
        assert np.allclose(uvw[:2] / uvw[2], project(p_cam[None, :3], K)[0])


def test_cityscapes_camera_angles_of_a_tilted_camera():
    """A camera yawed left by 0.3 rad and pitched down by 0.1 rad gives those angles back."""
    R_vehicle = _rotation(0.3, 0.1, -0.05)
    cam_to_ego = np.eye(4)
    cam_to_ego[:3, :3] = R_vehicle @ cs_layout.CV_FROM_VEHICLE_AXES.T
    cam_to_ego[:3, 3] = (1.5, 0.2, 1.3)
    ext = cs_layout.cityscapes_camera(np.eye(3), cam_to_ego)["extrinsic"]
    assert (ext["yaw"], ext["pitch"], ext["roll"]) == pytest.approx((0.3, 0.1, -0.05))
    assert (ext["x"], ext["y"], ext["z"]) == (1.5, 0.2, 1.3)
    # Pitch down: the optical axis points below the horizon (vehicle z < 0).
    assert (cam_to_ego[:3, :3] @ [0, 0, 1])[2] < 0


def test_a_level_camera_writes_no_negative_zero():
    """Issue 32: a level, straight-ahead camera's angles are 0.0 in the JSON, never -0.0."""
    import json

    cam_to_ego = np.eye(4)
    cam_to_ego[:3, :3] = cs_layout.CV_FROM_VEHICLE_AXES.T
    text = json.dumps(cs_layout.cityscapes_camera(np.eye(3), cam_to_ego))
    assert "-0.0" not in text and '"pitch": 0.0' in text and '"yaw": 0.0' in text


def test_conventions_bev_writes_a_png(tmp_path):
    """reports.conventions_bev: a tiny episode drawn from above (docs/images/conventions_bev.png at full size)."""
    from PIL import Image

    from reports import conventions_bev

    out = tmp_path / "images" / "bev.png"
    assert conventions_bev.write_bev(str(out), root=str(tmp_path / "root"), frames=2, width=64, height=36) == str(out)
    image = Image.open(out)
    assert image.format == "PNG" and image.size == (640, 640)
    rows, points, classes = conventions_bev.episode_points(str(tmp_path / "root"))
    assert [r["frame"] for r in rows] == [0, 1] and len(points) == len(classes) > 0
    # The cloud lies around the camera path, under the cameras (world z up).
    centres = np.array([[r["cam_to_world"][i] for i in (3, 7, 11)] for r in rows])
    assert np.median(points[:, 2]) < centres[:, 2].min()
    assert np.linalg.norm(points[:, :2] - centres[0, :2], axis=1).min() < 5.0
