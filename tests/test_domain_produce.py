"""Issue 25.1 end to end: a user-declared weather (derived from CN, other sun and fog)
is produced on real Ray workers at 64x36 in the test world; the root's run.json records
the entry, so resume, verify and query need no file, and a changed entry is refused."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from manifests.reader import read_manifest
from pipeline.cli import app

pytestmark = pytest.mark.slow
runner = CliRunner()

FOG = '[[weather]]\ncode = "FG1"\nlike = "CN"\nname = "FoggyNoon"\nsun_elevation_deg = 35.0\nvisibility_m = {fog}\n'
ARGS = ["--frames-per-scenario", "2", "--width", "64", "--height", "36", "--seed", "7", "--world", "test"]


@pytest.fixture(scope="module")
def ray_local():
    import ray

    ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()


def _digests(root: Path, scenario: str) -> dict[str, str]:
    return {p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted((root / scenario).rglob("*.png"))}


def test_user_weather_end_to_end(ray_local, tmp_path):
    fog = tmp_path / "fog.toml"
    fog.write_text(FOG.format(fog=3000.0))
    root = tmp_path / "root"
    domains = ["--domains", "towns=T01 weathers=CN,FG1 viewpoints=A"]
    result = runner.invoke(app, ["produce", *domains, *ARGS, "--catalog", str(fog), "--out", str(root)])
    assert result.exit_code == 0, result.output
    table = read_manifest(str(root))
    assert sorted(table.column("scenario").to_pylist()) == ["T01_CN_A"] * 2 + ["T01_FG1_A"] * 2
    recorded = json.loads((root / "run.json").read_text())["config"]["catalog"]
    assert [row["code"] for row in recorded["weather"]] == ["FG1"] and recorded["weather"][0]["visibility_m"] == 3000.0
    assert recorded["weather"][0]["sky_zenith"] == [38, 98, 190]  # resolved: CN's, not a reference to it

    # the built-in scenario keeps its bytes: the same frames as a run without the file
    plain = tmp_path / "plain"
    result = runner.invoke(app, ["produce", "--domains", "T01_CN_A", *ARGS, "--out", str(plain)])
    assert result.exit_code == 0, result.output
    assert _digests(root, "T01_CN_A") == _digests(plain, "T01_CN_A") != {}
    # a new root is paired (docs/weathers.md): the fog entry's episode is CN's scene, so its labels
    # are CN's byte for byte, and only its colour differs
    fog_files, noon_files = _digests(root, "T01_FG1_A"), _digests(root, "T01_CN_A")
    same = {k.replace("FG1", "CN"): v for k, v in fog_files.items() if "/rgb/" not in k}
    assert same and same == {k: v for k, v in noon_files.items() if "/rgb/" not in k}
    rgb = {v for k, v in fog_files.items() if "/rgb/" in k}
    assert rgb and rgb.isdisjoint(noon_files.values())

    # without the file: resume, verify and query read the entry from run.json
    result = runner.invoke(app, ["produce", *domains, *ARGS, "--out", str(root)])
    assert result.exit_code == 0 and "nothing to render" in result.output, result.output
    result = runner.invoke(app, ["verify", str(root), "--domains", "weathers=FG1", "--no-ray"])
    assert result.exit_code == 0 and result.output.startswith("OK"), result.output
    result = runner.invoke(app, ["query", str(root), "--domains", "weathers=FG1"])
    assert result.exit_code == 0 and "T01_FG1_A" in result.output and "2 frames selected" in result.output, result.output

    # a changed entry is refused, like any frame-defining change; an added one needs --extend
    fog.write_text(FOG.format(fog=2000.0))
    result = runner.invoke(app, ["produce", *domains, *ARGS, "--catalog", str(fog), "--out", str(root), "--extend"])
    assert result.exit_code == 2 and "other parameters for the domain weather 'FG1'" in result.output, result.output
    fog.write_text(FOG.format(fog=3000.0) + FOG.format(fog=1000.0).replace("FG1", "FG2"))
    result = runner.invoke(app, ["produce", *domains, *ARGS, "--catalog", str(fog), "--out", str(root)])
    assert result.exit_code == 2 and "pass --extend" in result.output, result.output
