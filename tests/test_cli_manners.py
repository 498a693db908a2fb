"""The idda command's manners: --version, -h, shell completion, one exit-code
rule, the same --chart option everywhere, per-scenario charts."""

import os
import subprocess
import sys
from importlib.metadata import version

import pytest
from PIL import Image
from typer.testing import CliRunner

from manifests.synthetic import episode_rows
from manifests.writer import write_part
from pipeline.cli import app
from pipeline.planner import make_plan
from pipeline.settings import PlanConfig
from storage import Storage

runner = CliRunner()


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    path = tmp_path_factory.mktemp("manners")
    storage = Storage.from_uri(str(path))
    plan = make_plan(PlanConfig(domains="T01_CN_A,T01_CN_J,T07_HRN_B", frames_per_scenario=4, width=64, height=36))
    for spec in plan.episodes:
        write_part(storage, spec.scenario, spec.episode, episode_rows(spec))
    return path


def test_version_and_short_help():
    for flag in ("--version", "-V"):
        result = runner.invoke(app, [flag])
        assert result.exit_code == 0 and result.output.strip() == f"idda {version('idda-pipeline')}"
    top = runner.invoke(app, ["-h"])
    assert top.exit_code == 0 and "produce" in top.output and "Exit codes" in top.output
    sub = runner.invoke(app, ["query", "-h"])
    assert sub.exit_code == 0 and "--preset" in sub.output


IDDA = os.path.join(os.path.dirname(sys.executable), "idda")  # the installed entry point


def test_shell_completion_script_and_completions():
    # Typer detects the user's shell from the process tree (shellingham), which has no shell when the suite runs
    # detached (nohup, a CI agent); its test switch makes --show-completion take the shell's name instead.
    detached = dict(os.environ, _TYPER_COMPLETE_TEST_DISABLE_SHELL_DETECTION="1")
    script = subprocess.run([IDDA, "--show-completion", "bash"], env=detached, capture_output=True, text=True,
                            timeout=60)
    assert script.returncode == 0 and "complete -o default -F _idda_completion idda" in script.stdout, script.stderr
    # What that script asks the program at a <TAB>: the entry point answers with the commands.
    env = dict(os.environ, _IDDA_COMPLETE="complete_bash", COMP_WORDS="idda ex", COMP_CWORD="1")
    done = subprocess.run([IDDA], env=env, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and done.stdout.split() == ["export"], (done.stdout, done.stderr)


def test_empty_selection_exits_2_for_query_export_and_stats(root, tmp_path):
    empty = "T01_CN_A"
    for args in (
        ["query", str(root), "--domains", empty, "--has", "rider", "--min-share", "rider=0.99"],
        ["export", str(root), "--format", "idda", "--to", str(tmp_path / "x"), "--domains", "T05_CN_A"],
        ["stats", str(root), "--domains", "T05_CN_A"],
    ):
        result = runner.invoke(app, args)
        assert result.exit_code == 2, (args, result.output)
        assert "error:" in result.output and "Traceback" not in result.output
    ok = runner.invoke(app, ["query", str(root), "--domains", empty])
    assert ok.exit_code == 0 and "4 frames selected" in ok.output


def test_stats_and_distances_share_the_chart_option(root, tmp_path):
    overall, per = tmp_path / "all.png", tmp_path / "per.png"
    assert runner.invoke(app, ["stats", str(root), "--chart", str(overall)]).exit_code == 0
    result = runner.invoke(app, ["stats", str(root), "--per-scenario", "--chart", str(per)])
    assert result.exit_code == 0, result.output
    # One panel per scenario: three panels stacked, each as tall as the single one.
    w1, h1 = Image.open(overall).size
    w3, h3 = Image.open(per).size
    assert w1 == w3 and h3 == 3 * h1
    assert "--chart" in runner.invoke(app, ["distances", "-h"]).output
    assert "--plot" not in runner.invoke(app, ["distances", "-h"]).output


def test_stats_writes_its_chart_beside_the_command_never_into_the_root(root, tmp_path, monkeypatch):
    here = tmp_path / "here"
    here.mkdir()
    monkeypatch.chdir(here)
    before = sorted(p.relative_to(root) for p in root.rglob("*"))
    result = runner.invoke(app, ["stats", str(root)])
    assert result.exit_code == 0, result.output
    assert result.output.splitlines()[-1] == "chart: class_shares.png (12 of the 12 frames the root holds)"
    assert Image.open(here / "class_shares.png").format == "PNG"
    assert sorted(p.relative_to(root) for p in root.rglob("*")) == before  # nothing written into the data
    inside = runner.invoke(app, ["stats", str(root), "--chart", str(root / "shares.png")])
    assert inside.exit_code == 2 and inside.output.count("\n") == 1 and "inside the output root" in inside.output
    monkeypatch.chdir(root)  # the default, from inside the root: refused too
    assert runner.invoke(app, ["stats", "."]).exit_code == 2
    assert sorted(p.relative_to(root) for p in root.rglob("*")) == before


ROOT_COMMANDS = (
    ["status"], ["verify"], ["query"], ["stats"], ["export", "--format", "idda", "--to", "EXPORT"],
    ["distances"], ["card"], ["shifts"],
)


def test_a_missing_root_gets_one_sentence_from_every_command(tmp_path):
    from pipeline.cli.data import register

    register(app)
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "a.txt").write_text("not a dataset")
    for where in (tmp_path / "missing", tmp_path / "notes"):
        want = (f"error: {where} is not an output root (no idda-root.json, run.json or manifest/ there); "
                f"`idda produce --out {where}` makes one")
        for command in ROOT_COMMANDS:
            args = [a.replace("EXPORT", str(tmp_path / "export")) for a in command[1:]]
            result = runner.invoke(app, [command[0], str(where), *args])
            if command[0] == "shifts" and "PyTorch" in result.output:  # without torch it says that first
                continue
            assert result.exit_code == 2, (command, result.output)
            assert result.output.splitlines() == [want], (command, result.output)
    assert not (tmp_path / "export").exists()


def test_a_bad_option_value_is_one_error_line_not_a_usage_box(tmp_path):
    for args, needle in (
        (["plan", "--frames-per-scenario", "x"], "Invalid value for '--frames-per-scenario'"),
        (["produce", "--out", str(tmp_path / "o"), "--width", "wide"], "Invalid value for '--width'"),
        (["query", str(tmp_path), "--total", "1.5"], "Invalid value for '--total'"),
        (["plan", "--scale", "half"], "Invalid value for '--scale'"),
        (["plan", "--no-such-option"], "No such option: --no-such-option"),
        (["query"], "Missing argument"),
    ):
        result = runner.invoke(app, args, prog_name="idda")
        assert result.exit_code == 2, (args, result.output)
        lines = result.output.splitlines()
        assert len(lines) == 1 and lines[0].startswith("error: ") and needle in lines[0], (args, result.output)
        assert lines[0].endswith(f"; `idda {args[0]} -h` lists the options"), lines
        assert "Usage:" not in result.output and "Try " not in result.output
    assert not (tmp_path / "o").exists()
    help_text = runner.invoke(app, [])  # `idda` alone still prints the help
    assert "Commands" in help_text.output and "error:" not in help_text.output
