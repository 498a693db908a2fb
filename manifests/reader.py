"""The public reader: the whole manifest as one Arrow table or dataset.

Everything that reads a produced dataset (status, verify, query, stats,
exports, loaders, tests) goes through here.
"""

from __future__ import annotations

import io
import json
import re
from collections import defaultdict

import pyarrow as pa
import pyarrow.dataset as ds
import pyarrow.parquet as pq

from manifests.schema import (
    INDEX_EPISODES_KEY,
    INDEX_NAME,
    MANIFEST_DIR,
    MANIFEST_SCHEMA,
    PARTITION_SCHEMA,
    PART_SCHEMA,
    index_path,
)

_PART_RE = re.compile(
    r"^manifest/town=(T\d\d)/weather=(\w+)/viewpoint=(\w)/((T\d\d)_(\w+)_(\w))_e(\d{4})\.parquet$"
)


def as_storage(root):
    """A Storage for a root given as a Storage, a local path or an s3:// URI."""
    from storage import Storage

    return root if isinstance(root, Storage) else Storage.from_uri(str(root))


def _listing(storage) -> tuple[dict[str, dict[int, str]], dict[str, str]]:
    """Parts per scenario ({episode: path}) and index files per scenario."""
    parts: dict[str, dict[int, str]] = defaultdict(dict)
    indexes: dict[str, str] = {}
    for rel in storage.list_files(MANIFEST_DIR + "/", suffix=".parquet"):
        match = _PART_RE.match(rel)
        if match:
            parts[match.group(4)][int(match.group(8))] = rel
        elif rel.endswith("/" + INDEX_NAME):
            town, weather, viewpoint = (seg.split("=", 1)[1] for seg in rel.split("/")[1:4])
            indexes[f"{town}_{weather}_{viewpoint}"] = rel
    return parts, indexes


def done_episodes(root) -> set[tuple[str, int]]:
    """(scenario, episode) of every manifest part present under ``root``."""
    parts, _ = _listing(as_storage(root))
    return {(scenario, episode) for scenario, eps in parts.items() for episode in eps}


def index_episodes(storage, rel: str) -> set[int] | None:
    """Episodes a scenario index covers (from its footer), or None if unreadable."""
    try:
        with storage.filesystem.open_input_file(storage.path(rel)) as f:
            meta = pq.read_metadata(f).metadata or {}
        return set(json.loads(meta[INDEX_EPISODES_KEY]))
    except Exception:
        return None


def manifest_files(root) -> list[str]:
    """The files that hold the manifest now: a scenario's index where it covers
    exactly the parts present, else the scenario's parts (relative paths)."""
    storage = as_storage(root)
    parts, indexes = _listing(storage)
    files = []
    for scenario in sorted(parts):
        index = indexes.get(scenario)
        if index is not None and index_episodes(storage, index) == set(parts[scenario]):
            files.append(index)
        else:
            files.extend(parts[scenario][e] for e in sorted(parts[scenario]))
    return files


def manifest_dataset(root) -> ds.Dataset:
    """A hive-partitioned pyarrow dataset over the manifest (lazy, filterable).

    A root with no parts yet gives an empty dataset with the full schema.
    """
    storage = as_storage(root)
    return ds.dataset(
        [storage.path(rel) for rel in manifest_files(storage)],
        filesystem=storage.filesystem,
        format="parquet",
        schema=MANIFEST_SCHEMA,
        partitioning=ds.partitioning(PARTITION_SCHEMA, flavor="hive"),
        partition_base_dir=storage.path(MANIFEST_DIR),
    )


def compact(root, scenarios: list[str] | None = None) -> list[str]:
    """Merge each scenario's parts into one index file, where it is stale.

    Parts stay the source of truth (they are the "done" markers); an index is
    only used while it covers exactly the parts present. Returns the scenarios
    whose index was (re)written.
    """
    from manifests.writer import read_part

    storage = as_storage(root)
    parts, indexes = _listing(storage)
    for scenario in set(indexes) - set(parts):  # every part of it was removed
        storage.delete(indexes[scenario])
    written = []
    for scenario in sorted(parts if scenarios is None else set(scenarios) & set(parts)):
        episodes = sorted(parts[scenario])
        index = indexes.get(scenario)
        if index is not None and index_episodes(storage, index) == set(episodes):
            continue
        index_dir, _, index_name = index_path(scenario).rpartition("/")
        storage.remove_stale_temp(index_dir, index_name)  # from a compaction that was killed
        table = pa.concat_tables([read_part(storage, scenario, e) for e in episodes])
        meta = {INDEX_EPISODES_KEY: json.dumps(episodes).encode()}
        sink = io.BytesIO()
        pq.write_table(table.replace_schema_metadata(meta), sink, compression="zstd", row_group_size=1 << 16)
        storage.write_bytes(index_path(scenario), sink.getvalue())
        written.append(scenario)
    return written


def read_manifest(root, filter: ds.Expression | None = None, columns: list[str] | None = None) -> pa.Table:
    """Read the manifest (optionally filtered), sorted by scenario, episode, frame."""
    table = manifest_dataset(root).to_table(filter=filter, columns=columns)
    sort_keys = [(k, "ascending") for k in ("scenario", "episode", "frame") if k in table.column_names]
    return table.sort_by(sort_keys) if sort_keys else table
