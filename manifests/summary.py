"""A manifest part in a few numbers (``PartSummary``), from its rows or from its
footer's statistics alone: what resume, status and the run.json checks need
of a part, with no row decoded. The reader (``manifests.reader``) reads the
footers and indexes that hold them."""

from __future__ import annotations

from dataclasses import dataclass

import pyarrow as pa
import pyarrow.parquet as pq

from manifests.schema import PART_SCHEMA
from outputs.table import file_of_path

# ---------------------------------------------------------------- summaries ----
# What resume, status and the run.json checks need of a part, read from its
# footer (row count and column statistics) without decoding a row, and carried
# by the scenario's index for every part it covers: so a scan is O(parts), and
# O(scenarios) reads where the indexes are current.


@dataclass(frozen=True)
class PartSummary:
    """One part in a few numbers: its size in bytes (what the listing shows) and rows,
    and the distinct seeds, resolutions and rgb file formats its rows hold."""

    size: int
    rows: int
    seeds: tuple[int, ...]
    resolutions: tuple[tuple[int, int], ...]
    rgb: tuple[str, ...]  # FORMATS keys of its rgb files; () without the rgb output
    # the distinct scenarios and episodes its rows name (None: recorded by an older index, unknown)
    scenarios: tuple[str, ...] | None = None
    episodes: tuple[int, ...] | None = None

    def to_json(self, episode: int) -> list:
        return [episode, self.size, self.rows, list(self.seeds), [list(r) for r in self.resolutions], list(self.rgb),
                list(self.scenarios or ()), list(self.episodes or ())]

    @classmethod
    def from_json(cls, item: list) -> tuple[int, PartSummary]:
        episode, size, rows, seeds, resolutions, rgb, *names = item  # indexes before 2026-11 lack the names
        scenarios, episodes = (tuple(names[0]), tuple(names[1])) if len(names) == 2 else (None, None)
        return int(episode), cls(int(size), int(rows), tuple(seeds), tuple(tuple(r) for r in resolutions), tuple(rgb),
                                 scenarios, episodes)

    def misfiled(self, scenario: str, episode: int) -> bool:
        """Whether its rows name another scenario or episode than the part's path
        (a part copied or swapped into the wrong place)."""
        return (self.scenarios is not None and self.scenarios not in ((), (scenario,))) or (
            self.episodes is not None and self.episodes not in ((), (episode,)))


_SUMMARY_COLUMNS = ("seed", "width", "height", "rgb_path", "scenario", "episode")
_SUMMARY_AT = {name: PART_SCHEMA.get_field_index(name) for name in _SUMMARY_COLUMNS}  # where a part has them


def _summary(size: int, rows: int, bounds: dict[str, tuple]) -> PartSummary:
    """From each summary column's (min, max); (None, None) for an all-null column."""
    def distinct(values) -> tuple:
        return tuple(sorted(set(v for v in values if v is not None)))

    (w0, w1), (h0, h1) = bounds["width"], bounds["height"]
    return PartSummary(
        size=size,
        rows=rows,
        seeds=distinct(bounds["seed"]),
        resolutions=distinct([(w0, h0), (w1, h1)] if rows else []),
        rgb=distinct(file_of_path("rgb", p) if p is not None else None for p in bounds["rgb_path"]),
        scenarios=distinct(bounds["scenario"]),
        episodes=distinct(bounds["episode"]),
    )


def summary_of_table(table: pa.Table, size: int) -> PartSummary:
    """A part's summary from its rows (``size``: the bytes it was read from)."""
    import pyarrow.compute as pc

    bounds = {}
    for name in _SUMMARY_COLUMNS:
        column = table.column(name)
        if column.null_count == len(column):
            bounds[name] = (None, None)
        else:
            found = pc.min_max(column)
            bounds[name] = (found["min"].as_py(), found["max"].as_py())
    return _summary(size, len(table), bounds)


def summary_of_footer(meta: pq.FileMetaData, size: int) -> PartSummary | None:
    """A part's summary from its footer's statistics; None where they are missing."""
    schema = meta.schema
    at = {name: i if i < len(schema) and schema.column(i).name == name else schema.names.index(name)
          for name, i in _SUMMARY_AT.items()}
    bounds: dict[str, tuple] = {name: (None, None) for name in _SUMMARY_COLUMNS}
    for g in range(meta.num_row_groups):
        group = meta.row_group(g)
        for name in _SUMMARY_COLUMNS:
            stats = group.column(at[name]).statistics
            if stats is None:
                return None
            if not stats.has_min_max:
                if stats.null_count != group.num_rows:
                    return None
                continue
            lo, hi = bounds[name]
            bounds[name] = (stats.min if lo is None else min(lo, stats.min), stats.max if hi is None else max(hi, stats.max))
    return _summary(size, meta.num_rows, bounds)
