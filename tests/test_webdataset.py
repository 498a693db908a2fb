"""WebDataset shards (exports.webdataset): read back with the real ``webdataset``
package in a torch DataLoader and with Ray Data's ``read_webdataset``, no
project code in the loop, every byte checked against the root; bounded,
deterministic, per-split shard sets; resuming, --force and s3 targets."""

from __future__ import annotations

import csv
import glob
import json
import os
import re
import tarfile
from pathlib import Path

import pytest
from typer.testing import CliRunner

from exports import export as ex
from exports import webdataset as wd
from manifests.query import Query
from manifests.reader import read_manifest
from roots.contract import RootError
from manifests.schema import output_columns
from tests.s3_server import s3_server  # noqa: F401  (fixture)
from tests.test_export import cli_app, make_tiny_root, upload_root

BOUND = 64 * 1024  # a few 64x36 frames per shard, so every split has several shards


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    return make_tiny_root(tmp_path_factory)


@pytest.fixture(scope="module")
def rows(root):
    from storage import Storage

    return {r["uid"]: r for r in read_manifest(Storage.from_uri(str(root))).to_pylist()}


@pytest.fixture(scope="module")
def shards(root, tmp_path_factory) -> Path:
    target = tmp_path_factory.mktemp("wds") / "export"
    ex.export(ex.ExportConfig(root=str(root), to=str(target), format="webdataset", shard_size=BOUND))
    return target


def expected_sample(root: Path, row: dict) -> dict[str, bytes]:
    """The members a frame's sample must hold: every output file of the row, and the row as JSON."""
    sample = {}
    for name in ex_outputs(row):
        path = row[output_columns(name)[0]]
        sample[f"{name}{os.path.splitext(path)[1]}"] = (root / path).read_bytes()
    return sample


def ex_outputs(row: dict) -> list[str]:
    from outputs.table import OUTPUTS

    return [o for o in OUTPUTS if row.get(output_columns(o)[0])]


def _refuse(name: str):
    raise AssertionError(f"{name} in a sample's JSON: not strict JSON")


def check_samples(samples: list[dict], root: Path, rows: dict) -> None:
    """``samples`` ({"__key__", ext: bytes, ...}) are exactly the root's frames, byte for byte."""
    assert sorted(s["__key__"] for s in samples) == sorted(rows)
    for s in samples:
        row = rows[s["__key__"]]
        got = {k: bytes(v) for k, v in s.items() if not k.startswith("__")}
        text = got.pop("json").decode()
        assert json.loads(text, parse_constant=_refuse) == wd.strict_json(json.loads(json.dumps(row)))
        assert got == expected_sample(root, row)


def test_shards_stream_into_a_torch_dataloader_byte_for_byte(shards, root, rows):
    import torch.utils.data
    import webdataset

    urls = sorted(glob.glob(str(shards / "*" / "*.tar")))
    dataset = webdataset.WebDataset(urls, shardshuffle=False, empty_check=False)
    samples = list(torch.utils.data.DataLoader(dataset, batch_size=None, num_workers=0))
    check_samples(samples, root, rows)
    splits = {r["split"] for r in rows.values()}
    assert len(splits) >= 2  # the tiny root has several splits: one shard set each
    for s in samples:  # each sample sits in its own split's shard set
        assert os.path.basename(os.path.dirname(s["__url__"])) == rows[s["__key__"]]["split"]
    for url in urls:
        assert os.path.getsize(url) <= BOUND
    assert len(urls) > len(splits)  # the bound made several shards per split


def test_ray_read_webdataset_gives_the_same_bytes(shards, root, rows):
    import ray

    ray.init(address="local", num_cpus=1, include_dashboard=False, ignore_reinit_error=True)
    try:
        samples = []
        for split in sorted(p.name for p in shards.iterdir() if p.is_dir() and p.name != wd.STATS):
            samples += ray.data.read_webdataset(str(shards / split), decoder=None).take_all()
    finally:
        ray.shutdown()
    check_samples(samples, root, rows)


def test_the_index_lists_every_shard_and_frame(shards, rows):
    index = json.loads((shards / wd.SHARDS_INDEX).read_text())
    with open(shards / wd.FRAMES_INDEX) as f:
        frames = list(csv.DictReader(f))
    assert sorted(f["uid"] for f in frames) == sorted(rows)
    assert sum(s["frames"] for s in index) == len(rows)
    for entry in index:
        assert os.path.getsize(shards / entry["name"]) == entry["bytes"]
    for f in frames:  # offset: where the sample's first member's header starts
        with open(shards / f["shard"], "rb") as tar:
            tar.seek(int(f["offset"]))
            header = tarfile.TarInfo.frombuf(tar.read(512), "utf-8", "surrogateescape")
        assert header.name.startswith(f["uid"] + ".") and f["split"] == rows[f["uid"]]["split"]
    marker = json.loads((shards / ex.MARKER).read_text())
    assert marker["format"] == "webdataset" and marker["frames"] == len(rows)


def test_same_root_and_selection_give_the_same_shard_bytes(shards, root, tmp_path):
    again = tmp_path / "again"
    ex.export(ex.ExportConfig(root=str(root), to=str(again), format="webdataset", shard_size=BOUND, threads=1))
    names = sorted(p.relative_to(shards).as_posix() for p in shards.rglob("*") if p.is_file())
    assert names == sorted(p.relative_to(again).as_posix() for p in again.rglob("*") if p.is_file())
    for name in names:
        if name != ex.MARKER:  # the marker names the target's tree, the same here too
            assert (shards / name).read_bytes() == (again / name).read_bytes(), name
    with tarfile.open(shards / [n for n in names if n.endswith(".tar")][-1]) as tar:
        assert {(m.mtime, m.uid, m.gid, m.uname, m.gname, m.mode) for m in tar.getmembers()} == {(0, 0, 0, "", "", 0o644)}


def test_selected_outputs_only(root, rows, tmp_path):
    target = tmp_path / "rgb"
    report = ex.export(ex.ExportConfig(root=str(root), to=str(target), format="webdataset",
                                       outputs=("rgb", "semantic_raw"), query=Query(domains="T01_CS_*")))
    assert report.frames == sum(r["scenario"].startswith("T01_CS_") for r in rows.values())
    names = [m for p in sorted(target.rglob("*.tar")) for m in tarfile.open(p).getnames()]
    assert {n.split(".", 1)[1] for n in names} == {"rgb.png", "semantic_raw.png", "json"}
    with pytest.raises(ValueError, match="'flow' output"):
        ex.export(ex.ExportConfig(root=str(root), to=str(tmp_path / "flow"), format="webdataset", outputs=("flow",)))


def test_an_interrupted_export_resumes_and_rewrites_only_what_is_not_done(shards, root, tmp_path, monkeypatch):
    target = tmp_path / "resumed"
    real = wd.shard_bytes
    calls = []

    def dies_on_the_fourth(source, shard, pool):
        calls.append(shard.name)
        if len(calls) == 4:
            raise KeyboardInterrupt  # as Ctrl-C or a kill mid-export
        return real(source, shard, pool)

    monkeypatch.setattr(wd, "shard_bytes", dies_on_the_fourth)
    config = ex.ExportConfig(root=str(root), to=str(target), format="webdataset", shard_size=BOUND)
    with pytest.raises(KeyboardInterrupt):
        ex.export(config)
    assert not (target / ex.MARKER).exists()
    first, second = calls[0], calls[1]
    with open(target / second, "r+b") as f:  # a damaged finished shard is written again
        f.seek(700)
        f.write(b"\xff")
    calls.clear()
    report = ex.export(config)  # no --force needed: the same plan resumes
    assert report.resumed == 2 and first not in calls and second in calls
    for p in shards.rglob("*"):
        if p.is_file() and p.name != ex.MARKER:
            assert (target / p.relative_to(shards)).read_bytes() == p.read_bytes(), p
    calls.clear()
    assert ex.export(config).resumed == len(list(shards.rglob("*.tar"))) and not calls  # finished: all kept


def test_force_replaces_only_an_export(root, shards, tmp_path):
    import shutil

    target = tmp_path / "t"
    shutil.copytree(shards, target)
    other = ex.ExportConfig(root=str(root), to=str(target), format="webdataset", shard_size=2 * BOUND)
    with pytest.raises(ValueError, match="another selection.*--force"):
        ex.export(other)
    (target / "notes.txt").write_text("mine")
    with pytest.raises(RootError, match="notes.txt"):
        ex.export(ex.ExportConfig(**{**other.__dict__, "force": True}))
    (target / "notes.txt").unlink()
    ex.export(ex.ExportConfig(**{**other.__dict__, "force": True}))
    assert len(list(target.rglob("*.tar"))) < len(list(shards.rglob("*.tar")))
    assert json.loads((target / wd.PLAN).read_text())["shard_size"] == 2 * BOUND
    # a finished export of another format: replaced only with --force, as every export
    cs = tmp_path / "cs"
    ex.export(ex.ExportConfig(root=str(root), to=str(cs), format="idda"))
    with pytest.raises(ValueError, match="--force"):
        ex.export(ex.ExportConfig(root=str(root), to=str(cs), format="webdataset"))
    ex.export(ex.ExportConfig(root=str(root), to=str(cs), format="webdataset", force=True))
    assert sorted(p.name for p in cs.iterdir()) == sorted([ex.MARKER, wd.PLAN, wd.SHARDS_INDEX, wd.FRAMES_INDEX,
                                                           wd.STATS, *{r for r in ("train", "val", "test")
                                                                       if (cs / r).exists()}])
    os.symlink(cs, tmp_path / "link")
    with pytest.raises(RootError, match="symlink"):
        ex.export(ex.ExportConfig(root=str(root), to=str(tmp_path / "link"), format="webdataset", force=True))
    with pytest.raises(RootError, match="output root"):
        ex.export(ex.ExportConfig(root=str(root), to=str(root / "wds"), format="webdataset"))


def test_s3_target_holds_the_same_bytes(root, shards, s3_server):  # noqa: F811
    from storage import Storage

    uri = s3_server.uri("wds")
    ex.export(ex.ExportConfig(root=str(root), to=uri, format="webdataset", shard_size=BOUND))
    remote = Storage.from_uri(uri)
    for p in shards.rglob("*.tar"):
        assert remote.read_bytes(p.relative_to(shards).as_posix()) == p.read_bytes()
    report = ex.export(ex.ExportConfig(root=str(root), to=uri, format="webdataset", shard_size=BOUND))
    assert report.resumed == len(list(shards.rglob("*.tar")))
    remote.write_bytes("other.bin", b"x")
    with pytest.raises(RootError, match="other.bin"):
        ex.export(ex.ExportConfig(root=str(root), to=uri, format="webdataset", force=True))


def test_cli_export_webdataset_and_its_errors(root, tmp_path):
    runner = CliRunner()
    app = cli_app()
    done = runner.invoke(app, ["export", str(root), "--format", "webdataset", "--to", str(tmp_path / "w"),
                               "--shard-size", "100KB", "--outputs", "rgb"])
    assert done.exit_code == 0, done.output
    assert re.search(r"exported \d+ .* as webdataset", done.output)
    for args, message in ((["--shard-size", "lots"], "bad size"), (["--shard-size", "1KB"], "at least"),
                          (["--outputs", "rgb", "--format", "idda"], "webdataset format")):
        fmt = [] if "--format" in args else ["--format", "webdataset"]
        bad = runner.invoke(app, ["export", str(root), *fmt, "--to", str(tmp_path / "x"), *args])
        assert bad.exit_code == 2 and message in bad.output and len(bad.output.strip().splitlines()) == 1, bad.output


def test_parse_size_and_tar_bytes():
    assert wd.parse_size("1GB") == 10**9 and wd.parse_size("256MiB") == 256 * 2**20 and wd.parse_size("4096") == 4096
    for bad in ("", "GB", "-1MB", "1XB"):
        with pytest.raises(ValueError):
            wd.parse_size(bad)
    assert wd.tar_bytes([]) == 10240 and wd.tar_bytes([1]) == 10240 and wd.tar_bytes([10240 - 3 * 512]) == 10240
    assert wd.tar_bytes([10240 - 3 * 512 + 1]) == 20480


def test_the_training_snippet_in_the_docs_runs(shards, rows, tmp_path, monkeypatch):
    docs = (Path(__file__).resolve().parents[1] / "docs" / "training.md").read_text()
    snippet = next(block for block in re.findall(r"```python\n(.*?)```", docs, re.S) if "import webdataset" in block)
    (tmp_path / "shards").symlink_to(shards)
    monkeypatch.chdir(tmp_path)
    seen: dict = {}
    exec(compile(snippet.replace("    pass  #", "    seen.setdefault('batches', []).append((images, labels, K))  #"),
                 "training.md", "exec"), {"seen": seen})
    images = [im for batch in seen["batches"] for im in batch[0]]
    train = [r for r in rows.values() if r["split"] == "train"]
    assert len(images) == len(train) and tuple(images[0].shape) == (3, train[0]["height"], train[0]["width"])
    assert {tuple(k.flatten().tolist()) for batch in seen["batches"] for k in batch[2]} == {
        tuple(float(v) for v in r["K"]) for r in train}


def test_bench_export_end_to_end_tiny(tmp_path):
    from benchmarks import bench_export as bench

    result = bench.main(out_dir=str(tmp_path), frames=2, width=64, height=36, world="test", rounds=1)
    assert list(result["variants"]) == list(bench.VARIANTS)
    assert all(v["seconds"] > 0 and v["frames_per_s"] > 0 for v in result["variants"].values())
    assert result["variants"]["webdataset, 1 GB shards"]["shards"] >= 1
    assert "| webdataset, 1 GB shards |" in (tmp_path / "bench_export.md").read_text()


def test_a_damaged_root_file_refuses_the_export(root, rows, tmp_path):
    import shutil

    from exports.shared import DamagedFile

    copy = tmp_path / "root"
    shutil.copytree(root, copy)
    row = next(iter(rows.values()))
    victim = copy / row["depth_raw_path"]
    victim.write_bytes(victim.read_bytes()[:-1] + b"\x00")  # same size, other bytes
    target = tmp_path / "w"
    with pytest.raises(DamagedFile, match=row["depth_raw_path"]):
        ex.export(ex.ExportConfig(root=str(copy), to=str(target), format="webdataset", shard_size=BOUND))
    assert not (target / ex.MARKER).exists()
    with pytest.raises(ValueError, match="--skip-damaged is not available"):
        ex.export(ex.ExportConfig(root=str(copy), to=str(target), format="webdataset", skip_damaged=True))


def test_a_samples_json_is_strict_even_where_the_row_holds_infinity(rows):
    """A clear day's ``visibility_m`` is infinite; strict JSON has no Infinity (readers outside Python refuse
    it), so the sample's JSON says null there and keeps every finite value."""
    row = dict(next(iter(rows.values())), visibility_m=float("inf"), fog_density=float("nan"))
    member = wd._members(row, ())[-1]
    text = member.data.decode()
    parsed = json.loads(text, parse_constant=_refuse)
    assert parsed["visibility_m"] is None and parsed["fog_density"] is None
    assert parsed["K"] == list(row["K"]) and parsed["uid"] == row["uid"]
    assert member.size == len(member.data)
