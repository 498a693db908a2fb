"""Every client reads a real small run right: DuckDB, Polars, pandas and HF
datasets on the manifest; FedDrive, cityscapesScripts, a torchvision-style
Cityscapes loader and HF datasets on the exports.

One rendered root (3 scenarios x 4 frames, one episode each, 64x36) is shared
by the module. FedDrive and torchvision are not imported: FedDrive is a
research repository, not a package, and torchvision's PyPI wheel for
torch==2.13.0 links against CUDA torch (its ``_C.so`` needs
``libtorch_cuda.so``), so it cannot be imported next to the CPU torch the
project pins. Their readers are re-written here from their sources' facts.
"""

from __future__ import annotations

import glob
import json
import os
import shutil
from pathlib import Path

import numpy as np
import pyarrow.compute as pc
import pytest
from PIL import Image
from typer.testing import CliRunner

from exports import cityscapes as cs_layout
from exports import export as ex
from domains.catalog import EVALUATED_IDS
from manifests.reader import read_manifest

os.environ.setdefault("HF_HUB_OFFLINE", "1")  # no hub access here; everything is local
os.environ.setdefault("HF_DATASETS_OFFLINE", "1")

DOMAINS = "T01_CN_A,T01_HRN_J,T07_CS_B"
FRAMES = 4
WIDTH, HEIGHT = 64, 36


@pytest.fixture(scope="module")
def root(tmp_path_factory) -> Path:
    """A real small run: episodes rendered by the worker function, then compacted as produce does."""
    from pipeline.settings import PlanConfig, RunConfig
    from tests.roots import render_root

    path = tmp_path_factory.mktemp("clients") / "run"
    config = RunConfig(PlanConfig(domains=DOMAINS, frames_per_scenario=FRAMES, width=WIDTH, height=HEIGHT, seed=7), world="test")
    render_root(path, config, compact=True)
    return path


@pytest.fixture(scope="module")
def manifest(root):
    return read_manifest(str(root))


def app():
    from pipeline.cli import app as the_app

    return the_app


# ------------------------------------------------------------- manifests ----
def test_every_reader_counts_one_row_per_frame_and_agrees(root, manifest, tmp_path):
    """The one-line reads documented in the README, and one query in each."""
    import duckdb
    import pandas as pd
    import polars as pl
    from datasets import load_dataset

    glob_path = f"{root}/manifest/**/*.parquet"
    n = len(manifest)
    assert n == 3 * FRAMES
    # Reference: vehicle pixels of the HRN frames per scenario, from the project's reader.
    hrn = manifest.filter(pc.equal(manifest.column("scenario"), "T01_HRN_J"))
    want = (len(hrn), int(pc.sum(hrn.column("px_vehicle")).as_py()))

    con = duckdb.connect()
    rel = f"read_parquet('{glob_path}', hive_partitioning=true)"
    assert con.execute(f"select count(*) from {rel}").fetchall()[0][0] == n
    got = con.execute(f"select count(*), sum(px_vehicle) from {rel} where weather = 'HRN'").fetchall()[0]
    assert tuple(int(v) for v in got) == want

    frame = pl.scan_parquet(glob_path, hive_partitioning=True)
    assert frame.select(pl.len()).collect().item() == n
    got = frame.filter(pl.col("weather") == "HRN").select(pl.len(), pl.col("px_vehicle").sum()).collect().row(0)
    assert tuple(int(v) for v in got) == want

    df = pd.read_parquet(f"{root}/manifest")  # pyarrow engine, hive partitions as columns
    assert len(df) == n
    hrn_df = df[df["weather"] == "HRN"]
    assert (len(hrn_df), int(hrn_df["px_vehicle"].sum())) == want

    hf = load_dataset("parquet", data_files=glob_path, split="train", cache_dir=str(tmp_path / "hf"))
    assert hf.num_rows == n
    hrn_hf = hf.filter(lambda row: row["scenario"] == "T01_HRN_J")
    assert (hrn_hf.num_rows, sum(hrn_hf["px_vehicle"])) == want


def test_calibration_columns_are_arrays_of_known_shape(root, manifest, tmp_path):
    """Issue 32: K and the poses are fixed_size_list<double>[9] and [16] where the Arrow schema is known:
    the project's reader (DuckDB and Polars over its table: DOUBLE[9], Array(Float64, (9,))) and the
    indexes, which store it. Parts keep Parquet's plain lists (bytes as before; DuckDB and Polars over
    the parts see lists of 9 and 16 and cast them as docs/querying.md shows), and an index written
    with plain lists (a root from before) still reads as arrays and verifies."""
    import duckdb
    import polars as pl
    import pyarrow as pa
    import pyarrow.parquet as pq

    from manifests.reader import index_bytes
    from manifests.schema import INDEX_DIR, MANIFEST_SCHEMA, as_plain_lists

    shapes = {"K": 9, "cam_to_world": 16, "ego_to_world": 16, "cam_to_ego": 16}
    for name, size in shapes.items():
        assert manifest.schema.field(name).type == pa.list_(pa.float64(), size) == MANIFEST_SCHEMA.field(name).type
    assert np.asarray(manifest.column("K").combine_chunks().flatten()).reshape(-1, 3, 3).shape == (len(manifest), 3, 3)
    con = duckdb.connect()
    types = dict(con.execute("select column_name, column_type from (describe select K, cam_to_world from manifest)")
                 .fetchall())
    assert types == {"K": "DOUBLE[9]", "cam_to_world": "DOUBLE[16]"}
    frame = pl.from_arrow(manifest)
    assert frame.schema["K"] == pl.Array(pl.Float64, 9) and frame["cam_to_ego"].to_numpy().shape == (len(manifest), 16)
    indexes = sorted(glob.glob(f"{root}/{INDEX_DIR}/*.parquet"))
    assert pl.read_parquet(indexes).schema["ego_to_world"] == pl.Array(pl.Float64, 16)
    parts = f"{root}/manifest/**/*.parquet"
    cast = con.execute(f"select K::DOUBLE[9] as K from read_parquet('{parts}') limit 1").fetchall()[0][0]
    assert list(cast) == manifest.column("K")[0].as_py()  # K is the same in every frame at one resolution
    listed = pl.scan_parquet(parts).select(pl.col("K").list.to_array(9)).collect()
    assert listed.schema["K"] == pl.Array(pl.Float64, 9) and len(listed) == len(manifest)
    # an index as roots made before wrote it: plain lists in its stored schema
    copy = tmp_path / "old-index"
    shutil.copytree(root, copy)
    rel = os.path.relpath(indexes[0], root)
    old = as_plain_lists(pq.read_table(copy / rel, schema=MANIFEST_SCHEMA).replace_schema_metadata(
        pq.read_schema(copy / rel).metadata))
    (copy / rel).write_bytes(index_bytes(old))
    assert pq.read_schema(copy / rel).field("K").type == pa.list_(pa.float64())
    again = read_manifest(str(copy))
    assert again.schema.field("K").type == pa.list_(pa.float64(), 9) and again.equals(manifest)
    result = CliRunner().invoke(app(), ["verify", str(copy), "--no-ray"])
    assert result.exit_code == 0 and result.output.startswith("OK"), result.output


# --------------------------------------------------------------- FedDrive ----
# Facts from FedDrive (github.com/Erosinho13/FedDrive), src/dataset/idda.py and
# src/utils/client_utils.py: every *.json in a split directory is read and its
# "user_data" merged ({user: {"x": [...], "y": [...]}}); paths are relative
# to the image root; the label is Image.open(y) mapped through a 256-entry
# table built from class_eval ("remap", its 16 evaluated classes, 255 ignore).
FEDDRIVE_CLASS_EVAL = [255, 2, 4, 255, 11, 5, 0, 0, 1, 8, 13, 3, 7, 6, 255, 255, 15, 14, 12, 9, 10]


def feddrive_read_dir(directory: Path) -> dict:
    data = {}
    for name in os.listdir(directory):
        if name.endswith(".json"):
            with open(directory / name) as f:
                data.update(json.load(f)["user_data"])
    return data


def feddrive_target(images_dir: Path, y: str) -> np.ndarray:
    mapping = np.zeros((256,), dtype=np.int64) + 255
    for i, cl in enumerate(FEDDRIVE_CLASS_EVAL):
        mapping[i] = cl
    return mapping[Image.open(images_dir / y)]


def test_feddrive_reads_the_idda_export(root, manifest, tmp_path):
    target = tmp_path / "IDDAsmall"
    result = CliRunner().invoke(app(), ["export", str(root), "--format", "idda", "--to", str(target),
                                        "--splits", "feddrive", "--holdout", "towns=T07"])
    assert result.exit_code == 0, result.output
    train = feddrive_read_dir(target / "feddrive" / "train")
    test = feddrive_read_dir(target / "feddrive" / "test")
    # One client per scenario with train frames; T07 is the unseen domain. The three one-episode
    # scenarios (three scenes) take train, val and test in table order (docs/layout.md, "Splits"): T01_CN_A
    # trains, T01_HRN_J is val, and T07_CS_B (test) is held out, so no same-domain test frames.
    assert sorted(train) == ["T01_CN_A"]
    assert sorted(test) == ["test_user_diff_domain"]  # LEAF lists no user without frames
    assert len(test["test_user_diff_domain"]["x"]) == FRAMES
    assert all(x.startswith("T07_CS_B/RGB/") for x in test["test_user_diff_domain"]["x"])
    leaf = json.loads((target / "feddrive" / "train" / "idda_train_clients.json").read_text())
    assert leaf["num_samples"] == [len(leaf["user_data"][u]["x"]) for u in leaf["users"]]
    semantic = {f"{r['frame_id']}_{r['scenario']}": r["semantic_raw_path"] for r in manifest.to_pylist()}
    users = {**train, **test}
    seen = set()
    for user, data in users.items():
        assert len(data["x"]) == len(data["y"])
        for x, y in zip(data["x"], data["y"]):
            image = np.array(Image.open(target / x).convert("RGB"))
            label = feddrive_target(target, y)
            assert image.shape == (HEIGHT, WIDTH, 3) and label.shape == (HEIGHT, WIDTH)
            assert set(np.unique(label)) <= set(range(16)) | {255}
            ids = np.array(Image.open(root / semantic[Path(y).stem]))[..., 0]
            assert np.array_equal(label, np.array(FEDDRIVE_CLASS_EVAL + [255] * 235)[ids])
            seen.add(Path(y).stem)
    val = feddrive_read_dir(target / "feddrive" / "val")
    val_stems = {Path(y).stem for y in val["test_user_same_domain"]["y"]}
    assert len(val_stems) == FRAMES and all(stem.endswith("T01_HRN_J") for stem in val_stems)
    assert not val_stems & seen and seen | val_stems == set(semantic)
    assert len(EVALUATED_IDS) == 16 == len(set(FEDDRIVE_CLASS_EVAL) - {255})


# ------------------------------------------------------------- Cityscapes ----
def torchvision_cityscapes(root: Path, split: str, target_type: str) -> list[tuple[str, str]]:
    """(image, target) pairs as torchvision.datasets.Cityscapes lists them
    (its source: cities from leftImg8bit/<split>, target name =
    file_name.split('_leftImg8bit')[0] + '_gtFine_<suffix>')."""
    suffix = {"semantic": "labelIds.png", "color": "color.png", "instance": "instanceIds.png"}[target_type]
    images_dir, targets_dir = root / "leftImg8bit" / split, root / "gtFine" / split
    if not images_dir.is_dir() or not targets_dir.is_dir():
        raise RuntimeError("Dataset not found or incomplete")
    pairs = []
    for city in os.listdir(images_dir):
        for name in os.listdir(images_dir / city):
            pairs.append((str(images_dir / city / name), str(targets_dir / city / f"{name.split('_leftImg8bit')[0]}_gtFine_{suffix}")))
    return pairs


def test_cityscapes_export_has_every_split_and_reads_like_cityscapes(root, manifest, tmp_path):
    from cityscapesscripts.helpers.csHelpers import getCsFileInfo

    target = tmp_path / "cs"
    result = CliRunner().invoke(app(), ["export", str(root), "--format", "cityscapes", "--to", str(target)])
    assert result.exit_code == 0, result.output
    # Three one-episode scenarios of three scenes: one episode in each split (docs/layout.md, "Splits").
    assert f"{len(manifest)} of the {len(manifest)} frames the root holds (4 train, 4 val, 4 test)" in result.output
    for split in ("train", "val", "test"):
        for kind in ("semantic", "color", "instance"):
            pairs = torchvision_cityscapes(target, split, kind)
            assert len(pairs) == 4
            for image, label in pairs:
                city = os.path.basename(os.path.dirname(image))
                assert getCsFileInfo(image).city == city == os.path.basename(os.path.dirname(label))
                assert Image.open(image).convert("RGB").size == (WIDTH, HEIGHT)
                mode = Image.open(label).mode
                assert mode == {"semantic": "L", "color": "RGBA", "instance": "I;16"}[kind], (kind, mode)
    # The export's splits are the manifest's, frame by frame.
    for row in manifest.to_pylist():
        name = cs_layout.cityscapes_name(row["scenario"], row["episode"], row["frame"])
        city = row["scenario"].replace("_", "-")
        assert (target / "leftImg8bit" / row["split"] / city / f"{name}_leftImg8bit.png").is_file()


def test_idda_evaluate_scores_ground_truth_as_prediction_1(root, tmp_path):
    target = tmp_path / "cs"
    ex.export(ex.ExportConfig(root=str(root), to=str(target), format="cityscapes", as_split="val"))
    predictions = tmp_path / "pred"
    predictions.mkdir()
    for gt in glob.glob(str(target / "gtFine" / "val" / "*" / "*_gtFine_labelIds.png")):
        Image.open(gt).save(predictions / os.path.basename(gt).replace("_gtFine_labelIds", "_pred"))
    result = CliRunner().invoke(app(), ["evaluate", str(target), "--predictions", str(predictions),
                                        "--json", str(tmp_path / "result.json")])
    assert result.exit_code == 0, result.output
    assert f"mIoU 1.000 over classes, 1.000 over categories ({len(os.listdir(predictions))} images)" in result.output
    assert json.loads((tmp_path / "result.json").read_text())["averageScoreClasses"] == 1.0
    missing = CliRunner().invoke(app(), ["evaluate", str(target), "--predictions", str(tmp_path)])
    assert missing.exit_code == 2 and "error: matching predictions" in missing.output


# ------------------------------------------------------------ HuggingFace ----
def test_hf_export_loads_with_image_features(root, manifest, tmp_path):
    from datasets import Image as HFImage
    from datasets import load_dataset
    from huggingface_hub import DatasetCard

    target = tmp_path / "hf"
    result = CliRunner().invoke(app(), ["export", str(root), "--format", "hf", "--to", str(target)])
    assert result.exit_code == 0, result.output
    splits = ("train", "validation", "test")  # HF's names; the manifest's val is validation
    files = {split: sorted(str(p) for p in (target / "data").glob(f"{split}-*.parquet")) for split in splits}
    data = load_dataset("parquet", data_files=files, cache_dir=str(tmp_path / "cache"))
    assert {s: data[s].num_rows for s in data} == {"train": 4, "validation": 4, "test": 4}
    for name in ("rgb", "semantic", "depth"):
        assert isinstance(data["train"].features[name], HFImage), name
    by_name = {r["frame_id"] + r["scenario"]: r for r in manifest.to_pylist()}
    for split in data:
        for sample in data[split]:
            row = by_name[sample["frame_id"] + sample["scenario"]]
            assert sample["uid"] == row["uid"]
            assert sample["split"] == split and {"train": "train", "validation": "val", "test": "test"}[split] == row["split"]
            semantic = np.array(sample["semantic"])
            assert sample["semantic"].mode == "L" and semantic.shape == (HEIGHT, WIDTH)
            assert np.array_equal(semantic, np.array(Image.open(root / row["semantic_raw_path"]))[..., 0])
            assert np.array_equal(np.array(sample["rgb"]), np.array(Image.open(root / row["rgb_path"]).convert("RGB")))
            assert np.array_equal(np.array(sample["depth"]), np.array(Image.open(root / row["depth_raw_path"])))
    # The export's own card: the hub's parser reads it, and load_dataset(dir) follows its configs.
    card = DatasetCard.load(target / "README.md").data.to_dict()
    assert card["license"] and card["task_categories"] and card["configs"][0]["config_name"] == "default"
    assert [f["split"] for f in card["configs"][0]["data_files"]] == list(splits)
    info = card["dataset_info"]["splits"]
    assert [s["name"] for s in info] == list(splits) and [s["num_examples"] for s in info] == [4, 4, 4]
    again = load_dataset(str(target), cache_dir=str(tmp_path / "cache2"))
    assert sorted(again) == sorted(splits) and isinstance(again["validation"].features["rgb"], HFImage)
    for s in info:  # num_bytes as datasets itself counts them (Arrow bytes of the split)
        assert s["num_bytes"] == again[s["name"]].data.nbytes, s


def test_hf_reads_the_manifest_as_the_docs_say(root, manifest, tmp_path):
    """docs/querying.md: datasets gives the parts' columns (no hive columns), and
    the card's manifest config splits them into train / validation / test."""
    from datasets import load_dataset

    from manifests.schema import RULE_PART_SCHEMA
    from exports.card import CardConfig, write_card

    every = load_dataset("parquet", data_files=f"{root}/manifest/**/*.parquet", split="train",
                         cache_dir=str(tmp_path / "hf"))
    # a front root's parts: the rig columns (sensor, the LiDAR's files) are only in a rig root's parts
    assert every.column_names == RULE_PART_SCHEMA.names and "town" not in every.column_names
    copy = tmp_path / "root"
    shutil.copytree(root, copy)
    write_card(CardConfig(root=str(copy)))
    by_split = load_dataset(str(copy), "manifest", cache_dir=str(tmp_path / "hf2"))
    assert sorted(by_split) == ["test", "train", "validation"]
    want = {"train": "train", "validation": "val", "test": "test"}
    for split, rows in by_split.items():
        assert sorted(rows["frame_id"]) == sorted(r["frame_id"] for r in manifest.to_pylist() if r["split"] == want[split])
        assert set(rows["split"]) == {want[split]}


# --------------------------------------------------------------- Ray Data ----
def test_ray_data_reads_the_manifest_and_frames_with_its_own_readers(root, manifest):
    """Ray Data's own readers, no project code: read_parquet on manifest/
    (hive partitions as columns) and read_images on the paths it lists."""
    import ray
    import ray.data

    want = {r["scenario"]: r for r in manifest.to_pylist() if r["frame"] == 0}
    ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False)
    try:
        ds = ray.data.read_parquet(f"{root}/manifest")
        assert ds.count() == len(manifest)
        rows = ds.filter(lambda r: r["weather"] == "HRN").take_all()
        assert len(rows) == FRAMES and {r["town"] for r in rows} == {"T01"} and {r["viewpoint"] for r in rows} == {"J"}
        assert sum(r["px_vehicle"] for r in rows) == sum(r["px_vehicle"] for r in manifest.to_pylist() if r["weather"] == "HRN")
        firsts = sorted(want.values(), key=lambda r: r["scenario"])
        rgb = ray.data.read_images([str(root / r["rgb_path"]) for r in firsts], include_paths=True).take_all()
        semantic = ray.data.read_images([str(root / r["semantic_raw_path"]) for r in firsts], include_paths=True).take_all()
    finally:
        ray.shutdown()
    by_path = {Path(r["path"]).resolve(): r["image"] for r in rgb + semantic}
    for row in firsts:
        image = by_path[(root / row["rgb_path"]).resolve()]
        assert image.shape == (HEIGHT, WIDTH, 3)
        assert np.array_equal(image, np.array(Image.open(root / row["rgb_path"]).convert("RGB")))
        classes = by_path[(root / row["semantic_raw_path"]).resolve()][..., 0]  # CARLA: the class id in the red channel
        counts = np.bincount(classes.ravel(), minlength=24)
        assert int(counts[10]) == row["px_vehicle"] and int(counts.sum()) == WIDTH * HEIGHT
