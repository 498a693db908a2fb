"""Manifest parts written through the writer, read back through the public
reader, then queried and summarised."""

import json

import pyarrow.csv as pv
import pyarrow.parquet as pq
import pytest

from manifests import query as q
from domains.catalog import LABELS, split_code
from manifests.reader import done_episodes, manifest_dataset, read_manifest
from manifests.schema import MANIFEST_SCHEMA, PART_SCHEMA, part_path, with_uids
from tests.roots import part_of
from manifests.stats import PAPER_SHARES, bar_chart_png, class_pixels, share_table
from manifests.synthetic import episode_rows
from manifests.part_file import ManifestError
from manifests.writer import part_bytes, part_table, write_part
from pipeline.planner import make_plan
from pipeline.settings import PlanConfig
from storage import Storage


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    storage = Storage.from_uri(str(tmp_path_factory.mktemp("root")))
    plan = make_plan(PlanConfig(domains="towns=T01,T07 weathers=CN,HRN viewpoints=A,J,B", frames_per_scenario=30, width=64, height=36))
    for spec in plan.episodes:
        write_part(storage, spec.scenario, spec.episode, episode_rows(spec))
    return storage, plan


def test_read_back_through_public_reader(root):
    storage, plan = root
    table = read_manifest(storage)
    assert table.schema.names == MANIFEST_SCHEMA.names
    assert len(table) == plan.total_frames
    assert done_episodes(storage) == {(e.scenario, e.episode) for e in plan.episodes}
    row = table.slice(0, 1).to_pylist()[0]
    assert row["scenario"] == "T01_CN_A" and row["town"] == "T01" and row["weather"] == "CN"
    assert row["rgb_path"] == "T01_CN_A/e0000/rgb/0000_000_T01_CN_A.png"  # synthetic parts: a new root's layout
    pixels = sum(row[label.column] for label in LABELS)
    assert pixels == 64 * 36


def test_part_bytes_are_deterministic(root):
    _, plan = root
    rows = episode_rows(plan.episodes[0])
    assert part_bytes(part_table(rows)) == part_bytes(part_table(episode_rows(plan.episodes[0])))
    with pytest.raises(ManifestError, match="lacks manifest columns: frame_id"):
        part_table([{k: v for k, v in rows[0].items() if k != "frame_id"}])


def test_empty_root_reads_as_empty_table(tmp_path):
    table = read_manifest(Storage.from_uri(str(tmp_path)))
    assert len(table) == 0 and table.schema.names == MANIFEST_SCHEMA.names


def test_filters_by_axis_split_episode(root):
    storage, _ = root
    table = read_manifest(storage)
    res = q.run_query(table, q.Query(domains="towns=T07 weathers=HRN", splits=("train",), episodes=(0,)))
    got = res.table.to_pylist()
    assert got and all(r["town"] == "T07" and r["weather"] == "HRN" and r["episode"] == 0 for r in got)
    # Same answer from the lazy dataset (partition pruning) as from the table.
    lazy = q.run_query(manifest_dataset(storage), q.Query(domains="towns=T07 weathers=HRN", splits=("train",), episodes=(0,)))
    assert lazy.table.equals(res.table)


def test_class_presence_and_min_share(root):
    storage, _ = root
    table = read_manifest(storage)
    res = q.run_query(table, q.Query(min_share=(("sky", 0.3),), classes=("rider",)))
    for row in res.table.to_pylist():
        assert row["px_sky"] >= 0.3 * 64 * 36 and row["px_rider"] > 0
    everything = q.run_query(table, q.Query())
    expected = sum(1 for r in everything.table.to_pylist() if r["px_sky"] >= 0.3 * 64 * 36 and r["px_rider"] > 0)
    assert res.matched == expected


def test_stratified_sampling_is_seeded_and_stratified(root):
    storage, _ = root
    table = read_manifest(storage)
    a = q.run_query(table, q.Query(per_scenario=5, seed=3)).table
    b = q.run_query(table, q.Query(per_scenario=5, seed=3)).table
    c = q.run_query(table, q.Query(per_scenario=5, seed=4)).table
    assert a.equals(b) and not a.equals(c)
    codes = a.column("scenario").to_pylist()
    assert all(codes.count(s) == 5 for s in set(codes)) and len(set(codes)) == 12
    total = q.run_query(table, q.Query(total=100, seed=0))
    assert len(total.table) == 100 and not total.shortfall
    per = {s: total.table.column("scenario").to_pylist().count(s) for s in set(codes)}
    assert max(per.values()) - min(per.values()) <= 1  # equal-size scenarios get equal shares


def test_presets_report_shortfall_on_small_runs(root):
    storage, _ = root
    res = q.run_query(read_manifest(storage), q.preset("worst-case"))
    assert set(res.table.column("scenario").to_pylist()) == {"T07_HRN_J", "T07_HRN_B"}
    assert len(res.table) == 60 and res.shortfall["(total)"] == 40_128 - 60
    best = q.run_query(read_manifest(storage), q.preset("best-case"))
    assert best.shortfall["T02_CN_A"] == 2_496  # in the pool, not produced


@pytest.mark.parametrize(
    "query, message",
    [
        (q.Query(splits=("dev",)), "valid splits: train, val, test"),
        (q.Query(classes=("cat",)), "valid classes"),
        (q.Query(min_share=(("sky", 2.0),)), "must be in"),
        (q.Query(per_scenario=2, total=3), "either"),
        (q.Query(domains="towns=T42"), "valid towns"),
    ],
)
def test_bad_queries(query, message):
    with pytest.raises(ValueError, match=message):
        query.validate()
    with pytest.raises(ValueError, match="valid presets: best-case, worst-case"):
        q.preset("average-case")


def test_writers(root, tmp_path):
    storage, _ = root
    table = q.run_query(read_manifest(storage), q.Query(total=7)).table
    lines = q.encode_result(table, "list").decode().splitlines()
    assert len(lines) == 7 and lines[0].split()[0].endswith(".png") and "/semantic_raw/" in lines[0].split()[1]
    csv_text = q.encode_result(table, "csv").decode().splitlines()
    assert csv_text[0].replace('"', "").split(",") == table.column_names and len(csv_text) == 8
    (tmp_path / "s.csv").write_bytes(q.encode_result(table, "csv"))
    back = pv.read_csv(tmp_path / "s.csv")
    assert back.column("frame_id").to_pylist() == table.column("frame_id").to_pylist()
    assert back.column("px_sky").to_pylist() == table.column("px_sky").to_pylist()
    assert json.loads(back.column("cam_to_world")[0].as_py()) == table.column("cam_to_world")[0].as_py()
    (tmp_path / "s.parquet").write_bytes(q.encode_result(table, "parquet"))
    assert pq.read_table(tmp_path / "s.parquet").equals(table)
    with pytest.raises(ValueError, match="valid formats: list, csv, parquet"):
        q.encode_result(table, "xlsx")


def test_share_table_and_chart(root):
    storage, _ = root
    table = read_manifest(storage)
    shares = share_table(table)
    total = class_pixels(table).sum()
    assert total == len(table) * 64 * 36
    assert abs(sum(shares.column("share").to_pylist()) - 1.0) < 1e-9
    sky = [r for r in shares.to_pylist() if r["class"] == "sky"][0]
    assert sky["paper_share"] == pytest.approx(PAPER_SHARES["sky"]) and 0.2 < sky["paper_share"] < 0.3
    per = share_table(table, by_scenario=True)
    assert len(per) == 12 * 24
    png = bar_chart_png(shares)
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000


def test_compaction_is_used_only_while_it_matches_the_parts(root, tmp_path):
    import shutil

    from manifests.reader import compact, manifest_files
    from manifests.schema import index_path

    storage, plan = root
    copy = Storage.from_uri(str(tmp_path / "copy"))
    shutil.copytree(storage.path(), copy.path(), dirs_exist_ok=True)
    before = read_manifest(copy)
    assert compact(copy) == sorted(plan.scenarios())
    assert compact(copy) == []  # nothing stale
    files = manifest_files(copy)
    assert files == [index_path(s) for s in sorted(plan.scenarios())]
    assert read_manifest(copy).equals(before)
    # A part removed (as --repair does) makes that scenario's index stale.
    spec = plan.episodes[0]
    copy.delete(part_of(copy, spec.scenario, spec.episode))
    files = manifest_files(copy)
    assert index_path(spec.scenario) not in files
    assert len(read_manifest(copy)) == len(before) - spec.frames
    assert compact(copy) == []  # that scenario has no parts left: its index goes
    assert not copy.exists(index_path(spec.scenario))
    assert len(read_manifest(copy)) == len(before) - spec.frames


def test_manifest_dir_holds_one_row_per_frame_after_compaction(root, tmp_path):
    """Readers that glob manifest/** (DuckDB, Polars, HF) must not see an index
    there; pyarrow over the directory, without our reader, counts each frame once."""
    import shutil

    import pyarrow.dataset as ds

    from manifests.reader import compact

    storage, plan = root
    copy = Storage.from_uri(str(tmp_path / "copy"))
    shutil.copytree(storage.path(), copy.path(), dirs_exist_ok=True)
    # A root compacted by an older version: the index inside manifest/ goes.
    legacy = "manifest/town=T01/weather=CN/viewpoint=A/_index.parquet"
    copy.write_bytes(legacy, copy.read_bytes(part_of(copy, plan.episodes[0].scenario, plan.episodes[0].episode)))
    compact(copy)
    assert not copy.exists(legacy)
    files = copy.list_files("manifest/")
    assert files and all(f.rsplit("/", 1)[1].startswith(("T0", "T1")) for f in files)
    rows = pq.ParquetDataset(copy.path("manifest"), partitioning="hive").read().num_rows
    assert rows == plan.total_frames
    # ignore_prefixes=[] switches off pyarrow's underscore rule, like a plain glob
    dataset = ds.dataset(copy.path("manifest"), format="parquet", partitioning="hive", ignore_prefixes=[])
    assert dataset.count_rows() == plan.total_frames
    assert len(read_manifest(copy)) == plan.total_frames


def test_what_is_in_the_files_and_what_in_the_paths(root, tmp_path):
    """As the README says: a part holds PART_SCHEMA (town / weather / viewpoint
    only in its hive path); an index holds them inside, matching ``scenario``. A root of the
    default rig (front) leaves the rig's columns (sensor, LiDAR files) out of both."""
    import shutil

    from manifests.reader import compact
    from manifests.schema import PARTITION_KEYS, RIG_FIELDS, RULE_PART_SCHEMA, index_path

    storage, plan = root
    copy = Storage.from_uri(str(tmp_path / "copy"))
    shutil.copytree(storage.path(), copy.path(), dirs_exist_ok=True)
    compact(copy)
    spec = plan.episodes[0]
    part = pq.read_table(copy.path(part_of(copy, spec.scenario, spec.episode)))
    rig = {name for name, _ in RIG_FIELDS}
    assert part.schema.names == RULE_PART_SCHEMA.names == [n for n in PART_SCHEMA.names if n not in rig]
    assert not set(PARTITION_KEYS) & set(part.schema.names)
    index = pq.read_table(copy.path(index_path(spec.scenario)))
    assert index.schema.names == [n for n in MANIFEST_SCHEMA.names if n not in rig]
    for key, value in zip(PARTITION_KEYS, split_code(spec.scenario)):
        assert set(index.column(key).to_pylist()) == {value}


def test_each_scenario_gets_its_own_sample_draw(root):
    """Issue 21.13b: seeding the draw by the query seed alone gave every scenario the same frames."""
    storage, _ = root
    table = read_manifest(storage)
    result = q.run_query(table, q.Query(per_scenario=5, seed=3)).table
    picks: dict[str, set] = {}
    for row in result.select(["scenario", "episode", "frame"]).to_pylist():
        picks.setdefault(row["scenario"], set()).add((row["episode"], row["frame"]))
    assert len(picks) == 12 and all(len(p) == 5 for p in picks.values())
    assert len({frozenset(p) for p in picks.values()}) > 6  # 12 draws of 5 from 30: near-certainly all differ
    # and a scenario's draw does not depend on which other scenarios are selected
    alone = q.run_query(table, q.Query(domains="T07_HRN_B", per_scenario=5, seed=3)).table
    assert {(r["episode"], r["frame"]) for r in alone.select(["episode", "frame"]).to_pylist()} == picks["T07_HRN_B"]


EMPTY_SELECTIONS = ["", "   ", ",", " , ;", ";;"]


@pytest.mark.parametrize("text", EMPTY_SELECTIONS)
def test_an_empty_selection_is_an_error_not_everything(text):
    """Issue 21.6: an empty --domains selected all 105 scenarios."""
    from domains.selection import parse_selection

    with pytest.raises(ValueError, match="empty selection"):
        parse_selection(text)
    with pytest.raises(ValueError, match="empty selection"):
        q.Query(domains=text).validate()
    with pytest.raises(ValueError, match="empty selection"):
        make_plan(PlanConfig(domains=text, frames_per_scenario=2))


def test_every_command_refuses_an_empty_selection_in_one_line(root, tmp_path, monkeypatch):
    """Issue 21.6 through the CLI: each command that takes --domains answers one
    'error:' line and exit code 2, and produce writes nothing (not even the root)."""
    from typer.testing import CliRunner

    import pipeline.driver
    from pipeline.cli import app

    def render_everything(*args, **kwargs):
        raise AssertionError("produce went on to render with an empty selection")

    monkeypatch.setattr(pipeline.driver, "_render_on_ray", render_everything)
    storage, _ = root
    src = storage.path()
    out = tmp_path / "new_root"
    commands = {
        "plan": ["plan", "--frames-per-scenario", "2"],
        "produce": ["produce", "--out", str(out), "--frames-per-scenario", "2", "--world", "test"],
        "query": ["query", src],
        "stats": ["stats", src, "--chart", str(tmp_path / "c.png")],
        "export": ["export", src, "--format", "idda", "--to", str(tmp_path / "export")],
        "distances": ["distances", src],
        "preview": ["preview", "--out", str(tmp_path / "preview"), "--world", "test"],
    }
    runner = CliRunner()
    for name, args in commands.items():
        for text in ("", " ,; "):
            result = runner.invoke(app, [*args, "--domains", text])
            lines = result.output.strip().splitlines()
            assert result.exit_code == 2, (name, result.output)
            assert len(lines) == 1 and lines[0].startswith("error: ") and "empty selection" in lines[0], (name, result.output)
    assert not out.exists() and not (tmp_path / "export").exists() and not (tmp_path / "preview").exists()


def test_parts_written_before_the_pose_columns_still_read(tmp_path):
    """A part of an older version (no calibration or pose columns) reads with those columns null."""
    storage = Storage.from_uri(str(tmp_path))
    spec = make_plan(PlanConfig(domains="towns=T01 weathers=CN viewpoints=A", frames_per_scenario=2,
                                width=64, height=36)).episodes[0]
    new = ("uid", "K", "cam_to_world", "ego_to_world", "cam_to_ego")
    old = part_table(episode_rows(spec)).drop_columns(list(new))
    storage.write_bytes(part_path(spec.scenario, spec.episode), part_bytes(old))
    table = read_manifest(storage)
    assert table.schema.names == MANIFEST_SCHEMA.names and len(table) == 2
    for name in new:
        assert table.column(name).null_count == 2
    assert table.column("frame_id").to_pylist() == old.column("frame_id").to_pylist()
    assert with_uids(table).column("uid").to_pylist() == [f"{f}_{spec.scenario}" for f in table["frame_id"].to_pylist()]


def test_uids_are_unique_in_a_root(root):
    """frame_id repeats across scenarios (0000_000 in each); uid does not, and names the files."""
    table = read_manifest(root[0])
    uids = table.column("uid").to_pylist()
    assert len(set(uids)) == len(uids) > len(set(table.column("frame_id").to_pylist()))
    assert with_uids(table).equals(table)
    for uid, path in zip(uids, table.column("rgb_path").to_pylist()):
        assert path.rsplit("/", 1)[1].split(".")[0] == uid
