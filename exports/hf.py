"""HuggingFace: the export layout ``hf`` and the dataset card's YAML header.

``idda export --format hf`` writes what ``datasets.load_dataset`` reads with
no loading script::

    data/<split>-<i:05d>-of-<n:05d>.parquet   frames with their images embedded
    README.md                                  card: YAML header (configs, splits, features), citation

Columns: ``rgb`` (the RGB PNG), ``semantic`` (a single-channel PNG of the 24
IDDA class ids), ``depth`` (the depth_raw PNG, CARLA's 24-bit encoding) as
``datasets.Image()`` features (Arrow ``struct<bytes, path>``), then the
frame's metadata, with ``K`` (row-major 3x3) and ``cam_to_world`` (row-major
4x4, OpenCV camera axes) as lists of float64, as docs/conventions.md defines
them. The features are declared in each shard's Arrow schema
metadata (key ``huggingface``), where ``datasets`` looks for them.

The card header (``card_header``) is shared with the output root's card
(``exports/card.py``), and both cite the IDDA paper (``CITATION``).
"""

from __future__ import annotations

import json
import os
from concurrent.futures import ThreadPoolExecutor

import pyarrow as pa
import pyarrow.parquet as pq

from domains.catalog import code_axes
from manifests.query import SPLITS
from exports.shared import Layout, decode, png

SHARD_FRAMES = 256  # frames per Parquet shard
LICENSE = "cc-by-4.0"  # declared for the generated frames; edit the card if yours differs
TASK_CATEGORIES = ("image-segmentation", "depth-estimation")
TAGS = ("autonomous-driving", "semantic-segmentation", "domain-adaptation", "synthetic")

# The IDDA paper (shared/seed/idda-paper.tex: IEEE RA-L 2020, also at IROS 2020).
CITATION = """@article{alberti2020idda,
  title     = {{IDDA}: a large-scale multi-domain dataset for autonomous driving},
  author    = {Alberti, Emanuele and Tavera, Antonio and Masone, Carlo and Caputo, Barbara},
  journal   = {IEEE Robotics and Automation Letters},
  volume    = {5},
  number    = {4},
  pages     = {5526--5533},
  year      = {2020},
  doi       = {10.1109/LRA.2020.3009075}
}"""

_IMAGE = pa.struct([("bytes", pa.binary()), ("path", pa.string())])
SCHEMA = pa.schema(
    [
        ("rgb", _IMAGE),
        ("semantic", _IMAGE),
        ("depth", _IMAGE),
        ("frame_id", pa.string()),
        ("uid", pa.string()),  # unique in the root (manifests.schema.frame_uid)
        ("scenario", pa.string()),
        ("town", pa.string()),
        ("weather", pa.string()),
        ("viewpoint", pa.string()),
        ("episode", pa.int32()),
        ("frame", pa.int32()),
        ("split", pa.string()),
        ("K", pa.list_(pa.float64())),  # row-major 3x3 intrinsics (docs/conventions.md)
        ("cam_to_world", pa.list_(pa.float64())),  # row-major 4x4, OpenCV camera axes, world z up, metres
    ]
)
IMAGE_COLUMNS = ("rgb", "semantic", "depth")
# HuggingFace's split names for the manifest's splits: its loaders and the Hub
# know train, validation and test (a split named "val" is just another name).
HF_SPLITS = {"train": "train", "val": "validation", "test": "test"}
_VALUE_DTYPES = {pa.string(): "string", pa.int32(): "int32", pa.float64(): "float64"}


def features() -> dict:
    """The ``datasets`` features of ``SCHEMA``, as its serialised dict."""
    out = {}
    for f in SCHEMA:
        if f.name in IMAGE_COLUMNS:
            out[f.name] = {"_type": "Image"}
        elif pa.types.is_list(f.type):
            out[f.name] = {"feature": {"dtype": _VALUE_DTYPES[f.type.value_type], "_type": "Value"}, "_type": "List"}
        else:
            out[f.name] = {"dtype": _VALUE_DTYPES[f.type], "_type": "Value"}
    return out


def _yaml_feature(name: str, spec: dict) -> dict:
    """One feature as the card's YAML header lists it (``datasets``' ``_to_yaml_list`` form)."""
    if spec["_type"] == "Image":
        return {"name": name, "dtype": "image"}
    if spec["_type"] == "List":
        return {"name": name, "list": spec["feature"]["dtype"]}
    return {"name": name, "dtype": spec["dtype"]}


def _row(storage, frame) -> dict:
    semantic = png(decode(storage, frame.path("semantic_raw"))[..., 0])
    depth_rel = frame.path("depth_raw")
    scenario = frame.scenario
    return {
        "rgb": {"bytes": storage.read_bytes(frame.path("rgb")), "path": os.path.basename(frame.path("rgb"))},
        "semantic": {"bytes": semantic, "path": os.path.basename(frame.path("semantic_raw"))},
        "depth": {"bytes": storage.read_bytes(depth_rel), "path": os.path.basename(depth_rel)},
        "frame_id": frame.frame_id,
        "uid": frame.uid,
        "scenario": scenario,
        **code_axes(scenario),
        "episode": frame.episode,
        "frame": frame.frame,
        "split": HF_SPLITS[frame.split],
        "K": frame.K,
        "cam_to_world": frame.cam_to_world,
    }


def shard_names(split: str, n_frames: int) -> list[str]:
    """The shards of ``split`` (an HF split name) holding ``n_frames`` frames."""
    n = max(1, -(-n_frames // SHARD_FRAMES))
    return [f"data/{split}-{i:05d}-of-{n:05d}.parquet" for i in range(n)]


def write_hf(storage, frames: list, tmp: str, threads: int = 8) -> tuple[list[dict], list[str]]:
    """Write the shards and the card into ``tmp``; returns each frame's shard and the extra files."""
    metadata = {b"huggingface": json.dumps({"info": {"features": features()}}).encode()}
    schema = SCHEMA.with_metadata(metadata)
    os.makedirs(os.path.join(tmp, "data"), exist_ok=True)
    where: dict[int, dict] = {}
    sizes: dict[str, tuple[int, int]] = {}  # HF split: (frames, Arrow bytes)
    with ThreadPoolExecutor(max_workers=threads) as pool:
        for split in SPLITS:
            index = [i for i, f in enumerate(frames) if f.split == split]
            if not index:
                continue
            name_of_split = HF_SPLITS[split]
            n_bytes = 0
            for k, name in enumerate(shard_names(name_of_split, len(index))):
                chunk = index[k * SHARD_FRAMES : (k + 1) * SHARD_FRAMES]
                shard = pa.Table.from_pylist(list(pool.map(lambda i: _row(storage, frames[i]), chunk)), schema=schema)
                pq.write_table(shard, os.path.join(tmp, name), compression="zstd")
                n_bytes += shard.nbytes
                where.update({i: {"shard": name} for i in chunk})
            sizes[name_of_split] = (len(index), n_bytes)
    card = card_header(sizes, {split: f"data/{split}-*.parquet" for split in sizes}, with_features=True)
    card += "\n# IDDA-style synthetic frames\n\nLoad with `datasets.load_dataset(\"parquet\", data_dir=...)` " \
            "or `datasets.load_dataset(PATH)`. `semantic` holds the 24 IDDA class ids; `depth` the CARLA 24-bit " \
            "depth: `depth_m = 1000 * (R + G*256 + B*65536) / (256**3 - 1)`.\n\n" + citation_section()
    with open(os.path.join(tmp, "README.md"), "w") as f:
        f.write(card)
    return [where[i] for i in range(len(frames))], sorted({w["shard"] for w in where.values()}) + ["README.md"]


def size_category(n: int) -> str:
    for limit, name in ((1_000, "n<1K"), (10_000, "1K<n<10K"), (100_000, "10K<n<100K"), (1_000_000, "100K<n<1M")):
        if n < limit:
            return name
    return "1M<n<10M"


def card_header(split_sizes: dict[str, tuple[int, int]], data_files: dict[str, str | list[str]],
                config: str = "default", with_features: bool = False) -> str:
    """The YAML block HF's ``DatasetCard`` parses: licence, tasks, one config
    with its data files (a glob or a list) per split, and each split's frames
    and bytes (``split_sizes``: HF split name -> (num_examples, num_bytes), the
    bytes as Arrow counts them, which is what ``datasets`` records)."""
    info: dict = {"config_name": config}
    if with_features:
        info["features"] = [_yaml_feature(name, spec) for name, spec in features().items()]
    info["splits"] = [{"name": s, "num_bytes": b, "num_examples": n} for s, (n, b) in split_sizes.items()]
    header = {
        "license": LICENSE,
        "task_categories": list(TASK_CATEGORIES),
        "tags": list(TAGS),
        "pretty_name": "IDDA-style synthetic driving dataset",
        "size_categories": [size_category(sum(n for n, _ in split_sizes.values()))],
        "configs": [{"config_name": config, "data_files": [{"split": s, "path": p} for s, p in data_files.items()]}],
        "dataset_info": info,
    }
    import yaml  # PyYAML, a dependency of Ray

    return "---\n" + yaml.safe_dump(header, sort_keys=False) + "---\n"


def citation_section() -> str:
    return "## Citation\n\nThe dataset re-creates IDDA; please cite its paper:\n\n```bibtex\n" + CITATION + "\n```\n"


def _build(storage, frames: list, tmp: str, config) -> tuple[list[dict], list[str]]:
    return write_hf(storage, frames, tmp, threads=config.threads)


LAYOUT = Layout(outputs=("rgb", "semantic_raw", "depth_raw"), build=_build)
