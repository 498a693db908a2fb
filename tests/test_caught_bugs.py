"""Hand-made bugs the suite once missed (issue 33), one test each.

Each test fails with its bug put back into the data-protecting code and
passes without it (checked by hand once; `make mutants` keeps the habit,
docs/mutants.md). All are fast and need no Ray.
"""

from __future__ import annotations

import io
import json
import os

import pyarrow.parquet as pq
import pytest

from roots.lease import (
    LeaseLost,
    bump_generation,
    check_fence,
    live_producers,
    read_generation,
    register_producer,
)
from manifests.reader import done_episodes, episode_parts
from roots.contract import RootError, claim_root, export_tree
from roots.run_file import RunRecordError, read_record, record_bytes
from manifests.schema import RUN_FILE, part_path
from manifests.synthetic import episode_table
from manifests.part_file import ManifestError, read_part_file
from manifests.writer import part_bytes
from pipeline.planner import make_plan
from pipeline.settings import PlanConfig, RunConfig
from pipeline.provenance import RunConfigError, check_before_repair, prepare_root
from storage import Storage

TINY = PlanConfig(domains="T01_CN_A", frames_per_scenario=3, width=64, height=36, seed=5)


def tiny_spec():
    return make_plan(TINY).episodes[0]


# ----------------------------------------------------------------- storage/atomic ----


def _fd_path(fd: int) -> str:
    return os.readlink(f"/proc/self/fd/{fd}")


@pytest.mark.parametrize("how", ["atomic_write", "exclusive_write"])
def test_a_file_is_fsynced_before_it_is_renamed_or_linked_into_place(monkeypatch, tmp_path, how):
    """Bug: the temp file's fsync skipped. After a crash, the rename could be on
    disk before the data: a whole-looking file of zeros under the final name."""
    from storage import atomic

    events = []
    real_fsync, real_replace, real_link = os.fsync, os.replace, os.link
    monkeypatch.setattr(os, "fsync", lambda fd: (events.append(("fsync", _fd_path(fd))), real_fsync(fd))[1])
    monkeypatch.setattr(os, "replace", lambda a, b: (events.append(("place", str(a))), real_replace(a, b))[1])
    monkeypatch.setattr(os, "link", lambda a, b: (events.append(("place", str(a))), real_link(a, b))[1])
    target = tmp_path / "d" / "f.bin"
    getattr(atomic, how)(str(target), b"payload")
    assert target.read_bytes() == b"payload"
    placed = [i for i, e in enumerate(events) if e[0] == "place"]
    assert len(placed) == 1, events
    tmp = events[placed[0]][1]
    assert ("fsync", tmp) in events[: placed[0]], events  # the data is durable before its name is


# ------------------------------------------------------ manifests/writer (pages) ----


def test_a_flipped_byte_in_a_data_page_is_caught_by_its_page_checksum():
    """Bug: page checksums not verified on read (or not written). A flipped bit
    inside a compressed page often still decompresses; only the page's CRC
    tells the rows are wrong. Every flip in the first page that reads back as
    other rows without verification must be refused by read_part_file."""
    table = episode_table(tiny_spec())
    data = part_bytes(table)
    clean = pq.read_table(io.BytesIO(data))  # as read back (parts hold plain lists where the table has fixed-size ones)
    # the last bytes of the first column chunk: page data, which the CRC covers (a page header, with its
    # statistics, is not: a flip there can read back as other rows with every checksum right)
    chunk = pq.ParquetFile(io.BytesIO(data)).metadata.row_group(0).column(0)
    begin = min(chunk.data_page_offset, chunk.dictionary_page_offset or chunk.data_page_offset)
    end = begin + chunk.total_compressed_size
    silent = []
    for offset in range(max(chunk.data_page_offset + 16, end - 20), end):
        flipped = bytearray(data)
        flipped[offset] ^= 0x01
        try:
            unchecked = pq.read_table(io.BytesIO(bytes(flipped)), page_checksum_verification=False)
        except Exception:
            continue  # caught without the checksum anyway
        if not unchecked.equals(clean):
            silent.append(bytes(flipped))
    assert silent, "no flip in the first page reads back as other rows: the test no longer probes anything"
    for damaged in silent:
        with pytest.raises(ManifestError, match="unreadable"):
            read_part_file(_NoStorage(), "T01_CN_A/e0000.parquet", data=damaged)
    assert read_part_file(_NoStorage(), "T01_CN_A/e0000.parquet", data=data).equals(clean)


class _NoStorage:
    """read_part_file with ``data`` given only names the file."""

    def join(self, rel: str) -> str:
        return f"root/{rel}"


# ---------------------------------------------------------------- manifests/lease ----


def test_a_repair_bumps_the_generation_even_when_no_dead_lease_is_found(tmp_path):
    """Bug: the generation bumped only when a dead producer lease was found. A
    producer whose lease file was not there when repair looked (removed by
    someone, or written a moment later by a registration that read the
    generation before) must still be fenced out of committing."""
    storage = Storage.from_uri(str(tmp_path / "root"))
    claim_root(storage)
    producer = register_producer(storage, ttl_s=60)
    producer._stop.set()
    producer._thread.join()
    body = storage.read_bytes(producer.rel)
    storage.delete(producer.rel)  # not there when repair lists the leases: no dead lease is found
    assert live_producers(storage) == []
    assert read_generation(storage) == 1
    storage.write_bytes(producer.rel, body)  # its lease back, as a late write puts it
    with pytest.raises(LeaseLost, match="generation 0 -> 1"):
        check_fence(storage, producer.fence)


# ------------------------------------------------------------ manifests/runrecord ----


def test_a_run_json_edited_in_shape_fails_its_checksum(tmp_path):
    """Bug: the checksum never compared. An edit that keeps the record's shape
    (another seed, another pairing) is found only by the checksum."""
    storage = Storage.from_uri(str(tmp_path / "root"))
    claim_root(storage)
    prepare_root(storage, RunConfig(plan=TINY, world="test"))
    assert read_record(storage)["config"]["seed"] == 5
    record = json.loads(storage.read_bytes(RUN_FILE))
    record["config"]["seed"] = 6
    storage.write_bytes(RUN_FILE, json.dumps(record).encode())
    with pytest.raises(RunRecordError, match="checksum does not match"):
        read_record(storage)
    storage.write_bytes(RUN_FILE, record_bytes(record))  # resealed: a record of seed 6, read as such
    assert read_record(storage)["config"]["seed"] == 6


# -------------------------------------------------------------- pipeline/runmeta ----


def test_the_pairing_flag_is_frame_defining_even_with_extend(tmp_path):
    """Bug: pairing not among the frame-defining settings. Episode seeds depend
    on it, so an --extend (or a repair) with the other pairing would add
    frames that do not match the root's: refused, naming pairing."""
    from dataclasses import replace

    storage = Storage.from_uri(str(tmp_path / "root"))
    claim_root(storage)
    prepare_root(storage, RunConfig(plan=TINY, world="test"))
    other = RunConfig(plan=replace(TINY, pairing=1 - TINY.pairing), world="test")
    # the root holds no frames yet, so the refusal says so ("another pairing");
    # with frames it says "different pairing": either way it names pairing
    with pytest.raises(RunConfigError, match="(another|different) pairing"):
        prepare_root(storage, other, extend=True)
    with pytest.raises(RunConfigError, match="(another|different) pairing"):
        check_before_repair(storage, other, extend=True)


# --------------------------------------------------------------- pipeline/repair ----


def test_repair_deletes_every_part_name_of_a_damaged_episode(tmp_path):
    """Bug: repair deleted only the first of an episode's part names. A writer
    killed between writing the counted name and removing the old one leaves
    both; if the episode is damaged, both must go, or the stale one marks the
    episode done again with rows that list the damaged files."""
    from pipeline.settings import ProduceConfig
    from pipeline.repair import _repair
    from tests.roots import render_root

    root = tmp_path / "root"
    storage = render_root(root, RunConfig(plan=TINY, world="test"))
    spec = tiny_spec()
    (counted,) = episode_parts(storage, spec.scenario, spec.episode)
    old = part_path(spec.scenario, spec.episode)
    storage.write_bytes(old, storage.read_bytes(counted))  # the old name beside the counted one
    assert sorted(episode_parts(storage, spec.scenario, spec.episode)) == sorted([counted, old])
    frame = next(p for p in sorted((root / spec.scenario).rglob("*.png")))
    frame.write_bytes(frame.read_bytes()[:-4] + b"XXXX")  # a damaged frame: its episode re-renders
    config = ProduceConfig(run=RunConfig(plan=TINY, world="test"), out=str(root), workers=1)
    touched = _repair(storage, config, make_plan(TINY), owner="test")
    assert f"{spec.scenario}/e{spec.episode:04d}" in touched
    assert episode_parts(storage, spec.scenario, spec.episode) == []
    assert done_episodes(storage) == set()


# --------------------------------------------------------------- exports/export ----


def test_an_export_commit_rechecks_the_tree_it_replaces(tmp_path):
    """Bug: the commit replaced the target without checking it still holds what
    was found before the export began. A file put there meanwhile (a user's)
    would be deleted with the old export: the commit refuses, and puts the
    old export back whole."""
    from exports.export import _commit

    target, tmp = tmp_path / "export", tmp_path / ".export.new"
    (target / "rgb").mkdir(parents=True)
    (target / "rgb" / "a.png").write_bytes(b"old")
    (tmp / "rgb").mkdir(parents=True)
    (tmp / "rgb" / "a.png").write_bytes(b"new")
    found = export_tree(str(target))
    (target / "notes.txt").write_text("a user's file, added while exporting")
    with pytest.raises(RootError, match="changed while exporting"):
        _commit(str(tmp), str(target), found)
    assert (target / "notes.txt").read_text().startswith("a user's file")
    assert (target / "rgb" / "a.png").read_bytes() == b"old"
    assert sorted(p.name for p in tmp_path.iterdir()) == [".export.new", "export"]  # nothing left aside
    (target / "notes.txt").unlink()  # as found: now it is replaced
    _commit(str(tmp), str(target), found)
    assert (target / "rgb" / "a.png").read_bytes() == b"new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["export"]


# ---------------------------------------------------------- pipeline/episode_job ----


def test_a_part_written_while_the_lease_was_lost_is_deleted_again(monkeypatch, tmp_path):
    """Bug: the fence re-check after writing the part removed. A takeover that
    lands while the part is being written (after the first check) must not
    leave the episode marked done by a producer that no longer holds the root."""
    from pipeline import episode_job

    storage = Storage.from_uri(str(tmp_path / "root"))
    claim_root(storage)
    spec = tiny_spec()
    producer = register_producer(storage, ttl_s=60)
    real_write_part = episode_job.write_part

    def write_part_then_taken_over(*args, **kwargs):
        rel = real_write_part(*args, **kwargs)
        bump_generation(storage)  # a repair took the root over during the write
        return rel

    monkeypatch.setattr(episode_job, "write_part", write_part_then_taken_over)
    try:
        with pytest.raises(LeaseLost, match="generation 0 -> 1"):
            episode_job.commit_part(storage, spec, episode_table(spec).to_pylist(), producer.fence)
    finally:
        producer.release()
    assert episode_parts(storage, spec.scenario, spec.episode) == []
    assert done_episodes(storage) == set()
