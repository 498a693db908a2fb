"""Plans as Parquet: one row per episode, the config in the file metadata."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from manifests.schema import PLAN_CONFIG_KEY, PLAN_SCHEMA
from pipeline.planner import Plan, make_plan
from pipeline.settings import PlanConfig, recorded


def plan_table(plan: Plan) -> pa.Table:
    columns: dict[str, list] = {name: [] for name in PLAN_SCHEMA.names}
    for e in plan.episodes:
        row = {
            "scenario": e.scenario,
            "town": e.town,
            "weather": e.weather,
            "viewpoint": e.viewpoint,
            "episode": e.episode,
            "frames": e.frames,
            "seed": e.seed,
            "split": e.split,
            "width": e.width,
            "height": e.height,
        }
        for key, value in row.items():
            columns[key].append(value)
    meta = {PLAN_CONFIG_KEY: json.dumps(plan.config.to_dict(), sort_keys=True).encode()}
    return pa.table(columns, schema=PLAN_SCHEMA.with_metadata(meta))


def write_plan(plan: Plan, path: str | os.PathLike) -> None:
    """Write atomically: a reader never sees half a plan."""
    path = Path(path)
    if path.parent and not path.parent.exists():
        raise ValueError(f"cannot write plan to {path}: directory {path.parent} does not exist")
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        pq.write_table(plan_table(plan), tmp)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def read_plan(path: str | os.PathLike) -> Plan:
    """Re-create the plan from its recorded config, and check the rows agree."""
    table = pq.read_table(path)
    meta = table.schema.metadata or {}
    if PLAN_CONFIG_KEY not in meta:
        raise ValueError(f"{path} is not an idda plan (no {PLAN_CONFIG_KEY.decode()} metadata)")
    plan = make_plan(PlanConfig(**recorded(json.loads(meta[PLAN_CONFIG_KEY]))))
    if not plan_table(plan).equals(table.replace_schema_metadata(plan_table(plan).schema.metadata)):
        raise ValueError(f"{path}: rows do not match the plan its config describes")
    return plan
