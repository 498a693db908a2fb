"""Per-frame condition columns (domains.conditions): in every manifest row, null in older
parts, and filtered on by `idda query --min-condition / --max-condition`."""

import pyarrow as pa
import pytest
from typer.testing import CliRunner

from manifests import query as q
from domains.catalog import weather
from domains.conditions import CONDITION_COLUMNS, CONDITIONS, frame_conditions
from manifests.reader import read_manifest
from manifests.schema import MANIFEST_SCHEMA, part_path
from manifests.synthetic import episode_rows
from manifests.writer import part_bytes, part_table, write_part
from pipeline.cli import app
from pipeline.planner import make_plan
from pipeline.settings import PlanConfig
from storage import Storage


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    storage = Storage.from_uri(str(tmp_path_factory.mktemp("cond")))
    plan = make_plan(PlanConfig(domains="towns=T01 weathers=CN,CS,HRN viewpoints=A", frames_per_scenario=4,
                                width=64, height=36))
    for spec in plan.episodes:
        write_part(storage, spec.scenario, spec.episode, episode_rows(spec))
    return storage


def test_every_row_carries_the_six_conditions_of_its_weather(root):
    assert CONDITION_COLUMNS == ("sun_altitude_deg", "cloudiness", "precipitation", "visibility_m", "road_wetness",
                                 "snow_cover")
    assert all(c.unit and c.meaning for c in CONDITIONS)
    table = read_manifest(root)
    assert set(CONDITION_COLUMNS) <= set(MANIFEST_SCHEMA.names)
    assert MANIFEST_SCHEMA.field("visibility_m").type == pa.float64() and table.column("fog_density").null_count == 12
    for row in table.to_pylist():
        expected = frame_conditions(weather(row["weather"]))
        assert {k: row[k] for k in CONDITION_COLUMNS} == pytest.approx({k: expected[k] for k in CONDITION_COLUMNS})
        assert row["visibility_m"] == weather(row["weather"]).visibility_m  # float64: as declared
    hrn = frame_conditions(weather("HRN"))
    assert hrn["precipitation"] == 0.6 and hrn["road_wetness"] == 0.6 and hrn["snow_cover"] == 0.0


def test_query_filters_on_conditions(root):
    table = read_manifest(root)
    wet = q.filter_frames(table, q.Query(min_condition=(("precipitation", 0.5),)))
    assert set(wet.column("weather").to_pylist()) == {"HRN"} and len(wet) == 4
    low_sun = q.filter_frames(table, q.Query(max_condition=(("sun_altitude_deg", 20.0),)))
    assert set(low_sun.column("weather").to_pylist()) == {"CS"}
    band = q.filter_frames(table, q.Query(min_condition=(("visibility_m", 50_000),), max_condition=(("visibility_m", 1e5),)))
    assert set(band.column("weather").to_pylist()) == {"CS"}
    with pytest.raises(ValueError, match="unknown condition 'fog'; valid conditions: sun_altitude_deg"):
        q.filter_frames(table, q.Query(min_condition=(("fog", 0.5),)))
    with pytest.raises(ValueError, match="fog is recorded as visibility_m"):
        q.filter_frames(table, q.Query(min_condition=(("fog_density", 0.5),)))


def test_cli_query_condition_options(root, tmp_path):
    runner = CliRunner()
    out = tmp_path / "wet.csv"
    result = runner.invoke(app, ["query", root.path(), "--min-condition", "precipitation=0.5", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "T01_HRN_A" in result.output and "T01_CN_A" not in result.output
    assert "visibility_m" in out.read_text().splitlines()[0]
    for bad, words in ((["--max-condition", "fog=1"], "unknown condition 'fog'"),
                       (["--min-condition", "fog_density"], "--min-condition takes NAME=VALUE"),
                       (["--min-condition", "fog_density=thick"], "VALUE a number")):
        result = runner.invoke(app, ["query", root.path(), *bad])
        lines = result.output.strip().splitlines()
        assert result.exit_code == 2 and len(lines) == 1 and lines[0].startswith("error: ") and words in lines[0], \
            result.output


def test_parts_written_before_the_condition_columns_read_null_and_never_pass_a_bound(tmp_path):
    storage = Storage.from_uri(str(tmp_path))
    [spec] = make_plan(PlanConfig(domains="T01_HRN_A", frames_per_scenario=2, width=64, height=36)).episodes
    rows = part_table(episode_rows(spec))
    kept = [name for name in rows.column_names if name not in (*CONDITION_COLUMNS, "fog_density")]
    storage.write_bytes(part_path(spec.scenario, spec.episode), part_bytes(rows.select(kept)))
    table = read_manifest(storage)
    assert table.schema.names == MANIFEST_SCHEMA.names
    assert [table.column(name).null_count for name in CONDITION_COLUMNS] == [2] * len(CONDITION_COLUMNS)
    assert len(q.filter_frames(table, q.Query())) == 2
    assert len(q.filter_frames(table, q.Query(min_condition=(("precipitation", 0.0),)))) == 0


def test_a_root_made_before_rules_keeps_fog_density_and_queries_read_its_visibility(tmp_path):
    """Issue 32: a root of OLD_RULES writes parts as it did (fog_density float32, no visibility_m
    column); a query on visibility_m reads it from fog_density."""
    import pyarrow.parquet as pq

    from manifests.schema import OLD_PART_SCHEMA
    from manifests.schema import OLD_RULES

    storage = Storage.from_uri(str(tmp_path))
    plan = make_plan(PlanConfig(domains="towns=T01 weathers=CN,FG viewpoints=A", frames_per_scenario=2, width=64,
                                height=36, rules=OLD_RULES))
    for spec in plan.episodes:
        rel = write_part(storage, spec.scenario, spec.episode, episode_rows(spec))
        assert pq.read_schema(storage.path(rel)).names == OLD_PART_SCHEMA.names  # no visibility_m
    table = read_manifest(storage)
    fog = dict(zip(table.column("weather").to_pylist(), table.column("fog_density").to_pylist()))
    assert fog == {"CN": pytest.approx(0.02), "FG": pytest.approx(0.99999)} and table.column("visibility_m").null_count == 4
    dense = q.filter_frames(table, q.Query(domains="catalog", max_condition=(("visibility_m", 1000.0),)))
    assert set(dense.column("weather").to_pylist()) == {"FG"} and len(dense) == 2
