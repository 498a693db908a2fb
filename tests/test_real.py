"""Synthetic to real (issue 25, item 4): `idda distances` and `idda shifts` with a real folder in
Cityscapes layout, here a Cityscapes export of another small root standing in for real data."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from analysis.metrics import EVAL_CLASSES, IGNORE, TRAIN_INDEX_LUT
from analysis.real import CITYSCAPES_TO_INDEX, OTHER_VEHICLES, REAL, RealFolder
from analysis.shift_table import load_real
from domains.catalog import LABELS, class_id
from tests.test_export import cli_app, make_tiny_root

STANDIN = "T07_HRN_A,T01_CN_A"  # the stand-in "real" root's domains: 3 frames each


def export(root, to, *options) -> None:
    result = CliRunner().invoke(cli_app(), ["export", str(root), "--format", "cityscapes", "--to", str(to),
                                            "--as-split", "val", *options])
    assert result.exit_code == 0, result.output


@pytest.fixture(scope="module")
def standin(tmp_path_factory):
    """(another root, its Cityscapes export): two domains, 3 frames each, 64x36, test world."""
    from pipeline.settings import PlanConfig, RunConfig
    from tests.roots import render_root

    base = tmp_path_factory.mktemp("real")
    config = RunConfig(plan=PlanConfig(domains=STANDIN, frames_per_scenario=3, width=64, height=36, seed=5),
                       world="test")
    render_root(base / "root", config)
    export(base / "root", base / "cityscapes")
    return base / "root", base / "cityscapes"


def test_cityscapes_classes_map_to_our_sixteen():
    for label in LABELS:
        if label.evaluated:
            assert CITYSCAPES_TO_INDEX[label.cityscapes_id] == TRAIN_INDEX_LUT[label.id], label.name
    vehicle = EVAL_CLASSES.index("vehicle")
    assert [CITYSCAPES_TO_INDEX[i] for i in OTHER_VEHICLES] == [vehicle] * 3  # truck, bus, train
    assert CITYSCAPES_TO_INDEX[26] == vehicle  # car, from the catalog's table
    for ignored in (0, 1, 3, 4, 5, 6, 9, 10, 14, 15, 16, 18, 29, 30):  # void, ego vehicle, caravan, trailer...
        assert CITYSCAPES_TO_INDEX[ignored] == IGNORE, ignored
    assert int((CITYSCAPES_TO_INDEX != IGNORE).sum()) == 19  # Cityscapes' 19 evaluated classes


def test_not_cityscapes_layout_says_what_is_missing(tmp_path):
    def error(folder, labels=False, splits=("val",)):
        with pytest.raises(ValueError) as info:
            RealFolder(str(folder), splits).images(labels)
        return str(info.value)

    assert "does not exist" in error(tmp_path / "nope")
    assert error(tmp_path) == f"{tmp_path} is not in Cityscapes layout: it has no leftImg8bit/ " \
                              "(expected leftImg8bit/<split>/<city>/*_leftImg8bit.png)"
    (tmp_path / "leftImg8bit" / "train" / "aachen").mkdir(parents=True)
    assert error(tmp_path) == f"{tmp_path} has no leftImg8bit/val/ (splits there: train)"
    assert error(tmp_path, splits=("train",)) == f"{tmp_path} has no images leftImg8bit/train/<city>/*_leftImg8bit.png"
    from PIL import Image

    Image.new("RGB", (8, 4)).save(tmp_path / "leftImg8bit" / "train" / "aachen" / "aachen_000000_000019_leftImg8bit.png")
    assert len(RealFolder(str(tmp_path), ("train",)).images()) == 1  # images alone do for distances
    assert error(tmp_path, True, ("train",)).endswith("has no gtFine/: shifts score on "
                                                      "gtFine/<split>/<city>/*_gtFine_labelIds.png")
    (tmp_path / "gtFine").mkdir()
    assert error(tmp_path, True, ("train",)) == (
        f"{tmp_path}: 1 of 1 images have no label ids, e.g. gtFine/train/aachen/aachen_000000_000019_gtFine_labelIds.png")


def test_an_export_reads_back_as_the_frames_it_came_from(standin):
    from analysis.shift_table import load_domain

    root, folder = standin
    real = load_real(RealFolder(str(folder)), 64, 32)
    assert len(real) == 6 and real.splits.tolist() == ["val"] * 6
    assert real.episodes.tolist() == [0, 0, 0, 1, 1, 1] and real.frames.tolist() == [0, 1, 2] * 2  # cities T01-CN-A, T07-HRN-A
    ours = load_domain(root, "T01_CN_A", 64, 32)
    assert np.array_equal(real.images[:3], ours.images)  # the same pixels
    assert np.array_equal(real.labels[:3], ours.labels)  # our ids -> Cityscapes ids -> our training indices
    assert (ours.labels != IGNORE).any() and (ours.labels == EVAL_CLASSES.index("road")).any()
    assert len(load_real(RealFolder(str(folder)), 64, 32, max_frames=4)) == 4


def test_distances_with_a_real_folder(tmp_path_factory, standin, tmp_path):
    root = make_tiny_root(tmp_path_factory)
    app = cli_app()
    # every sampled domain against the real folder when no pair names it
    result = CliRunner().invoke(app, ["distances", str(root), "--samples", "2", "--real", str(standin[1]),
                                      "--chart", str(tmp_path / "chart.png")])
    assert result.exit_code == 0, result.output
    rows = [line.split() for line in result.output.splitlines() if line.startswith("-")][1:]
    assert [r[1:3] for r in rows] == [[code, REAL] for code in sorted(
        ["T01_CS_A", "T01_CS_J", "T01_HRN_A", "T01_HRN_J", "T07_HRN_A"])]
    assert all(float(r[3]) > 0 for r in rows)
    assert "6 domains, 2 frames each" in result.output
    # the real folder holding the root's own T07_HRN_A frames is at distance 0 from it
    same = tmp_path / "same"
    export(root, same, "--domains", "T07_HRN_A")
    result = CliRunner().invoke(app, ["distances", str(root), "--samples", "2", "--real", str(same),
                                      "--pairs", f"T07_HRN_A:{REAL},T01_CS_A:{REAL}"])
    assert result.exit_code == 0, result.output
    rows = {tuple(line.split()[1:3]): line.split() for line in result.output.splitlines() if line.startswith("- ")}
    assert float(rows["T07_HRN_A", REAL][3]) == 0.0 and float(rows["T07_HRN_A", REAL][7]) == 0.0
    assert float(rows["T01_CS_A", REAL][3]) > 0.0
    # not Cityscapes layout: one line, exit 2
    bad = CliRunner().invoke(app, ["distances", str(root), "--real", str(tmp_path)])
    assert bad.exit_code == 2 and bad.output.strip().splitlines() == [
        f"error: {tmp_path} is not in Cityscapes layout: it has no leftImg8bit/ "
        "(expected leftImg8bit/<split>/<city>/*_leftImg8bit.png)"]
    lonely = CliRunner().invoke(app, ["distances", str(root), "--pairs", f"T01_CS_A:{REAL}"])
    assert lonely.exit_code == 2 and "no real folder is given (--real FOLDER)" in lonely.output


TINY = ["--steps", "30", "--batch-size", "2", "--width", "64", "--height", "32", "--threads", "1"]


def test_shifts_train_on_a_domain_and_score_on_the_real_folder(tmp_path_factory, standin, tmp_path):
    root = make_tiny_root(tmp_path_factory)
    app = cli_app()
    out = tmp_path / "shifts.json"
    pairs = f"T01_CS_A:{REAL},{REAL}:T07_HRN_A"
    result = CliRunner().invoke(app, ["shifts", str(root), "--pairs", pairs, "--real", str(standin[1]), *TINY,
                                      "--json", str(out)])
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    assert [line.split()[:3] for line in lines[2:4]] == [["-", "T01_CS_A", REAL], ["-", REAL, "T07_HRN_A"]]
    assert [line.split()[9] for line in lines[2:4]] == ["-", "-"]  # no paper value for these pairs
    report = json.loads(out.read_text())
    to_real, from_real = report["results"]
    assert (to_real["target_frames"], to_real["target_held_out_frames"]) == (6, 2)  # the last of each city held out
    assert (from_real["train_frames"], from_real["held_out_frames"]) == (4, 2)
    for r in report["results"]:
        assert r["paper_kept"] is None and 0.0 <= r["target_miou"] <= 1.0 and 0.0 < r["source_miou"] <= 1.0
        assert r["kept"] == pytest.approx(r["target_miou"] / r["source_miou"])
    assert report["config"]["real"] == str(standin[1]) and report["config"]["real_splits"] == ["val"]
    # a domain's network does not depend on the other pairs: the same numbers alone
    alone = CliRunner().invoke(app, ["shifts", str(root), "--pairs", f"T01_CS_A:{REAL}", "--real", str(standin[1]),
                                     *TINY, "--json", str(tmp_path / "alone.json")])
    assert alone.exit_code == 0, alone.output
    again = json.loads((tmp_path / "alone.json").read_text())["results"][0]
    assert (again["source_miou"], again["target_miou"]) == (to_real["source_miou"], to_real["target_miou"])


def test_shifts_real_errors_are_one_line(tmp_path_factory, standin, tmp_path):
    root = make_tiny_root(tmp_path_factory)
    app = cli_app()
    images_only = tmp_path / "images_only"
    images_only.mkdir()
    (images_only / "leftImg8bit").symlink_to(standin[1] / "leftImg8bit")
    for args, expected in (
        (["--pairs", f"T01_CS_A:{REAL}", "--real", str(images_only)],
         f"error: {images_only} has no gtFine/: shifts score on gtFine/<split>/<city>/*_gtFine_labelIds.png"),
        (["--pairs", f"T01_CS_A:{REAL}", "--real", str(standin[1]), "--real-split", "train"],
         f"error: {standin[1]} has no leftImg8bit/train/ (splits there: val)"),
        (["--real", str(standin[1])],
         f"error: the real folder {standin[1]} is in no pair: name it in one, e.g. --pairs T01_CN_A:{REAL}"),
        (["--pairs", "T01_CS_A:T09_CN_A"], "error: unknown town 'T09'"),
    ):
        result = CliRunner().invoke(app, ["shifts", str(root), *args, *TINY, "--json", str(tmp_path / "x.json")])
        assert result.exit_code == 2, result.output
        assert len(result.output.strip().splitlines()) == 1 and result.output.startswith(expected), result.output


def test_vehicle_is_one_class_for_car_truck_bus_and_train():
    ids = np.array([[26, 27, 28, 31, 29, 7]], dtype=np.uint8)
    vehicle, road = EVAL_CLASSES.index("vehicle"), TRAIN_INDEX_LUT[class_id("road")]
    assert CITYSCAPES_TO_INDEX[ids].tolist() == [[vehicle] * 4 + [IGNORE, road]]
