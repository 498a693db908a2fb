"""The loaders return exactly the pixels on disk for the queried frames:
FrameDataset (also pickled, in worker processes) and the Ray Data reader."""

from __future__ import annotations

import importlib.util
import multiprocessing
import pickle

import numpy as np
import pytest
from PIL import Image

from domains.catalog import TRAIN_ID_LUT
from outputs.table import SEED_OUTPUTS as OUTPUTS
from analysis.loaders import DECODERS, META_COLUMNS, FrameDataset, ray_dataset
from manifests.query import Query, run_query
from manifests.reader import read_manifest
from tests.s3_server import s3_server  # noqa: F401  (fixture)
from tests.test_export import make_tiny_root, upload_root

QUERY = Query(domains="towns=T01 weathers=HRN", splits=("train", "val"))  # the two one-episode scenarios: A train, J val


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    return make_tiny_root(tmp_path_factory)


@pytest.fixture(scope="module")
def rows(root):
    return run_query(read_manifest(str(root)), QUERY).table.to_pylist()


def on_disk(root, row: dict) -> dict:
    """The frame's arrays decoded straight from its PNG files (PIL, no project code)."""
    px = {o: np.array(Image.open(root / row[f"{o}_path"]).convert("RGB")) for o in OUTPUTS}
    raw = px["depth_raw"].astype(np.float64)
    depth = 1000.0 * (raw[..., 0] + raw[..., 1] * 256 + raw[..., 2] * 65536) / (256**3 - 1)
    return {
        "rgb": px["rgb"],
        "semantic": px["semantic_raw"][..., 0],
        "semantic_color": px["semantic_color"],
        "depth": depth.astype(np.float32),
        "depth_gray": px["depth_gray"][..., 0],
        "depth_log": px["depth_log"][..., 0],
    }


def assert_sample(sample: dict, root, row: dict, keys) -> None:
    expected = on_disk(root, row)
    for name in META_COLUMNS:
        assert sample[name] == row[name]
    for key in keys:
        assert sample[key].dtype == expected[key].dtype, key
        assert np.array_equal(sample[key], expected[key]), key


def test_frame_dataset_gives_the_pixels_on_disk(root, rows):
    data = FrameDataset(root, QUERY, outputs=OUTPUTS)
    assert len(data) == len(rows) == 4
    keys = [DECODERS[o].key for o in OUTPUTS]
    for i, row in enumerate(rows):
        sample = data[i]
        assert sample["index"] == i
        assert_sample(sample, root, row, keys)
        assert sample["rgb"].shape == (36, 64, 3) and sample["depth"].shape == (36, 64)
        assert sample["uid"] == f"{row['frame_id']}_{row['scenario']}"
        assert sample["K"].shape == (3, 3) and np.array_equal(sample["K"].ravel(), row["K"])
        assert np.array_equal(sample["cam_to_world"].ravel(), row["cam_to_world"])
    assert len({data[i]["uid"] for i in range(len(data))}) == len(data)
    assert data[-1]["frame_id"] == rows[-1]["frame_id"]
    with pytest.raises(IndexError, match="out of range for 4 frames"):
        data[4]


def test_label_maps_and_raw_bytes(root, rows):
    train = FrameDataset(str(root), QUERY, outputs=("semantic_raw",), labels="train")
    assert np.array_equal(train[0]["semantic"], TRAIN_ID_LUT[on_disk(root, rows[0])["semantic"]])
    raw = FrameDataset(str(root), QUERY, outputs=("rgb",), decode=False)
    assert raw[1]["rgb"] == (root / rows[1]["rgb_path"]).read_bytes()
    everything = FrameDataset(str(root))
    assert len(everything) == len(read_manifest(str(root)))
    with pytest.raises(ValueError, match="valid outputs: rgb, depth_raw"):
        FrameDataset(root, outputs=("lidar",))
    with pytest.raises(ValueError, match="valid label maps: idda, cityscapes, train"):
        FrameDataset(root, labels="coco")


def _first_pixel_sum(sample: dict) -> int:
    return int(sample["rgb"].sum())


def test_works_in_worker_processes(root, rows):
    data = FrameDataset(root, QUERY, transform=None)
    data[0]  # the parent reads before workers fork, as a DataLoader user would
    clone = pickle.loads(pickle.dumps(data))
    assert len(clone) == len(data) and clone._pid is None
    assert_sample(clone[2], root, rows[2], ["rgb", "semantic"])
    if importlib.util.find_spec("torch") is not None:
        from torch.utils.data import DataLoader

        batches = list(DataLoader(data, batch_size=2, num_workers=2))
        got = np.concatenate([b["rgb"].numpy() for b in batches])
    else:
        with multiprocessing.get_context("fork").Pool(2) as pool:
            got = np.stack([s["rgb"] for s in pool.map(data.__getitem__, range(len(data)))])
    assert np.array_equal(got, np.stack([on_disk(root, r)["rgb"] for r in rows]))


def test_frame_dataset_reads_s3_roots(root, rows, s3_server):  # noqa: F811
    uri = s3_server.uri("tiny")
    upload_root(root, uri)
    data = FrameDataset(uri, QUERY, outputs=("rgb", "semantic_raw", "depth_raw"))
    assert data.root == uri and len(data) == len(rows)
    clone = pickle.loads(pickle.dumps(data))
    for i, row in enumerate(rows):
        assert_sample(clone[i], root, row, ["rgb", "semantic", "depth"])


def test_ray_dataset_gives_the_pixels_on_disk(root, rows):
    import ray

    ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False)
    try:
        ds = ray_dataset(root, QUERY, outputs=("rgb", "semantic_raw", "depth_raw"), rows_per_block=2, batch_size=2,
                         metadata=META_COLUMNS)
        got = {(r["scenario"], r["frame_id"]): r for r in ds.take_all()}
        # As is, into torch: every column a tensor, the pixels those on disk.
        import torch

        batches = list(ray_dataset(root, QUERY, outputs=("rgb", "semantic_raw", "depth_raw"), rows_per_block=2)
                       .iter_torch_batches(batch_size=2))
    finally:
        ray.shutdown()
    assert sorted(got) == [(r["scenario"], r["frame_id"]) for r in rows]
    for row in rows:
        sample = got[(row["scenario"], row["frame_id"])]
        sample = {k: (v.item() if isinstance(v, np.generic) else v) for k, v in sample.items()}
        assert_sample(sample, root, row, ["rgb", "semantic", "depth"])
    assert [len(b["rgb"]) for b in batches] == [2] * (len(rows) // 2) + [1] * (len(rows) % 2)
    assert all(isinstance(v, torch.Tensor) for b in batches for v in b.values())
    assert sorted(batches[0]) == ["depth", "episode", "frame", "height", "rgb", "semantic", "width"]
    flat = {k: torch.cat([b[k] for b in batches]).numpy() for k in ("rgb", "semantic", "depth")}
    for key, dtype in (("rgb", np.uint8), ("semantic", np.uint8), ("depth", np.float32)):
        assert flat[key].dtype == dtype
        got_frames = sorted(a.tobytes() for a in flat[key])
        assert got_frames == sorted(on_disk(root, r)[key].tobytes() for r in rows), key
    with pytest.raises(ValueError, match="valid outputs"):
        ray_dataset(root, outputs=("lidar",))
    with pytest.raises(ValueError, match="valid columns"):
        ray_dataset(root, metadata=("seed",))
