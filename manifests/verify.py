"""Check an output root: its manifest (parts, indexes, run.json) and every
file the manifest lists: missing, corrupt and extra files.

The parts are the source of truth. Each one is read whole with its page
checksums verified, re-encoded and compared byte for byte (when this pyarrow
wrote it), and its rows are checked against its name and against run.json
(resolution, seeds). Each index is rebuilt from its parts and compared byte
for byte. run.json carries a checksum of itself.
"""

from __future__ import annotations

import functools
import io
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Callable

import pyarrow as pa
import pyarrow.parquet as pq

from manifests.catalog import SCENARIO_BY_CODE
from manifests.encoding import RGB_FORMATS
from manifests.outputs import OUTPUTS
from manifests.reader import as_storage, index_bytes, index_episodes, index_files, index_summaries, index_table, part_files
from manifests.root import FRAME_FILE_RE
from manifests.runrecord import RunRecordError, read_record
from manifests.schema import PART_SCHEMA, RUN_FILE, frame_id, frame_path, output_columns
from manifests.spec import episode_seed
from manifests.writer import ManifestError, part_bytes, read_part_file
from storage import StorageError, sha256_bytes

# Problem kinds: missing | corrupt | extra (frame files), bad-part | bad-index | bad-run (the manifest)
EPISODE_KINDS = ("missing", "corrupt", "bad-part")  # the episode must be rendered again


@dataclass(frozen=True)
class Problem:
    kind: str
    path: str  # relative to the output root
    scenario: str | None
    episode: int | None
    detail: str = ""


@dataclass
class VerifyReport:
    files_checked: int = 0
    bytes_checked: int = 0
    seconds: float = 0.0
    problems: list[Problem] = field(default_factory=list)

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


def _episode_of(path: str) -> tuple[str | None, int | None]:
    match = FRAME_FILE_RE.match(path)
    if not match:
        return None, None
    return match.group("scenario"), int(match.group("episode"))


@functools.cache
def _this_writer() -> str:
    """``created_by`` of the Parquet files this pyarrow writes."""
    return pq.read_metadata(io.BytesIO(part_bytes(PART_SCHEMA.empty_table()))).created_by


def part_problem(table: pa.Table, scenario: str, episode: int, config: dict | None) -> str | None:
    """Why a part's rows do not belong to its name (or to run.json's config), or None."""
    n = len(table)
    if n == 0:
        return "no rows"
    col = {name: table.column(name).to_pylist() for name in ("scenario", "episode", "frame", "frame_id", "seed", "width", "height")}
    if set(col["scenario"]) != {scenario} or set(col["episode"]) != {episode}:
        return "rows of another scenario or episode"
    if col["frame"] != list(range(n)) or col["frame_id"] != [frame_id(episode, i) for i in range(n)]:
        return "frames are not numbered 0.." + str(n - 1)
    # the rgb files' format: run.json's (older records: png); without run.json, any one format
    formats = [config.get("rgb_format", RGB_FORMATS[0])] if config is not None else list(RGB_FORMATS)
    for output in OUTPUTS:
        paths = table.column(output_columns(output)[0]).to_pylist()
        if paths == [None] * n:  # an output the run did not ask for
            continue
        if all(paths != [frame_path(scenario, output, f, fmt) for f in col["frame_id"]] for fmt in formats):
            return f"{output} paths do not follow the layout"
    if len(set(col["seed"])) != 1 or len(set(zip(col["width"], col["height"]))) != 1:
        return "mixed seeds or resolutions"
    if config is not None:
        if (col["width"][0], col["height"][0]) != (config["width"], config["height"]):
            return f"frames are {col['width'][0]}x{col['height'][0]}, run.json says {config['width']}x{config['height']}"
        if col["seed"][0] != episode_seed(config["seed"], SCENARIO_BY_CODE[scenario], episode):
            return f"episode seed does not derive from run.json's seed {config['seed']}"
    return None


def _check_part(storage, rel: str, scenario: str, episode: int, config: dict | None) -> tuple[pa.Table | None, Problem | None]:
    try:
        data = storage.read_bytes(rel)
        table = read_part_file(storage, rel, PART_SCHEMA, data=data)
    except (ManifestError, StorageError, OSError) as exc:
        return None, Problem("bad-part", rel, scenario, episode, str(exc))
    detail = part_problem(table, scenario, episode, config)
    if detail is None and pq.read_metadata(io.BytesIO(data)).created_by == _this_writer() and part_bytes(table) != data:
        detail = "its bytes differ from its own rows re-encoded (damaged metadata)"
    if detail is not None:
        return None, Problem("bad-part", rel, scenario, episode, detail)
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
    rebuilt = index_bytes(index_table([good[(scenario, e)] for e in eps], scenario, eps, sizes))  # parts already read
    try:
        same = storage.read_bytes(rel) == rebuilt
    except (ManifestError, StorageError, OSError) as exc:
        return Problem("bad-index", rel, scenario, None, str(exc))
    return None if same else Problem("bad-index", rel, scenario, None, "differs from the index rebuilt from its parts")


def verify(root, threads: int = 8, progress: Callable[[int, int], None] | None = None) -> VerifyReport:
    """Check the manifest itself, recompute every checksum it lists, look for strays.

    ``progress(files_done, files_total)`` is called as files are checked.
    """
    storage = as_storage(root)
    start = time.perf_counter()
    report = VerifyReport()
    parts = part_files(storage)

    config = None
    try:
        record = read_record(storage)
        if record is None and parts:
            report.problems.append(Problem("bad-run", RUN_FILE, None, None, "missing"))
        config = record["config"] if record else None
    except RunRecordError as exc:
        report.problems.append(Problem("bad-run", RUN_FILE, None, None, str(exc)))

    good: dict[tuple[str, int], pa.Table] = {}  # parts that passed, by (scenario, episode)
    for scenario in sorted(parts):
        for episode, rel in sorted(parts[scenario].items()):
            table, problem = _check_part(storage, rel, scenario, episode, config)
            if problem is not None:
                report.problems.append(problem)
            else:
                good[(scenario, episode)] = table
    for scenario, rel in sorted(index_files(storage).items()):
        problem = _check_index(storage, rel, scenario, parts.get(scenario), good)
        if problem is not None:
            report.problems.append(problem)

    expected: list[tuple[str, int, str, str, int]] = []
    for table in good.values():
        scenarios, episodes = table.column("scenario").to_pylist(), table.column("episode").to_pylist()
        for output in OUTPUTS:
            path_col, bytes_col, sha_col = output_columns(output)
            rows = zip(*(table.column(c).to_pylist() for c in (path_col, bytes_col, sha_col)), scenarios, episodes)
            expected.extend(row for row in rows if row[0] is not None)

    def check(item) -> Problem | int:
        rel, size, sha, scenario, episode = item
        try:
            data = storage.read_bytes(rel)
        except FileNotFoundError:
            return Problem("missing", rel, scenario, episode)
        except (StorageError, OSError) as exc:  # a directory or a FIFO in its place, an I/O error
            return Problem("corrupt", rel, scenario, episode, str(exc))
        if len(data) != size or sha256_bytes(data) != sha:
            return Problem("corrupt", rel, scenario, episode, f"{len(data)} bytes, expected {size}")
        return len(data)

    total = len(expected)
    with ThreadPoolExecutor(max_workers=threads) as pool:
        for i, outcome in enumerate(pool.map(check, expected), 1):
            report.files_checked += 1
            if isinstance(outcome, Problem):
                report.problems.append(outcome)
            else:
                report.bytes_checked += outcome
            if progress is not None and (i % 256 == 0 or i == total):
                progress(i, total)

    listed = {item[0] for item in expected}
    for rel in storage.list_files():
        if rel.split("/", 1)[0] in SCENARIO_BY_CODE and rel not in listed and FRAME_FILE_RE.match(rel):
            s, e = _episode_of(rel)
            report.problems.append(Problem("extra", rel, s, e, "not in the manifest"))
    report.seconds = time.perf_counter() - start
    return report
