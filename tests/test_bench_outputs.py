"""`BENCH=outputs make bench` at a tiny size: the same probes, before (the baseline tree) and after."""

from __future__ import annotations

import json

import pytest

from benchmarks import bench_outputs as bench


def test_sets_add_each_opt_in_output_to_the_default():
    from outputs.table import DEFAULT_OUTPUTS

    assert bench._outputs("default") == DEFAULT_OUTPUTS
    assert bench._outputs("+flow") == (*DEFAULT_OUTPUTS, "flow")
    assert bench._outputs("+all")[-3:] == bench.OPT_IN
    assert bench._outputs(bench.ISAL_SET) == DEFAULT_OUTPUTS  # the same outputs, deflated as before issue 21.11
    long = {"frame": 5.0, "frame_cpu": 9.0, "outputs": 1.0, "sink": 2.0, "bytes": {"rgb": 10}}
    short = {"frame": 2.0, "frame_cpu": 3.0, "outputs": 0.4, "sink": 0.5, "bytes": {"rgb": 10}}
    got = bench.per_frame(long, short, 4)
    assert got.pop("bytes") == {"rgb": 10}
    assert got == pytest.approx({"frame": 1.0, "frame_cpu": 2.0, "outputs": 0.2, "sink": 0.5})


def test_bench_outputs_end_to_end_tiny(tmp_path):
    result = bench.main(out_dir=str(tmp_path), frames=2, width=64, height=36, rounds=1, world="test")
    assert result["before_missing"] is None, result["before_missing"]  # the baseline tree ran
    assert list(result["after"]) == list(bench.SETS)
    default = set(result["after"]["default"]["bytes"])
    assert set(result["before"]["bytes"]) == default  # the same eight outputs on both sides
    for name in bench.OPT_IN:
        assert set(result["after"][f"+{name}"]["bytes"]) == default | {name}
        assert result["after"][f"+{name}"]["bytes"][name] > 0
    assert set(result["after"]["+all"]["bytes"]) == default | set(bench.OPT_IN)
    v = result["verdict"]  # issue 24's question, asked with the baseline's deflater on both sides
    same = result["after"][bench.ISAL_SET]
    assert set(same["bytes"]) == default and same["bytes"] != result["after"]["default"]["bytes"]  # other PNG bytes
    assert v["measured"] and v["wall_ratio"] == pytest.approx(same["frame"] / result["before"]["frame"])
    assert v["deflater_cpu"] == pytest.approx(bench.added_by(result["after"]["default"], same, "rounds_cpu"))
    assert json.loads((tmp_path / "bench_outputs.json").read_text())["verdict"] == v
    page = (tmp_path / "bench_outputs.md").read_text()
    assert "| +flow |" in page and "## The default outputs before and after issue 24" in page
    assert ("**yes**" in page) == v["within"]
