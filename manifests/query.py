"""Select frames from a manifest and draw seeded, stratified samples.

Filters: domains (the selection grammar; none given: every scenario the root
holds, whatever the catalog it was made with), split, episode, class presence,
minimum class share and the per-frame conditions (``domains.conditions``:
a minimum or maximum of e.g. visibility_m; rows without conditions, from older
roots, never pass one). Sampling: N frames per scenario, or N in total spread
over scenarios in proportion to what each has. Presets give the paper's
"best case" and "worst case" subsets.
"""

from __future__ import annotations

import io
import json
import math
from collections import Counter
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from domains.catalog import ALL_SCENARIOS, AXES, NAME2LABEL, class_id, lookup, scenario, weather
from domains.conditions import check_condition, with_visibility
from domains.rigs import DEFAULT_RIG, NAME_RE
from outputs.table import OUTPUTS
from manifests.reader import datasets
from manifests.schema import output_columns
from domains.selection import parse_selection

if TYPE_CHECKING:
    import pyarrow.dataset as ds

SPLITS = ("train", "val", "test")
SPLIT_SHARES = (0.8, 0.1, 0.1)  # each scenario tends to these shares of episodes (pipeline.planner.SPLIT_PATTERN)


@dataclass(frozen=True)
class Query:
    domains: str | None = None  # selection grammar, as for --domains; None: every scenario the root holds
    splits: tuple[str, ...] = ()  # empty: any split
    episodes: tuple[int, ...] = ()  # empty: any episode
    sensors: tuple[str, ...] = ()  # empty: any sensor of the root's rig (domains.rigs; the default rig's camera: front)
    classes: tuple[str, ...] = ()  # each frame must contain all of these
    min_share: tuple[tuple[str, float], ...] = ()  # (class, minimum share in [0, 1])
    min_condition: tuple[tuple[str, float], ...] = ()  # (condition column, minimum value), inclusive
    max_condition: tuple[tuple[str, float], ...] = ()  # (condition column, maximum value), inclusive
    paired: tuple[str, ...] = ()  # weathers: keep frames present under all of them (the same scene), aligned
    per_scenario: int | None = None  # sample this many frames per scenario
    total: int | None = None  # or this many in total, stratified by scenario
    seed: int = 0

    def validate(self) -> None:
        if self.domains is not None:
            parse_selection(self.domains)
        for split in self.splits:
            if split not in SPLITS:
                raise ValueError(f"unknown split {split!r}; valid splits: {', '.join(SPLITS)}")
        for name in self.sensors:
            if not NAME_RE.match(name):
                raise ValueError(f"sensor {name!r} is not a sensor name (lower-case letters and digits)")
        for name in self.classes:
            class_id(name)
        for name, share in self.min_share:
            class_id(name)
            if not 0.0 <= share <= 1.0:
                raise ValueError(f"minimum share of {name} must be in [0, 1], got {share}")
        for name, value in self.min_condition + self.max_condition:
            check_condition(name)
            if not math.isfinite(value):
                raise ValueError(f"the bound on {name} must be a finite number, got {value}")
        for code in self.paired:
            weather(code)
        if len(set(self.paired)) != len(self.paired) or len(self.paired) == 1:
            raise ValueError(f"pairs need two or more different weathers, got {', '.join(self.paired)}")
        if self.paired and (self.per_scenario is not None or self.total is not None):
            raise ValueError("pairs are whole: give either weathers to pair or a sample size, not both")
        if self.per_scenario is not None and self.total is not None:
            raise ValueError("give either a per-scenario or a total sample size, not both")
        for label, n in (("per-scenario sample", self.per_scenario), ("total sample", self.total)):
            if n is not None and n < 1:
                raise ValueError(f"{label} size must be at least 1, got {n}")
        if self.seed < 0:
            raise ValueError(f"seed must be non-negative, got {self.seed}")


# The paper's subsets (shared/REFERENCE.md): 2,496 frames from each of
# T01-T06 x {A, M} x CN, and 40,128 frames from T07 x {J, B} x HRN.
PRESETS: dict[str, Query] = {
    "best-case": Query(domains="towns=T01-T06 weathers=CN viewpoints=A,M", per_scenario=2_496),
    "worst-case": Query(domains="towns=T07 weathers=HRN viewpoints=J,B", total=40_128),
}


def preset(name: str, **overrides) -> Query:
    base = lookup(PRESETS, name, "preset")
    return replace(base, **{k: v for k, v in overrides.items() if v is not None})


@dataclass
class QueryResult:
    table: pa.Table  # the chosen frames, sorted by scenario, episode, frame
    matched: int  # frames that passed the filters, before sampling
    shortfall: dict[str, int] = field(default_factory=dict)  # scenario -> frames missing from the sample
    split_apart: int = 0  # paired queries: frames left out whose weathers lie in different splits


def _partition_filter(query: Query) -> ds.Expression:
    ds = datasets()
    expr = ds.scalar(True)
    if query.domains is not None:
        chosen = parse_selection(query.domains)
        expr = ds.field("scenario").isin(sorted({s.code for s in chosen}))
        for key in AXES:
            values = sorted({getattr(s, key).code for s in chosen})
            expr = expr & ds.field(key).isin(values)
    if query.splits:
        expr = expr & ds.field("split").isin(list(query.splits))
    if query.episodes:
        expr = expr & ds.field("episode").isin(list(query.episodes))
    return expr


def filter_frames(table_or_dataset, query: Query) -> pa.Table:
    """Frames matching the query's filters (no sampling)."""
    query.validate()
    expr = _partition_filter(query)
    if isinstance(table_or_dataset, pa.Table):
        table = table_or_dataset.filter(expr)
    else:
        table = table_or_dataset.to_table(filter=expr)
    if query.sensors:  # null: a root of the default rig, whose one camera is front
        named = pc.fill_null(table.column("sensor"), DEFAULT_RIG) if "sensor" in table.column_names \
            else pa.array([DEFAULT_RIG] * len(table))
        table = table.filter(pc.is_in(named, value_set=pa.array(list(query.sensors))))
    if query.classes or query.min_share:
        pixels = pc.multiply(table.column("width"), table.column("height"))
        mask = pa.array(np.ones(len(table), dtype=bool))
        for name in query.classes:
            mask = pc.and_(mask, pc.greater(table.column(NAME2LABEL[name].column), 0))
        for name, share in query.min_share:
            frac = pc.divide(pc.cast(table.column(NAME2LABEL[name].column), pa.float64()), pc.cast(pixels, pa.float64()))
            mask = pc.and_(mask, pc.greater_equal(frac, share))
        table = table.filter(mask)
    if query.min_condition or query.max_condition:
        table = with_visibility(table)  # roots made before rules: from their fog_density
        mask = pa.array(np.ones(len(table), dtype=bool))
        for bounds, compare in ((query.min_condition, pc.greater_equal), (query.max_condition, pc.less_equal)):
            for name, value in bounds:
                passed = compare(pc.cast(table.column(name), pa.float64()), value)
                mask = pc.and_(mask, pc.fill_null(passed, False))  # null: a row from before the columns
        table = table.filter(mask)
    return table.sort_by([("scenario", "ascending"), ("episode", "ascending"), ("frame", "ascending")])


FRAME_KEY = ("scenario", "episode", "frame")  # one frame; a rig's root has a row per sensor of each


def count_frames(table: pa.Table) -> int:
    """The frames ``table`` holds: its distinct (scenario, episode, frame). In a root of the default rig a row is
    a frame; in a rig's root a row is a sensor frame, and every sensor of the rig sees every frame."""
    return sum(frames_per_scenario(table).values())


def frames_per_scenario(table: pa.Table) -> dict[str, int]:
    """The frames ``table`` holds per scenario (``count_frames`` of each), in any row order."""
    if len(table) == 0:
        return {}
    frames = table.select(list(FRAME_KEY)).group_by(list(FRAME_KEY)).aggregate([])
    counts = frames.group_by("scenario").aggregate([("scenario", "count")])
    return dict(zip(counts.column("scenario").to_pylist(), counts.column("scenario_count").to_pylist()))


def frame_runs(table: pa.Table) -> tuple[np.ndarray, np.ndarray]:
    """Where each frame's rows start and end in ``table`` (sorted by scenario, episode, frame, as
    ``filter_frames`` leaves it): one row each in a root of the default rig, one per sensor in a rig's root."""
    n = len(table)
    if n == 0 or "sensor" not in table.column_names or table.column("sensor").null_count == n:
        return np.arange(n), np.arange(1, n + 1)
    keys = [table.column(k).to_numpy(zero_copy_only=False) for k in FRAME_KEY]
    new = np.ones(n, dtype=bool)
    new[1:] = np.logical_or.reduce([k[1:] != k[:-1] for k in keys])
    firsts = np.flatnonzero(new)
    return firsts, np.append(firsts[1:], n)


def count_held(dataset: ds.Dataset) -> tuple[int, int]:
    """The frames and the manifest rows (sensor frames) a root's manifest dataset holds."""
    rows = dataset.count_rows()
    if "sensor" not in dataset.schema.names:
        return rows, rows
    return count_frames(dataset.to_table(columns=list(FRAME_KEY))), rows


def rig_sensors(table: pa.Table) -> tuple[str, ...]:
    """The sensors whose rows ``table`` holds, in their first row's order; () in a root of the default rig."""
    if "sensor" not in table.column_names:
        return ()
    return tuple(dict.fromkeys(s for s in table.column("sensor").to_pylist() if s is not None))


def _allocate(total: int, available: dict[str, int]) -> dict[str, int]:
    """Spread ``total`` over scenarios in proportion to their frames (largest remainder)."""
    pool = sum(available.values())
    if total >= pool:
        return dict(available)
    exact = {k: total * v / pool for k, v in available.items()}
    counts = {k: math.floor(x) for k, x in exact.items()}
    order = sorted(available, key=lambda k: (exact[k] - counts[k], k), reverse=True)
    for k in order[: total - sum(counts.values())]:
        counts[k] += 1
    return counts


PAIR_KEY = ("town", "viewpoint", "episode", "frame")  # what a frame's paired frames share


def paired_frames(table: pa.Table, weathers: tuple[str, ...]) -> tuple[pa.Table, int]:
    """The rows of ``table`` (manifest rows) whose frame is present under every one of ``weathers``
    with the same episode seed (the same scene: a paired root, roots.episode_spec) and in the same split,
    sorted so each group of len(weathers) rows is one frame (in a rig's root: one sensor's frame, the
    sensors in the rig's order) under the weathers in the order given; and how many frames present under
    every weather were left out because their weathers lie in different splits (a paired root made before
    splits were drawn per scene: pipeline.planner)."""
    table = table.filter(pc.is_in(table.column("weather"), pa.array(list(weathers))))
    if len(table) == 0:
        return table, 0
    sensors = rig_sensors(table)  # a rig's root: a row per sensor of each frame, paired sensor by sensor
    sensor_rank = ([sensors.index(s) for s in table.column("sensor").to_pylist()] if sensors
                   else [0] * len(table))
    scenes = list(zip(*(table.column(k).to_pylist() for k in (*PAIR_KEY, "seed")), sensor_rank))
    keys = [(*scene, split) for scene, split in zip(scenes, table.column("split").to_pylist())]
    present = Counter(keys)  # one row per weather: (town, viewpoint, episode, frame, sensor) is unique per scenario
    whole = Counter(scenes)
    apart = sum(1 for scene, n in whole.items() if n == len(weathers)) - sum(
        1 for n in present.values() if n == len(weathers))
    if sensors:  # counted in frames, as everywhere: a frame's sensors lie apart together
        apart //= len(sensors)
    keep = pa.array([present[k] == len(weathers) for k in keys], pa.bool_())
    rank = pa.array([weathers.index(w) for w in table.column("weather").to_pylist()], pa.int32())
    table = table.append_column("_sensor", pa.array(sensor_rank, pa.int32())).append_column("_rank", rank).filter(keep)
    order = [(k, "ascending") for k in (*PAIR_KEY, "_sensor", "_rank")]
    return table.sort_by(order).drop_columns(["_sensor", "_rank"]), apart


def run_query(table_or_dataset, query: Query) -> QueryResult:
    """Filter, then draw the seeded stratified sample the query asks for (or keep the pairs asked for)."""
    table = filter_frames(table_or_dataset, query)
    if query.paired:
        table, apart = paired_frames(table, query.paired)
        return QueryResult(table, count_frames(table), split_apart=apart)  # a rig's root: frames, not rows
    firsts, ends = frame_runs(table)  # the draws are of frames; a rig's frame brings every sensor's row
    matched = len(firsts)
    if query.per_scenario is None and query.total is None:
        return QueryResult(table, matched)
    scenarios = table.column("scenario").to_numpy(zero_copy_only=False)[firsts]
    codes, starts, sizes = np.unique(scenarios, return_index=True, return_counts=True)
    available = dict(zip(codes.tolist(), sizes.tolist()))
    if query.per_scenario is not None:
        # Every selected scenario is a stratum, also those with no frames yet.
        for s in parse_selection(query.domains) if query.domains is not None else ():
            available.setdefault(s.code, 0)
        want = {k: query.per_scenario for k in available}
    else:
        want = _allocate(query.total, available)
    builtin_index = {s.code: i for i, s in enumerate(ALL_SCENARIOS)}

    def stratum(code: str) -> list[int]:  # a built-in scenario's draw never depends on user entries
        i = builtin_index.get(code)
        return [i] if i is not None else [len(ALL_SCENARIOS), *scenario(code).key]

    picks = []
    shortfall = {}
    for code, start, size in zip(codes.tolist(), starts.tolist(), sizes.tolist()):
        n = min(want.get(code, 0), size)
        rng = np.random.default_rng([query.seed, *stratum(code)])
        picks.append(start + np.sort(rng.choice(size, size=n, replace=False)))
    for code, n in want.items():
        have = available.get(code, 0)
        if n > have:
            shortfall[code] = n - have
    chosen = np.concatenate(picks) if picks else np.array([], dtype=np.int64)
    index = np.concatenate([np.arange(firsts[i], ends[i]) for i in chosen] or [np.array([], dtype=np.int64)]) \
        if len(firsts) < len(table) else chosen
    if query.total is not None and sum(want.values()) < query.total:
        shortfall["(total)"] = query.total - sum(want.values())
    return QueryResult(table.take(pa.array(index, type=pa.int64())), matched, shortfall)


# ------------------------------------------------------------- writers ----
def _file_list(table: pa.Table, outputs: tuple[str, ...]) -> bytes:
    cols = [table.column(output_columns(o)[0]).to_pylist() for o in outputs]
    return "".join(" ".join(paths) + "\n" for paths in zip(*cols)).encode()


def _csv(table: pa.Table, outputs: tuple[str, ...]) -> bytes:
    """Every manifest column, as in Parquet (``outputs`` only shapes file lists); list columns
    (``K``, the poses) as JSON arrays, e.g. ``"[1.0, 0.0, ...]"``."""
    import pyarrow.csv as pcsv

    for i, field in enumerate(table.schema):
        if pa.types.is_list(field.type) or pa.types.is_fixed_size_list(field.type):
            text = [None if v is None else json.dumps(v) for v in table.column(i).to_pylist()]
            table = table.set_column(i, field.name, pa.array(text, pa.string()))
    sink = io.BytesIO()
    pcsv.write_csv(table, sink, pcsv.WriteOptions(quoting_style="needed"))
    return sink.getvalue()


def _parquet(table: pa.Table, outputs: tuple[str, ...]) -> bytes:
    import pyarrow.parquet as pq

    sink = io.BytesIO()
    pq.write_table(table, sink, compression="zstd")
    return sink.getvalue()


WRITERS = {"list": _file_list, "csv": _csv, "parquet": _parquet}
FORMAT_BY_SUFFIX = {".txt": "list", ".lst": "list", ".csv": "csv", ".parquet": "parquet"}


def encode_result(table: pa.Table, fmt: str, outputs: tuple[str, ...] = ("rgb", "semantic_raw")) -> bytes:
    """Serialise a query result: a file list (the ``outputs``' root-relative
    paths, one frame per line), or CSV / Parquet (all manifest columns)."""
    if fmt not in WRITERS:
        raise ValueError(f"unknown output format {fmt!r}; valid formats: {', '.join(WRITERS)}")
    for o in outputs:
        if o not in OUTPUTS:
            raise ValueError(f"unknown output {o!r}; valid outputs: {', '.join(OUTPUTS)}")
    return WRITERS[fmt](table, outputs)
