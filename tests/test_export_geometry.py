"""Calibration in the exports: HF rows carry K and cam_to_world.

One small rendered root (one scenario, 3 frames, 64x36, world "test") is shared by the module.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from exports import export as ex
from manifests.reader import read_manifest

DOMAINS = "T01_CS_A"
FRAMES = 3


@pytest.fixture(scope="module")
def root(tmp_path_factory) -> Path:
    from pipeline.planner import PlanConfig
    from pipeline.runmeta import RunConfig
    from tests.roots import render_root

    path = tmp_path_factory.mktemp("geometry_exports") / "run"
    config = RunConfig(PlanConfig(domains=DOMAINS, frames_per_scenario=FRAMES, width=64, height=36, seed=5), world="test")
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
