"""Exports of a small rendered root: Cityscapes layout evaluated by
cityscapesScripts itself, IDDA layout, safe writes and the CLI."""

from __future__ import annotations

import glob
import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from exports import cityscapes as cs_layout, idda
from exports import export as ex
from exports.shared import Layout, per_frame
from domains.catalog import CITYSCAPES_ID_LUT, LABELS, TRAIN_ID_LUT
from manifests.query import Query
from manifests.reader import read_manifest
from tests.s3_server import s3_server  # noqa: F401  (fixture)

# The paper's three distance pairs need these five scenarios; two frames each.
TINY_DOMAINS = "T01_CS_A,T01_CS_J,T01_HRN_A,T01_HRN_J,T07_HRN_A"
TINY_FRAMES = 2


def make_tiny_root(tmp_path_factory) -> Path:
    """A small rendered root (test world, 64x36), built once per test session
    and shared by the export, loader, distance and card tests (read-only)."""
    from pipeline.settings import PlanConfig, RunConfig
    from tests.roots import render_root

    root = tmp_path_factory.getbasetemp() / "tiny_root"
    done = tmp_path_factory.getbasetemp() / "tiny_root.done"
    if done.exists():
        return root
    shutil.rmtree(root, ignore_errors=True)
    config = RunConfig(
        plan=PlanConfig(domains=TINY_DOMAINS, frames_per_scenario=TINY_FRAMES, width=64, height=36, seed=3), world="test"
    )
    render_root(root, config)
    done.write_text("ok")
    return root


def upload_root(root: Path, uri: str) -> None:
    """Copy a local root's files to an s3:// root through storage."""
    from storage import Storage

    target = Storage.from_uri(uri)
    for path in sorted(root.rglob("*")):
        if path.is_file():
            target.write_bytes(path.relative_to(root).as_posix(), path.read_bytes())


def cli_app():
    from pipeline.cli import data as cli_data
    from pipeline.cli import app

    cli_data.register(app)
    return app


def read_png(path) -> np.ndarray:
    return np.array(Image.open(path))


@pytest.fixture(scope="module")
def root(tmp_path_factory) -> Path:
    return make_tiny_root(tmp_path_factory)


@pytest.fixture(scope="module")
def manifest(root):
    return read_manifest(str(root))


@pytest.fixture(scope="module")
def cityscapes(root, tmp_path_factory) -> Path:
    target = tmp_path_factory.mktemp("cs") / "export"
    report = ex.export(ex.ExportConfig(root=str(root), to=str(target), format="cityscapes"))
    assert report.frames == 5 * TINY_FRAMES and report.target == str(target)
    return target


def test_cityscapes_layout_and_label_images(root, manifest, cityscapes):
    from cityscapesscripts.helpers.csHelpers import getCsFileInfo
    from cityscapesscripts.helpers.labels import id2label

    assert ex.is_complete(str(cityscapes))
    marker = json.loads((cityscapes / ex.MARKER).read_text())
    assert marker["frames"] == len(manifest) and marker["format"] == "cityscapes"
    split_of = {(r["frame_id"], r["scenario"]): r["split"] for r in manifest.to_pylist()}
    for row in manifest.to_pylist():
        name = cs_layout.cityscapes_name(row["scenario"], row["episode"], row["frame"])
        info = getCsFileInfo(f"{name}_gtFine_labelIds.png")
        assert (info.city, info.sequenceNb, info.frameNb) == (
            row["scenario"].replace("_", "-"), f"{row['episode']:06d}", f"{row['frame']:06d}"
        )
        city = row["scenario"].replace("_", "-")  # the folder is the file names' city
        image = cityscapes / "leftImg8bit" / split_of[row["frame_id"], row["scenario"]] / city / f"{name}_leftImg8bit.png"
        assert os.path.samefile(image, root / row["rgb_path"])  # hard link, not a re-render
        gt = cityscapes / "gtFine" / split_of[row["frame_id"], row["scenario"]] / city
        classes = read_png(root / row["semantic_raw_path"])[..., 0]
        label_ids = read_png(gt / f"{name}_gtFine_labelIds.png")
        assert label_ids.dtype == np.uint8 and label_ids.shape == classes.shape
        assert np.array_equal(label_ids, CITYSCAPES_ID_LUT[classes])
        assert np.array_equal(read_png(gt / f"{name}_gtFine_labelTrainIds.png"), TRAIN_ID_LUT[classes])
        instance_ids = read_png(gt / f"{name}_gtFine_instanceIds.png").astype(np.int64)
        plain = instance_ids < 1000  # objects of instance classes: label id * 1000 + index
        assert np.array_equal(instance_ids[plain], label_ids[plain])
        assert np.array_equal(instance_ids[~plain] // 1000, label_ids[~plain])
        color = Image.open(gt / f"{name}_gtFine_color.png")
        assert color.mode == "RGBA"  # as Cityscapes' own colour images
        color = np.array(color)
        expected = np.array([id2label[int(i)].color for i in label_ids.ravel()], dtype=np.uint8)
        assert np.array_equal(color[..., :3], expected.reshape(color.shape[:2] + (3,)))  # cityscapesScripts' colours
        assert (color[..., 3] == 255).all()
    # Excluded classes land on labels that Cityscapes ignores in evaluation.
    for label in LABELS:
        assert id2label[label.cityscapes_id].ignoreInEval == (not label.evaluated)
        assert (label.train_id == 255) == (not label.evaluated)


def _evaluate(cityscapes: Path, predictions: Path):
    """cityscapesScripts' pixel-level evaluation through ``idda evaluate``'s API (val split)."""
    from analysis.evaluate import EvaluateConfig, evaluate

    report = evaluate(EvaluateConfig(export=str(cityscapes), predictions=str(predictions), split="val"))
    gts = sorted(glob.glob(str(cityscapes / "gtFine" / "val" / "*" / "*_gtFine_labelIds.png")))
    assert report.images == len(gts)
    return {"classScores": report.class_iou, "averageScoreClasses": report.miou}, gts


def _predict(cityscapes: Path, out: Path, relabel: dict[int, int]) -> None:
    out.mkdir()
    for gt in glob.glob(str(cityscapes / "gtFine" / "*" / "*" / "*_gtFine_labelIds.png")):
        labels = read_png(gt)
        for src, dst in relabel.items():
            labels = np.where(labels == src, dst, labels).astype(np.uint8)
        name = os.path.basename(gt).replace("_gtFine_labelIds.png", "_pred.png")
        Image.fromarray(labels).save(out / name)


def test_cityscapes_scripts_evaluate_the_export(root, tmp_path):
    from cityscapesscripts.helpers.labels import id2label

    cityscapes = tmp_path / "as_val"  # every frame in val, where the evaluation looks
    ex.export(ex.ExportConfig(root=str(root), to=str(cityscapes), format="cityscapes", as_split="val"))
    assert not (cityscapes / "gtFine" / "train").exists()
    _predict(cityscapes, tmp_path / "perfect", {})
    result, gts = _evaluate(cityscapes, tmp_path / "perfect")
    gt_pixels = np.concatenate([read_png(g).ravel() for g in gts])
    present = {id2label[int(i)].name for i in np.unique(gt_pixels) if not id2label[int(i)].ignoreInEval}
    assert {"road", "sidewalk"} <= present
    scores = result["classScores"]
    assert all(scores[name] == 1.0 for name in present)
    assert all(np.isnan(v) for name, v in scores.items() if name not in present)
    assert result["averageScoreClasses"] == 1.0

    # Relabel every road pixel as sidewalk: road IoU 0, sidewalk IoU S/(S+R).
    road, sidewalk = 7, 8
    _predict(cityscapes, tmp_path / "perturbed", {road: sidewalk})
    result, _ = _evaluate(cityscapes, tmp_path / "perturbed")
    n_road, n_sidewalk = int((gt_pixels == road).sum()), int((gt_pixels == sidewalk).sum())
    sidewalk_iou = n_sidewalk / (n_sidewalk + n_road)
    assert result["classScores"]["road"] == 0.0
    assert result["classScores"]["sidewalk"] == pytest.approx(sidewalk_iou)
    expected = (len(present) - 2 + sidewalk_iou) / len(present)
    assert result["averageScoreClasses"] == pytest.approx(expected)
    assert expected < 1.0


def test_idda_layout_and_split_files(root, manifest, tmp_path):
    target = tmp_path / "idda"
    report = ex.export(ex.ExportConfig(root=str(root), to=str(target), format="idda", files="copy"))
    assert report.frames == len(manifest) and ex.is_complete(str(target))
    rows = manifest.to_pylist()
    for row in rows:
        stem = f"{row['frame_id']}_{row['scenario']}"
        jpeg = target / row["scenario"] / "RGB" / f"{stem}.jpg"
        assert jpeg.read_bytes()[:2] == b"\xff\xd8"
        rgb = read_png(root / row["rgb_path"]).astype(int)
        assert np.abs(read_png(jpeg).astype(int) - rgb).mean() < 6  # JPEG quality 95
        semantic = target / row["scenario"] / "Semantic" / f"{stem}.png"
        assert Image.open(semantic).mode == "L"  # single-channel class ids, as IDDA's labels
        assert np.array_equal(read_png(semantic), read_png(root / row["semantic_raw_path"])[..., 0])
    for split in ("train", "val", "test"):
        listing = json.loads((target / f"{split}.json").read_text())
        assert sorted(listing) == sorted({r["scenario"] for r in rows})
        want = {(r["scenario"], r["frame_id"]) for r in rows if r["split"] == split}
        assert {(s, f) for s, ids in listing.items() for f in ids} == want
    lines = (target / ex.INDEX).read_text().splitlines()
    assert lines[0].startswith("frame_id,scenario") and len(lines) == len(rows) + 1
    uid = lines[0].split(",").index("uid")
    assert sorted(line.split(",")[uid] for line in lines[1:]) == sorted(r["uid"] for r in rows)


def test_query_selects_frames_and_symlinks(root, tmp_path):
    target = tmp_path / "sub"
    query = Query(domains="towns=T01 viewpoints=J", per_scenario=1, seed=5)
    report = ex.export(ex.ExportConfig(root=str(root), to=str(target), format="idda", query=query, files="symlink"))
    assert report.frames == 2
    semantic = sorted(target.glob("*/Semantic/*.png"))
    assert [p.parent.parent.name for p in semantic] == ["T01_CS_J", "T01_HRN_J"]
    cs = tmp_path / "cs"
    ex.export(ex.ExportConfig(root=str(root), to=str(cs), format="cityscapes", query=query, files="symlink"))
    images = sorted(cs.glob("leftImg8bit/*/*/*.png"))
    assert len(images) == 2 and all(p.is_symlink() and p.resolve().is_relative_to(root) for p in images)


def test_refuses_non_empty_target_and_force_replaces(root, tmp_path):
    target = tmp_path / "busy"
    target.mkdir()
    (target / "keep.txt").write_text("user data")
    config = ex.ExportConfig(root=str(root), to=str(target), format="idda", query=Query(domains="T07_*_*"))
    with pytest.raises(ValueError, match="not empty; pass --force"):
        ex.export(config)
    # --force replaces only an earlier export of ours, never the user's files
    with pytest.raises(ValueError, match="not an earlier export"):
        ex.export(ex.ExportConfig(**{**config.__dict__, "force": True}))
    assert (target / "keep.txt").read_text() == "user data"
    (target / "keep.txt").unlink()
    ex.export(config)
    ex.export(ex.ExportConfig(**{**config.__dict__, "force": True, "format": "cityscapes"}))
    assert ex.is_complete(str(target)) and (target / "gtFine").is_dir() and not (target / "T07_CN_A").exists()
    with pytest.raises(ValueError, match="is an output root"):
        ex.export(ex.ExportConfig(root=str(root), to=str(root), format="idda", force=True))
    for bad, match in (({"format": "voc"}, "valid formats: cityscapes, idda"), ({"files": "move"}, "valid modes")):
        with pytest.raises(ValueError, match=match):
            ex.export(ex.ExportConfig(**{**config.__dict__, **bad}))


def test_export_never_touches_an_output_root(root, tmp_path):
    """Issue 10.1: a target inside a root (its manifest/, a scenario folder, an
    empty new folder) or holding one is refused, with or without --force."""
    from roots.verify import verify

    copy = tmp_path / "root"
    shutil.copytree(root, copy)
    before = sorted(p.relative_to(copy).as_posix() for p in copy.rglob("*"))
    app = cli_app()
    runner = CliRunner()
    for inside in ("manifest", "T01_CS_A", "T01_CS_A/e0000/rgb", "new_folder"):
        result = runner.invoke(app, ["export", str(copy), "--format", "cityscapes", "--to", str(copy / inside), "--force"])
        assert result.exit_code == 2 and "inside the output root" in result.output, result.output
        assert len(result.output.strip().splitlines()) == 1
    holder = tmp_path
    result = runner.invoke(app, ["export", str(copy), "--format", "idda", "--to", str(holder), "--force"])
    assert result.exit_code == 2 and "holds the output root" in result.output, result.output
    other = tmp_path / "other_root"
    shutil.copytree(root, other)
    result = runner.invoke(app, ["export", str(copy), "--format", "idda", "--to", str(other), "--force"])
    assert result.exit_code == 2 and "is an output root" in result.output, result.output
    assert sorted(p.relative_to(copy).as_posix() for p in copy.rglob("*")) == before
    assert verify(str(copy)).ok and verify(str(other)).ok


def test_failed_export_leaves_nothing_behind(root, tmp_path, monkeypatch):
    calls = []

    def flaky(storage, frame, tmp, place):
        calls.append(frame)
        if len(calls) == 3:
            raise OSError("disk full")
        return idda.idda_frame(storage, frame, tmp, place)

    monkeypatch.setattr(idda, "LAYOUT", Layout(idda.LAYOUT.outputs, per_frame(flaky, idda.idda_dirs, idda.split_files)))
    target = tmp_path / "out"
    with pytest.raises(OSError, match="disk full"):
        ex.export(ex.ExportConfig(root=str(root), to=str(target), format="idda", threads=1))
    assert not target.exists() and os.listdir(tmp_path) == []


def test_cli_export(root, tmp_path):
    runner = CliRunner()
    app = cli_app()
    target = tmp_path / "cli"
    result = runner.invoke(
        app, ["export", str(root), "--format", "cityscapes", "--to", str(target), "--domains", "T01_*_A", "--total", "3", "--copy"]
    )
    assert result.exit_code == 0, result.output
    assert "exported 3 of the 10 frames the root holds" in result.output
    assert len(list(target.glob("leftImg8bit/*/*/*_leftImg8bit.png"))) == 3
    again = runner.invoke(app, ["export", str(root), "--format", "cityscapes", "--to", str(target)])
    assert again.exit_code == 2 and "not empty; pass --force" in again.output
    bad = runner.invoke(app, ["export", str(root), "--format", "kitti", "--to", str(tmp_path / "x")])
    assert bad.exit_code == 2 and "valid formats: cityscapes, idda" in bad.output
    bad = runner.invoke(app, ["export", str(root), "--format", "idda", "--to", str(tmp_path / "y"), "--has", "unicorn"])
    assert bad.exit_code == 2 and "unknown class 'unicorn'" in bad.output


def test_export_from_s3_root_downloads(root, manifest, tmp_path, s3_server):  # noqa: F811
    uri = s3_server.uri("tiny")
    upload_root(root, uri)
    target = tmp_path / "from_s3"
    report = ex.export(ex.ExportConfig(root=uri, to=str(target), format="cityscapes", query=Query(domains="T07_*_*")))
    assert report.frames == TINY_FRAMES
    marker = json.loads((target / ex.MARKER).read_text())
    assert marker["source"] == uri and marker["file_mode"] == "copy"
    for row in manifest.to_pylist():
        if row["scenario"] == "T07_HRN_A":
            name = cs_layout.cityscapes_name(row["scenario"], row["episode"], row["frame"])
            image = target / "leftImg8bit" / row["split"] / "T07-HRN-A" / f"{name}_leftImg8bit.png"
            assert image.read_bytes() == (root / row["rgb_path"]).read_bytes()


def test_a_new_format_is_one_module_and_one_registry_line(root, tmp_path, monkeypatch):
    """A format module only provides LAYOUT (its outputs and builder); FORMATS names it; the rest is shared."""
    import types

    def frame(storage, f, tmp, place):
        rel = f"{f.scenario}/{f.frame_id}.png"
        place(storage, f.path("rgb"), os.path.join(tmp, rel))
        return {"image": rel}

    module = types.SimpleNamespace(LAYOUT=Layout(("rgb",), per_frame(frame, lambda frames: {f.scenario for f in frames})))
    monkeypatch.setitem(ex.FORMATS, "toy", module)  # registered by import: the module object itself
    report = ex.export(ex.ExportConfig(root=str(root), to=str(tmp_path / "toy"), format="toy", threads=1))
    assert report.frames > 0 and ex.is_complete(str(tmp_path / "toy"))
    assert len(list((tmp_path / "toy").glob("T*/*.png"))) == report.frames
    with pytest.raises(ValueError, match="valid formats: .*toy"):
        ex.ExportConfig(root=str(root), to=str(tmp_path / "x"), format="nope").validate()


def _listing(path: Path) -> dict[str, str]:
    """Every entry under ``path`` (symlinks as their link text, never followed) with its bytes' sha256."""
    import hashlib

    out = {}
    for p in sorted(path.rglob("*")):
        rel = p.relative_to(path).as_posix()
        if p.is_symlink():
            out[rel] = "-> " + os.readlink(p)
        elif p.is_file():
            out[rel] = hashlib.sha256(p.read_bytes()).hexdigest()
        else:
            out[rel] = "dir"
    return out


def test_force_deletes_only_what_an_earlier_export_wrote(root, tmp_path):
    """Issue 21.4: --force deleted an output root nested two levels below --to.
    It may replace only an export holding exactly what it wrote; symlinks are never followed."""
    from roots.contract import RootError

    target = tmp_path / "exp"
    config = ex.ExportConfig(root=str(root), to=str(target), format="idda", query=Query(domains="T07_*_*"))
    ex.export(config)
    force = ex.ExportConfig(**{**config.__dict__, "force": True})
    nested = target / "T07_HRN_A" / "RGB" / "kept"  # an output root two levels below an export folder
    shutil.copytree(root, nested)
    before = _listing(target)
    with pytest.raises(RootError, match="holds the output root .*kept"):
        ex.export(force)
    assert _listing(target) == before
    shutil.rmtree(nested)
    cases = {  # what a user may have put into an export, and how --force must answer
        "a file beside it": (lambda: (target / "notes.txt").write_text("mine"), "holds 'notes.txt'"),
        "a file inside it": (lambda: (target / "T07_HRN_A" / "notes.txt").write_text("mine"), "content changed"),
        "an empty folder": (lambda: (target / "T07_HRN_A" / "mine").mkdir(), "content changed"),
        "a link to a root": (lambda: (target / "data").symlink_to(root, target_is_directory=True), "holds 'data'"),
    }
    root_before = _listing(root)
    for name, (make, match) in cases.items():
        snapshot = _listing(target)
        make()
        changed = _listing(target)
        with pytest.raises(RootError, match=match):
            ex.export(force)
        assert _listing(target) == changed, name
        for extra in set(changed) - set(snapshot):  # undo it (a link is removed, not followed)
            path = target / extra
            path.unlink() if path.is_symlink() or path.is_file() else path.rmdir()
    assert _listing(root) == root_before
    link = tmp_path / "link"
    link.symlink_to(target, target_is_directory=True)
    with pytest.raises(RootError, match="is a symlink"):
        ex.export(ex.ExportConfig(**{**force.__dict__, "to": str(link)}))
    ex.export(force)  # untouched since: replaced
    marker = json.loads((target / ex.MARKER).read_text())
    assert marker["tree"]["top"] == sorted(set(os.listdir(target)) - {ex.MARKER})
    assert "T07_HRN_A" in marker["tree"]["top"] and marker["tree"]["entries"] == len(_listing(target)) - 1
    # an export made before EXPORT.json listed its tree is left to the user
    del marker["tree"]
    (target / ex.MARKER).write_text(json.dumps(marker))
    with pytest.raises(RootError, match="older idda"):
        ex.export(force)


def test_leftovers_of_a_killed_export_are_cleaned(root, tmp_path):
    """Issue 21.9a: a killed export left its .tmp / .old folders beside the target.
    The next export removes ours (this host, process gone) and keeps the rest."""
    import socket
    import subprocess
    import uuid

    dead = subprocess.Popen(["true"])  # a process id that no longer runs
    dead.wait()
    host = socket.gethostname()

    def temp(target: Path, pid: int, kind: str, host: str = host) -> Path:
        path = target.parent / f".{target.name}.idda-export.{host}.{pid}.{uuid.uuid4().hex}.{kind}"
        (path / "T07_CN_A" / "RGB").mkdir(parents=True)
        (path / "T07_CN_A" / "RGB" / "half.jpg").write_bytes(b"half an export")
        return path

    target = tmp_path / "exp"
    config = ex.ExportConfig(root=str(root), to=str(target), format="idda", query=Query(domains="T07_*_*"))
    ex.export(config)
    killed_tmp = temp(target, dead.pid, "tmp")
    killed_old = temp(target, dead.pid, "old")
    live = temp(target, os.getppid(), "tmp")  # an export still running
    remote = temp(target, dead.pid, "tmp", host="elsewhere.example")  # another host's: cannot tell
    foreign = tmp_path / f".{target.name}.0123456789abcdef0123456789abcdef.tmp"  # not marked as ours
    foreign.mkdir()
    ex.export(ex.ExportConfig(**{**config.__dict__, "force": True}))
    assert not killed_tmp.exists() and not killed_old.exists()
    assert live.exists() and remote.exists() and foreign.exists() and ex.is_complete(str(target))
    # killed between its two renames: the finished export it was replacing is put back, not lost
    moved = target.parent / f".{target.name}.idda-export.{host}.{dead.pid}.{uuid.uuid4().hex}.old"
    os.rename(target, moved)
    before = _listing(moved)
    with pytest.raises(ValueError, match="not empty; pass --force"):
        ex.export(config)
    assert not moved.exists() and _listing(target) == before
