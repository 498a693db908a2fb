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
from dataclasses import dataclass, field
from functools import cache
from typing import TYPE_CHECKING

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from domains.catalog import scenario_pattern, split_code
from manifests import footer_pool  # by module: tests spy on its functions
from manifests.part_file import ManifestError, MisfiledParts, read_part_file
from manifests.schema import (
    INDEX_DIR,
    INDEX_EPISODES_KEY,
    INDEX_PARTS_KEY,
    LEGACY_INDEX_NAME,
    MANIFEST_DIR,
    MANIFEST_SCHEMA,
    PARTITION_KEYS,
    RIG_FIELDS,
    PARTITION_SCHEMA,
    PART_SCHEMA,
    index_path,
    PART_RE,
    named_rows,
    newer_part,
    part_path,
    part_stem,
    output_columns,
)
from outputs.table import OUTPUTS
from manifests.summary import _SUMMARY_COLUMNS, PartSummary, summary_of_footer, summary_of_table  # noqa: F401 (public here too)
from storage import Storage
from storage.buffers import arrow_reader

if TYPE_CHECKING:
    import pyarrow.dataset as ds

_INDEX_RE = re.compile("^" + INDEX_DIR + "/" + scenario_pattern() + r"\.parquet$")

log = logging.getLogger(__name__)


@cache
def datasets():
    """``pyarrow.dataset``, imported on first use: importing it imports pandas (which ray[data] installs),
    about a second of every process's start (each CLI command, each Ray worker) that reads no dataset."""
    import pyarrow.dataset

    return pyarrow.dataset


@cache
def _parquet_format():
    return datasets().ParquetFileFormat()


def as_storage(root):
    """A Storage for a root given as a Storage, a local path or an s3:// URI."""
    return root if isinstance(root, Storage) else Storage.from_uri(str(root))


def part_listing(storage) -> dict[str, dict[int, tuple[str, int]]]:
    """Parts per scenario with their sizes: {scenario: {episode: (relative path, bytes)}}."""
    return _manifest_listing(storage)[0]


def _manifest_listing(storage) -> tuple[dict[str, dict[int, tuple[str, int]]], list[str]]:
    """One listing of manifest/: its parts (as :func:`part_listing`) and what compaction
    removes: the indexes older versions wrote there, and parts under another name of an
    episode than the one read (``schema.newer_part``: a writer killed between the two)."""
    parts: dict[str, dict[int, tuple[str, int]]] = defaultdict(dict)
    legacy = []
    for rel, size in storage.list_sizes(MANIFEST_DIR + "/", suffix=".parquet").items():
        match = PART_RE.match(rel)
        if match and not filed_where_named(rel):
            log.warning("%s is filed under another scenario's folder: not read (`idda verify` names it)", storage.join(rel))
        elif match:
            scenario, episode = match.group("scenario"), int(match.group("episode"))
            held = parts[scenario].get(episode)
            if held is None or newer_part(rel, held[0]):
                parts[scenario][episode] = (rel, size)
            if held is not None:  # the one of the two not read
                legacy.append(held[0] if parts[scenario][episode][0] == rel else rel)
        elif rel.endswith("/" + LEGACY_INDEX_NAME):
            legacy.append(rel)
    return parts, sorted(legacy)


def filed_where_named(rel: str) -> bool:
    """Whether the part at ``rel`` lies in the folder its name's scenario files it under
    (not misfiled into another scenario's folder)."""
    match = PART_RE.match(rel)
    return match is not None and rel.rpartition("/")[0] == part_path(match.group("scenario"), 0).rpartition("/")[0]


def episode_parts(storage, scenario: str, episode: int) -> list[str]:
    """Every part file of one episode (one listing of its folder), the one readers use first:
    one name normally; an old name beside a counted one if a writer was killed between them."""
    folder = part_path(scenario, episode).rpartition("/")[0]
    found = []
    for rel in storage.list_files(f"{folder}/{part_stem(scenario, episode)}", suffix=".parquet"):
        match = PART_RE.match(rel)
        if match and match.group("scenario") == scenario and int(match.group("episode")) == episode:
            found.append(rel)
    return sorted(found, key=lambda rel: -1 if named_rows(rel) is None else named_rows(rel), reverse=True)


def read_part(storage, scenario: str, episode: int) -> pa.Table:
    """An episode's part, under whichever name it was written."""
    listed = episode_parts(storage, scenario, episode)
    return read_part_file(storage, listed[0] if listed else part_path(scenario, episode), PART_SCHEMA)


def part_files(storage) -> dict[str, dict[int, str]]:
    """Parts per scenario: {scenario: {episode: relative path}}."""
    return {scenario: {e: rel for e, (rel, _) in eps.items()} for scenario, eps in part_listing(storage).items()}


def index_files(storage) -> dict[str, str]:
    """Index files per scenario: {scenario: relative path}."""
    return {scenario: rel for scenario, (rel, _) in index_listing(storage).items()}


def index_listing(storage) -> dict[str, tuple[str, int]]:
    """Index files per scenario with their sizes: {scenario: (relative path, bytes)}."""
    indexes = {}
    for rel, size in storage.list_sizes(INDEX_DIR + "/", suffix=".parquet").items():
        match = _INDEX_RE.match(rel)
        if match:
            indexes[match.group("scenario")] = (rel, size)
    return indexes


def done_episodes(root) -> set[tuple[str, int]]:
    """(scenario, episode) of every manifest part present under ``root``."""
    parts = part_files(as_storage(root))
    return {(scenario, episode) for scenario, eps in parts.items() for episode in eps}


def index_episodes(storage, rel: str, size: int | None = None) -> set[int] | None:
    """Episodes a scenario index covers (from its footer), or None if unreadable."""
    meta = _footer(storage, rel, size)
    try:
        return None if meta is None else set(json.loads((meta.metadata or {})[INDEX_EPISODES_KEY]))
    except (KeyError, ValueError, TypeError):
        return None


def _footer(storage, rel: str, size: int | None = None) -> pq.FileMetaData | None:
    """The footer of the Parquet file at ``rel``; None if gone, torn or not Parquet. ``size``: its
    bytes as listed, which spares the HEAD request S3 needs to learn them (one GET of the tail,
    not two requests); a file changed since it was listed is read again the usual way."""
    if size is not None and not storage.is_local:
        try:
            return _parquet_format().make_fragment(storage.path(rel), storage.filesystem, file_size=size).metadata
        except Exception:  # rewritten since the listing, or damaged: as below
            pass
    try:
        with storage.filesystem.open_input_file(storage.path(rel)) as f:
            return pq.read_metadata(f)
    except Exception:  # gone, torn or not Parquet: the caller treats it as absent
        return None


def part_summary(storage, rel: str, size: int) -> PartSummary | None:
    """The summary of the part at ``rel`` (listed with ``size`` bytes); None if unreadable."""
    meta = _footer(storage, rel, size)
    if meta is None:
        return None
    summary = summary_of_footer(meta, size)
    if summary is None:  # a part written without statistics: read the few columns
        try:
            with storage.filesystem.open_input_file(storage.path(rel)) as f:
                summary = summary_of_table(pq.read_table(f, columns=list(_SUMMARY_COLUMNS)), size)
        except Exception:
            return None
    return summary


def _recorded(meta: dict) -> dict[int, PartSummary] | None:
    try:
        return dict(PartSummary.from_json(item) for item in json.loads(meta[INDEX_PARTS_KEY]))
    except (KeyError, ValueError, TypeError):
        return None


def index_summaries(storage, rel: str, size: int | None = None) -> dict[int, PartSummary] | None:
    """The parts an index was built from, per episode; None if unreadable or
    written before indexes recorded them (such an index is never used)."""
    meta = _footer(storage, rel, size)
    return None if meta is None else _recorded(meta.metadata or {})


def _is_current(summaries: dict[int, PartSummary] | None, listed: dict[int, tuple[str, int]]) -> bool:
    """An index is current while it was built from exactly the parts listed now, size for size."""
    return summaries is not None and {e: s.size for e, s in summaries.items()} == {e: size for e, (_, size) in listed.items()}


FOOTER_THREADS = 32  # footers read at once (one small ranged read each on S3)


@dataclass
class ManifestScan:
    """What a root's manifest holds now, from one listing and the footers."""

    parts: dict[str, dict[int, tuple[str, int]]]  # {scenario: {episode: (path, bytes)}}
    indexes: dict[str, str]  # every index file present
    current: dict[str, dict[int, PartSummary]]  # scenarios whose index is current: its summaries
    legacy: list[str] = field(default_factory=list)  # indexes older versions left inside manifest/, shadowed parts

    def summaries(self, storage, threads: int = FOOTER_THREADS, read=part_summary) -> dict[tuple[str, int], PartSummary | None]:
        """Every part's summary: from its scenario's index where that is current, else
        ``read(storage, rel, size)`` from the part's own footer (None: unreadable, so not done)."""
        found: dict[tuple[str, int], PartSummary | None] = {}
        unindexed = []
        for scenario, episodes in self.parts.items():
            if scenario in self.current:
                found.update(((scenario, e), s) for e, s in self.current[scenario].items())
            else:
                unindexed.extend(((scenario, e), item) for e, item in episodes.items())
        found.update(zip((k for k, _ in unindexed), _read_all(storage, read, [item for _, item in unindexed], threads)))
        return found


def _read_all(storage, read, items: list[tuple[str, int]], threads: int) -> list:
    """``read(storage, rel, size)`` of every item, in order: in processes where many local
    footers are read (``manifests.footer_pool``), else in threads on S3 (hiding its
    latency) and in this thread on local disk (where threads only contend for the GIL)."""
    processes = footer_pool.processes_for(storage, len(items))
    done = footer_pool.read_in_processes(storage, read, items, processes) if processes else None
    if done is not None:
        return done
    if storage.is_local:
        return [read(storage, *item) for item in items]
    with ThreadPoolExecutor(max_workers=threads) as pool:  # one small read per part: many at once on S3
        return list(pool.map(lambda item: read(storage, *item), items))


def scan(root) -> ManifestScan:
    """List the manifest and read each index's footer (in parallel): which indexes are current."""
    storage = as_storage(root)
    with ThreadPoolExecutor(max_workers=2) as pool:
        listing = pool.submit(_manifest_listing, storage)
        indexes = index_listing(storage)
        parts, legacy = listing.result()
    return _scan_listed(storage, dict(parts), legacy, indexes)


def _scan_listed(storage, parts: dict[str, dict[int, tuple[str, int]]], legacy: list[str],
                 indexes: dict[str, tuple[str, int]]) -> ManifestScan:
    """The scan of ``parts`` as listed: each listed index's footer read (in parallel) to say which are current."""
    candidates = sorted(s for s in indexes if s in parts)
    with ThreadPoolExecutor(max_workers=FOOTER_THREADS) as pool:
        recorded = dict(zip(candidates, pool.map(lambda s: index_summaries(storage, *indexes[s]), candidates)))
    current = {s: recorded[s] for s in candidates if _is_current(recorded[s], parts[s])}
    return ManifestScan(parts=parts, indexes={s: rel for s, (rel, _) in indexes.items()}, current=current,
                        legacy=legacy)


def part_summaries(root) -> dict[tuple[str, int], PartSummary | None]:
    """{(scenario, episode): summary} of every part present (None: unreadable)."""
    storage = as_storage(root)
    return scan(storage).summaries(storage)


def episode_frames(root, summaries: dict | None = None) -> dict[tuple[str, int], int]:
    """Frames held by each done episode's part: {(scenario, episode): rows}
    (0 for an unreadable part). Read from a scenario's index where it is
    current, else from each part's footer; ``summaries`` if already scanned."""
    if summaries is None:  # the row counts alone: no footer is searched for statistics
        summaries = _listed_rows(as_storage(root))
    return {key: 0 if s is None else s if isinstance(s, int) else 0 if s.misfiled(*key) else s.rows
            for key, s in summaries.items()}


def _listed_rows(storage) -> dict[tuple[str, int], PartSummary | int | None]:
    """Each part's rows from the listing where its name carries them (every part
    written since counted names): no read at all. A scenario with old names
    is scanned as before: its index where current, else its parts' footers."""
    parts, legacy = _manifest_listing(storage)
    found: dict[tuple[str, int], PartSummary | int | None] = {
        (s, e): named_rows(rel) for s, eps in parts.items() for e, (rel, _) in eps.items()}
    old = sorted({s for (s, _), rows in found.items() if rows is None})
    if old:
        state = _scan_listed(storage, {s: parts[s] for s in old}, legacy, index_listing(storage))
        found.update(state.summaries(storage, read=_part_rows))
    return found


def _kept_beside(parts: dict[str, dict[int, tuple[str, int]]], rel: str) -> tuple[str, int] | None:
    """The part readers use (path, bytes) where ``rel`` is another name of its episode; None
    where ``rel`` is not a part (an index older versions left inside manifest/)."""
    match = PART_RE.match(rel)
    if match is None:
        return None
    return parts.get(match.group("scenario"), {}).get(int(match.group("episode")))


def _holds_its_named_rows(storage, rel: str, size: int) -> bool:
    """Whether the part at ``rel`` is readable and holds the rows its name says (an old name says none)."""
    rows = rows_read(storage, rel, size)
    return rows is not None and named_rows(rel) in (None, rows)


def rows_read(storage, rel: str, size: int | None = None) -> int | None:
    """The rows the part at ``rel`` holds, from its footer (not from its name); None if unreadable."""
    meta = _footer(storage, rel, size)
    return None if meta is None else meta.num_rows


def _part_rows(storage, rel: str, size: int) -> int | None:
    if named_rows(rel) is not None:
        return named_rows(rel)
    meta = _footer(storage, rel, size)
    return None if meta is None else meta.num_rows


def refuse_misfiled(storage, summaries: dict[tuple[str, int], PartSummary | None]) -> None:
    """MisfiledParts naming the parts whose rows belong to another scenario or
    episode (swapped or copied parts): such a root is damaged, not done."""
    wrong = sorted(key for key, s in summaries.items() if isinstance(s, PartSummary) and s.misfiled(*key))
    if wrong:
        names = ", ".join(part_stem(*key) for key in wrong[:3]) + (f" and {len(wrong) - 3} more" if len(wrong) > 3 else "")
        raise MisfiledParts(
            f"{storage.uri}: {len(wrong)} manifest part(s) hold the rows of another scenario or episode ({names}); "
            f"`idda verify {storage.uri}` lists them, `idda produce ... --repair` renders those episodes again"
        )


def _refuse_misfiled_fragments(storage, part_ds: ds.Dataset, rels: list[str]) -> None:
    """MisfiledParts naming the parts (of those read without an index) whose rows name another
    scenario or episode than their names: a swapped or copied part would give another
    scenario's frames twice. Each footer is read once and kept for the scan that follows."""
    by_path = {storage.path(rel): rel for rel in rels}

    def misfiled(fragment) -> str | None:
        try:
            fragment.ensure_complete_metadata()
            summary = summary_of_footer(fragment.metadata, 0)
        except (pa.ArrowException, OSError):  # damaged: the scan names it (scan_manifest)
            return None
        match = PART_RE.match(by_path[fragment.path])
        wrong = summary is not None and summary.misfiled(match.group("scenario"), int(match.group("episode")))
        return by_path[fragment.path] if wrong else None

    fragments = list(part_ds.get_fragments())
    if storage.is_local:
        found = map(misfiled, fragments)
    else:  # one small read per footer: many at once on S3
        with ThreadPoolExecutor(max_workers=FOOTER_THREADS) as pool:
            found = list(pool.map(misfiled, fragments))
    wrong = sorted(rel for rel in found if rel is not None)
    if wrong:
        raise MisfiledParts(
            f"{storage.join(wrong[0])} holds the rows of another scenario or episode ({len(wrong)} such part(s)): "
            f"not read, the frames would count twice; `idda verify {storage.uri}` lists them, "
            "`idda produce ... --repair` renders those episodes again"
        )


def manifest_files(root) -> list[str]:
    """The files that hold the manifest now: a scenario's index where it is
    current (built from exactly the parts present), else its parts."""
    state = scan(as_storage(root))
    files = []
    for scenario in sorted(state.parts):
        if scenario in state.current:
            files.append(state.indexes[scenario])
        else:
            files.extend(state.parts[scenario][e][0] for e in sorted(state.parts[scenario]))
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
    ds = datasets()
    part_ds = ds.dataset(
        parts,
        partitioning=ds.partitioning(PARTITION_SCHEMA, flavor="hive"),
        partition_base_dir=storage.path(MANIFEST_DIR),
        **common,
    )
    _refuse_misfiled_fragments(storage, part_ds, [rel for rel in files if rel.startswith(MANIFEST_DIR + "/")])
    if not indexes:
        return part_ds
    return ds.dataset([part_ds, ds.dataset(indexes, **common)])


# ------------------------------------------------------------------ indexes ----


def _repeated(value: str, n: int) -> pa.Array:
    """A string column of ``n`` times ``value``, from its buffers: converting Python objects makes pyarrow
    import pandas (0.2 CPU-s), which a fold at the end of a run would otherwise wait for."""
    data = value.encode()
    offsets = np.arange(n + 1, dtype=np.int32) * len(data)
    return pa.StringArray.from_buffers(n, pa.py_buffer(offsets), pa.py_buffer(data * n))


def index_table(parts: list[pa.Table], scenario: str, episodes: list[int], sizes: dict[int, int] | None = None) -> pa.Table:
    """A scenario's index: its parts' rows with the partition columns; in the
    footer, the covered episodes and, given the parts' ``sizes`` (bytes they
    were read from), each part's summary, which says what the index was built
    from."""
    table = pa.concat_tables(parts)
    for key, value in zip(PARTITION_KEYS, split_code(scenario)):
        table = table.append_column(key, _repeated(value, len(table)))
    meta = {INDEX_EPISODES_KEY: json.dumps(episodes).encode()}
    if sizes is not None:
        items = [summary_of_table(part, sizes[e]).to_json(e) for part, e in zip(parts, episodes)]
        meta[INDEX_PARTS_KEY] = json.dumps(items, separators=(",", ":")).encode()
    return table.cast(MANIFEST_SCHEMA).replace_schema_metadata(meta)


def index_bytes(table: pa.Table) -> bytes:
    """Serialise an index deterministically: the same parts give the same bytes
    (whether folded in at once or a few at a time). The rig columns are left out of the index of a
    root whose rig is the default (null in every row), as its parts leave them out."""
    rig_columns = [name for name, _ in RIG_FIELDS if name in table.column_names]
    if rig_columns and all(table.column(name).null_count == len(table) for name in rig_columns):
        table = table.drop_columns(rig_columns)
    sink = io.BytesIO()
    pq.write_table(table.combine_chunks(), sink, compression="zstd", row_group_size=1 << 16, write_page_checksum=True)
    return sink.getvalue()


def _fold(storage, scenario: str, listed: dict[int, tuple[str, int]], index: str | None) -> bytes | None:
    """``scenario``'s index over the parts ``listed``: the rows of its current
    index for every part it was built from that is unchanged, and the rows of
    the other parts, read now. The sizes recorded are those of the bytes read,
    so a part rewritten meanwhile leaves the new index stale, never wrong.
    None where a part holds another scenario's or episode's rows (never indexed)."""
    kept: dict[int, tuple[pa.Table, int]] = {}
    try:
        data = storage.read_bytes(index) if index is not None else None
        recorded = _recorded(pq.read_metadata(arrow_reader(data)).metadata or {}) if data else None
        old = read_part_file(storage, index, MANIFEST_SCHEMA, data=data) if recorded else None
    except (ManifestError, FileNotFoundError, pa.ArrowException, OSError):  # gone or damaged: from the parts alone
        recorded = old = None
    if old is not None:
        old = old.select(PART_SCHEMA.names)
        episode = old.column("episode").to_numpy()
        for e, summary in recorded.items():
            if e in listed and listed[e][1] == summary.size:
                rows = old.filter(episode == e)
                if len(rows) == summary.rows:
                    kept[e] = (rows, summary.size)

    def read(e: int) -> tuple[pa.Table, int]:
        if e in kept:
            return kept[e]
        data = storage.read_bytes(listed[e][0])
        return read_part_file(storage, listed[e][0], PART_SCHEMA, data=data), len(data)

    episodes = sorted(listed)
    with ThreadPoolExecutor(max_workers=FOOTER_THREADS) as pool:  # on S3 many reads at once, not one round trip after another
        read_in = list(pool.map(read, episodes))
    for e, (table, size) in zip(episodes, read_in):
        if e not in kept and summary_of_table(table, size).misfiled(scenario, e):
            log.warning("%s holds the rows of another scenario or episode: %s not indexed", storage.join(listed[e][0]),
                        scenario)
            return None
    sizes = {e: size for e, (_, size) in zip(episodes, read_in)}
    return index_bytes(index_table([table for table, _ in read_in], scenario, episodes, sizes))


def compact(root, scenarios: list[str] | None = None, state: ManifestScan | None = None) -> list[str]:
    """Fold each scenario's new or changed parts into its index, where the index is not current.

    Incremental: the rows of parts an index already holds are taken from it,
    only the other parts are read. Parts stay the source of truth (they are
    the "done" markers); an index records the size of every part it was
    built from and is used only while those are exactly the parts listed, so
    compaction needs no lock: one racing a writer of parts, or another
    compaction, leaves an index that is current or one that readers bypass.
    ``state``: a scan of the root just made (default: one now); indexes
    older versions wrote inside manifest/ (they doubled rows for glob readers)
    are removed, and so are the parts no reader uses beside an episode's
    newer name (the old name a killed writer left). Returns the scenarios whose index was (re)written.
    """
    storage = as_storage(root)
    state = scan(storage) if state is None else state
    for rel in state.legacy:
        kept = _kept_beside(state.parts, rel)
        if kept is not None and not _holds_its_named_rows(storage, *kept):
            log.warning("%s and %s name the same episode, and the one readers use does not hold the rows its name "
                        "says: both kept; `idda verify` names them, `idda produce --repair` renders the episode again",
                        storage.join(rel), storage.join(kept[0]))
            continue
        storage.delete(rel)
    for scenario in set(state.indexes) - set(state.parts):  # every part of it was removed
        storage.delete(state.indexes[scenario])
    written = []
    for scenario in sorted(state.parts if scenarios is None else set(scenarios) & set(state.parts)):
        if scenario in state.current:
            continue
        index_dir, _, index_name = index_path(scenario).rpartition("/")
        storage.remove_stale_temp(index_dir, index_name)  # from a compaction that was killed
        folded = _fold(storage, scenario, state.parts[scenario], state.indexes.get(scenario))
        if folded is not None:
            storage.write_bytes(index_path(scenario), folded)
            written.append(scenario)
    return written


def _readable_files(storage, files: list[str]) -> list[str]:
    """``files`` with each unreadable index swapped for its scenario's parts;
    ManifestError naming an unreadable part."""
    parts = part_files(storage)
    out = []
    for rel in files:
        try:
            read_part_file(storage, rel)
            out.append(rel)
        except (ManifestError, FileNotFoundError) as exc:
            if not rel.startswith(INDEX_DIR + "/"):
                raise ManifestError(f"{exc}; run `idda verify` and `idda produce --repair`") from None
            scenario = _INDEX_RE.match(rel).group("scenario")
            log.warning("ignoring the damaged index %s (%s); reading its parts", storage.join(rel), exc)
            out.extend(parts[scenario][e] for e in sorted(parts.get(scenario, {})))
    return out


def scan_manifest(root, scan):
    """``scan(dataset)`` over the manifest. If the scan fails on a damaged file,
    a damaged index is skipped (its parts are read instead) and a damaged part
    raises ManifestError naming it: never an anonymous Arrow error."""
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
