"""Files per folder (issue 22): a new root keeps each episode's frames in a
folder of its own; an old root, whose run.json records no layout, stays flat
and is still read and verified in its own layout. Real rendering (test world),
no Ray."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import pytest

from manifests.layout import (
    EPISODE_DIRS,
    FLAT,
    LAYOUT_KEY,
    PATTERNS,
    frame_path,
    held_layout,
    layout_of_path,
    match_frame_file,
    record_layout,
)
from manifests.reader import read_manifest
from roots.contract import claim_root
from roots.run_file import RunRecordError, check_record, read_record, record_bytes
from manifests.schema import RUN_FILE
from roots.verify import verify
from pipeline.planner import make_plan
from pipeline.settings import PlanConfig, RunConfig
from pipeline.provenance import _fresh_record, prepare_root
from storage import Storage
from tests.roots import render_root

# 81 frames: two episodes (41 + 40) of one scenario, at the smallest size
SCENARIO = "T01_CN_A"
RUN = RunConfig(plan=PlanConfig(domains=SCENARIO, frames_per_scenario=81, width=32, height=32, seed=3,
                                outputs=("rgb", "semantic_raw")), world="test")


def frame_files(root: Path) -> dict[str, bytes]:
    """Every file under the scenario's folder, by its path relative to the root."""
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in (root / SCENARIO).rglob("*") if p.is_file()}


def flat_root(path: Path) -> Storage:
    """An old root: its run.json (as roots made before layouts were recorded) has no layout."""
    storage = Storage.from_uri(str(path))
    claim_root(storage)
    record = _fresh_record(RUN.to_dict())
    del record[LAYOUT_KEY]
    storage.write_bytes(RUN_FILE, record_bytes(record))
    return storage


@pytest.fixture(scope="module")
def new_root(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("layout") / "new"
    render_root(root, RUN)
    return root


@pytest.fixture(scope="module")
def old_root(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("layout") / "old"
    flat_root(root)
    render_root(root, RUN)
    return root


def test_paths_of_both_layouts():
    assert frame_path(SCENARIO, "rgb", "0012_040", "png", EPISODE_DIRS) == "T01_CN_A/e0012/rgb/0012_040_T01_CN_A.png"
    assert frame_path(SCENARIO, "rgb", "0012_040", "jpg", FLAT) == "T01_CN_A/rgb/0012_040_T01_CN_A.jpg"
    assert frame_path(SCENARIO, "objects", "0001_000", "jpg", EPISODE_DIRS).endswith("e0001/objects/0001_000_T01_CN_A.parquet")
    for layout in (FLAT, EPISODE_DIRS):
        rel = frame_path(SCENARIO, "semantic_raw", "0003_007", "png", layout)
        match = match_frame_file(rel, (layout,))
        assert layout_of_path(rel) == layout and match_frame_file(rel, (3 - layout,)) is None
        assert (match["scenario"], match["output"], match["episode"], match["frame"]) == (SCENARIO, "semantic_raw", "0003", "007")
    for foreign in ("T01_CN_A/e0003/rgb/0004_000_T01_CN_A.png",  # another episode's name in e0003
                    "T01_CN_A/e0003/rgb/0003_000_T01_CN_A.parquet",  # not the rgb output's extension
                    "T01_CN_A/e0003/notes/0003_000_T01_CN_A.png", "T01_CN_A/e0003/rgb/my_crop.png",
                    "T01_CN_A/e0003/e0003/rgb/0003_000_T01_CN_A.png"):
        assert layout_of_path(foreign) is None, foreign
    with pytest.raises(ValueError, match="unknown file layout"):
        frame_path(SCENARIO, "rgb", "0000_000", "png", 3)


def test_run_json_records_the_layout():
    record = _fresh_record(RUN.to_dict())
    assert record[LAYOUT_KEY] == EPISODE_DIRS == record_layout(record)
    del record[LAYOUT_KEY]
    assert record_layout(record) == FLAT  # an old root
    for bad in (3, "2", True):
        with pytest.raises(RunRecordError, match="unknown file layout"):
            check_record({**record, LAYOUT_KEY: bad}, "run.json")


def test_a_new_root_holds_one_episodes_frames_per_folder(new_root):
    files = frame_files(new_root)
    per_folder = Counter(rel.rpartition("/")[0] for rel in files)
    assert sorted(per_folder) == [f"{SCENARIO}/e{e:04d}/{o}" for e in (0, 1) for o in ("rgb", "semantic_raw")]
    assert sorted(set(per_folder.values())) == [40, 41]  # one episode's frames: at most 80 at any scale
    assert sorted(p.name for p in (new_root / SCENARIO).iterdir()) == ["e0000", "e0001"]
    table = read_manifest(str(new_root))
    assert sorted(table.column("rgb_path").to_pylist() + table.column("semantic_raw_path").to_pylist()) == sorted(files)
    assert read_record(Storage.from_uri(str(new_root)))[LAYOUT_KEY] == EPISODE_DIRS
    assert verify(str(new_root)).ok


def test_verify_flags_a_stray_in_an_episode_folder_and_nothing_else(new_root, tmp_path):
    import shutil

    root = tmp_path / "root"
    shutil.copytree(new_root, root)
    strays = ["T01_CN_A/e0001/rgb/0001_041_T01_CN_A.png",  # a frame no part lists, in its episode's folder
              "T01_CN_A/e0007/semantic_raw/0007_000_T01_CN_A.png"]  # an episode no part lists
    foreign = ["T01_CN_A/rgb/0000_000_T01_CN_A.png",  # ours by name in the flat layout: not this root's
               "T01_CN_A/e0001/rgb/0000_000_T01_CN_A.png", "T01_CN_A/e0001/notes.txt"]
    for rel in strays + foreign:
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_bytes(b"x")
    report = verify(str(root))
    assert sorted((p.kind, p.path, p.episode) for p in report.problems) == [
        ("extra", strays[0], 1), ("extra", strays[1], 7)]


def test_an_old_root_stays_flat_and_verifies(old_root, new_root):
    files = frame_files(old_root)
    assert sorted({rel.rpartition("/")[0] for rel in files}) == [f"{SCENARIO}/rgb", f"{SCENARIO}/semantic_raw"]
    storage = Storage.from_uri(str(old_root))
    assert LAYOUT_KEY not in read_record(storage) and held_layout(storage) == FLAT
    assert verify(str(old_root)).ok
    # the same frames, byte for byte, as the new root's: only the folders differ
    moved = {f"{SCENARIO}/e{rel.rpartition('/')[2][:4]}/{rel.split('/')[1]}/{rel.rpartition('/')[2]}": data
             for rel, data in files.items()}
    assert moved == frame_files(new_root)
    # a stray in the flat layout is reported; one in the other layout's place is not ours here
    (old_root / SCENARIO / "rgb" / "0003_000_T01_CN_A.png").write_bytes(b"x")
    (old_root / SCENARIO / "e0000" / "rgb").mkdir(parents=True)
    (old_root / SCENARIO / "e0000" / "rgb" / "0000_099_T01_CN_A.png").write_bytes(b"x")
    try:
        assert [(p.kind, p.path) for p in verify(str(old_root)).problems] == [("extra", "T01_CN_A/rgb/0003_000_T01_CN_A.png")]
    finally:
        (old_root / SCENARIO / "rgb" / "0003_000_T01_CN_A.png").unlink()
        (old_root / SCENARIO / "e0000" / "rgb" / "0000_099_T01_CN_A.png").unlink()


def test_a_lost_run_json_is_rewritten_in_the_layout_of_the_frames(old_root, new_root, tmp_path):
    import shutil

    for source, layout in ((old_root, FLAT), (new_root, EPISODE_DIRS)):
        root = tmp_path / f"layout{layout}"
        shutil.copytree(source, root)
        (root / RUN_FILE).unlink()
        storage = Storage.from_uri(str(root))
        assert held_layout(storage) == layout
        assert [p.kind for p in verify(str(root)).problems] == ["bad-run"]  # missing; the frames still check out
        assert record_layout(prepare_root(storage, RUN)) == layout
        assert verify(str(root)).ok
    specs = make_plan(RUN.plan).episodes
    assert [s.layout for s in specs] == [EPISODE_DIRS, EPISODE_DIRS]  # a plan's default: a new root's


def test_an_old_root_reads_and_exports_as_a_new_one(old_root, new_root, tmp_path):
    """Loaders and exports go through the manifest's paths: an old root gives the same samples and files."""
    import numpy as np

    from analysis.loaders import FrameDataset
    from exports import export as ex
    from manifests.query import Query

    old, new = (FrameDataset(str(r), Query(), outputs=("rgb", "semantic_raw")) for r in (old_root, new_root))
    assert len(old) == len(new) == 81
    for i in (0, 41, 80):
        a, b = old[i], new[i]
        assert a.keys() == b.keys() and all(np.array_equal(np.asarray(a[k]), np.asarray(b[k])) for k in a)
    trees = []
    for name, root in (("old", old_root), ("new", new_root)):
        target = tmp_path / name
        assert ex.export(ex.ExportConfig(root=str(root), to=str(target), format="cityscapes")).frames == 81
        trees.append({p.relative_to(target).as_posix(): p.read_bytes()
                      for p in target.rglob("*") if p.is_file() and p.name != "EXPORT.json"})
    assert trees[0] == trees[1] and len(trees[0]) > 81


def test_the_dataset_card_names_the_roots_own_layout(old_root, new_root):
    from exports.card import card_markdown

    for root, layout in ((old_root, FLAT), (new_root, EPISODE_DIRS)):
        text = card_markdown(read_manifest(str(root)), read_record(Storage.from_uri(str(root))), ".", [])
        assert f"`{PATTERNS[layout]}.<png|jpg|parquet>`" in text


def test_an_episode_folder_that_is_a_link_is_never_followed(new_root, tmp_path):
    import shutil

    root, outside = tmp_path / "root", tmp_path / "outside"
    shutil.copytree(new_root, root)
    shutil.move(root / SCENARIO / "e0001", outside)
    (root / SCENARIO / "e0001").symlink_to(outside, target_is_directory=True)
    (outside / "rgb" / "0001_050_T01_CN_A.png").write_bytes(b"behind the link")  # would be a stray
    problems = verify(str(root)).problems
    assert [(p.kind, p.path) for p in problems] == [("link", f"{SCENARIO}/e0001")]
