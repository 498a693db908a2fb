"""The public reader: the whole manifest as one Arrow table or dataset.

Everything that reads a produced dataset (status, verify, query, stats,
exports, loaders, tests) goes through here.
"""

from __future__ import annotations

import io
import json
import logging
import re
from collections import defaultdict
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pyarrow as pa
import pyarrow.dataset as ds
import pyarrow.parquet as pq

from manifests.catalog import split_code
from manifests.schema import (
    INDEX_DIR,
    INDEX_EPISODES_KEY,
    LEGACY_INDEX_NAME,
    MANIFEST_DIR,
    MANIFEST_SCHEMA,
    PARTITION_KEYS,
    PARTITION_SCHEMA,
    index_path,
    output_columns,
)
from manifests.outputs import OUTPUTS

_PART_RE = re.compile(
    r"^manifest/town=(T\d\d)/weather=(\w+)/viewpoint=(\w)/((T\d\d)_(\w+)_(\w))_e(\d{4})\.parquet$"
)
_INDEX_RE = re.compile(r"^" + INDEX_DIR + r"/((T\d\d)_(\w+)_(\w))\.parquet$")

log = logging.getLogger(__name__)


def as_storage(root):
    """A Storage for a root given as a Storage, a local path or an s3:// URI."""
    from storage import Storage

    return root if isinstance(root, Storage) else Storage.from_uri(str(root))


def part_files(storage) -> dict[str, dict[int, str]]:
    """Parts per scenario: {scenario: {episode: relative path}}."""
    parts: dict[str, dict[int, str]] = defaultdict(dict)
    for rel in storage.list_files(MANIFEST_DIR + "/", suffix=".parquet"):
        match = _PART_RE.match(rel)
        if match:
            parts[match.group(4)][int(match.group(8))] = rel
    return parts


def index_files(storage) -> dict[str, str]:
    """Index files per scenario: {scenario: relative path}."""
    indexes = {}
    for rel in storage.list_files(INDEX_DIR + "/", suffix=".parquet"):
        match = _INDEX_RE.match(rel)
        if match:
            indexes[match.group(1)] = rel
    return indexes


def done_episodes(root) -> set[tuple[str, int]]:
    """(scenario, episode) of every manifest part present under ``root``."""
    parts = part_files(as_storage(root))
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
    parts, indexes = part_files(storage), index_files(storage)
    files = []
    for scenario in sorted(parts):
        index = indexes.get(scenario)
        if index is not None and index_episodes(storage, index) == set(parts[scenario]):
            files.append(index)
        else:
            files.extend(parts[scenario][e] for e in sorted(parts[scenario]))
    return files


def manifest_dataset(root) -> ds.Dataset:
    """A pyarrow dataset over the manifest (lazy, filterable): hive-partitioned
    parts under manifest/ and indexes under _index/ (which carry the partition
    columns themselves). A root with no parts yet gives an empty dataset with
    the full schema.
    """
    storage = as_storage(root)
    return _dataset(storage, manifest_files(storage))


def _dataset(storage, files: list[str]) -> ds.Dataset:
    parts = [storage.path(rel) for rel in files if rel.startswith(MANIFEST_DIR + "/")]
    indexes = [storage.path(rel) for rel in files if rel.startswith(INDEX_DIR + "/")]
    common = dict(filesystem=storage.filesystem, format="parquet", schema=MANIFEST_SCHEMA)
    part_ds = ds.dataset(
        parts,
        partitioning=ds.partitioning(PARTITION_SCHEMA, flavor="hive"),
        partition_base_dir=storage.path(MANIFEST_DIR),
        **common,
    )
    if not indexes:
        return part_ds
    return ds.dataset([part_ds, ds.dataset(indexes, **common)])


def episode_frames(root) -> dict[tuple[str, int], int]:
    """Frames held by each done episode's part: {(scenario, episode): rows}.

    Read from a scenario's index where it covers exactly the parts present (one
    column), else from each part's footer.
    """
    storage = as_storage(root)
    parts, indexes = part_files(storage), index_files(storage)
    counts: dict[tuple[str, int], int] = {}
    unindexed: list[tuple[tuple[str, int], str]] = []
    for scenario, episodes in parts.items():
        index = indexes.get(scenario)
        if index is not None and index_episodes(storage, index) == set(episodes):
            try:
                with storage.filesystem.open_input_file(storage.path(index)) as f:
                    column = pq.read_table(f, columns=["episode"]).column("episode").to_numpy()
                found = dict(zip(*(v.tolist() for v in np.unique(column, return_counts=True))))
                counts.update(((scenario, e), found.get(e, 0)) for e in episodes)
                continue
            except Exception:  # a damaged index: fall back to the parts
                pass
        unindexed.extend(((scenario, episode), rel) for episode, rel in episodes.items())

    def rows(rel: str) -> int:
        try:
            with storage.filesystem.open_input_file(storage.path(rel)) as f:
                return pq.read_metadata(f).num_rows
        except Exception:
            return 0  # unreadable: not done

    with ThreadPoolExecutor(max_workers=16) as pool:  # one small read per part: many at once on S3
        counts.update(zip((key for key, _ in unindexed), pool.map(rows, [rel for _, rel in unindexed])))
    return counts


def index_table(parts: list[pa.Table], scenario: str, episodes: list[int]) -> pa.Table:
    """A scenario's index: its parts' rows with the partition columns, and the
    covered episodes in the footer."""
    table = pa.concat_tables(parts)
    for key, value in zip(PARTITION_KEYS, split_code(scenario)):
        table = table.append_column(key, pa.array([value] * len(table), pa.string()))
    meta = {INDEX_EPISODES_KEY: json.dumps(episodes).encode()}
    return table.cast(MANIFEST_SCHEMA).replace_schema_metadata(meta)


def index_bytes(table: pa.Table) -> bytes:
    """Serialise an index deterministically: the same parts give the same bytes."""
    sink = io.BytesIO()
    pq.write_table(table, sink, compression="zstd", row_group_size=1 << 16, write_page_checksum=True)
    return sink.getvalue()


def build_index(storage, scenario: str, episodes: list[int]) -> bytes:
    """The bytes of ``scenario``'s index over ``episodes``, built from its parts."""
    from manifests.writer import read_part

    return index_bytes(index_table([read_part(storage, scenario, e) for e in episodes], scenario, episodes))


def _remove_legacyindex_files(storage) -> None:
    """Indexes that older versions wrote inside manifest/ (they doubled rows for glob readers)."""
    for rel in storage.list_files(MANIFEST_DIR + "/", suffix="/" + LEGACY_INDEX_NAME):
        storage.delete(rel)


def compact(root, scenarios: list[str] | None = None) -> list[str]:
    """Merge each scenario's parts into one index file, where it is stale.

    Parts stay the source of truth (they are the "done" markers); an index is
    only used while it covers exactly the parts present. Returns the scenarios
    whose index was (re)written.
    """
    storage = as_storage(root)
    _remove_legacyindex_files(storage)
    parts, indexes = part_files(storage), index_files(storage)
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
        storage.write_bytes(index_path(scenario), build_index(storage, scenario, episodes))
        written.append(scenario)
    return written


def _readable_files(storage, files: list[str]) -> list[str]:
    """``files`` with each unreadable index swapped for its scenario's parts;
    ManifestError naming an unreadable part."""
    from manifests.writer import ManifestError, read_part_file

    parts = part_files(storage)
    out = []
    for rel in files:
        try:
            read_part_file(storage, rel)
            out.append(rel)
        except (ManifestError, FileNotFoundError) as exc:
            if not rel.startswith(INDEX_DIR + "/"):
                raise ManifestError(f"{exc}; run `idda verify` and `idda produce --repair`") from None
            scenario = _INDEX_RE.match(rel).group(1)
            log.warning("ignoring the damaged index %s (%s); reading its parts", storage.join(rel), exc)
            out.extend(parts[scenario][e] for e in sorted(parts.get(scenario, {})))
    return out


def scan_manifest(root, scan):
    """``scan(dataset)`` over the manifest. If the scan fails on a damaged file,
    a damaged index is skipped (its parts are read instead) and a damaged part
    raises ManifestError naming it: never an anonymous Arrow error."""
    from manifests.writer import ManifestError

    storage = as_storage(root)
    try:
        return scan(manifest_dataset(storage))
    except (pa.ArrowException, OSError) as exc:
        files = manifest_files(storage)
        good = _readable_files(storage, files)
        if good == files:
            raise ManifestError(f"cannot read the manifest of {storage.uri}: {exc}") from exc
        return scan(_dataset(storage, good))


def read_manifest(root, filter: ds.Expression | None = None, columns: list[str] | None = None) -> pa.Table:
    """Read the manifest (optionally filtered), sorted by scenario, episode, frame."""
    table = scan_manifest(root, lambda dataset: dataset.to_table(filter=filter, columns=columns))
    sort_keys = [(k, "ascending") for k in ("scenario", "episode", "frame") if k in table.column_names]
    return table.sort_by(sort_keys) if sort_keys else table


def require_outputs(table: pa.Table, names, where: str) -> None:
    """ValueError in one line unless every row of ``table`` has each of the ``names`` outputs."""
    for name in names:
        column = table.column(output_columns(name)[0])
        if column.null_count:
            have = [o for o in OUTPUTS if table.column(output_columns(o)[0]).null_count == 0]
            raise ValueError(
                f"{where} does not hold the {name!r} output for {column.null_count:,} of {len(table):,} frames "
                f"(every frame has: {', '.join(have) or 'none'}); produce it with `idda produce --outputs` into a new root"
            )
