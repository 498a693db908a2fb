"""`idda shifts`: the mIoU by hand, the held-out rule, and a tiny end-to-end run of the command."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from typer.testing import CliRunner

from domains.catalog import EVALUATED_IDS, LABELS, class_id
from tests.test_export import cli_app
from analysis.metrics import EVAL_CLASSES, IGNORE, NUM_EVAL, TRAIN_INDEX_LUT, class_iou, confusion, mean_iou
from analysis.shift_table import CASES, ShiftConfig, held_out_mask

SHIFT_DOMAINS = "T01_CS_A,T01_CS_J,T01_HRN_J,T01_HRN_A,T07_HRN_A"


# ------------------------------------------------------------ mIoU ----------
def test_evaluated_classes_map_to_sixteen_training_indices():
    assert NUM_EVAL == 16 == len(EVAL_CLASSES)
    assert [TRAIN_INDEX_LUT[i] for i in EVALUATED_IDS] == list(range(16))
    for label in LABELS:
        if not label.evaluated:
            assert TRAIN_INDEX_LUT[label.id] == IGNORE, label.name
    assert TRAIN_INDEX_LUT[class_id("road")] == EVAL_CLASSES.index("road")


def test_miou_by_hand():
    gt = np.array([[0, 0, 1, 1]])
    pred = np.array([[0, 1, 1, 1]])
    # class 0: 1 hit, union 2 -> 1/2; class 1: 2 hits, union 3 -> 2/3
    assert confusion(gt, pred, 3).tolist() == [[1, 1, 0], [0, 2, 0], [0, 0, 0]]
    assert mean_iou(confusion(gt, pred, 3)) == pytest.approx((1 / 2 + 2 / 3) / 2)
    assert mean_iou(confusion(gt, gt, 3)) == 1.0


def test_miou_counts_only_classes_in_the_ground_truth():
    gt = np.array([0, 0, 0, 0, 1, 1])
    pred = np.array([0, 0, 2, 2, 1, 2])
    # class 2 is absent from the ground truth: no IoU of its own, but its false
    # positives cost classes 0 (2/4) and 1 (1/2).
    iou = class_iou(confusion(gt, pred, 3))
    assert iou[:2].tolist() == [0.5, 0.5] and np.isnan(iou[2])
    assert mean_iou(confusion(gt, pred, 3)) == 0.5


def test_miou_skips_ignored_pixels_and_all_wrong_is_zero():
    gt = np.array([0, 1, IGNORE, IGNORE])
    pred = np.array([1, 0, 0, 1])
    assert confusion(gt, pred, 2).sum() == 2
    assert mean_iou(confusion(gt, pred, 2)) == 0.0
    with pytest.raises(ValueError, match="no scored pixels"):
        mean_iou(confusion(np.full(4, IGNORE), pred, 2))
    with pytest.raises(ValueError, match="differ in size"):
        confusion(gt, pred[:3], 2)
    with pytest.raises(ValueError, match="class indices"):
        confusion(gt, np.array([0, 5, 0, 0]), 2)


# ------------------------------------------------------------ held out ------
def test_held_out_frames_by_split_when_there_are_held_out_episodes():
    episodes = np.array([0, 0, 1, 1, 2])
    splits = np.array(["train", "train", "val", "val", "test"])
    mask, rule = held_out_mask(episodes, np.array([0, 1, 0, 1, 0]), splits)
    assert rule == "split" and mask.tolist() == [False, False, True, True, True]


def test_held_out_frames_are_each_episodes_last_fifth_otherwise():
    episodes = np.repeat([0, 1], [10, 5])
    frames = np.concatenate([np.arange(10)[::-1], np.arange(5)])  # order in the table does not matter
    mask, rule = held_out_mask(episodes, frames, np.array(["train"] * 15))
    assert rule == "tail"
    assert sorted(frames[:10][mask[:10]]) == [8, 9] and frames[10:][mask[10:]].tolist() == [4]
    with pytest.raises(ValueError, match="at least 2 frames"):
        held_out_mask(np.array([0]), np.array([0]), np.array(["train"]))


def test_config_is_checked_and_cases_come_from_the_paper():
    assert [(c.name, c.pair.source, c.pair.target) for c in CASES] == [
        ("viewpoint", "T01_CS_A", "T01_CS_J"), ("weather", "T01_CS_J", "T01_HRN_J"), ("city", "T01_HRN_A", "T07_HRN_A")]
    assert [round(c.paper_kept, 2) for c in CASES] == [0.79, 0.51, 0.28]
    from analysis.segnet import STRIDE
    from analysis.shift_table import INPUT_MULTIPLE

    assert INPUT_MULTIPLE == STRIDE
    assert ShiftConfig(root="x", cases=("city",)).domains == ["T01_HRN_A", "T07_HRN_A"]
    for bad, match in ((dict(cases=("season",)), "valid cases: viewpoint, weather, city"),
                       (dict(width=100), "multiple of 16"), (dict(device="tpu"), "valid devices"),
                       (dict(steps=0), "steps must be at least 1")):
        with pytest.raises(ValueError, match=match):
            ShiftConfig(root="x", **bad).validate()


def test_pipeline_and_renderers_never_import_torch():
    code = ("import sys, pipeline.cli, pipeline.driver, render_workers.render.episode, analysis.loaders, analysis.metrics; "
            "sys.exit(1 if 'torch' in sys.modules else 0)")
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0


# ------------------------------------------------------------ end to end ----
@pytest.fixture(scope="module")
def shift_root(tmp_path_factory):
    """The paper's five domains, 10 frames each (one episode) at 64x36, test world."""
    from pipeline.settings import PlanConfig, RunConfig
    from tests.roots import render_root

    root = tmp_path_factory.mktemp("shifts") / "root"
    config = RunConfig(plan=PlanConfig(domains=SHIFT_DOMAINS, frames_per_scenario=10, width=64, height=36, seed=1),
                       world="test")
    render_root(root, config)
    return root


TINY = ["--steps", "60", "--batch-size", "4", "--width", "64", "--height", "32", "--threads", "1"]


def test_shifts_command_on_a_tiny_run(shift_root, tmp_path):
    out = tmp_path / "shifts.json"
    result = CliRunner().invoke(cli_app(), ["shifts", str(shift_root), *TINY, "--json", str(out)])
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    assert lines[0].split() == ["case", "source", "target", "source", "mIoU", "target", "mIoU", "kept",
                                "target*", "mIoU", "oracle", "mIoU", "kept*", "paper", "kept"]
    rows = [line.split() for line in lines[2:5]]
    assert [r[:3] for r in rows] == [[c.name, c.pair.source, c.pair.target] for c in CASES]
    assert [r[9] for r in rows] == ["0.79", "0.51", "0.28"]
    assert lines[-3].startswith("kept: ") and lines[-2].startswith("kept*: ")
    assert "(paper: viewpoint > weather > city)" in lines[-2]

    report = json.loads(out.read_text())
    assert report["device"] == "cpu" and 300_000 < report["parameters"] < 700_000
    for r in report["results"]:
        for key in ("source_miou", "target_miou", "constant_miou"):
            assert 0.0 <= r[key] <= 1.0, (r["case"], key)
        assert r["kept"] == pytest.approx(r["target_miou"] / r["source_miou"])
        assert r["oracle_kept"] == pytest.approx(r["target_held_out_miou"] / r["oracle_miou"])
        assert r["source_miou"] > 2 * r["constant_miou"], r  # it learned something on the source
        assert (r["train_frames"], r["held_out_frames"], r["target_frames"], r["target_held_out_frames"]) == (8, 2, 10, 2)
        assert r["held_out_rule"] == "tail"
        assert set(r["source_iou"]) == set(EVAL_CLASSES)
    assert [f"{r['source_miou']:.3f}" for r in report["results"]] == [r[3] for r in rows]
    # one network per domain: the weather case's source network is the viewpoint case's oracle
    viewpoint, weather = report["results"][:2]
    assert viewpoint["oracle_miou"] == weather["source_miou"]

    # Deterministic: the same config gives the same numbers.
    again = CliRunner().invoke(cli_app(), ["shifts", str(shift_root), *TINY, "--cases", "city",
                                           "--json", str(tmp_path / "again.json")])
    assert again.exit_code == 0, again.output
    city = json.loads((tmp_path / "again.json").read_text())["results"][0]
    assert city["source_miou"] == report["results"][2]["source_miou"]
    assert city["target_miou"] == report["results"][2]["target_miou"]


def test_shifts_command_errors_are_one_line(shift_root, tmp_path, monkeypatch):
    from analysis.loaders import FrameDataset  # noqa: F401  (imported before torch is hidden)

    missing = CliRunner().invoke(cli_app(), ["shifts", str(tmp_path), "--json", str(tmp_path / "x.json")])
    assert missing.exit_code == 2
    assert missing.output.startswith("error: ") and len(missing.output.strip().splitlines()) == 1
    assert f"{tmp_path} is not an output root" in missing.output  # the sentence every command gives

    bad = CliRunner().invoke(cli_app(), ["shifts", str(shift_root), "--cases", "season"])
    assert bad.exit_code == 2 and "unknown case 'season'" in bad.output

    monkeypatch.setitem(sys.modules, "torch", None)  # as if torch were not installed
    no_torch = CliRunner().invoke(cli_app(), ["shifts", str(shift_root), "--json", str(tmp_path / "y.json")])
    assert no_torch.exit_code == 2
    assert no_torch.output.strip() == "error: idda shifts needs PyTorch: pip install -e '.[analysis]'"
