"""The PNG deflater: zlib-ng for new roots, photographs by runs (issue 35); zlib-ng at level 3 for every output
(issue 35's eighth round), libdeflate (issue 21.11) and ISA-L kept by roots written with them."""

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
from outputs.deflaters import (DEFLATERS, deflater, deflater_named_by, deflater_of_files, deflaters_of_png,
                               deflating_with)
from manifests.reader import read_manifest
from roots.run_file import record_bytes
from pipeline.episode_job import run_episode
from pipeline.planner import make_plan
from pipeline.settings import PlanConfig, RunConfig
from pipeline.provenance import RunConfigError, check_encoder, prepare_root, root_deflater
from storage import Storage

PLAN = PlanConfig(domains="T01_CN_A,T01_HRN_A", frames_per_scenario=2, width=64, height=36, seed=5)
ISAL_IDENTITY = f"png-sub-isal level 1, isal {metadata.version('isal')}"  # as roots written before recorded it
LIBDEFLATE_IDENTITY = f"png-sub-libdeflate level 2, deflate {metadata.version('deflate')}"  # roots of issues 21.11-35
ZLIBNG_L3_IDENTITY = f"png-sub-zlib-ng level 3, zlib-ng {metadata.version('zlib-ng')}"  # issue 35's eighth round
OLD_IDENTITIES = {"isal": ISAL_IDENTITY, "libdeflate": LIBDEFLATE_IDENTITY, "zlib-ng-l3": ZLIBNG_L3_IDENTITY}


def idat(data: bytes) -> bytes:
    """The zlib stream of a PNG (its IDAT chunks joined)."""
    out, i = b"", 8
    while i < len(data):
        (n,) = struct.unpack(">I", data[i:i + 4])
        if data[i + 4:i + 8] == b"IDAT":
            out += data[i + 8:i + 8 + n]
        i += 12 + n
    return out


def deflated_by(png: bytes, photo: bool = False) -> set[str]:
    """The deflaters that give this PNG's zlib stream from its own rows (``photo``: as a photograph's)."""
    stream = idat(png)
    rows = zlib.decompress(stream)
    return {name for name, row in DEFLATERS.items() if row.deflate(rows, photo) == stream}


def test_identities_name_the_deflater_its_level_and_version():
    assert enc.encoder_identity() == f"png-sub-zlib-ng level 3, rgb run-length, zlib-ng {metadata.version('zlib-ng')}"
    assert enc.encoder_identity("png", "isal") == ISAL_IDENTITY  # what older run.json files hold, to the letter
    assert enc.encoder_identity("png", "libdeflate") == LIBDEFLATE_IDENTITY
    assert enc.encoder_identity("png", "zlib-ng-l3") == ZLIBNG_L3_IDENTITY
    assert deflater_named_by(ISAL_IDENTITY) == "isal" and deflater_named_by(LIBDEFLATE_IDENTITY) == "libdeflate"
    assert deflater_named_by(enc.encoder_identity()) == "zlib-ng" and deflater_named_by(ZLIBNG_L3_IDENTITY) == "zlib-ng-l3"
    assert deflater_named_by("png-sub-isal level 1, isal 0.0.1") is None  # another version: not ours
    assert deflater_named_by("png-sub-zlib-ng level 3, zlib-ng 0.0.1") is None
    assert deflater_named_by("png-sub-zlib-ng level 3, rgb run-length, zlib-ng 0.0.1") is None
    with pytest.raises(ValueError, match="unknown PNG deflater 'zopfli'; valid PNG deflaters: zlib-ng, zlib-ng-l3, "
                                         "libdeflate, isal"):
        deflater("zopfli")


def test_png_files_are_deflated_by_the_deflater_in_force_in_this_thread_only():
    image = np.random.default_rng(0).integers(0, 4, (27, 48, 3), dtype=np.uint8)
    new = enc.encode_png(image)
    assert deflated_by(new) == {"zlib-ng", "zlib-ng-l3"}  # not a photograph: both give level 3's stream
    for name in ("isal", "libdeflate"):
        with deflating_with(name):
            old = enc.encode_png(image)
            assert name in deflated_by(old)
        assert enc.encode_png(image) == new != old  # each deflater writes its own bytes for this image
        assert np.array_equal(enc.decode_png(old), image) and np.array_equal(enc.decode_png(new), image)


def test_a_photograph_is_deflated_by_runs_and_every_other_output_at_level_3():
    """The rgb output's rows (PHOTO_OUTPUTS, by the output's name) get run-length matches only; the
    semantic colours, an RGB image too, and every other output get level 3; a root of the eighth round
    (zlib-ng-l3) deflates its photographs at level 3 as well. Each file names its deflater."""
    from zlib_ng import zlib_ng

    from outputs.table import file_bytes

    rng = np.random.default_rng(1)
    photo = np.clip(rng.normal(120, 30, (36, 64, 3)) + np.arange(64)[None, :, None], 0, 255).astype(np.uint8)
    photo[10:20, 5:40] = photo[10, 5]  # flat runs beside noise: run-length and full matching differ
    runs, full = file_bytes("rgb", photo), file_bytes("semantic_color", photo)
    rows = zlib.decompress(idat(runs))
    assert zlib.decompress(idat(full)) == rows and np.array_equal(enc.decode_png(runs), photo)
    c = zlib_ng.compressobj(3, zlib_ng.DEFLATED, 15, 8, zlib_ng.Z_RLE)
    assert idat(runs) == c.compress(rows) + c.flush() != idat(full) == zlib_ng.compress(rows, 3)
    assert deflated_by(runs, photo=True) == {"zlib-ng"} and deflated_by(full) == {"zlib-ng", "zlib-ng-l3"}
    assert deflaters_of_png(runs, photo=True) == {"zlib-ng"} and deflaters_of_png(full) == {"zlib-ng", "zlib-ng-l3"}
    with deflating_with("zlib-ng-l3"):
        assert file_bytes("rgb", photo) == full  # the eighth round's photograph: level 3
        assert deflated_by(full, photo=True) == {"zlib-ng-l3"}
    assert file_bytes("rgb", photo) == runs  # the deflater in force is back to the default


def test_the_deflater_of_a_roots_files_is_the_one_every_file_names():
    assert deflater_of_files([{"zlib-ng-l3"}, {"zlib-ng", "zlib-ng-l3"}]) == "zlib-ng-l3"  # its photograph tells
    assert deflater_of_files([{"zlib-ng", "zlib-ng-l3"}] * 3) == "zlib-ng"  # no photograph (a JPEG root): the default
    assert deflater_of_files([{"isal"}, set(), {"isal"}]) == "isal"  # a damaged file says nothing
    assert deflater_of_files([{"isal"}, {"libdeflate"}]) is None and deflater_of_files([]) is None
    assert deflater_of_files([{"isal", "libdeflate"}]) is None  # several, none the default: no guess
    assert deflaters_of_png(b"\x89PNG\r\n\x1a\n") == set()


def test_zlib_ng_is_deterministic_on_real_sized_rows():
    """Full-HD-sized rows of low-entropy and noisy images: one stream per input, every call, and
    the rows come back; level 3 is zlib-ng's medium strategy, not the fixed-Huffman quick one."""
    from zlib_ng import zlib_ng

    rng = np.random.default_rng(3)
    flat = np.repeat(rng.integers(0, 24, (1080, 8), dtype=np.uint8), 240, axis=1)  # label-like runs
    noisy = rng.integers(0, 256, (1080, 1920 * 3), dtype=np.uint8)
    for rows in (flat, noisy):
        data = rows.tobytes()
        first = deflater("zlib-ng").compress(data)
        assert all(deflater("zlib-ng").compress(bytearray(data)) == first for _ in range(3))
        assert zlib.decompress(first) == data and first == zlib_ng.compress(data, 3) != zlib_ng.compress(data, 1)
        runs = deflater("zlib-ng").deflate(data, photo=True)
        assert all(deflater("zlib-ng").deflate(bytearray(data), photo=True) == runs for _ in range(3))
        assert zlib.decompress(runs) == data and runs != first


def test_root_deflater_reads_the_record():
    assert root_deflater(None) == "zlib-ng" and root_deflater({}) == "zlib-ng"
    assert root_deflater({"encoder": ISAL_IDENTITY}) == "isal"
    assert root_deflater({"encoder": LIBDEFLATE_IDENTITY}) == "libdeflate"
    assert root_deflater({"encoder": ZLIBNG_L3_IDENTITY}) == "zlib-ng-l3"
    assert root_deflater({"encoder": f"{ISAL_IDENTITY}; rgb jpeg-libjpeg-turbo-opencv quality 95, opencv 4"}) == "isal"
    assert root_deflater({"encoder": "png-sub-isal level 1, isal 0.0.1"}) == "zlib-ng"


def _old_root(root: Path, name: str = "isal") -> Storage:
    """A root as an older version left it: run.json names deflater ``name``, its first episode done with it."""
    storage = Storage.from_uri(str(root))
    storage.ensure_writable()
    config = RunConfig(plan=PLAN, world="test")
    record = prepare_root(storage, config)
    storage.write_bytes("run.json", record_bytes({**record, "encoder": OLD_IDENTITIES[name]}))
    first = make_plan(PLAN).episodes[0]
    run_episode(replace(first, png_deflater=name), storage, world="test")
    return storage


@pytest.mark.parametrize("name", ["isal", "libdeflate", "zlib-ng-l3"])
def test_an_old_root_resumes_with_its_deflater_and_a_new_root_uses_zlib_ng(tmp_path, name):
    from pipeline.episode_job import render_plan

    storage = _old_root(tmp_path / "old", name)
    render_plan(storage, RunConfig(plan=PLAN, world="test"))  # resume: the second episode, the root's deflater
    assert json.loads((tmp_path / "old" / "run.json").read_text())["encoder"] == OLD_IDENTITIES[name]
    assert _pngs_by(tmp_path / "old", name) == (16, 16)

    fresh = Storage.from_uri(str(tmp_path / "new"))
    render_plan(fresh, RunConfig(plan=PLAN, world="test"))
    record = json.loads((tmp_path / "new" / "run.json").read_text())
    assert record["encoder"] == enc.encoder_identity()
    assert _pngs_by(tmp_path / "new", "zlib-ng") == (16, 16)


def test_a_root_of_an_unknown_deflater_is_still_refused(tmp_path):
    storage = _old_root(tmp_path / "old")
    record = json.loads((tmp_path / "old" / "run.json").read_text())
    with pytest.raises(RunConfigError, match="another encoder"):
        check_encoder(storage, {**record, "encoder": "png-sub-isal level 1, isal 0.0.1"})
    assert check_encoder(storage, record)["encoder"] == ISAL_IDENTITY  # its own: kept


def _pngs_by(root: Path, name: str) -> tuple[int, int]:
    """(PNG files the manifest lists, those deflated by ``name``)."""
    table = read_manifest(str(root))
    pngs = [(p, col == "rgb_path") for col in ("rgb_path", "semantic_color_path", "depth_raw_path", "instance_path")
            for p in table.column(col).to_pylist()]
    return len(pngs), sum(name in deflated_by((root / p).read_bytes(), photo) for p, photo in pngs)


def _isal_pngs(root: Path) -> tuple[int, int]:
    """(PNG files the manifest lists, those deflated by ISA-L)."""
    return _pngs_by(root, "isal")


@pytest.mark.parametrize("name", ["isal", "libdeflate", "zlib-ng-l3"])
def test_an_old_root_extended_keeps_its_deflater(tmp_path, name):
    """Issue 33: ``--extend`` rewrote run.json's encoder to libdeflate, so the new
    episodes were deflated by libdeflate beside the ISA-L ones: one root, two deflaters."""
    from pipeline.episode_job import run_episode

    storage = _old_root(tmp_path / "old", name)
    more = RunConfig(plan=replace(PLAN, domains="T01_CN_A,T01_HRN_A,T07_CN_A"), world="test")
    record = prepare_root(storage, more, extend=True)
    assert record["encoder"] == OLD_IDENTITIES[name] == json.loads((tmp_path / "old" / "run.json").read_text())["encoder"]
    assert root_deflater(record) == name
    for spec in make_plan(more.plan).episodes[1:]:  # what produce's workers are handed
        run_episode(replace(spec, png_deflater=root_deflater(record)), storage, world="test")
    assert _pngs_by(tmp_path / "old", name) == (24, 24)


@pytest.mark.parametrize("name", ["isal", "libdeflate", "zlib-ng-l3"])
def test_an_old_root_repaired_with_a_damaged_run_json_keeps_its_deflater(tmp_path, name):
    """A damaged (or lost) run.json is written afresh by repair: with the deflater of the
    root's own PNG files, not the default one (which would mix two deflaters)."""
    storage = _old_root(tmp_path / "old", name)
    run = tmp_path / "old" / "run.json"
    run.write_bytes(run.read_bytes()[:-9])  # torn
    record = prepare_root(storage, RunConfig(plan=PLAN, world="test"), repair=True)
    assert record["encoder"] == OLD_IDENTITIES[name] and root_deflater(record) == name
    run.unlink()  # lost: the same
    assert prepare_root(storage, RunConfig(plan=PLAN, world="test"))["encoder"] == OLD_IDENTITIES[name]

