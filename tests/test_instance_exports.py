"""Instance exports of the shared tiny root: Cityscapes instanceIds scored by
cityscapesScripts' own instance evaluation, and COCO read back by pycocotools."""

from __future__ import annotations

import glob
import json
import os

import numpy as np
import pytest
from PIL import Image

from domains.catalog import INSTANCE_LABELS
from outputs.table import read_output
from manifests.reader import read_manifest
from tests.test_export import make_tiny_root
from exports import cityscapes as cs_layout
from exports import export as ex


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    return make_tiny_root(tmp_path_factory)


@pytest.fixture(scope="module")
def cityscapes(root, tmp_path_factory):
    target = tmp_path_factory.mktemp("csi") / "export"
    ex.export(ex.ExportConfig(root=str(root), to=str(target), format="cityscapes", as_split="val"))
    return target


def test_instance_ids_follow_cityscapes(cityscapes):
    files = sorted(glob.glob(str(cityscapes / "gtFine/val/*/*_gtFine_instanceIds.png")))
    objects = 0
    for path in files:
        ids = np.array(Image.open(path)).astype(np.int64)
        labels = np.array(Image.open(path.replace("instanceIds", "labelIds"))).astype(np.int64)
        assert Image.open(path).mode.startswith("I")  # 16 bit
        inst = ids >= 1000
        assert (ids[inst] // 1000 == labels[inst]).all() and (ids[~inst] == labels[~inst]).all()
        assert set(np.unique(labels[inst])) <= set(cs_layout.CITYSCAPES_INSTANCE_IDS)
        for cs_id in np.unique(labels[inst]):
            indices = np.unique(ids[inst & (labels == cs_id)] % 1000)
            assert list(indices) == list(range(len(indices)))  # 0, 1, ... per class and frame
        objects += len(np.unique(ids[inst]))
    assert objects >= 5


def test_cityscapes_instance_evaluation_of_ground_truth_gives_ap_1(cityscapes, tmp_path):
    from analysis.evaluate import evaluate_instances

    predictions = tmp_path / "pred"
    predictions.mkdir()
    for path in sorted(glob.glob(str(cityscapes / "gtFine/val/*/*_gtFine_instanceIds.png"))):
        stem = os.path.basename(path).replace("_gtFine_instanceIds.png", "")
        ids = np.array(Image.open(path)).astype(np.int64)
        lines = []
        for k, iid in enumerate(i for i in np.unique(ids) if i >= 1000):
            mask = f"{stem}_{k}.png"
            Image.fromarray(((ids == iid) * 255).astype(np.uint8)).save(predictions / mask)
            lines.append(f"{mask} {iid // 1000} 1.0\n")
        (predictions / f"{stem}_pred.txt").write_text("".join(lines))
    averages = evaluate_instances(str(cityscapes), str(predictions), "val", min_region_px=1)
    assert averages["allAp"] == pytest.approx(1.0) and averages["allAp50%"] == pytest.approx(1.0)
    scored = [c["ap"] for c in averages["classes"].values() if not np.isnan(c["ap"])]
    assert scored and all(ap == pytest.approx(1.0) for ap in scored)


def test_coco_export_loads_in_pycocotools_and_masks_round_trip(root, tmp_path):
    from pycocotools.coco import COCO

    target = tmp_path / "coco"
    report = ex.export(ex.ExportConfig(root=str(root), to=str(target), format="coco"))
    manifest = read_manifest(str(root))
    by_frame = {(r["scenario"], r["frame_id"]): r for r in manifest.to_pylist()}
    total = 0
    for ann_file in sorted(glob.glob(str(target / "annotations/instances_*.json"))):
        coco = COCO(ann_file)
        assert {c["name"] for c in coco.loadCats(coco.getCatIds())} == {label.name for label in INSTANCE_LABELS}
        for image in coco.loadImgs(coco.getImgIds()):
            assert os.path.isfile(target / "images" / image["file_name"])
            row = by_frame[(image["scenario"], image["idda_frame_id"])]
            assert image["idda_uid"] == row["uid"] and image["file_name"].endswith(row["uid"] + ".png")
            assert image["K"] == row["K"] and image["cam_to_world"] == row["cam_to_world"]  # docs/conventions.md
            instance = read_output("instance", (root / row["instance_path"]).read_bytes())
            anns = coco.loadAnns(coco.getAnnIds(imgIds=image["id"]))
            assert len(anns) == sum(row[label.object_column] for label in INSTANCE_LABELS)
            for ann in anns:
                mask = coco.annToMask(ann)
                assert (mask.astype(bool) == (instance == ann["instance_id"])).all()
                ys, xs = np.nonzero(mask)
                assert ann["bbox"] == [xs.min(), ys.min(), xs.max() + 1 - xs.min(), ys.max() + 1 - ys.min()]
                assert ann["area"] == mask.sum()
            total += len(anns)
    assert total >= 5 and report.frames == len(manifest)
    marker = json.loads((target / "EXPORT.json").read_text())
    assert marker["format"] == "coco"


def test_frame_dataset_returns_instance_and_objects(root):
    from analysis.loaders import FrameDataset

    data = FrameDataset(root, outputs=("semantic_raw", "instance", "objects"))
    sample = data[0]
    instance, objects = sample["instance"], sample["objects"]
    assert instance.dtype == np.uint16 and instance.shape == sample["semantic"].shape
    assert set(objects) >= {"instance_id", "class_id", "x0", "cz", "yaw"}
    assert sorted(objects["instance_id"]) == sorted(i for i in np.unique(instance) if i > 1)
