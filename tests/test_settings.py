"""Issue 36: a run's settings have one home (pipeline.settings). The tables the run record, the config
guard and the readers of old records use are read from the settings' fields; roots/, which does not
import the pipeline, is handed the record's shape by the commands that read run.json."""

from __future__ import annotations

import dataclasses
import json

from typer.testing import CliRunner

from manifests.schema import OLD_RULES, RUN_FILE
from outputs.table import SEED_OUTPUTS
from pipeline.cli import app
from pipeline.settings import (CONFIG_SHAPE, CONFIG_TYPES, FRAME_DEFINING, OPTIONAL_CONFIG, RECORDED_DEFAULTS,
                               PlanConfig, RunConfig, recorded)
from roots.contract import ROOT_MARKER, ROOT_MARKER_BODY
from roots.episode_spec import FRAME_PERIOD_S, UNPAIRED
from roots.verify import verify
from storage import Storage


def test_the_recorded_tables_are_the_settings_fields():
    """Every field of PlanConfig and RunConfig (but the nested plan) is a recorded setting, and the
    tables say what the hand-kept ones said before (run_file's CONFIG_TYPES and OPTIONAL_CONFIG,
    provenance's FRAME_DEFINING, the defaults of records from before a setting)."""
    fields = [f.name for f in dataclasses.fields(PlanConfig)] + ["world"]
    assert list(CONFIG_TYPES) == fields
    assert set(RunConfig(plan=PlanConfig()).to_dict()) == set(CONFIG_TYPES) - {"catalog"}  # catalog: user entries only
    assert set(FRAME_DEFINING) == {"seed", "width", "height", "world", "outputs", "rgb_format", "frame_interval_s",
                                   "pairing", "rules", "rig"}
    assert set(OPTIONAL_CONFIG) == {"world", "outputs", "rgb_format", "catalog", "frame_interval_s", "pairing", "rules",
                                    "rig"}
    assert RECORDED_DEFAULTS == {"outputs": list(SEED_OUTPUTS), "rgb_format": "png", "frame_interval_s": FRAME_PERIOD_S,
                                 "pairing": UNPAIRED, "rules": OLD_RULES, "rig": "front"}
    assert CONFIG_SHAPE.types == CONFIG_TYPES and CONFIG_SHAPE.optional == OPTIONAL_CONFIG


def test_a_record_from_before_a_setting_reads_as_it_meant_and_shares_nothing():
    old = recorded({"domains": "T01_CN_A", "width": 64, "height": 36, "seed": 1})
    assert old["outputs"] == list(SEED_OUTPUTS) and old["pairing"] == UNPAIRED and "world" not in old
    old["outputs"].append("instance")  # a caller's change stays its own
    assert recorded({})["outputs"] == list(SEED_OUTPUTS)
    assert recorded({"pairing": 1})["pairing"] == 1


def _root_with_record(path, **config) -> str:
    """An output root holding only its marker and a run.json (no checksum, as old roots wrote it)."""
    path.mkdir()
    (path / ROOT_MARKER).write_bytes(ROOT_MARKER_BODY)
    base = RunConfig(plan=PlanConfig(domains="T01_CN_A", frames_per_scenario=1, width=64, height=36)).to_dict()
    record = {"config": {**base, **config}, "history": []}
    (path / RUN_FILE).write_text(json.dumps(record))
    return str(path)


def test_verify_checks_the_recorded_config_by_the_settings_shape(tmp_path):
    """The shape reaches roots.verify from the command: a width recorded as a string is a damaged
    run.json (bad-run), so verify never compares frames against it."""
    root = _root_with_record(tmp_path / "root", width="64")
    problems = verify(Storage.from_uri(root), shape=CONFIG_SHAPE).problems
    assert [(p.kind, p.path) for p in problems] == [("bad-run", RUN_FILE)] and "config 'width' is '64'" in problems[0].detail
    result = CliRunner().invoke(app, ["verify", root, "--no-ray"])
    assert result.exit_code != 0 and "config 'width' is '64'" in result.output, result.output
    sound = _root_with_record(tmp_path / "sound")
    assert verify(Storage.from_uri(sound), shape=CONFIG_SHAPE).problems == []
