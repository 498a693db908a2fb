"""--outputs: a root holds any subset of the output table; commands work on what
it holds and name what it lacks; object counts in the manifest."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from domains.catalog import INSTANCE_LABELS
from outputs.table import OUTPUTS, read_output
from manifests.reader import read_manifest
from manifests.schema import output_columns
from roots.verify import verify
from tests.test_export import make_tiny_root

runner = CliRunner()
SUBSET = ("rgb", "semantic_raw")
DOMAINS = "T01_CN_A"


def cli_app():
    from pipeline.cli import data as cli_data
    from pipeline.cli import app

    cli_data.register(app)
    return app


def one_line_error(result) -> str:
    lines = result.output.strip().splitlines()
    assert result.exit_code == 2, result.output
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in result.output, result.output
    return lines[0]


def plan_config(outputs):
    from pipeline.settings import PlanConfig

    return PlanConfig(domains=DOMAINS, frames_per_scenario=2, width=64, height=36, seed=4, outputs=outputs)


@pytest.fixture(scope="module")
def subset_root(tmp_path_factory):
    """A root produced with --outputs rgb,semantic_raw (test world, 64x36, 2 frames)."""
    from pipeline.planner import make_plan
    from pipeline.settings import RunConfig
    from tests.roots import render_root

    root = tmp_path_factory.mktemp("subset") / "root"
    config = RunConfig(plan=plan_config(SUBSET), world="test")
    for spec in make_plan(config.plan).episodes:
        assert spec.outputs == SUBSET
    render_root(root, config)
    return root


def test_a_subset_root_holds_only_its_outputs(subset_root):
    table = read_manifest(str(subset_root))
    assert len(table) == 2
    for name in OUTPUTS:
        paths = table.column(output_columns(name)[0]).to_pylist()
        if name in SUBSET:
            assert all(p and (subset_root / p).is_file() for p in paths)
        else:
            assert paths == [None, None] and not (subset_root / DOMAINS / name).exists()
    assert json.loads((subset_root / "run.json").read_text())["config"]["outputs"] == list(SUBSET)
    report = verify(str(subset_root))
    assert report.ok and report.files_checked == 2 * len(SUBSET)
    # object counts come from the instance pass whatever the outputs
    assert all(v is not None for label in INSTANCE_LABELS for v in table.column(label.object_column).to_pylist())


def test_missing_outputs_are_named_in_one_line(subset_root, tmp_path):
    from analysis.loaders import FrameDataset

    app = cli_app()
    line = one_line_error(runner.invoke(app, ["export", str(subset_root), "--format", "coco", "--to", str(tmp_path / "c")]))
    assert "'instance' output" in line and "rgb, semantic_raw" in line
    line = one_line_error(runner.invoke(app, ["query", str(subset_root), "--outputs", "depth_raw", "--out", str(tmp_path / "l.txt")]))
    assert "'depth_raw' output" in line
    result = runner.invoke(app, ["query", str(subset_root), "--out", str(tmp_path / "l.txt")])  # rgb, semantic_raw: held
    assert result.exit_code == 0 and len((tmp_path / "l.txt").read_text().splitlines()) == 2
    with pytest.raises(ValueError, match="does not hold the 'instance' output"):
        FrameDataset(subset_root, outputs=("instance",))
    result = runner.invoke(app, ["export", str(subset_root), "--format", "cityscapes", "--to", str(tmp_path / "cs")])
    assert result.exit_code == 0, result.output  # label ids only: the root has no instance output


def test_resume_with_other_outputs_is_refused(subset_root):
    app = cli_app()
    args = ["produce", "--out", str(subset_root), "--domains", DOMAINS, "--frames-per-scenario", "2",
            "--width", "64", "--height", "36", "--seed", "4", "--world", "test"]
    line = one_line_error(runner.invoke(app, args))  # the default: all eight outputs
    assert "holds the outputs rgb,semantic_raw" in line and "--outputs rgb,semantic_raw" in line
    line = one_line_error(runner.invoke(app, args + ["--extend"]))  # --extend does not mix outputs either
    assert "holds the outputs rgb,semantic_raw" in line
    line = one_line_error(runner.invoke(app, args + ["--outputs", "rgb,lidar"]))
    assert "unknown output 'lidar'" in line
    line = one_line_error(runner.invoke(app, args + ["--outputs", "rgb,semantic_raw", "--frame-interval", "0.1"]))
    assert "frame_interval_s 3.0 -> 0.1" in line and "use a new --out" in line  # frames would not match
    line = one_line_error(runner.invoke(app, args + ["--outputs", "rgb,semantic_raw", "--frame-interval", "0"]))
    assert "frame interval must be in (0, 60]" in line
    assert json.loads((subset_root / "run.json").read_text())["config"]["frame_interval_s"] == 3.0
    result = runner.invoke(app, args + ["--outputs", "semantic_raw,rgb"])  # the same set: resumes (nothing left to do)
    assert result.exit_code == 0, result.output


def test_manifest_object_counts_sum_the_objects_sidecars(tmp_path_factory):
    root = make_tiny_root(tmp_path_factory)
    table = read_manifest(str(root))
    total = 0
    for row in table.to_pylist():
        objects = read_output("objects", (root / row["objects_path"]).read_bytes())
        classes = objects.column("class_id").to_pylist()
        for label in INSTANCE_LABELS:
            assert row[label.object_column] == classes.count(label.id)
        instance = read_output("instance", (root / row["instance_path"]).read_bytes())
        assert sorted(objects.column("instance_id").to_pylist()) == [i for i in np.unique(instance) if i > 1]
        total += len(classes)
    assert total >= 5


OPT_IN = ("semantic_raw", "semantic_trainid", "normals", "flow")


def test_an_opt_in_output_follows_through_verify_query_and_loaders(tmp_path):
    """semantic_trainid is not a default output; asked for, it is written, verified, listed and loaded."""
    from analysis.loaders import FrameDataset
    from domains.catalog import TRAIN_ID_LUT
    from outputs.table import DEFAULT_OUTPUTS
    from pipeline.settings import RunConfig
    from tests.roots import render_root

    assert "semantic_trainid" not in DEFAULT_OUTPUTS
    root = tmp_path / "root"
    render_root(root, RunConfig(plan=plan_config(OPT_IN), world="test"))
    report = verify(str(root))
    assert report.ok and report.files_checked == 2 * len(OPT_IN)
    result = runner.invoke(cli_app(), ["query", str(root), "--outputs", "semantic_trainid", "--out", str(tmp_path / "l.txt")])
    assert result.exit_code == 0, result.output
    assert all("/semantic_trainid/" in line for line in (tmp_path / "l.txt").read_text().splitlines())
    data = FrameDataset(root, outputs=OPT_IN)
    for i in range(len(data)):
        sample = data[i]
        assert sample["semantic_trainid"].dtype == np.uint8 and sample["semantic_trainid"].shape == (36, 64)
        assert np.array_equal(sample["semantic_trainid"], TRAIN_ID_LUT[sample["semantic"]])
        assert sample["normals"].dtype == np.float32 and sample["normals"].shape == (36, 64, 3)
        assert sample["flow"].shape == (36, 64, 3) and sample["flow"][..., 2].any() == (i % 2 == 0)  # none after the last
