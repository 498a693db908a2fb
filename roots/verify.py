"""Check an output root: its manifest (parts, indexes, run.json) and every
file the manifest lists: missing, corrupt and extra files.

The work is cut into units, one per scenario (``VerifyUnit``: a small frozen
description, never data). ``check_unit`` checks one: it lists the scenario's
folder once (never following a symbolic link), reads the scenario's parts in
scope, hashes the files they list, and looks for strays. ``verify`` runs the
units in this process by default; ``pipeline.verify_ray`` runs the same
function as Ray tasks across a cluster, so both give the same verdicts. The
driver holds the part listing and the problems, never the manifest's rows.

A file missing from the listing is missing without a request, and one whose
listed size is wrong is corrupt without a read: only files that may be
intact are read, once each.

The parts are the source of truth. Each one is read whole with its page
checksums verified, re-encoded and compared byte for byte (when this pyarrow
wrote it), and its rows are checked against its name and against run.json
(resolution, seeds). Each index is rebuilt from its parts and compared byte
for byte. run.json carries a checksum of itself.
"""

from __future__ import annotations

import datetime as dt
import functools
import logging
import re
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Callable, Iterable, Iterator

import pyarrow as pa
import pyarrow.parquet as pq

from domains.catalog import all_scenarios, scenario as lookup_scenario, using
from domains.rigs import DEFAULT_RIG, RigError, rig_named
from outputs.encoding import RGB_FORMATS
from outputs.table import OUTPUTS
from manifests.reader import as_storage, filed_where_named, index_bytes, index_episodes, index_files, index_summaries, index_table
from manifests.layout import LAYOUTS, frame_path, held_layout, match_frame_file, record_layout
from roots.contract import own_top_names, root_entries
from roots.lease import live_producers
from roots.run_file import ConfigShape, RunRecordError, read_record
from manifests.schema import (MANIFEST_DIR, PART_RE, PART_SCHEMA, RUN_FILE, as_plain_lists, frame_id, named_rows,
                              newer_part, output_columns, part_path)
from roots.episode_spec import UNPAIRED, episode_seed
from manifests.part_file import ManifestError, read_part_file
from storage.buffers import arrow_reader
from manifests.writer import part_bytes
from storage import StorageError, sha256_bytes

# Problem kinds: missing | corrupt | extra (frame files), bad-part | bad-index | bad-run (the manifest),
# link (a symbolic link inside the root: never followed, never repaired through)
EPISODE_KINDS = ("missing", "corrupt", "bad-part")  # the episode must be rendered again
LINK_DETAIL = "a symbolic link; verify and repair never follow links"

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Problem:
    kind: str
    path: str  # relative to the output root
    scenario: str | None
    episode: int | None
    detail: str = ""
    conflict: bool = False  # a part whose rows disagree with the run's config (seed, resolution)


@dataclass
class VerifyReport:
    files_checked: int = 0
    bytes_checked: int = 0
    seconds: float = 0.0
    problems: list[Problem] = field(default_factory=list)
    episodes_checked: int = 0
    first_hash_s: float | None = None  # seconds from the start to the first file hashed
    in_progress: set[tuple[str, int]] = field(default_factory=set)  # frames of a live producer, no part yet
    foreign: list[str] = field(default_factory=list)  # files not of the root's layout: listed, not damage

    @property
    def ok(self) -> bool:
        return not self.problems

    def affected_episodes(self) -> set[tuple[str, int]]:
        """Episodes whose files or part must be rendered again."""
        return {(p.scenario, p.episode) for p in self.problems if p.kind in EPISODE_KINDS and p.episode is not None}

    def counts(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for p in self.problems:
            out[p.kind] = out.get(p.kind, 0) + 1
        return out


def _episode_of(path: str, layouts: tuple[int, ...]) -> tuple[str | None, int | None]:
    match = match_frame_file(path, layouts)
    if not match:
        return None, None
    return match.group("scenario"), int(match.group("episode"))


@functools.cache
def _this_writer() -> str:
    """``created_by`` of the Parquet files this pyarrow writes."""
    return pq.read_metadata(arrow_reader(part_bytes(PART_SCHEMA.empty_table()))).created_by


def part_problem(table: pa.Table, scenario: str, episode: int, config: dict | None,
                 layouts: tuple[int, ...] = LAYOUTS) -> str | None:
    """Why a part's rows do not belong to its name (or to run.json's config), or None.
    Its paths must follow one of ``layouts`` (the root's: ``manifests.layout``)."""
    n = len(table)
    if n == 0:
        return "no rows"
    col = {name: table.column(name).to_pylist() for name in ("scenario", "episode", "frame", "frame_id", "seed", "width", "height")}
    if set(col["scenario"]) != {scenario} or set(col["episode"]) != {episode}:
        return "rows of another scenario or episode"
    # a rig's part: one row per sensor frame, frame-major in the rig's order (the sensor column; null: no rig)
    sensors = table.column("sensor").to_pylist() if "sensor" in table.column_names else [None] * n
    order = list(dict.fromkeys(sensors))
    k = len(order)
    if n % k or sensors != order * (n // k) or (k > 1 and None in order):
        return "sensor rows are not in the rig's order, frame by frame"
    frames = n // k
    if col["frame"] != [i for i in range(frames) for _ in order] \
            or col["frame_id"] != [frame_id(episode, i) for i in range(frames) for _ in order]:
        return "frames are not numbered 0.." + str(frames - 1)
    # the rgb files' format: run.json's (older records: png); without run.json, any one format
    formats = [config.get("rgb_format", RGB_FORMATS[0])] if config is not None else list(RGB_FORMATS)
    for output in OUTPUTS:
        paths = table.column(output_columns(output)[0]).to_pylist()
        if paths == [None] * n:  # an output the run did not ask for
            continue
        if not any(_follows(paths, scenario, output, col["frame_id"], sensors, fmt, layout)
                   for fmt in formats for layout in layouts):
            return f"{output} paths do not follow the layout"
    if len(set(col["seed"])) != 1 or len(set(zip(sensors, col["width"], col["height"]))) != k:  # a camera may have its own
        return "mixed seeds or resolutions"
    return config_conflict(part_sizes(table), col["seed"][0], scenario, episode, config)


def _follows(paths: list, scenario: str, output: str, fids: list, sensors: list, fmt: str, layout: int) -> bool:
    """Whether an output's ``paths`` (None: a row without it) are those of ``layout`` in format ``fmt``."""
    try:
        return paths == [p if p is None else frame_path(scenario, output, f, fmt, layout, s or "")
                         for p, f, s in zip(paths, fids, sensors)]
    except ValueError:  # a rig's sensor in the flat layout, which has no place for one: not this layout
        return False


def part_sizes(table: pa.Table) -> dict[str | None, tuple[int, int]]:
    """The image size of each sensor's rows in a part (None: a part of the default rig), from its first rows."""
    sensors = table.column("sensor").to_pylist() if "sensor" in table.column_names else [None] * len(table)
    sizes: dict[str | None, tuple[int, int]] = {}
    for sensor, width, height in zip(sensors, table.column("width").to_pylist(), table.column("height").to_pylist()):
        sizes.setdefault(sensor, (width, height))
    return sizes


def config_conflict(sizes: dict[str | None, tuple[int, int]], seed: int, scenario: str, episode: int,
                    config: dict | None) -> str | None:
    """Why an episode's frames (``sizes``: each sensor's image size, ``part_sizes``) cannot belong to the run
    ``config`` describes, or None. A sensor's size is the run's unless the run's rig gives it its own."""
    if config is None:
        return None
    try:
        rig = rig_named(config.get("rig", DEFAULT_RIG))
    except RigError as exc:
        return f"run.json's rig: {exc}"
    for sensor, (width, height) in sizes.items():
        want = rig.size_of(sensor or "", config["width"], config["height"])
        if (width, height) != want:
            return f"{f'{sensor} ' if sensor else ''}frames are {width}x{height}, run.json says {want[0]}x{want[1]}"
    with using(config.get("catalog")):  # the root's own domain entries (run.json), wherever this runs
        derived = episode_seed(config["seed"], lookup_scenario(scenario), episode, config.get("pairing", UNPAIRED))
    if seed != derived:
        return f"episode seed does not derive from run.json's seed {config['seed']}"
    return None


def _reencoded(table: pa.Table, data: bytes, encode) -> tuple[bytes, ...]:
    """The bytes ``encode(table, plain)`` gives ``table`` (a part's or index's rows read with today's
    schema) in the columns the file ``data`` holds (a root made before rules has no visibility_m):
    as written now, and with plain lists for K and the poses and, for a part, its Arrow schema
    stored (plain True), as files were written before."""
    try:
        own = table.select(pq.read_schema(arrow_reader(data)).names)
    except (KeyError, pa.ArrowException):
        return ()
    return encode(own, False), encode(as_plain_lists(own), True)


def _check_part(storage, rel: str, scenario: str, episode: int, config: dict | None,
                layouts: tuple[int, ...]) -> tuple[pa.Table | None, Problem | None]:
    try:
        data = storage.read_bytes(rel)
        table = read_part_file(storage, rel, PART_SCHEMA, data=data)
    except (ManifestError, StorageError, OSError) as exc:
        return None, Problem("bad-part", rel, scenario, episode, str(exc))
    detail, conflict = part_problem(table, scenario, episode, None, layouts), False  # the part's own shape first
    if detail is None and named_rows(rel) not in (None, len(table)):  # status counts frames from the name
        detail = f"its name says {named_rows(rel)} rows, it holds {len(table)}"
    if detail is None:
        detail = config_conflict(part_sizes(table), table.column("seed")[0].as_py(), scenario, episode, config)
        conflict = detail is not None
    if detail is None and pq.read_metadata(arrow_reader(data)).created_by == _this_writer() \
            and data not in _reencoded(table, data, lambda t, plain: part_bytes(t, store_schema=plain)):
        detail = "its bytes differ from its own rows re-encoded (damaged metadata)"
    if detail is not None:
        return None, Problem("bad-part", rel, scenario, episode, detail, conflict)
    return table, None


def _check_index(storage, rel: str, scenario: str, episodes: dict[int, str] | None,
                 good: dict[tuple[str, int], pa.Table]) -> Problem | None:
    """An index is damaged if it is unreadable, or covers the parts present but
    differs from the index rebuilt from them (a stale index is only unused)."""
    if not episodes:
        return Problem("bad-index", rel, scenario, None, "its scenario has no parts")
    covered = index_episodes(storage, rel)
    if covered is None:
        return Problem("bad-index", rel, scenario, None, "unreadable footer")
    if covered != set(episodes) or not all((scenario, e) in good for e in episodes):
        return None  # stale (or its parts are being repaired): readers ignore it, compaction rewrites it
    eps = sorted(episodes)
    sizes = {e: storage.size(episodes[e]) for e in eps}  # what the index records it was built from
    if {e: p.size for e, p in (index_summaries(storage, rel) or {}).items()} != sizes:
        return None  # built from other parts (or before indexes recorded them): stale, readers ignore it
    rebuilt = index_table([good[(scenario, e)] for e in eps], scenario, eps, sizes)  # parts already read
    try:
        stored = storage.read_bytes(rel)
        same = stored in _reencoded(rebuilt, stored, lambda t, plain: index_bytes(t))
    except (ManifestError, StorageError, OSError) as exc:
        return Problem("bad-index", rel, scenario, None, str(exc))
    return None if same else Problem("bad-index", rel, scenario, None, "differs from the index rebuilt from its parts")




# ------------------------------------------------------------ units ----
@dataclass(frozen=True)
class Scope:
    """What to verify: some scenarios (None: all), and of them the episodes
    whose part was written at or after ``since`` (seconds since the epoch; None: all)."""

    scenarios: frozenset[str] | None = None
    since: float | None = None


@dataclass(frozen=True)
class VerifyUnit:
    """One task: a scenario's episodes in scope. Small and serialisable."""

    scenario: str
    parts: tuple[tuple[int, str], ...]  # (episode, part path) to check
    with_part: frozenset[int]  # every episode of the scenario that has a part
    index: str | None  # the scenario's index, checked when every part is in scope
    since: float | None  # stray files older than this are out of scope
    producer_live: bool  # frames without a part belong to a running producer
    layouts: tuple[int, ...] = LAYOUTS  # the root's file layout (both when run.json cannot tell)
    # (episode, part path): other names of an episode in scope beside the part readers use (``parts``)
    shadowed: tuple[tuple[int, str], ...] = ()


@dataclass
class UnitResult:
    scenario: str
    problems: list[Problem] = field(default_factory=list)
    files_checked: int = 0
    bytes_checked: int = 0
    episodes_checked: int = 0
    in_progress: set[int] = field(default_factory=set)
    foreign: list[str] = field(default_factory=list)
    first_hash_at: float | None = None  # wall-clock time of the unit's first hash


def parse_since(text: str, now: float | None = None) -> float:
    """``--since``: an age (``90s``, ``30m``, ``2h``, ``3d``) or an ISO time
    (``2026-11-25T13:00``, UTC unless it names a zone); seconds since the epoch."""
    now = time.time() if now is None else now
    match = re.fullmatch(r"\s*(\d+(?:\.\d+)?)\s*([smhd])\s*", text)
    if match:
        return now - float(match.group(1)) * {"s": 1, "m": 60, "h": 3600, "d": 86400}[match.group(2)]
    try:
        when = dt.datetime.fromisoformat(text.strip())
    except ValueError:
        raise ValueError(f"--since {text!r} is neither an age (90s, 30m, 2h, 3d) nor an ISO time (2026-11-25T13:00)") from None
    if when.tzinfo is None:
        when = when.replace(tzinfo=dt.timezone.utc)
    return when.timestamp()


def _is_hidden(rel: str) -> bool:
    """A name starting with a dot (an in-flight temp file, OS litter such as .DS_Store): never listed."""
    return rel.rpartition("/")[2].startswith(".")


def _under_link(rel: str, links: list[str]) -> bool:
    return any(rel == link or rel.startswith(link + "/") for link in links)


def check_unit(storage, unit: VerifyUnit, config: dict | None, threads: int = 8,
               on_files: Callable[[int], None] | None = None) -> UnitResult:
    """Check one scenario's parts in scope, hash the files they list, find strays.

    The scenario's folder is listed once (links listed, never followed); files
    behind a link are the link's problem, never read. ``on_files(n)`` is called
    as files are hashed (n since the last call)."""
    result = UnitResult(unit.scenario)
    listing = {entry.rel: entry for entry in storage.walk(unit.scenario)}
    links = sorted(rel for rel, entry in listing.items() if entry.link)
    result.problems.extend(Problem("link", rel, unit.scenario, None, LINK_DETAIL) for rel in links)

    good: dict[tuple[str, int], pa.Table] = {}
    for episode, rel in unit.parts:
        table, problem = _check_part(storage, rel, unit.scenario, episode, config, unit.layouts)
        result.episodes_checked += 1
        if problem is not None:
            result.problems.append(problem)
        else:
            good[(unit.scenario, episode)] = table
    bad = {p.episode: p.path for p in result.problems if p.kind == "bad-part"}
    for episode, rel in unit.shadowed:  # beside a sound part, a name a killed writer left (compaction drops it)
        if episode in bad:  # beside a damaged one (a lying copy): both are named, repair drops both
            result.problems.append(Problem("bad-part", rel, unit.scenario, episode,
                                           f"a second part of this episode, beside the damaged {bad[episode]}"))
    if unit.index is not None:
        paths = dict(unit.parts)
        problem = _check_index(storage, unit.index, unit.scenario,
                               {e: paths.get(e, part_path(unit.scenario, e)) for e in unit.with_part}, good)
        if problem is not None:
            result.problems.append(problem)

    expected: list[tuple[str, int, str, int]] = []
    for (_, episode), table in good.items():
        for output in OUTPUTS:
            path_col, bytes_col, sha_col = output_columns(output)
            rows = zip(*(table.column(c).to_pylist() for c in (path_col, bytes_col, sha_col)))
            expected.extend((rel, size, sha, episode) for rel, size, sha in rows if rel is not None)
    del good

    def check(item) -> Problem | int:
        rel, size, sha, episode = item
        entry = listing.get(rel)
        if entry is None and not storage.is_local:  # not listed: missing, no request needed
            return Problem("missing", rel, unit.scenario, episode)
        if entry is not None and entry.size != size:  # the listing's size: no read needed
            return Problem("corrupt", rel, unit.scenario, episode, f"{entry.size} bytes, expected {size}")
        if result.first_hash_at is None:
            result.first_hash_at = time.time()
        try:  # (locally, what the listing left out is read too: a folder or a FIFO in a file's place)
            data = storage.read_bytes(rel) if entry is None else storage.read_listed(rel, entry.size)
        except FileNotFoundError:
            return Problem("missing", rel, unit.scenario, episode)
        except (StorageError, OSError) as exc:  # a directory or a FIFO in its place, an I/O error
            return Problem("corrupt", rel, unit.scenario, episode, str(exc))
        if len(data) != size or sha256_bytes(data) != sha:
            return Problem("corrupt", rel, unit.scenario, episode, f"{len(data)} bytes, expected {size}")
        return len(data)

    expected = [item for item in expected if not _under_link(item[0], links)]
    pending = 0
    with ThreadPoolExecutor(max_workers=threads) as pool:
        for i, outcome in enumerate(pool.map(check, expected), 1):
            result.files_checked += 1
            if isinstance(outcome, Problem):
                result.problems.append(outcome)
            else:
                result.bytes_checked += outcome
            pending += 1
            if on_files is not None and (pending == 256 or i == len(expected)):
                on_files(pending)
                pending = 0

    _find_strays(unit, listing, {item[0] for item in expected}, result)
    return result


def _find_strays(unit: VerifyUnit, listing: dict, listed: set[str], result: UnitResult) -> None:
    """Frame files of the root's own layout that no part in scope lists: extra, or
    in progress beside a live producer; files of other names are foreign (listed, never ours)."""
    in_scope = {episode for episode, _ in unit.parts}
    for rel, entry in listing.items():
        if entry.link or rel in listed:
            continue
        scenario, episode = _episode_of(rel, unit.layouts)
        if episode is None:
            if not _is_hidden(rel) and (unit.since is None or entry.mtime >= unit.since):
                result.foreign.append(rel)
            continue
        if episode not in in_scope:
            if episode in unit.with_part or (unit.since is not None and entry.mtime < unit.since):
                continue  # out of scope
            if unit.producer_live:  # frames of an episode a live producer is writing
                result.in_progress.add(episode)
                continue
        result.problems.append(Problem("extra", rel, scenario, episode, "not in the manifest"))


def plain_runner(storage, units: list[VerifyUnit], config: dict | None, threads: int,
                 on_files: Callable[[int], None] | None) -> Iterator[UnitResult]:
    """Run the units one after another in this process (the default: small roots, tests)."""
    for unit in units:
        yield check_unit(storage, unit, config, threads, on_files)


Runner = Callable[..., Iterable[UnitResult]]


@dataclass(frozen=True)
class VerifyProgress:
    episodes_done: int
    episodes_total: int
    files_done: int
    elapsed_s: float


def _part_listing(storage, report: VerifyReport) -> tuple[dict[str, dict[int, tuple[str, float]]],
                                                           dict[str, list[tuple[int, str]]]]:
    """Parts per scenario with their modification time, and per scenario the other
    names of an episode beside the part readers use; links under manifest/ become problems."""
    parts: dict[str, dict[int, tuple[str, float]]] = {}
    shadowed: dict[str, list[tuple[int, str]]] = {}
    for entry in storage.walk(MANIFEST_DIR):
        if entry.link:
            report.problems.append(Problem("link", entry.rel, None, None, LINK_DETAIL))
            continue
        match = PART_RE.match(entry.rel)
        if not match and not _is_hidden(entry.rel):
            report.foreign.append(entry.rel)
        elif match and not filed_where_named(entry.rel):  # not the episode's part: a stray file, never read
            report.problems.append(Problem("extra", entry.rel, None, None, "a part filed under another scenario's folder"))
        elif match:
            held = parts.setdefault(match.group("scenario"), {})
            episode = int(match.group("episode"))
            if episode in held:
                other = entry.rel
                if newer_part(entry.rel, held[episode][0]):  # the part readers use
                    other = held[episode][0]
                    held[episode] = (entry.rel, entry.mtime)
                shadowed.setdefault(match.group("scenario"), []).append((episode, other))
            else:
                held[episode] = (entry.rel, entry.mtime)
    return parts, shadowed


def _producer_live(storage, except_owner: str | None) -> bool:
    try:  # only looks: verify never changes the root (dead leases stay for the next producer to remove)
        return bool(live_producers(storage, except_owner=except_owner, take_over=False))
    except (StorageError, OSError):  # leases that cannot be listed: no producer known to be live
        return False


def plan_units(storage, scope: Scope, report: VerifyReport, producer_live: bool,
               layouts: tuple[int, ...] = LAYOUTS) -> list[VerifyUnit]:
    """The units of ``scope``: one per scenario that has parts or a folder."""
    parts, shadowed = _part_listing(storage, report)
    for rel in storage.folders(MANIFEST_DIR):  # a folder named as a part: every write of that part fails
        match = PART_RE.match(rel)
        if match and (scope.scenarios is None or match.group("scenario") in scope.scenarios):
            report.problems.append(Problem("bad-part", rel, match.group("scenario"), int(match.group("episode")),
                                           "a folder where a part file goes"))
    indexes = index_files(storage)
    codes = {s.code for s in all_scenarios()}  # of the catalog in force: the root's (verify)
    top = root_entries(storage)
    folders = {name for name in top if name in codes}
    report.foreign.extend(sorted(set(top) - own_top_names(codes)))
    units = []
    for scenario in sorted(set(parts) | folders | set(indexes)):
        if scope.scenarios is not None and scenario not in scope.scenarios:
            continue
        have = parts.get(scenario, {})
        chosen = tuple((e, rel) for e, (rel, mtime) in sorted(have.items()) if scope.since is None or mtime >= scope.since)
        index = indexes.get(scenario) if len(chosen) == len(have) else None
        others = tuple(sorted((e, rel) for e, rel in shadowed.get(scenario, []) if e in dict(chosen)))
        units.append(VerifyUnit(scenario, chosen, frozenset(have), index, scope.since, producer_live, layouts, others))
    return units


def verify(root, threads: int = 8, progress: Callable[[VerifyProgress], None] | None = None,
           scope: Scope | None = None, config: dict | None = None, runner: Runner | None = None,
           except_owner: str | None = None, shape: ConfigShape | None = None) -> VerifyReport:
    """Check the manifest itself, recompute every checksum it lists, look for strays.

    ``scope`` limits the check to some scenarios and recent episodes;
    ``config`` (a run config as run.json records it) replaces run.json's as
    what the rows must agree with; ``runner`` runs the units (default: in this
    process; ``pipeline.verify_ray.choose_runner`` gives one for Ray).
    Frames without a part while a producer's lease (other than
    ``except_owner``'s) is live are in progress, not strays.
    ``progress(VerifyProgress)`` is called as files are checked. ``shape``: what run.json's config
    may hold (``pipeline.settings.CONFIG_SHAPE``); None checks only the record's frame and checksum.
    """
    storage = as_storage(root)
    start, wall_start = time.perf_counter(), time.time()
    report = VerifyReport()
    scope = scope or Scope()

    recorded, damaged, layouts = None, False, None
    try:
        record = read_record(storage, shape)
        recorded = record["config"] if record else None
        layouts = (record_layout(record),) if record else None
    except RunRecordError as exc:
        report.problems.append(Problem("bad-run", RUN_FILE, None, None, str(exc)))
        damaged = True
    if layouts is None:  # run.json lost or damaged: the layout of the frames the parts list
        held = held_layout(storage)
        layouts = LAYOUTS if held is None else (held,)
    with using((recorded or {}).get("catalog")):  # the root's own domain entries: its folders are scenarios
        units = plan_units(storage, scope, report, _producer_live(storage, except_owner), layouts)
    if recorded is None and not damaged and any(u.with_part for u in units):
        report.problems.append(Problem("bad-run", RUN_FILE, None, None, "missing"))
    episodes_total = sum(len(u.parts) for u in units)
    files_done = 0

    def tell() -> None:
        if progress is not None:
            progress(VerifyProgress(report.episodes_checked, episodes_total, files_done, time.perf_counter() - start))

    def on_files(n: int) -> None:
        nonlocal files_done
        files_done += n
        tell()

    tell()
    first_hash = None
    for result in (runner or plain_runner)(storage, units, config if config is not None else recorded, threads, on_files):
        report.problems.extend(result.problems)
        report.files_checked += result.files_checked
        report.bytes_checked += result.bytes_checked
        report.episodes_checked += result.episodes_checked
        report.in_progress.update((result.scenario, e) for e in result.in_progress)
        report.foreign.extend(result.foreign)
        if result.first_hash_at is not None:
            first_hash = min(first_hash or result.first_hash_at, result.first_hash_at)
        files_done = report.files_checked
        tell()
    report.problems.sort(key=_problem_order)
    report.foreign.sort()
    report.first_hash_s = None if first_hash is None else max(0.0, first_hash - wall_start)
    report.seconds = time.perf_counter() - start
    return report


_KIND_ORDER = {kind: i for i, kind in enumerate(("bad-run", "link", "bad-part", "bad-index", "missing", "corrupt", "extra"))}


def _problem_order(p: Problem) -> tuple:
    """Same order whatever order the units finished in."""
    return (_KIND_ORDER.get(p.kind, len(_KIND_ORDER)), p.scenario or "", p.episode if p.episode is not None else -1, p.path)
