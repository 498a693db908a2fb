"""The PNG deflater: libdeflate for new roots, ISA-L kept by roots written with it (issue 21.11)."""

from __future__ import annotations

import json
import struct
import zlib
from dataclasses import replace
from importlib import metadata
from pathlib import Path

import numpy as np
import pytest

from outputs import encoding as enc
from outputs.deflaters import DEFLATERS, deflater, deflater_named_by, deflating_with
from manifests.reader import read_manifest
from roots.run_file import record_bytes
from pipeline.episode_job import run_episode
from pipeline.planner import make_plan
from pipeline.settings import PlanConfig, RunConfig
from pipeline.provenance import RunConfigError, check_encoder, prepare_root, root_deflater
from storage import Storage

PLAN = PlanConfig(domains="T01_CN_A,T01_HRN_A", frames_per_scenario=2, width=64, height=36, seed=5)
ISAL_IDENTITY = f"png-sub-isal level 1, isal {metadata.version('isal')}"  # as roots written before recorded it


def idat(data: bytes) -> bytes:
    """The zlib stream of a PNG (its IDAT chunks joined)."""
    out, i = b"", 8
    while i < len(data):
        (n,) = struct.unpack(">I", data[i:i + 4])
        if data[i + 4:i + 8] == b"IDAT":
            out += data[i + 8:i + 8 + n]
        i += 12 + n
    return out


def deflated_by(png: bytes) -> set[str]:
    """The deflaters that give this PNG's zlib stream from its own rows."""
    stream = idat(png)
    rows = zlib.decompress(stream)
    return {name for name, row in DEFLATERS.items() if row.compress(rows) == stream}


def test_identities_name_the_deflater_its_level_and_version():
    assert enc.encoder_identity() == f"png-sub-libdeflate level 2, deflate {metadata.version('deflate')}"
    assert enc.encoder_identity("png", "isal") == ISAL_IDENTITY  # what older run.json files hold, to the letter
    assert deflater_named_by(ISAL_IDENTITY) == "isal" and deflater_named_by(enc.encoder_identity()) == "libdeflate"
    assert deflater_named_by("png-sub-isal level 1, isal 0.0.1") is None  # another version: not ours
    with pytest.raises(ValueError, match="unknown PNG deflater 'zopfli'; valid PNG deflaters: libdeflate, isal"):
        deflater("zopfli")


def test_png_files_are_deflated_by_the_deflater_in_force_in_this_thread_only():
    image = np.random.default_rng(0).integers(0, 4, (27, 48, 3), dtype=np.uint8)
    assert deflated_by(enc.encode_png(image)) >= {"libdeflate"}
    with deflating_with("isal"):
        old = enc.encode_png(image)
        assert deflated_by(old) >= {"isal"}
    assert enc.encode_png(image) != old  # the two deflaters write different bytes for this image
    assert np.array_equal(enc.decode_png(old), image) and np.array_equal(enc.decode_png(enc.encode_png(image)), image)


def test_root_deflater_reads_the_record():
    assert root_deflater(None) == "libdeflate" and root_deflater({}) == "libdeflate"
    assert root_deflater({"encoder": ISAL_IDENTITY}) == "isal"
    assert root_deflater({"encoder": f"{ISAL_IDENTITY}; rgb jpeg-libjpeg-turbo-opencv quality 95, opencv 4"}) == "isal"
    assert root_deflater({"encoder": "png-sub-isal level 1, isal 0.0.1"}) == "libdeflate"


def _old_root(root: Path) -> Storage:
    """A root as the ISA-L version left it: run.json names ISA-L, its first episode done with it."""
    storage = Storage.from_uri(str(root))
    storage.ensure_writable()
    config = RunConfig(plan=PLAN, world="test")
    record = prepare_root(storage, config)
    storage.write_bytes("run.json", record_bytes({**record, "encoder": ISAL_IDENTITY}))
    first = make_plan(PLAN).episodes[0]
    run_episode(replace(first, png_deflater="isal"), storage, world="test")
    return storage


def test_an_isal_root_resumes_with_isal_and_a_new_root_uses_libdeflate(tmp_path):
    from pipeline.episode_job import render_plan

    storage = _old_root(tmp_path / "old")
    render_plan(storage, RunConfig(plan=PLAN, world="test"))  # resume: the second episode, the root's deflater
    assert json.loads((tmp_path / "old" / "run.json").read_text())["encoder"] == ISAL_IDENTITY
    table = read_manifest(str(tmp_path / "old"))
    pngs = [p for col in ("rgb_path", "semantic_color_path", "depth_raw_path", "instance_path")
            for p in table.column(col).to_pylist()]
    assert len(pngs) == 16 and all("isal" in deflated_by((tmp_path / "old" / p).read_bytes()) for p in pngs)

    fresh = Storage.from_uri(str(tmp_path / "new"))
    render_plan(fresh, RunConfig(plan=PLAN, world="test"))
    record = json.loads((tmp_path / "new" / "run.json").read_text())
    assert record["encoder"] == enc.encoder_identity()
    assert all("libdeflate" in deflated_by((tmp_path / "new" / p).read_bytes()) for p in pngs)


def test_a_root_of_an_unknown_deflater_is_still_refused(tmp_path):
    storage = _old_root(tmp_path / "old")
    record = json.loads((tmp_path / "old" / "run.json").read_text())
    with pytest.raises(RunConfigError, match="another encoder"):
        check_encoder(storage, {**record, "encoder": "png-sub-isal level 1, isal 0.0.1"})
    assert check_encoder(storage, record)["encoder"] == ISAL_IDENTITY  # its own: kept


def _isal_pngs(root: Path) -> tuple[int, int]:
    """(PNG files the manifest lists, those deflated by ISA-L)."""
    table = read_manifest(str(root))
    pngs = [p for col in ("rgb_path", "semantic_color_path", "depth_raw_path", "instance_path")
            for p in table.column(col).to_pylist()]
    return len(pngs), sum("isal" in deflated_by((root / p).read_bytes()) for p in pngs)


def test_an_isal_root_extended_keeps_isal(tmp_path):
    """Issue 33: ``--extend`` rewrote run.json's encoder to libdeflate, so the new
    episodes were deflated by libdeflate beside the ISA-L ones: one root, two deflaters."""
    from pipeline.episode_job import run_episode

    storage = _old_root(tmp_path / "old")
    more = RunConfig(plan=replace(PLAN, domains="T01_CN_A,T01_HRN_A,T07_CN_A"), world="test")
    record = prepare_root(storage, more, extend=True)
    assert record["encoder"] == ISAL_IDENTITY == json.loads((tmp_path / "old" / "run.json").read_text())["encoder"]
    assert root_deflater(record) == "isal"
    for spec in make_plan(more.plan).episodes[1:]:  # what produce's workers are handed
        run_episode(replace(spec, png_deflater=root_deflater(record)), storage, world="test")
    assert _isal_pngs(tmp_path / "old") == (24, 24)


def test_an_isal_root_repaired_with_a_damaged_run_json_keeps_isal(tmp_path):
    """A damaged (or lost) run.json is written afresh by repair: with the deflater of the
    root's own PNG files, not the default one (which would mix two deflaters)."""
    storage = _old_root(tmp_path / "old")
    run = tmp_path / "old" / "run.json"
    run.write_bytes(run.read_bytes()[:-9])  # torn
    record = prepare_root(storage, RunConfig(plan=PLAN, world="test"), repair=True)
    assert record["encoder"] == ISAL_IDENTITY and root_deflater(record) == "isal"
    run.unlink()  # lost: the same
    assert prepare_root(storage, RunConfig(plan=PLAN, world="test"))["encoder"] == ISAL_IDENTITY

