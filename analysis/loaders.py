"""Training input: a map-style dataset and a Ray Data reader over a query's frames.

Both read the images through ``storage`` (local roots and s3://) and decode
them to plain numpy arrays; neither imports torch. Per requested output:

``outputs.table.OUTPUT_TABLE`` lists each output's key, dtype,
channels and content (``DECODERS`` here is that table by name; ``rgb`` is
read from a PNG or, in a root made with ``--rgb-format jpg``, a JPEG, as
HxWx3 uint8 either way);
``semantic_raw`` arrives as ``semantic`` (HxW class ids, or mapped, ``labels``),
``depth_raw`` as ``depth`` (HxW float32 metres), ``instance`` as HxW uint16
instance ids and ``objects`` as a dict of numpy columns (one entry per visible
object, so batch it with a collate function that keeps lists).

``labels`` picks the semantic ids: ``idda`` (the 24 class ids), ``cityscapes``
(Cityscapes label ids) or ``train`` (Cityscapes trainIds, 255 = ignore).

Example with PyTorch::

    from torch.utils.data import DataLoader
    from analysis.loaders import FrameDataset
    from manifests.query import Query

    data = FrameDataset("output", Query(domains="T01_*_*", splits=("train",)), labels="train")
    for batch in DataLoader(data, batch_size=8, num_workers=4, shuffle=True):
        images, targets = batch["rgb"], batch["semantic"]
"""

from __future__ import annotations

import copy
import os
from typing import Any, Callable

import numpy as np
import pyarrow as pa

from domains.catalog import AXES, CITYSCAPES_ID_LUT, TRAIN_ID_LUT
from outputs.geometry import as_matrix
from outputs.table import OUTPUT_BY_NAME as DECODERS, OUTPUTS, read_output
from manifests.query import Query, run_query
from manifests.reader import as_storage, read_manifest, require_outputs
from manifests.schema import output_columns, with_uids

# Per-frame metadata returned with the arrays.
META_COLUMNS = ("uid", "frame_id", "scenario", *AXES, "episode", "frame", "split", "width", "height")
# Calibration and pose returned by FrameDataset as float64 matrices (outputs.geometry's convention;
# None in roots written before they existed): K 3x3, cam_to_world 4x4.
POSE_META = {"K": 3, "cam_to_world": 4}
# The numeric ones: what ray_dataset keeps by default, because Ray's
# iter_torch_batches turns every column into a tensor and strings cannot be.
NUMERIC_META = ("episode", "frame", "width", "height")


LABEL_MAPS: dict[str, np.ndarray | None] = {
    "idda": None,  # the 24 IDDA class ids
    "cityscapes": CITYSCAPES_ID_LUT,  # Cityscapes label ids
    "train": TRAIN_ID_LUT,  # Cityscapes trainIds, 255 = ignore
}


def _check_options(outputs: tuple[str, ...], labels: str) -> None:
    if not outputs:
        raise ValueError(f"ask for at least one output; valid outputs: {', '.join(OUTPUTS)}")
    for name in outputs:
        if name not in DECODERS:
            raise ValueError(f"unknown output {name!r}; valid outputs: {', '.join(OUTPUTS)}")
    if labels not in LABEL_MAPS:
        raise ValueError(f"unknown label map {labels!r}; valid label maps: {', '.join(LABEL_MAPS)}")


def select_frames(root, query: Query | None = None) -> pa.Table:
    """Manifest rows of the query's frames (all frames without a query)."""
    table = with_uids(read_manifest(as_storage(root)))  # roots written before the uid column get it derived
    return table if query is None else run_query(table, query).table


def load_output(storage, rel: str, output: str, decode: bool = True, labels: str = "idda"):
    """One output file: its decoded array, or its PNG bytes when ``decode`` is False."""
    data = storage.read_bytes(rel)
    if not decode:
        return data
    array = DECODERS[output].decode(read_output(output, data, storage.join(rel)))
    lut = LABEL_MAPS[labels]
    if output == "semantic_raw" and lut is not None:
        array = lut[array]
    return array


class FrameDataset:
    """Map-style dataset over a query's frames: ``len(ds)`` and ``ds[i]`` -> dict.

    A sample holds the decoded arrays (keys as ``outputs.table.OUTPUT_TABLE``'s ``key``; with
    ``decode=False`` the PNG bytes under the output names) and the frame's
    metadata (``META_COLUMNS``, ``index``, and ``K`` and ``cam_to_world`` as matrices: ``POSE_META``). Frames are in manifest order
    (scenario, episode, frame). The object is small and picklable and opens
    its storage lazily in each process, so DataLoader workers (fork or spawn)
    never share a file-system handle. ``transform``, if given, is applied to
    each sample and must be picklable for multi-process loading.
    """

    def __init__(
        self,
        root,
        query: Query | None = None,
        outputs: tuple[str, ...] = ("rgb", "semantic_raw"),
        decode: bool = True,
        labels: str = "idda",
        transform: Callable[[dict], Any] | None = None,
    ) -> None:
        outputs = tuple(outputs)
        _check_options(outputs, labels)
        storage = as_storage(root)
        table = select_frames(storage, query)
        require_outputs(table, outputs, storage.uri)
        columns = list(META_COLUMNS) + list(POSE_META) + [output_columns(o)[0] for o in outputs]
        self._table = table.select(columns).combine_chunks()
        self._storage = copy.copy(storage)  # a fresh copy holds no open file system
        self._pid: int | None = None
        self.root = storage.uri
        self.outputs = outputs
        self.decode = decode
        self.labels = labels
        self.transform = transform

    def __len__(self) -> int:
        return self._table.num_rows

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["_storage"] = copy.copy(self._storage)
        state["_pid"] = None
        return state

    def _reader(self):
        """This process's storage (re-created after a fork)."""
        if self._pid != os.getpid():
            self._storage = copy.copy(self._storage)
            self._pid = os.getpid()
        return self._storage

    def metadata(self, index: int) -> dict:
        """The frame's metadata (no image is read)."""
        n = len(self)
        if not -n <= index < n:
            raise IndexError(f"frame index {index} out of range for {n} frames")
        index %= n
        row = {name: self._table.column(name)[index].as_py() for name in META_COLUMNS}
        for name, size in POSE_META.items():
            cell = self._table.column(name)[index].as_py()
            row[name] = None if cell is None else as_matrix(cell, size)
        row["index"] = index
        return row

    def __getitem__(self, index: int) -> dict:
        sample = self.metadata(int(index))
        storage = self._reader()
        for output in self.outputs:
            rel = self._table.column(output_columns(output)[0])[sample["index"]].as_py()
            key = DECODERS[output].key if self.decode else output
            sample[key] = load_output(storage, rel, output, self.decode, self.labels)
        return self.transform(sample) if self.transform is not None else sample

    def __repr__(self) -> str:
        return f"FrameDataset({self.root!r}, {len(self)} frames, outputs={self.outputs})"


def _read_batch(batch: dict, storage, outputs: tuple[str, ...], labels: str, metadata: tuple[str, ...]) -> dict:
    """Ray Data map_batches function: the batch's metadata and decoded arrays."""
    out = {name: batch[name] for name in metadata}
    for output in outputs:
        paths = batch[output_columns(output)[0]]
        arrays = [load_output(storage, str(rel), output, True, labels) for rel in paths]
        if DECODERS[output].channels:
            out[DECODERS[output].key] = np.stack(arrays) if arrays else np.zeros((0,), dtype=np.uint8)
        else:  # a table per frame: one object array of column dicts
            out[DECODERS[output].key] = np.array(arrays + [None], dtype=object)[:-1]
    return out


def ray_dataset(
    root,
    query: Query | None = None,
    outputs: tuple[str, ...] = ("rgb", "semantic_raw"),
    labels: str = "idda",
    rows_per_block: int = 64,
    batch_size: int = 16,
    metadata: tuple[str, ...] = NUMERIC_META,
):
    """A ``ray.data.Dataset`` of the query's frames with decoded arrays.

    Rows carry the ``metadata`` columns and one array column per output (keys
    as the output table's ``key``). The default metadata is numeric only (``NUMERIC_META``),
    so ``iter_torch_batches()`` yields a tensor for every column as is; pass
    ``metadata=META_COLUMNS`` to also get the string columns (scenario,
    frame_id, split, ...) for ``iter_batches`` / ``take``. The manifest rows are
    split into blocks of ``rows_per_block`` frames so that reading and decoding
    spread over the cluster; every task reads through ``storage``, so s3://
    roots work from any node. Needs Ray (installed with this project) and a
    running or auto-started Ray instance.
    """
    outputs, metadata = tuple(outputs), tuple(metadata)
    _check_options(outputs, labels)
    for name in metadata:
        if name not in META_COLUMNS:
            raise ValueError(f"unknown metadata column {name!r}; valid columns: {', '.join(META_COLUMNS)}")
    if rows_per_block < 1 or batch_size < 1:
        raise ValueError(f"rows_per_block and batch_size must be at least 1, got {rows_per_block}, {batch_size}")
    try:
        import ray.data
    except ImportError as exc:
        raise ImportError("ray_dataset needs Ray Data: pip install 'ray[data]'") from exc
    storage = as_storage(root)
    table = select_frames(storage, query)
    require_outputs(table, outputs, storage.uri)
    columns = list(metadata) + [output_columns(o)[0] for o in outputs]
    table = table.select(columns).combine_chunks()
    if table.num_rows == 0:
        raise ValueError(f"no frames in {storage.uri} match the query")
    blocks = [table.slice(start, rows_per_block) for start in range(0, table.num_rows, rows_per_block)]
    return ray.data.from_arrow(blocks).map_batches(
        _read_batch,
        batch_format="numpy",
        batch_size=batch_size,
        fn_kwargs={"storage": copy.copy(storage), "outputs": outputs, "labels": labels, "metadata": metadata},
    )
