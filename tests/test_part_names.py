"""A part's name carries its row count (issue 22: ``idda status`` of a full
root without indexes read 14,355 footers); old roots' names still read."""

from __future__ import annotations

import pytest

import manifests.reader as reader
from manifests.reader import compact, episode_frames, episode_parts, part_listing, read_manifest
from manifests.schema import PART_RE, named_rows, part_path
from manifests.synthetic import episode_table
from roots.verify import verify
from manifests.writer import part_bytes, write_part
from pipeline.planner import make_plan
from pipeline.status import root_status
from tests.roots import part_of, to_old_names
from tests.test_control_plane import MANY, PLAN, expected_frames, synthetic_root

LISTING = 1 + 1 + 1 + 2  # manifest/, its town, weather and two viewpoint folders (MANY)


@pytest.fixture()
def no_footers(monkeypatch):
    """Count the footers read (each a read of the part on disk, a GET on S3)."""
    reads = []
    real = reader._footer

    def counted(storage, rel, size=None):
        reads.append(rel)
        return real(storage, rel, size)

    monkeypatch.setattr(reader, "_footer", counted)
    return reads


def test_parts_are_named_with_their_rows_and_status_reads_none(tmp_path, no_footers):
    storage = synthetic_root(str(tmp_path / "root"))
    for spec in make_plan(PLAN).episodes:
        assert part_of(tmp_path / "root", spec.scenario, spec.episode) == part_path(spec.scenario, spec.episode, spec.frames)
    assert part_path("T07_HRN_B", 3, 72).endswith("/T07_HRN_B_e0003_n72.parquet")
    status = root_status(storage)
    assert status.frames_done == status.frames_total == sum(expected_frames().values())
    assert no_footers == []  # before: one footer per part (no indexes yet)


def test_an_old_root_reads_from_its_footers_and_a_rerendered_episode_takes_the_new_name(tmp_path, no_footers):
    storage = synthetic_root(str(tmp_path / "root"))
    before = read_manifest(storage)
    parts = sum(len(e) for e in part_listing(storage).values())
    assert to_old_names(storage) == parts and all(named_rows(rel) is None for rel in storage.list_files("manifest/"))
    assert episode_frames(storage) == expected_frames() and len(no_footers) == parts
    assert read_manifest(storage).equals(before) and root_status(storage).frames_done == len(before)
    spec = make_plan(PLAN).episodes[0]  # rendered again (say, repaired) by this version
    assert write_part(storage, spec.scenario, spec.episode, episode_table(spec)) == part_path(spec.scenario, spec.episode, spec.frames)
    assert episode_parts(storage, spec.scenario, spec.episode) == [part_path(spec.scenario, spec.episode, spec.frames)]
    assert read_manifest(storage).equals(before) and episode_frames(storage) == expected_frames()
    assert compact(storage) and read_manifest(storage).equals(before)


def test_a_writer_killed_between_the_new_name_and_the_old_leaves_the_new_one_read(tmp_path):
    """Beside the part readers use, the old name (a writer killed before removing it) and
    a shorter counted part: the longest counted one is read, and compaction removes the others."""
    storage = synthetic_root(str(tmp_path / "root"))
    before = read_manifest(storage)
    spec = make_plan(PLAN).episodes[0]
    new = part_of(tmp_path / "root", spec.scenario, spec.episode)
    old, short = part_path(spec.scenario, spec.episode), part_path(spec.scenario, spec.episode, 1)
    storage.write_bytes(old, storage.read_bytes(new))
    storage.write_bytes(short, part_bytes(episode_table(spec).slice(0, 1)))
    assert part_listing(storage)[spec.scenario][spec.episode][0] == new
    assert episode_parts(storage, spec.scenario, spec.episode) == [new, short, old]
    assert episode_frames(storage) == expected_frames() and read_manifest(storage).equals(before)
    compact(storage)
    assert episode_parts(storage, spec.scenario, spec.episode) == [new] and read_manifest(storage).equals(before)


def test_verify_names_a_part_whose_name_disagrees_with_its_rows(tmp_path):
    storage = synthetic_root(str(tmp_path / "root"))
    spec = make_plan(PLAN).episodes[0]
    rel = part_of(tmp_path / "root", spec.scenario, spec.episode)
    wrong = part_path(spec.scenario, spec.episode, spec.frames + 1)
    storage.write_bytes(wrong, storage.read_bytes(rel))
    storage.delete(rel)
    assert episode_frames(storage)[(spec.scenario, spec.episode)] == spec.frames + 1  # status trusts names
    bad = [p for p in verify(storage).problems if p.kind == "bad-part"]
    assert [(p.path, p.episode) for p in bad] == [(wrong, spec.episode)] and "name says" in bad[0].detail


def _rename(storage, rel: str, to: str, keep: bool = False) -> None:
    storage.write_bytes(to, storage.read_bytes(rel))
    if not keep:
        storage.delete(rel)


def test_status_and_query_count_a_lying_part_by_its_rows(tmp_path):
    """Issue 33: ``_n<rows>`` renamed to say more rows than the part holds (and than
    the plan asks): status took it as done from its name, silently; now it reads
    that part's footer, counts its rows and says the name disagrees. Query reads rows."""
    storage = synthetic_root(str(tmp_path / "root"))
    spec = make_plan(PLAN).episodes[0]
    rel = part_of(tmp_path / "root", spec.scenario, spec.episode)
    lying = part_path(spec.scenario, spec.episode, 200)
    _rename(storage, rel, lying)
    storage.write_bytes(lying, part_bytes(episode_table(spec).slice(0, 4)))  # 4 rows under a name saying 200
    status = root_status(storage)
    assert status.frames_done == status.frames_total - (spec.frames - 4)
    assert status.misnamed == [f"{lying} (its name says 200 rows, it holds 4)"]
    table = read_manifest(storage)
    assert ((table.column("scenario").to_numpy(zero_copy_only=False) == spec.scenario)
            & (table.column("episode").to_numpy() == spec.episode)).sum() == 4


def test_a_lying_copy_never_costs_the_true_part(tmp_path):
    """Issue 33: a part copied to a name saying one row more (``_n4`` to ``_n5``). Readers
    use the higher name; compaction removed the other as a killed writer's leftover, so a
    plain resume deleted the true part and kept the false one. Now compaction keeps
    both (the one read does not hold the rows its name says) and verify names both."""
    storage = synthetic_root(str(tmp_path / "root"))
    spec = make_plan(PLAN).episodes[0]
    true = part_of(tmp_path / "root", spec.scenario, spec.episode)
    copy = part_path(spec.scenario, spec.episode, spec.frames + 1)
    _rename(storage, true, copy, keep=True)
    compact(storage)
    assert episode_parts(storage, spec.scenario, spec.episode) == [copy, true]
    bad = sorted((p.path, p.detail) for p in verify(storage).problems if p.kind == "bad-part")
    assert [path for path, _ in bad] == sorted([copy, true])
    assert dict(bad)[copy] == f"its name says {spec.frames + 1} rows, it holds {spec.frames}"
    assert dict(bad)[true] == f"a second part of this episode, beside the damaged {copy}"


def test_part_names_parse():
    match = PART_RE.match("manifest/town=T01/weather=CN/viewpoint=A/T01_CN_A_e0012_n72.parquet")
    assert (match.group("scenario"), match.group("episode"), match.group("rows")) == ("T01_CN_A", "0012", "72")
    assert PART_RE.match("manifest/town=T01/weather=CN/viewpoint=A/T01_CN_A_e0012.parquet").group("rows") is None
    assert PART_RE.match("manifest/town=T01/weather=CN/viewpoint=A/T01_CN_A_e0012_n0.parquet") is None


# ------------------------------------------------------ S3 request counts ----


def test_s3_status_of_a_root_without_indexes_is_its_listing():
    """Before: a GET per part's footer (26 here, 14,355 at full scale); now the listing alone."""
    from tests.s3_counter import counting_s3_server

    with counting_s3_server() as (server, counter):
        storage = synthetic_root(server.uri("root"), MANY)
        counter.reset()
        status = root_status(storage)
        requests = counter.counts()
    assert status.frames_done == status.frames_total == sum(expected_frames(MANY).values())
    # the listing (manifest/ and _index/), the root marker, run.json and _stats/driver.json
    assert sum(requests.values()) <= LISTING + 1 + 6 < len(make_plan(MANY).episodes), requests


def test_verify_on_s3_reads_each_file_in_one_get_and_finds_damage(reference, monkeypatch):
    """Verify on S3 reads each frame file with one GET (no HEAD before it: the listing gave
    its size), one request per file fewer than pyarrow's HEAD + GET, and still finds a file
    changed in place and one deleted."""
    from roots.verify import verify
    from storage import Storage
    from tests.s3_counter import counting_s3_server

    local = Storage.from_uri(str(reference))
    files = local.list_sizes()
    with counting_s3_server() as (server, counter):
        remote = Storage.from_uri(server.uri("root"))
        for rel in files:
            remote.write_bytes(rel, local.read_bytes(rel))
        counts = []
        for through_pyarrow in (False, True):
            with monkeypatch.context() as patch:
                if through_pyarrow:  # the reads as they were: pyarrow's HEAD then GET
                    patch.setattr(Storage, "read_listed", lambda self, rel, size: self.read_bytes(rel))
                counter.reset()
                report = verify(remote)
                counts.append((counter.counts(), report.files_checked))
            assert report.ok, report.problems
        (ours, checked), (pyarrows, _) = counts
        assert checked > 100
        assert pyarrows["HEAD"] - ours.get("HEAD", 0) >= checked  # a HEAD per file saved
        assert ours["GET"] <= pyarrows["GET"] + 3  # and no GET more (give or take a lease read)
        assert ours.get("HEAD", 0) + ours["GET"] <= checked * 1.5  # ~1 per file plus a few parts and listings
        frames = sorted(rel for rel in files if rel.endswith(".png"))
        damaged, gone = frames[0], frames[1]
        data = bytearray(local.read_bytes(damaged))
        data[len(data) // 2] ^= 0xFF
        remote.write_bytes(damaged, bytes(data))
        remote.delete(gone)
        found = {(p.kind, p.path) for p in verify(remote).problems}
    assert ("corrupt", damaged) in found and ("missing", gone) in found
