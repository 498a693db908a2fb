"""Verify at scale and repair's safety (issues 21 and 22): verify as Ray tasks
with the same verdicts as in this process, scoped verify and repair, symbolic
links never followed, config checked before anything is deleted, a live
producer's frames in progress, the Makefile's full-scale command."""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from manifests.reader import read_manifest
from roots.run_file import read_record, record_bytes
from manifests.schema import RUN_FILE, index_path
from roots.verify import Scope, verify
from pipeline.cli import app
from pipeline.driver import produce
from storage import Storage
from tests.roots import part_of
from tests.test_integrity import one_line_error
from tests.test_produce import ARGS, ray_local, tree_digest  # noqa: F401 (fixtures)

pytestmark = pytest.mark.slow
runner = CliRunner()
REPO = Path(__file__).resolve().parents[1]


def full_listing(root: Path) -> dict[str, str]:
    """Every file under ``root`` (links not followed) with its checksum: what a refusal must leave as it was."""
    out = {}
    for folder, dirs, files in os.walk(root):
        for name in files + [d for d in dirs if os.path.islink(os.path.join(folder, d))]:
            path = Path(folder) / name
            rel = path.relative_to(root).as_posix()
            if rel.startswith("_lease/"):
                continue
            out[rel] = ("link:" + os.readlink(path)) if path.is_symlink() else hashlib.sha256(path.read_bytes()).hexdigest()
    return out


@pytest.fixture()
def copy(reference, tmp_path) -> Path:
    root = tmp_path / "root"
    shutil.copytree(reference, root)
    return root


def stray(root: Path, scenario: str, episode: int, frame: int = 0, output: str = "rgb") -> Path:
    """Where a frame file of ours by name, that no part lists, goes in a new root (its episode's folder)."""
    folder = root / scenario / f"e{episode:04d}" / output
    folder.mkdir(parents=True, exist_ok=True)
    return folder / f"{episode:04d}_{frame:03d}_{scenario}.png"


def damage(root: Path) -> None:
    """One corrupt file, one missing file, one stray (ours by name), one truncated part
    (whose 32 files are then strays too: its episode renders again)."""
    table = read_manifest(str(root))
    corrupt = root / table.column("rgb_path")[0].as_py()
    corrupt.write_bytes(corrupt.read_bytes()[:-4] + b"XXXX")
    (root / table.column("depth_raw_path")[len(table) - 1].as_py()).unlink()
    stray(root, "T07_HRN_A", 7).write_bytes(b"stray")
    with open(root / part_of(root, "T07_CN_A", 0), "r+b") as f:
        f.truncate(100)


# -- verify on Ray --------------------------------------------------------------------
def test_verify_gives_the_same_report_on_ray_and_in_process(ray_local, copy):
    from pipeline.verify_ray import choose_runner

    damage(copy)
    plain = verify(str(copy))
    on_ray = verify(str(copy), runner=choose_runner(use_ray=True))
    assert not plain.ok and plain.counts() == {"corrupt": 1, "missing": 1, "extra": 33, "bad-part": 1}
    assert on_ray.problems == plain.problems
    assert (on_ray.files_checked, on_ray.bytes_checked, on_ray.episodes_checked) == (
        plain.files_checked, plain.bytes_checked, plain.episodes_checked)
    assert plain.episodes_checked == 4 and plain.first_hash_s is not None


def test_verify_cli_on_a_ray_cluster_of_its_own(copy):
    damage(copy)
    result = runner.invoke(app, ["verify", str(copy), "--ray", "--workers", "2"])
    assert result.exit_code == 1, result.output
    assert "FAILED: 1 bad-part, 1 corrupt, 33 extra, 1 missing" in result.output


def test_progress_lines_when_not_on_a_terminal():
    import io

    from roots.verify import VerifyProgress
    from pipeline.cli.app import VerifyDisplay

    stream = io.StringIO()
    display = VerifyDisplay(stream, every_s=10)
    for t, done in ((0, 0), (5, 1), (11, 2), (15, 3), (22, 4)):
        display.update(VerifyProgress(done, 4, 10 * done, t))
    lines = stream.getvalue().splitlines()
    assert lines == ["verify: 2/4 episodes, 20 files, 11 s", "verify: 4/4 episodes, 40 files, 22 s"]
    quiet = io.StringIO()  # a short run prints no progress
    VerifyDisplay(quiet, every_s=10).update(VerifyProgress(4, 4, 40, 1.0))
    assert quiet.getvalue() == ""


# -- scope ----------------------------------------------------------------------------
def test_verify_scoped_by_domains_and_since(copy):
    damage(copy)
    t01 = runner.invoke(app, ["verify", str(copy), "--domains", "T01_*_A"])
    assert t01.exit_code == 1 and "FAILED: 1 corrupt;" in t01.output, t01.output
    t07 = verify(str(copy), scope=Scope(scenarios=frozenset({"T07_CN_A", "T07_HRN_A"})))
    assert t07.counts() == {"bad-part": 1, "extra": 33, "missing": 1}
    old = time.time() - 3 * 3600  # every part and file written three hours ago, but one part
    for path in copy.rglob("*"):
        if path.is_file():
            os.utime(path, (old, old))
    os.utime(copy / part_of(copy, "T01_HRN_A", 0), None)
    scoped = verify(str(copy), scope=Scope(since=time.time() - 3600))
    assert scoped.episodes_checked == 1 and scoped.ok  # T01_HRN_A's files are intact; the damage is older
    result = runner.invoke(app, ["verify", str(copy), "--since", "1h"])
    assert result.exit_code == 0 and "checked 32 files" in result.output, result.output
    assert one_line_error(runner.invoke(app, ["verify", str(copy), "--since", "yesterday"])).startswith("error: --since")
    assert "--domains is empty" in one_line_error(runner.invoke(app, ["verify", str(copy), "--domains", " "]))


def test_repair_of_a_scope_verifies_and_touches_only_that_scope(ray_local, reference, copy):
    damage(copy)
    t01 = [a if a != "towns=T01,T07 weathers=CN,HRN viewpoints=A" else "towns=T01 weathers=CN,HRN viewpoints=A"
           for a in ARGS]
    result = runner.invoke(app, ["produce", *t01, "--out", str(copy), "--repair", "--extend"])
    assert result.exit_code == 0, result.output
    assert verify(str(copy), scope=Scope(scenarios=frozenset({"T01_CN_A", "T01_HRN_A"}))).ok
    # T07's damage is out of scope: its truncated part and stray are still there, untouched
    assert (copy / part_of(copy, "T07_CN_A", 0)).stat().st_size == 100
    assert stray(copy, "T07_HRN_A", 7).read_bytes() == b"stray"


# -- 21.1: never through a symbolic link -----------------------------------------------
def _linked_roots(reference, tmp_path) -> tuple[Path, Path]:
    """A root whose T01_CN_A folder is a link into a neighbour root, with damage behind the link."""
    root, neighbour = tmp_path / "root", tmp_path / "neighbour"
    shutil.copytree(reference, root)
    shutil.copytree(reference, neighbour)
    shutil.rmtree(root / "T01_CN_A")
    (root / "T01_CN_A").symlink_to(neighbour / "T01_CN_A", target_is_directory=True)
    stray(neighbour, "T01_CN_A", 5).write_bytes(b"neighbour's own")
    frame = next((neighbour / "T01_CN_A" / "e0000" / "depth_raw").iterdir())
    frame.write_bytes(frame.read_bytes()[:-3] + b"abc")
    return root, neighbour


def test_repair_refuses_a_folder_link_out_of_the_root(ray_local, reference, tmp_path):
    root, neighbour = _linked_roots(reference, tmp_path)
    before_root, before_neighbour = full_listing(root), full_listing(neighbour)
    line = one_line_error(runner.invoke(app, ["produce", *ARGS, "--out", str(root), "--repair"]))
    assert "T01_CN_A is a symbolic link" in line and "deletes nothing" in line
    assert full_listing(neighbour) == before_neighbour and full_listing(root) == before_root
    result = runner.invoke(app, ["verify", str(root)])  # verify lists the link, never what is behind it
    assert result.exit_code == 1 and "link     T01_CN_A" in result.output, result.output
    assert "missing" not in result.output and "corrupt" not in result.output and "0005_000" not in result.output


def test_repair_refuses_a_file_link_out_of_the_root(ray_local, reference, tmp_path):
    root, neighbour = tmp_path / "root", tmp_path / "neighbour"
    shutil.copytree(reference, root)
    shutil.copytree(reference, neighbour)
    rel = read_manifest(str(root)).column("rgb_path")[0].as_py()
    (root / rel).unlink()
    (root / rel).symlink_to(neighbour / rel)
    (neighbour / rel).write_bytes(b"changed in the neighbour")  # the link's target now looks corrupt
    before = full_listing(neighbour)
    line = one_line_error(runner.invoke(app, ["produce", *ARGS, "--out", str(root), "--repair"]))
    assert f"{rel} is a symbolic link" in line
    assert full_listing(neighbour) == before and (root / rel).is_symlink()


# -- 21.2: the config is checked before anything is deleted ----------------------------
def _foreign_run_json(root: Path, **changes) -> None:
    storage = Storage.from_uri(str(root))
    record = read_record(storage)
    record["config"] = {**record["config"], **changes}
    storage.write_bytes(RUN_FILE, record_bytes(record))  # a valid checksum: another run's record


@pytest.mark.parametrize("changes, options", [
    ({"seed": 8}, ["--seed", "8"]),  # run.json and the command agree, the rows do not
    ({"seed": 8}, []),  # run.json disagrees with the command
    ({"frames_per_scenario": 2}, ["--frames-per-scenario", "2"]),  # the rows hold more frames: a shrink
    ({"frames_per_scenario": 6}, []),
])
def test_repair_with_another_runs_config_deletes_nothing(ray_local, copy, changes, options):
    _foreign_run_json(copy, **changes)
    stray(copy, "T01_CN_A", 9).write_bytes(b"stray")  # something repair would delete
    before = full_listing(copy)
    args = list(ARGS)
    for i in range(0, len(options), 2):
        args[args.index(options[i]) + 1] = options[i + 1]
    result = runner.invoke(app, ["produce", *args, "--out", str(copy), "--repair"])
    one_line_error(result)
    assert full_listing(copy) == before


def test_repair_still_fixes_a_root_whose_run_json_is_its_own(ray_local, reference, copy):
    damage(copy)
    assert runner.invoke(app, ["produce", *ARGS, "--out", str(copy), "--repair"]).exit_code == 0
    assert verify(str(copy)).ok and tree_digest(copy) == tree_digest(reference)


# -- 21.10: a live producer's frames are in progress, not damage ------------------------
def test_verify_beside_a_live_producer_reports_in_progress(copy):
    from roots.lease import register_producer

    (copy / part_of(copy, "T01_CN_A", 0)).unlink()  # its frames are on disk, its part not yet
    (copy / index_path("T01_CN_A")).unlink()  # as produce does before it renders an episode again
    storage = Storage.from_uri(str(copy))
    producer = register_producer(storage)
    try:
        result = runner.invoke(app, ["verify", str(copy)])
        assert result.exit_code == 0, result.output
        assert "OK: " in result.output and "1 episode in progress" in result.output
        assert "extra" not in result.output and "--repair" not in result.output
        table = read_manifest(str(copy))
        (copy / table.column("rgb_path")[0].as_py()).unlink()
        result = runner.invoke(app, ["verify", str(copy)])
        assert result.exit_code == 1 and "FAILED: 1 missing" in result.output
        assert "when it has finished, run idda produce --repair" in result.output
        assert "Fix with" not in result.output
    finally:
        producer.release()
    result = runner.invoke(app, ["verify", str(copy)])  # no producer: those frames are strays
    assert result.exit_code == 1 and "extra" in result.output and "in progress" not in result.output


# -- issue 22: the README's full-dataset command ----------------------------------------
def _make_produce(*assignments: str) -> list[str]:
    out = subprocess.run(["make", "-n", "-C", str(REPO), "produce", *assignments], capture_output=True, text=True,
                         check=True).stdout
    line = next(line for line in out.replace("\\\n", " ").splitlines() if "idda produce" in line)
    import shlex

    return shlex.split(line)[2:]  # after ".venv/bin/idda produce"


@pytest.mark.parametrize("assignments, frames, size", [
    (("PRODUCE_ARGS=--scale 1",), 1_006_800, (1920, 1080)),
    (("SCALE=1",), 1_006_800, (1920, 1080)),
    (("SCALE=1", "WIDTH=960", "HEIGHT=540"), 1_006_800, (960, 540)),
    ((), 210, (480, 270)),  # the small default is unchanged
    (("PRODUCE_ARGS=--frames-per-scenario 3 --width 64",), 315, (64, 270)),
])
def test_make_produce_builds_a_command_the_cli_accepts(monkeypatch, assignments, frames, size):
    import sys

    from pipeline.planner import make_plan

    seen = []

    def fake_produce(config, progress=None, on_head_lost=None):
        seen.append(config)
        raise SystemExit(0)  # the plan is all this test wants

    # the CLI's own binding (imported at the top of pipeline.cli.app): patching pipeline.driver.produce would
    # leave the real one in place and start a full-scale run
    monkeypatch.setattr(sys.modules["pipeline.cli.app"], "run_produce", fake_produce)
    result = runner.invoke(app, ["produce", *_make_produce(*assignments)])
    assert result.exit_code == 0 and seen, result.output
    plan = seen[0].run.plan
    assert (plan.width, plan.height) == size and make_plan(plan).total_frames == frames


# -- issue 22: a root made before episode folders stays flat ---------------------------
def test_an_old_flat_root_resumes_extends_verifies_and_repairs(ray_local, reference, tmp_path):
    from dataclasses import replace

    from manifests.layout import FLAT, LAYOUT_KEY, layout_of_path
    from outputs.table import OUTPUTS
    from roots.contract import claim_root
    from manifests.schema import output_columns
    from pipeline.provenance import _fresh_record
    from tests.test_produce import PLAN, config

    root = tmp_path / "old"
    storage = Storage.from_uri(str(root))
    claim_root(storage)
    t01 = config(root, plan=replace(PLAN, domains="towns=T01 weathers=CN,HRN viewpoints=A"))
    record = _fresh_record(t01.run.to_dict())
    del record[LAYOUT_KEY]  # run.json as roots made before layouts were recorded
    storage.write_bytes(RUN_FILE, record_bytes(record))
    assert produce(t01).rendered_episodes == 2
    (root / part_of(root, "T01_HRN_A", 0)).unlink()  # killed before its part: resumed
    assert produce(t01).rendered_episodes == 1
    assert produce(config(root, extend=True)).rendered_episodes == 2  # T07 added, flat too
    assert read_record(storage)[LAYOUT_KEY] == FLAT

    def frames(where: Path) -> dict:
        table = read_manifest(str(where))
        rows = table.select(["scenario", "frame_id", *(c for o in OUTPUTS for c in output_columns(o))]).to_pylist()
        return {(r["scenario"], r["frame_id"], o): (r[f"{o}_path"], r[f"{o}_sha256"]) for r in rows for o in OUTPUTS}

    old, new = frames(root), frames(reference)
    assert {layout_of_path(path) for path, _ in old.values() if path is not None} == {FLAT}  # opt-in outputs: None
    assert {k: sha for k, (_, sha) in old.items()} == {k: sha for k, (_, sha) in new.items()}  # same bytes
    assert verify(str(root)).ok
    before = tree_digest(root)

    victim = root / old[("T07_CN_A", "0000_001", "depth_raw")][0]
    victim.write_bytes(victim.read_bytes()[:-4] + b"XXXX")
    flat_stray = root / "T01_CN_A" / "rgb" / "0000_009_T01_CN_A.png"
    flat_stray.write_bytes(b"stray")
    not_ours = stray(root, "T01_CN_A", 0, 9)  # the episode-folder layout's name: not this root's
    not_ours.write_bytes(b"user data")
    report = verify(str(root))
    assert sorted((p.kind, p.path) for p in report.problems) == [
        ("corrupt", victim.relative_to(root).as_posix()), ("extra", "T01_CN_A/rgb/0000_009_T01_CN_A.png")]
    assert produce(config(root, repair=True)).rendered_episodes == 1
    assert not flat_stray.exists() and not_ours.read_bytes() == b"user data"
    not_ours.unlink()
    assert verify(str(root)).ok and tree_digest(root) == before
