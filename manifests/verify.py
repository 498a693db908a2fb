"""Check an output root against its manifest: missing, corrupt and extra files."""

from __future__ import annotations

import re
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Callable

import pyarrow as pa

from manifests.catalog import OUTPUTS, SCENARIO_BY_CODE
from manifests.reader import as_storage, done_episodes, read_manifest
from manifests.schema import output_columns, part_path
from manifests.writer import read_part
from storage import sha256_bytes

_FRAME_FILE = re.compile(r"^(T\d\d_\w+_\w)/(\w+)/(\d{4})_(\d{3})_(T\d\d_\w+_\w)\.png$")


@dataclass(frozen=True)
class Problem:
    kind: str  # missing | corrupt | extra | bad-part
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
        return {
            (p.scenario, p.episode)
            for p in self.problems
            if p.scenario is not None and p.episode is not None and p.kind != "extra"
        }

    def counts(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for p in self.problems:
            out[p.kind] = out.get(p.kind, 0) + 1
        return out


def _episode_of(path: str) -> tuple[str | None, int | None]:
    match = _FRAME_FILE.match(path)
    if not match:
        return None, None
    return match.group(1), int(match.group(3))


def verify(root, threads: int = 8, progress: Callable[[int, int], None] | None = None) -> VerifyReport:
    """Recompute every checksum the manifest lists and look for strays.

    ``progress(files_done, files_total)`` is called as files are checked.
    """
    storage = as_storage(root)
    start = time.perf_counter()
    report = VerifyReport()

    # Parts that cannot be read are problems in themselves.
    try:
        table = read_manifest(storage)
    except Exception:
        good = []
        for scenario, episode in sorted(done_episodes(storage)):
            try:
                good.append(read_part(storage, scenario, episode))
            except Exception as exc:
                report.problems.append(Problem("bad-part", part_path(scenario, episode), scenario, episode, str(exc)))
        table = pa.concat_tables(good) if good else None
    expected: list[tuple[str, int, str, str, int]] = []
    if table is not None:
        cols = {name: table.column(name).to_pylist() for name in ("scenario", "episode")}
        for output in OUTPUTS:
            path_col, bytes_col, sha_col = output_columns(output)
            paths = table.column(path_col).to_pylist()
            sizes = table.column(bytes_col).to_pylist()
            shas = table.column(sha_col).to_pylist()
            for i, rel in enumerate(paths):
                expected.append((rel, sizes[i], shas[i], cols["scenario"][i], cols["episode"][i]))

    def check(item) -> Problem | int:
        rel, size, sha, scenario, episode = item
        try:
            data = storage.read_bytes(rel)
        except FileNotFoundError:
            return Problem("missing", rel, scenario, episode)
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
        if rel.split("/", 1)[0] in SCENARIO_BY_CODE and rel not in listed:
            s, e = _episode_of(rel)
            report.problems.append(Problem("extra", rel, s, e, "not in the manifest"))
    report.seconds = time.perf_counter() - start
    return report
