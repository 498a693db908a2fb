import pyarrow.parquet as pq
from typer.testing import CliRunner

from pipeline.cli import app
from pipeline.plan_file import read_plan

runner = CliRunner()


def test_plan_full_scale_prints_paper_total():
    result = runner.invoke(app, ["plan"])
    assert result.exit_code == 0, result.output
    assert "total (105 scenarios)" in result.output
    assert "1,006,800" in result.output
    assert "T07_HRN_B" in result.output


def test_plan_writes_parquet_that_reads_back(tmp_path):
    out = tmp_path / "plan.parquet"
    result = runner.invoke(
        app, ["plan", "--domains", "towns=T01,T02 weathers=CN", "--scale", "0.1", "--out", str(out)]
    )
    assert result.exit_code == 0, result.output
    table = pq.read_table(out)
    assert table.column_names == [
        "scenario", "town", "weather", "viewpoint", "episode", "frames", "seed", "split", "width", "height",
    ]
    assert set(table.column("scenario").to_pylist()) == {
        f"T0{t}_CN_{v}" for t in (1, 2) for v in "AMJVB"
    }
    plan = read_plan(out)
    assert plan.total_frames == sum(table.column("frames").to_pylist())


def test_bad_input_is_one_line_exit_2_and_writes_nothing(tmp_path):
    out = tmp_path / "plan.parquet"
    for args, needle in [
        (["--domains", "towns=T99"], "valid towns: T01"),
        (["--scale", "2"], "scale must be in (0, 1]"),
        (["--width", "0"], "width must be between 32 and 8192"),
        (["--domains", "T01_CS"], "malformed scenario code"),
    ]:
        result = runner.invoke(app, ["plan", *args, "--out", str(out)])
        assert result.exit_code == 2, result.output
        assert needle in result.output
        assert "Traceback" not in result.output
        assert len(result.output.strip().splitlines()) == 1
    assert not out.exists()


def test_help_lists_commands():
    result = runner.invoke(app, ["--help"])
    assert result.exit_code == 0
    assert "plan" in result.output
    result = runner.invoke(app, ["plan", "--help"])
    assert "--frames-per-scenario" in result.output and "--domains" in result.output


def test_read_commands_refuse_a_path_that_is_not_an_output_root(tmp_path):
    (tmp_path / "notes.txt").write_text("not a dataset")
    for command in (["verify"], ["query"], ["status"], ["query", "--preset", "best-case"]):
        for root in (tmp_path, tmp_path / "missing"):
            result = runner.invoke(app, [command[0], str(root), *command[1:]])
            assert result.exit_code == 2, (command, root, result.output)
            assert result.output.count("\n") == 1 and "is not an output root" in result.output
