"""Issue 32: one grammar for scenario codes, the catalog's. A domain file may declare any code of
letters and digits (a town not like T01, lower-case and long weathers, two-letter and digit
viewpoints); every parser of paths and part names takes its pattern from the catalog, so frames,
parts and indexes of such codes are seen by status, query, verify, repair, export and resume."""

from __future__ import annotations

import ast
import json
import re
import shutil
from pathlib import Path

import pytest

from domains.catalog import SCENARIO_RE, format_code, split_code
from domains.catalog_file import CODE_PATTERN
from manifests.layout import LAYOUTS, frame_path, match_frame_file
from manifests.reader import _INDEX_RE
from manifests.schema import PART_RE, STATS_RE, index_path, part_path, stats_path

# one code of every legal shape per axis: the paper's, digits, lower case, long and mixed case
TOWNS = ("T01", "Oslo", "t7", "42", "TownWithALongName9")
WEATHERS = ("CN", "CNtoNT", "FG1", "mist", "x")
VIEWPOINTS = ("A", "B2", "7", "bus", "TR")
SHAPES = [format_code(t, w, v) for t, w, v in zip(TOWNS, WEATHERS, VIEWPOINTS)] + [
    format_code(t, w, v) for t, w, v in zip(TOWNS, reversed(WEATHERS), VIEWPOINTS[1:] + VIEWPOINTS[:1])]


@pytest.mark.parametrize("code", SHAPES)
def test_every_parser_reads_every_legal_code(code):
    town, weather, view = split_code(code)
    assert all(CODE_PATTERN.fullmatch(part) for part in (town, weather, view))  # a domain file accepts each part
    for rows in (None, 72):
        match = PART_RE.match(part_path(code, 12, rows))
        assert match is not None, part_path(code, 12, rows)
        assert (match["scenario"], match["town"], match["weather"], match["viewpoint"], int(match["episode"])) == (
            code, town, weather, view, 12)
    assert _INDEX_RE.match(index_path(code))["scenario"] == code
    assert (STATS_RE.match(stats_path(code, 12))["scenario"], STATS_RE.match(stats_path(code, 12))["episode"]) == (
        code, "0012")
    for layout in LAYOUTS:
        for output, fmt in (("rgb", "png"), ("rgb", "jpg"), ("instance", "png"), ("objects", "png")):
            rel = frame_path(code, output, "0012_003", fmt, layout)
            match = match_frame_file(rel, (layout,))
            assert match is not None, rel
            assert (match["scenario"], match["output"], int(match["episode"]), int(match["frame"])) == (
                code, output, 12, 3)


@pytest.mark.parametrize("bad", ["T01_CN", "T01_CN_A_B", "T01__A", "T01_C-N_A", "T01_CN_*", "T01_CN_A ", "T01_CÑ_A"])
def test_what_the_grammar_refuses(bad):
    assert SCENARIO_RE.fullmatch(bad) is None
    with pytest.raises(ValueError, match="malformed scenario code"):
        split_code(bad)


def test_episode_stats_of_every_legal_code_are_read(tmp_path):
    """The report's per-episode timings: a stats file of any code (one whose weather starts with "e" too:
    its name holds "_e" twice), never the driver's own; globbing "T*_e*" and splitting at "_e" read
    only towns like T01, and cut "Oslo_eve_B2_e0000" at its weather."""
    from reports.sample import episode_stats

    codes = [*SHAPES, "Oslo_eve_B2"]
    (tmp_path / "_stats").mkdir()
    for code in codes:
        (tmp_path / stats_path(code, 3)).write_text(json.dumps({"frames": 2}))
    (tmp_path / "_stats" / "driver.json").write_text(json.dumps({"frames_per_s": 1.0}))
    assert sorted(s["scenario"] for s in episode_stats(str(tmp_path))) == sorted(codes)


# Written-out patterns that would be a second grammar of codes (domains.catalog's is the one): globs
# and classes of letters (T*, T\d, [A-Z...]), and cutting a name at a code's separator.
RESTATED = re.compile(r"T\*|T\\d|T\[|\[A-Z|\[A-Za-z|\[a-zA-Z|_e\*|\*_e")
# (file, what) that are not about codes: URIs' and buckets' grammars, a terminal colour code, a frame
# file's extension, a frame id ("0003_012"), CamVid's own file names
NOT_CODES = {("storage/errors.py", "[A-Za-z][A-Za-z0-9+.-]*"), ("storage/uri.py", "[a-z0-9]"),
             ("pipeline/cluster.py", "[A-Za-z]"), ("manifests/layout.py", "[a-z0-9]+$"),
             ("manifests/layout.py", "fid.partition('_')"), ("analysis/camvid_layout.py", "split('_')")}


def _restated(path: Path) -> list[str]:
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and RESTATED.search(node.value):
            found.append(node.value)
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
              and node.func.attr in ("split", "rsplit", "partition", "rpartition") and node.args
              and isinstance(node.args[0], ast.Constant) and node.args[0].value in ("_", "_e")):
            found.append(ast.unparse(node))
    return found


def test_no_second_grammar_of_codes_in_the_source():
    """Every pattern over codes or names made of them takes its grammar from the catalog (scenario_pattern,
    split_code, CODE_CHARS); only domains/ writes one out."""
    root = Path(__file__).resolve().parents[1]
    wrong = []
    for path in sorted(p for top in root.iterdir() if (top / "__init__.py").is_file() and top.name not in (
            "tests", "domains") for p in top.rglob("*.py")):
        rel = path.relative_to(root).as_posix()
        wrong += [f"{rel}: {what!r}" for what in _restated(path)
                  if not any(rel == file and part in what for file, part in NOT_CODES)]
    assert not wrong, "\n".join(wrong)


def test_the_grammar_check_sees_a_second_grammar(tmp_path):
    path = tmp_path / "m.py"
    path.write_text('import re\nPAT = re.compile(r"T\\d+_[A-Z]+_[A-Z]")\n'
                    'def f(p):\n    return p.glob("T*_e*.json"), p.stem.split("_e")[0]\n')
    assert _restated(path) == ["T\\d+_[A-Z]+_[A-Z]", "T*_e*.json", "p.stem.split('_e')"]


def test_names_that_are_not_ours_stay_unmatched():
    code = "Oslo_mist_B2"
    assert PART_RE.match(f"manifest/town=Oslo/weather=mist/viewpoint=B2/{code}_e0000_n0.parquet") is None
    assert match_frame_file(f"{code}/e0000/rgb/0000_000_Oslo_mist_B3.png") is None  # another scenario's name
    assert match_frame_file(f"{code}/e0000/rgb/0001_000_{code}.png") is None  # another episode's name
    assert match_frame_file(f"{code}/e0000/rgb/0000_000_{code}.exr") is None  # not the output's format


# -- end to end: declared codes of every shape through produce, status, query, verify, repair, export, resume --
DECLARED = """
[[town]]
code = "Oslo"
like = "T01"
name = "Oslo"

[[weather]]
code = "mist"
like = "CN"
name = "Mist"
visibility_m = 4321.93

[[viewpoint]]
code = "B2"
like = "B"
camera_height_m = 2.0

[[viewpoint]]
code = "7"
like = "A"
"""
# a town not like T01, a lower-case weather and the built-in shift CNtoNT (long, mixed case),
# a viewpoint of a letter and a digit and one of a digit alone: 4 scenarios, none of the paper's 105
CODES = ["Oslo_CNtoNT_7", "Oslo_CNtoNT_B2", "Oslo_mist_7", "Oslo_mist_B2"]
RUN = ["--domains", "towns=Oslo weathers=mist,CNtoNT viewpoints=B2,7", "--frames-per-scenario", "2",
       "--width", "64", "--height", "36", "--seed", "3", "--world", "test"]


def _files(root: Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file() and p.parts[len(root.parts)] in CODES}


@pytest.fixture(scope="module")
def ray_local():
    """One local Ray cluster for the module's produce and repair runs (each would start its own)."""
    import ray

    ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()


@pytest.mark.slow
def test_declared_codes_of_every_shape_end_to_end(ray_local, tmp_path):
    from typer.testing import CliRunner

    from pipeline.cli import app

    runner = CliRunner()
    domains = tmp_path / "codes.toml"
    domains.write_text(DECLARED)
    root = tmp_path / "root"
    result = runner.invoke(app, ["produce", *RUN, "--catalog", str(domains), "--out", str(root)])
    assert result.exit_code == 0, result.output
    rendered = _files(root)
    assert sorted({rel.partition("/")[0] for rel in rendered}) == CODES

    result = runner.invoke(app, ["status", str(root)])
    assert result.exit_code == 0 and "8 of 8 frames done (100.0%)" in result.output, result.output
    for code in CODES:
        assert re.search(rf"^{code} +1/1 +2/2 +done$", result.output, re.M), result.output
    # no --domains: the scenarios the root holds, not the paper's 105 (none of which it holds)
    result = runner.invoke(app, ["query", str(root)])
    assert result.exit_code == 0, result.output
    assert "8 frames selected of 8 matching the filters (8 of the 8 frames the root holds)" in result.output
    assert all(re.search(rf"^{code} +2$", result.output, re.M) for code in CODES), result.output
    # a resume renders nothing (no file needed: run.json records the entries)
    result = runner.invoke(app, ["produce", *RUN, "--out", str(root)])
    assert result.exit_code == 0 and "nothing to render" in result.output, result.output

    # planted damage: a missing, a corrupt and an extra file, and the frames of episodes a kill left
    # without their part (in the shift's and a declared weather's scenarios): a later episode's, and
    # a whole episode's whose part is gone (its 16 files, and its scenario's index covers it no more)
    missing = "Oslo_mist_B2/e0000/depth_raw/0000_001_Oslo_mist_B2.png"
    corrupt = "Oslo_CNtoNT_7/e0000/rgb/0000_000_Oslo_CNtoNT_7.png"
    extra = "Oslo_CNtoNT_7/e0000/semantic_raw/0000_007_Oslo_CNtoNT_7.png"
    killed = ["Oslo_mist_7/e0001/rgb/0001_000_Oslo_mist_7.png", "Oslo_mist_7/e0001/instance/0001_000_Oslo_mist_7.png",
              "Oslo_CNtoNT_7/e0001/depth_log/0001_001_Oslo_CNtoNT_7.png"]
    (root / missing).unlink()
    (root / corrupt).write_bytes(rendered[corrupt][:-4] + b"XXXX")
    for rel in [extra, *killed]:
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_bytes(b"stray")
    for part in (root / "manifest").rglob("Oslo_CNtoNT_B2_e0000*.parquet"):
        part.unlink()
    unlisted = [rel for rel in rendered if rel.startswith("Oslo_CNtoNT_B2/")]
    assert len(unlisted) == 16
    result = runner.invoke(app, ["verify", str(root), "--no-ray"])
    assert result.exit_code == 1, result.output
    assert "FAILED: 1 bad-index, 1 corrupt, 20 extra, 1 missing;" in result.output, result.output
    for kind, rel in [("missing", missing), ("corrupt", corrupt), ("extra", extra)] + [("extra", r) for r in killed]:
        assert re.search(rf"^{kind} +{re.escape(rel)}", result.output, re.M), result.output
    result = runner.invoke(app, ["produce", *RUN, "--out", str(root), "--repair"])
    assert result.exit_code == 0, result.output
    assert _files(root) == rendered  # the damaged files as they were, the strays gone
    result = runner.invoke(app, ["verify", str(root), "--no-ray"])
    assert result.exit_code == 0 and result.output.startswith("OK"), result.output

    target = tmp_path / "export"
    result = runner.invoke(app, ["export", str(root), "--format", "idda", "--to", str(target)])
    assert result.exit_code == 0 and "exported 8 of the 8 frames the root holds" in result.output, result.output
    assert sorted(p.name for p in target.iterdir() if p.is_dir()) == CODES
    result = runner.invoke(app, ["produce", *RUN, "--out", str(root)])
    assert result.exit_code == 0 and "nothing to render" in result.output, result.output


# -- a command's default selection is the root's scenarios, and it says what it covered of them --------------
@pytest.fixture(scope="module")
def held_root(tmp_path_factory):
    """A root of one frame each of T01_NT_A (built in, beyond the paper's 105) and two declared
    scenarios with codes longer than the tables' old column, rendered without Ray."""
    from domains.catalog import BUILTIN
    from domains.catalog_file import with_file
    from pipeline.settings import PlanConfig, RunConfig
    from tests.roots import render_root

    layer = with_file(BUILTIN, DECLARED.replace('"mist"', '"mistyMorning2"'), "codes.toml").layer_json()
    plan = PlanConfig(domains="T01_NT_A,Oslo_mistyMorning2_B2,Oslo_CNtoNT_7", frames_per_scenario=1, width=64,
                      height=36, seed=1, catalog=layer)
    root = tmp_path_factory.mktemp("held") / "root"
    render_root(root, RunConfig(plan=plan, world="test"), compact=True)
    return root


HELD = ["Oslo_CNtoNT_7", "Oslo_mistyMorning2_B2", "T01_NT_A"]


def _aligned(lines: list[str], column: int, edge: str) -> bool:
    """Whether column ``column`` (0: the first) of these table lines has its ``edge`` ("start" or
    "end") at one place in each: the codes fit the first column."""
    return len({getattr(list(re.finditer(r"\S+", line))[column], edge)() for line in lines}) == 1


def test_commands_default_to_the_scenarios_a_root_holds(held_root, tmp_path):
    from typer.testing import CliRunner

    from pipeline.cli import app

    runner = CliRunner()
    result = runner.invoke(app, ["query", str(held_root)])
    assert result.exit_code == 0, result.output
    assert "3 frames selected of 3 matching the filters (3 of the 3 frames the root holds)" in result.output
    rows = [line for line in result.output.splitlines() if line.split()[0] in HELD]
    assert sorted(row.split()[0] for row in rows) == HELD and _aligned(rows, 1, "end"), result.output
    result = runner.invoke(app, ["query", str(held_root), "--domains", "weathers=NT"])
    assert result.exit_code == 0 and "(1 of the 3 frames the root holds)" in result.output, result.output
    result = runner.invoke(app, ["query", str(held_root), "--domains", "all"])  # the paper's 105: none held
    assert result.exit_code == 2 and "(0 of the 3 frames the root holds match the filters)" in result.output

    result = runner.invoke(app, ["export", str(held_root), "--format", "idda", "--to", str(tmp_path / "idda")])
    assert result.exit_code == 0 and "exported 3 of the 3 frames the root holds" in result.output, result.output
    assert sorted(p.name for p in (tmp_path / "idda").iterdir() if p.is_dir()) == HELD
    result = runner.invoke(app, ["export", str(held_root), "--format", "idda", "--to", str(tmp_path / "nt"),
                                 "--domains", "T01_NT_A"])
    assert result.exit_code == 0 and "exported 1 of the 3 frames the root holds" in result.output, result.output

    chart = tmp_path / "shares.png"
    result = runner.invoke(app, ["stats", str(held_root), "--per-scenario", "--chart", str(chart)])
    assert result.exit_code == 0 and f"chart: {chart} (3 of the 3 frames the root holds)" in result.output
    rows = [line for line in result.output.splitlines() if line.split()[0] in HELD + ["scenario"]]
    assert {row.split()[0] for row in rows} == set(HELD) | {"scenario"} and _aligned(rows, 2, "start"), result.output

    result = runner.invoke(app, ["status", str(held_root)])
    rows = [line for line in result.output.splitlines() if line.split()[0] in HELD]
    assert result.exit_code == 0 and len(rows) == 3 and _aligned(rows, 1, "end"), result.output

    result = runner.invoke(app, ["distances", str(held_root), "--samples", "1", "--components", "2"])
    assert result.exit_code == 0 and "3 domains, 1 frames each" in result.output, result.output
    assert "cosine: not given: the means of 3 domains" in result.output

    copy = tmp_path / "card"
    shutil.copytree(held_root, copy)
    result = runner.invoke(app, ["card", str(copy)])
    assert result.exit_code == 0 and "(3 of the 3 frames the root holds)" in result.output, result.output
    assert "--domains 'towns=Oslo weathers=CNtoNT' --split train" in (copy / "README.md").read_text()  # one it holds


def test_produce_report_aligns_long_codes():
    from pipeline.cli.progress import format_produce_report
    from pipeline.driver import ProduceReport

    per = {code: {"episodes": 1, "frames": 2, "seconds": 1.5} for code in ["T01_CN_A", *HELD, "TownWithALongName9_x_TR"]}
    report = ProduceReport("out", 5, 10, 0, rendered_frames=10, rendered_episodes=5, seconds=3.0, per_scenario=per,
                           workers=2)
    lines = format_produce_report(report).splitlines()
    rows = [line for line in lines if line.split()[0] in per]
    header = next(line for line in lines if line.startswith("scenario"))
    assert len(rows) == 5 and _aligned(rows, 1, "end") and _aligned([header, rows[0]], 1, "end"), "\n".join(lines)
