"""Issue 25: paired scenes. New roots' episode seeds leave the weather out, so an episode is the
same scene under every weather (labels equal pixel for pixel; particles are on RGB only); roots
made before pairing keep their seeds; `idda query --paired` returns the aligned frames."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pyarrow.csv as pv
import pytest
from typer.testing import CliRunner

from domains.catalog import scenario
from outputs.table import read_output
from manifests.reader import read_manifest
from manifests.schema import part_path
from manifests.schema import NEW_RULES, OLD_RULES
from roots.episode_spec import PAIRED, UNPAIRED, episode_seed
from pipeline.cli import app
from pipeline.cli.domain_files import root_pairing, root_rules
from pipeline.settings import PlanConfig, RunConfig
from tests.roots import as_made_before, render_root

runner = CliRunner()
DOMAINS = "T01_CN_A,T01_HRN_A,T01_SN_A"


def _config(pairing: int) -> RunConfig:
    return RunConfig(plan=PlanConfig(domains=DOMAINS, frames_per_scenario=2, width=64, height=36, seed=4,
                                     outputs=("rgb", "depth_raw", "semantic_raw"), pairing=pairing), world="test")


@pytest.fixture(scope="module")
def paired_root(tmp_path_factory):
    root = tmp_path_factory.mktemp("paired")
    render_root(root, _config(PAIRED))
    return root


def test_paired_seeds_leave_the_weather_out_and_old_seeds_stay():
    cn, hrn, sn = (scenario(f"T01_{w}_A") for w in ("CN", "HRN", "SN"))
    assert episode_seed(4, cn, 2, PAIRED) == episode_seed(4, hrn, 2, PAIRED) == episode_seed(4, sn, 2, PAIRED)
    assert len({episode_seed(4, s, e, PAIRED) for s in (cn, scenario("T02_CN_A"), scenario("T01_CN_J"))
                for e in (0, 1)}) == 6
    # unpaired (roots from before): as always, a seed per weather
    assert episode_seed(4, cn, 2) == episode_seed(4, cn, 2, UNPAIRED) != episode_seed(4, hrn, 2)
    assert PlanConfig().pairing == PAIRED and PlanConfig().to_dict()["pairing"] == 1


def test_semantic_frames_match_across_weathers(paired_root):
    table = read_manifest(str(paired_root))
    assert json.loads((paired_root / "run.json").read_text())["config"]["pairing"] == 1 and root_pairing(
        str(paired_root)) == PAIRED
    rows = {(r["weather"], r["frame"]): r for r in table.to_pylist()}
    assert len({r["seed"] for r in rows.values()}) == 1
    for frame in (0, 1):
        labels = {w: read_output("semantic_raw", (paired_root / rows[w, frame]["semantic_raw_path"]).read_bytes())
                  for w in ("CN", "HRN", "SN")}
        depth = {w: (paired_root / rows[w, frame]["depth_raw_path"]).read_bytes() for w in ("CN", "HRN", "SN")}
        assert np.array_equal(labels["CN"], labels["HRN"]) and np.array_equal(labels["CN"], labels["SN"])
        assert depth["CN"] == depth["HRN"] == depth["SN"]
        rgb = {w: (paired_root / rows[w, frame]["rgb_path"]).read_bytes() for w in ("CN", "HRN", "SN")}
        assert len(set(rgb.values())) == 3  # the looks differ


def test_a_paired_root_verifies(paired_root):
    result = runner.invoke(app, ["verify", str(paired_root), "--no-ray"])
    assert result.exit_code == 0 and result.output.startswith("OK"), result.output


def test_query_returns_aligned_pairs(paired_root, tmp_path):
    out = tmp_path / "pairs.csv"
    result = runner.invoke(app, ["query", str(paired_root), "--paired", "SN,CN", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "4 frames selected" in result.output and "T01_HRN_A" not in result.output
    back = pv.read_csv(out)
    got = list(zip(back.column("weather").to_pylist(), back.column("frame").to_pylist()))
    assert got == [("SN", 0), ("CN", 0), ("SN", 1), ("CN", 1)]
    for bad, words in ((["--paired", "CN"], "two or more different weathers"),
                       (["--paired", "CN,XX"], "unknown weather 'XX'"),
                       (["--paired", "CN,SN", "--total", "2"], "not both")):
        result = runner.invoke(app, ["query", str(paired_root), *bad])
        lines = result.output.strip().splitlines()
        assert result.exit_code == 2 and len(lines) == 1 and words in lines[0], result.output


def test_a_root_from_before_pairing_keeps_its_seeds_and_bytes(tmp_path):
    """A root whose run.json has no "pairing" is unpaired for its life: the CLI reads it so, and
    re-rendering a lost episode gives the old bytes."""
    root = tmp_path / "old"
    storage = render_root(root, _config(UNPAIRED))
    as_made_before(storage, "pairing")
    assert root_pairing(str(root)) == UNPAIRED
    table = read_manifest(str(root))
    seeds = {r["scenario"]: r["seed"] for r in table.to_pylist()}
    assert seeds == {s: episode_seed(4, scenario(s), 0) for s in DOMAINS.split(",")} and len(set(seeds.values())) == 3
    before = {p: (root / p).read_bytes() for p in table.column("rgb_path").to_pylist()}
    storage.delete(part_path("T01_SN_A", 0))  # the episode is no longer done
    render_root(root, _config(root_pairing(str(root))))  # what `idda produce` on this root plans
    assert {p: (root / p).read_bytes() for p in before} == before
    result = runner.invoke(app, ["verify", str(root), "--no-ray"])
    assert result.exit_code == 0 and result.output.startswith("OK"), result.output
    # a paired run into it is refused: its frames would not match
    with pytest.raises(Exception, match="pairing"):
        render_root(root, _config(PAIRED))


def test_every_weather_of_a_scene_shares_its_split(paired_root, tmp_path):
    """Issue 32: a new root (run.json "rules": 1) draws the split per scene, so the three weathers of
    T01 A episode 0 are in one split (the old rule put them in train, val and test); an --extend to
    another weather and a viewpoint that comes first in table order keeps every scene's split."""
    assert json.loads((paired_root / "run.json").read_text())["config"]["rules"] == NEW_RULES
    assert root_rules(str(paired_root)) == NEW_RULES
    assert set(read_manifest(str(paired_root)).column("split").to_pylist()) == {"train"}
    root = tmp_path / "grown"
    small = RunConfig(plan=PlanConfig(domains="T01_CN_M,T01_CN_J", frames_per_scenario=1, width=32, height=32,
                                      seed=4, outputs=("semantic_raw",)), world="test")
    render_root(root, small)
    before = {r["scenario"]: r["split"] for r in read_manifest(str(root)).to_pylist()}
    assert before == {"T01_CN_M": "train", "T01_CN_J": "val"}
    grown = RunConfig(plan=replace(small.plan, domains="towns=T01 weathers=CN,FG viewpoints=A,M,J"), world="test")
    render_root(root, grown, extend=True)
    after = {r["scenario"]: r["split"] for r in read_manifest(str(root)).to_pylist()}
    assert {s: after[s] for s in before} == before and after["T01_FG_M"] == "train" and after["T01_FG_J"] == "val"
    assert after["T01_CN_A"] == after["T01_FG_A"] == "test"  # a new scene comes after the root's own
    result = runner.invoke(app, ["verify", str(root), "--no-ray"])
    assert result.exit_code == 0 and result.output.startswith("OK"), result.output


def test_a_root_from_before_scene_splits_keeps_its_splits_and_bytes(tmp_path):
    """A paired root whose run.json has no "rules" keeps splits per scenario place for its life:
    re-rendering a lost episode gives its old bytes and split, verify passes, and `query --paired`
    leaves out (and says so) the frames whose weathers straddle splits."""
    root = tmp_path / "old-splits"
    storage = render_root(root, RunConfig(plan=replace(_config(PAIRED).plan, rules=OLD_RULES), world="test"))
    as_made_before(storage, "rules")
    assert root_rules(str(root)) == OLD_RULES
    table = read_manifest(str(root))
    splits = {r["scenario"]: r["split"] for r in table.to_pylist()}
    assert splits == {"T01_CN_A": "train", "T01_HRN_A": "val", "T01_SN_A": "test"}
    files = [p for column in ("rgb_path", "semantic_raw_path") for p in table.column(column).to_pylist()]
    before = {p: (root / p).read_bytes() for p in files}
    storage.delete(part_path("T01_SN_A", 0))
    render_root(root, RunConfig(plan=replace(_config(root_pairing(str(root))).plan, rules=root_rules(str(root))),
                                world="test"))
    assert {p: (root / p).read_bytes() for p in before} == before
    assert {r["scenario"]: r["split"] for r in read_manifest(str(root)).to_pylist()} == splits
    result = runner.invoke(app, ["verify", str(root), "--no-ray"])
    assert result.exit_code == 0 and result.output.startswith("OK"), result.output
    result = runner.invoke(app, ["query", str(root), "--paired", "CN,SN"])
    assert result.exit_code == 2 and "left out 2 frame(s) whose weathers lie in different splits" in result.output
    with pytest.raises(Exception, match="rules"):  # a run of the new rules into it is refused
        render_root(root, _config(PAIRED))
