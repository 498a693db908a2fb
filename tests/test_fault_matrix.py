"""Destructive commands against faults (issue 21, "go further"): each cell runs a
real ``idda`` command in a subprocess (tests/faultkit.py), hurts it at a fixed
point or hurts the world around it, and expects either success with a clean
root, or a refusal: one ``error:`` line, exit 2 (1 for damaged data), and the
file listing (count and checksums) of the root and of a neighbour root unchanged.

Roots are tiny (two scenarios, two frames, 64x36, the test world), rendered
once per module without Ray and copied per cell. Compaction is ``produce`` on a
finished root without indexes: nothing to render, so no Ray either.
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import signal
import time
from pathlib import Path

import pytest

from tests.roots import part_of
from roots.verify import verify
from tests import faultkit

pytestmark = pytest.mark.slow

DOMAINS = "T01_CN_A,T07_HRN_A"
PRODUCE = ["--domains", DOMAINS, "--frames-per-scenario", "2", "--width", "64", "--height", "36", "--seed", "7",
           "--world", "test"]

@pytest.fixture(scope="module")
def tiny(tmp_path_factory) -> Path:
    from pipeline.settings import PlanConfig, RunConfig
    from tests.roots import render_root

    root = tmp_path_factory.mktemp("matrix") / "root"
    plan = PlanConfig(domains=DOMAINS, frames_per_scenario=2, width=64, height=36, seed=7)
    render_root(root, RunConfig(plan=plan, world="test"))
    return root


@pytest.fixture()
def world(tiny, tmp_path) -> dict[str, Path]:
    """A fresh copy of the root, a neighbour root beside it, and a folder for the pause handshake."""
    root, neighbour = tmp_path / "root", tmp_path / "neighbour"
    shutil.copytree(tiny, root, symlinks=True)
    shutil.copytree(tiny, neighbour, symlinks=True)
    return {"root": root, "neighbour": neighbour, "flags": tmp_path / "flags", "base": tmp_path}


def _data(path: Path) -> dict[str, str]:
    """A root's listing without its leases (a producer's lease comes and goes; it is not data).
    ``_lease`` is not even walked: a lease refresh's temp file may vanish while it is read."""
    return {rel: d for rel, d in faultkit.listing(path, skip=("_lease",)).items() if rel != "_lease"}


def _written(path: Path) -> dict[Path, tuple[int, int]]:
    """Every data file's inode and modification time (leases left out, as in ``_data``)."""
    return {p: (p.stat().st_ino, p.stat().st_mtime_ns) for p in path.rglob("*")
            if p.relative_to(path).parts[0] != "_lease" and p.is_file()}


def unchanged(*paths: Path):
    """A context check: the listings of ``paths`` before equal those after."""
    before = [_data(p) for p in paths]

    def check():
        assert [_data(p) for p in paths] == before

    return check


# -------------------------------------------------------------- export --force ----
def _export(world, target: Path, *extra: str) -> list[str]:
    return ["export", str(world["root"]), "--format", "idda", "--to", str(target), *extra]


@pytest.fixture()
def exported(world) -> Path:
    """An earlier export (what --force replaces), made in a subprocess like the rest."""
    target = world["base"] / "exports" / "exp"
    target.parent.mkdir()
    result = faultkit.run(_export(world, target), world["flags"] / "first")
    assert result.returncode == 0, result.stderr
    return target


def _clean_export(target: Path) -> None:
    """A finished export and nothing else of ours beside it (no .tmp / .old)."""
    assert (target / "EXPORT.json").is_file()
    assert sorted(os.listdir(target.parent)) == [target.name], os.listdir(target.parent)


@pytest.mark.parametrize("point", ["exports.export:_commit:1", "exports.export:export_tree:3"])
def test_export_force_killed_then_rerun(world, exported, point):
    """SIGKILL before the commit, or between its two renames (the old export moved aside)."""
    check_root = unchanged(world["root"], world["neighbour"])
    before = faultkit.listing(exported)
    child = faultkit.start(_export(world, exported, "--force"), world["flags"], pause_at=point)
    child.wait_paused()
    child.kill()
    result = faultkit.run(_export(world, exported, "--force"), world["flags"] / "again")
    assert result.returncode == 0, result.stderr
    _clean_export(exported)
    assert faultkit.listing(exported) == before  # same query, same export
    check_root()


@pytest.mark.parametrize("sig, codes", [(signal.SIGTERM, (-signal.SIGTERM, 143)), (signal.SIGINT, (130,))])
def test_export_force_signalled_keeps_the_old_export(world, exported, sig, codes):
    check = unchanged(world["root"], world["neighbour"], exported)
    child = faultkit.start(_export(world, exported, "--force"), world["flags"], pause_at="exports.export:_commit:1")
    child.wait_paused()
    child.signal(sig)
    result = child.finish()
    assert result.returncode in codes, (result.returncode, result.stderr)
    assert "Traceback" not in result.stderr
    check()
    result = faultkit.run(_export(world, exported, "--force"), world["flags"] / "again")
    assert result.returncode == 0, result.stderr
    _clean_export(exported)


def test_export_force_stopped_beside_another_export(world, exported):
    """One export stopped (SIGSTOP) before its commit while a second replaces the
    target: the second must not take the stopped one's temp folder; both finish."""
    check_root = unchanged(world["root"], world["neighbour"])
    before = faultkit.listing(exported)
    child = faultkit.start(_export(world, exported, "--force"), world["flags"], pause_at="exports.export:_commit:1")
    child.wait_paused()
    child.stop()
    try:
        other = faultkit.run(_export(world, exported, "--force"), world["flags"] / "other")
        assert other.returncode == 0, other.stderr
    finally:
        child.cont()
        child.release()
    result = child.finish()
    assert result.returncode == 0, result.stderr
    _clean_export(exported)
    assert faultkit.listing(exported) == before
    check_root()


def test_export_force_on_a_full_disk_is_one_line(world, tmp_path):
    with faultkit.full_disk(tmp_path, size_kb=2048) as disk:
        if disk is None:
            pytest.skip("no tmpfs mount allowed here (needs root)")
        target = disk / "exp"
        assert faultkit.run(_export(world, target), world["flags"] / "first").returncode == 0
        check = unchanged(world["root"], world["neighbour"], target)
        filler_bytes = faultkit.fill(disk)
        assert filler_bytes < 2048 * 1024
        result = faultkit.run(_export(world, target, "--force", "--copy"), world["flags"])
        assert result.returncode == 2 and "no space left" in result.error_line().lower()
        check()
        assert sorted(p for p in os.listdir(disk) if not p.startswith(".filler")) == ["exp"]  # no temp left


def test_export_force_refuses_a_folder_swapped_for_a_symlink(world, exported):
    """A folder of the earlier export replaced by a link into the neighbour root:
    --force refuses, and nothing behind the link is touched."""
    faultkit.symlink_swap(exported / "T01_CN_A", world["neighbour"] / "T01_CN_A")
    check = unchanged(world["root"], world["neighbour"], exported)
    result = faultkit.run(_export(world, exported, "--force"), world["flags"])
    assert result.returncode == 2 and "not only what an earlier export wrote" in result.error_line()
    check()


def test_export_force_from_s3_when_the_network_goes(world, tmp_path):
    from tests.s3_server import local_s3_server
    from tests.test_export import upload_root

    with local_s3_server() as server:
        uri = server.uri("tiny")
        upload_root(world["root"], uri)
        target = tmp_path / "exports" / "exp"
        target.parent.mkdir()
        args = ["export", uri, "--format", "idda", "--to", str(target), "--copy"]
        assert faultkit.run(args, world["flags"] / "first").returncode == 0
        check = unchanged(world["neighbour"], target)
        child = faultkit.start([*args, "--force"], world["flags"], pause_at="exports.idda:decode:1")
        child.wait_paused()
        faultkit.s3_outage(server)
        child.release()
        result = child.finish()
    assert result.returncode in (1, 2), result.stderr
    result.error_line()
    check()
    assert sorted(os.listdir(target.parent)) == ["exp"]


# ------------------------------------------------------------------ compaction ----
def _produce(world, *extra: str) -> list[str]:
    return ["produce", *PRODUCE, "--out", str(world["root"]), *extra]


def test_compaction_killed_then_rerun(world):
    check_neighbour = unchanged(world["neighbour"])
    parts = {rel: digest for rel, digest in faultkit.listing(world["root"]).items() if rel.startswith("manifest/")}
    child = faultkit.start(_produce(world), world["flags"], pause_at="manifests.reader:index_bytes:1")
    child.wait_paused()
    child.kill()
    after = faultkit.listing(world["root"])
    assert all(after.get(rel) == digest for rel, digest in parts.items())  # no part lost or changed
    result = faultkit.run(_produce(world), world["flags"] / "again")
    assert result.returncode == 0, result.stderr
    assert verify(str(world["root"])).ok
    check_neighbour()


def test_compaction_with_two_parts_swapped_indexes_nothing(world):
    """Two parts exchanged (each now holds the other's episode): compaction must
    not index them as if fine, nor touch anything; verify names both. Before the
    fix produce wrote _index/T01_CN_A.parquet from T07_HRN_A's rows, and said all done."""
    root = world["root"]
    a, b = part_of(root, "T01_CN_A", 0), part_of(root, "T07_HRN_A", 0)
    faultkit.swap(root / a, root / b)
    check = unchanged(root, world["neighbour"])
    result = faultkit.run(_produce(world), world["flags"])
    if result.returncode != 0:
        assert result.returncode in (1, 2) and "T01_CN_A" in result.error_line()
    check()
    report = verify(str(root))
    assert sorted((p.kind, p.path) for p in report.problems if p.kind == "bad-part") == [
        ("bad-part", a), ("bad-part", b)]


def test_produce_does_not_call_swapped_parts_done(world):
    """Before the fix produce answered "nothing to render; all 2 planned episodes are done"
    (exit 0) for a root whose two parts are exchanged: it refuses (exit 1, damaged data),
    and a repair then renders both episodes again, byte for byte."""
    root = world["root"]
    reference = faultkit.listing(root)
    faultkit.swap(root / part_of(root, "T01_CN_A", 0), root / part_of(root, "T07_HRN_A", 0))
    result = faultkit.run(_produce(world), world["flags"])
    assert result.returncode == 1 and "T01_CN_A" in result.error_line() and "--repair" in result.error_line()
    result = faultkit.run(_produce(world, "--repair", "--workers", "1"), world["flags"] / "repair")
    assert result.returncode == 0, result.stderr
    after = faultkit.listing(root)
    assert {rel: after.get(rel) for rel in reference if not rel.startswith("_")} == {
        rel: d for rel, d in reference.items() if not rel.startswith("_")}


def test_compaction_on_a_full_disk_keeps_the_root(world, tmp_path):
    with faultkit.full_disk(tmp_path, size_kb=4096) as disk:
        if disk is None:
            pytest.skip("no tmpfs mount allowed here (needs root)")
        root = disk / "root"
        shutil.copytree(world["root"], root)
        check = unchanged(root, world["neighbour"])
        faultkit.fill(disk)
        result = faultkit.run(["produce", *PRODUCE, "--out", str(root)], world["flags"])
        if result.returncode == 0:  # compaction put off (a warning), the root as it was
            check()
        else:
            assert result.returncode == 2 and "no space left" in result.error_line().lower()
            check()
        assert verify(str(root)).ok


# --------------------------------------------------------------------- readers ----
READERS = (["query"], ["stats"], ["export", "--format", "idda", "--to"])


def _read(world, args: list[str], name: str):
    target = {"export": [str(world["base"] / f"export-{name}")],
              "stats": ["--chart", str(world["base"] / "shares.png")]}.get(args[0], [])
    return faultkit.run([args[0], str(world["root"]), *args[1:], *target], world["flags"] / name)


def test_readers_refuse_parts_swapped_between_scenarios(world):
    """Issue 33: two scenarios' parts swapped. query gave each scenario's frames under the
    other's folders, stats counted them, export exited 0. Now each refuses in one line
    (exit 1, damaged data) naming a part, and nothing changes."""
    root = world["root"]
    faultkit.swap(root / part_of(root, "T01_CN_A", 0), root / part_of(root, "T07_HRN_A", 0))
    check = unchanged(root, world["neighbour"])
    for args in READERS:
        result = _read(world, args, args[0])
        assert result.returncode == 1 and "holds the rows of another scenario or episode" in result.error_line()
    assert not (world["base"] / "export-export").exists()
    check()


def test_readers_skip_a_part_misfiled_into_another_scenarios_folder(world, tiny):
    """Issue 33: a part copied into another scenario's folder (its name kept) gave its
    frames twice. Readers skip it and say so; verify names it; repair removes it alone."""
    root = world["root"]
    rel = part_of(root, "T01_CN_A", 0)
    stray = "manifest/town=T07/weather=HRN/viewpoint=A/" + rel.rpartition("/")[2]
    shutil.copyfile(root / rel, root / stray)
    check_neighbour = unchanged(world["neighbour"])
    result = _read(world, ["query"], "query")
    assert result.returncode == 0 and "4 frames selected of 4" in result.stdout
    assert "filed under another scenario's folder: not read" in result.stderr
    assert [(p.kind, p.path) for p in verify(str(root)).problems] == [("extra", stray)]
    result = faultkit.run(_produce(world, "--repair"), world["flags"] / "repair")
    assert result.returncode == 0, result.stderr
    assert verify(str(root)).ok and not (root / stray).exists()
    _same_data(root, tiny)
    check_neighbour()


@pytest.mark.parametrize("mode", [(), ("--copy",)])  # hard links (and symlinks) read to check; copies as they copy
def test_export_refuses_damaged_frame_files(world, mode):
    """Issue 33: a flipped bit in an rgb PNG and a PNG truncated to 0 bytes: export exited 0
    and copied the damage. Each file is checked against the manifest's sha256 as it is
    placed: a refusal in one line (exit 1, no target), or with --skip-damaged those
    frames left out and counted."""
    root = world["root"]
    flipped = next(root.glob("T01_CN_A/e0000/rgb/0000_001_*.png"))
    data = bytearray(flipped.read_bytes())
    data[len(data) // 2] ^= 0x10
    flipped.write_bytes(bytes(data))
    next(root.glob("T07_HRN_A/e0000/semantic_raw/0000_000_*.png")).write_bytes(b"")
    check = unchanged(root, world["neighbour"])
    target = world["base"] / "exp"
    result = faultkit.run(_export(world, target, *mode), world["flags"] / "refused")
    assert result.returncode == 1 and "is damaged" in result.error_line() and "--skip-damaged" in result.error_line()
    assert not target.exists() and sorted(os.listdir(world["base"])) == ["flags", "neighbour", "root"]
    result = faultkit.run(_export(world, target, *mode, "--skip-damaged"), world["flags"] / "skipped")
    assert result.returncode == 0, result.stderr
    assert "left out 2 frames with 2 damaged files" in result.stderr and "exported 2 of the 4 frames the root holds" in result.stdout
    rows = (target / "frames.csv").read_text().splitlines()[1:]
    assert sorted(row.split(",")[5] for row in rows) == ["0000_000_T01_CN_A", "0000_001_T07_HRN_A"]
    check()


@pytest.mark.parametrize("inside", ["T01_CN_A/e0000/rgb/new", "manifest"])  # a frame folder, manifest/
def test_produce_refuses_an_out_inside_another_root(world, inside):
    """Issue 33: ``--out`` inside a frame folder or ``manifest/`` of a root was accepted
    (exit 0). Refused in one line, as export refuses such a target; nothing is written."""
    check = unchanged(world["root"], world["neighbour"])
    args = ["produce", *PRODUCE, "--out", str(world["root"] / inside)]
    result = faultkit.run(args, world["flags"])
    assert result.returncode == 2 and f"is inside the output root {world['root']}" in result.error_line()
    check()


# ---------------------------------------------------------------------- repair ----
def test_repair_never_follows_a_scenario_symlink_into_a_neighbour(world):
    root = world["root"]
    faultkit.symlink_swap(root / "T01_CN_A", world["neighbour"] / "T01_CN_A")
    check = unchanged(world["neighbour"])
    result = faultkit.run(_produce(world, "--repair"), world["flags"])
    assert result.returncode in (1, 2) and "T01_CN_A" in result.error_line()
    check()


def test_repair_refuses_a_run_json_of_another_run(world):
    from pipeline.settings import PlanConfig, RunConfig
    from pipeline.provenance import prepare_root
    from storage import Storage

    other = RunConfig(plan=PlanConfig(domains=DOMAINS, frames_per_scenario=2, width=64, height=36, seed=8), world="test")
    elsewhere = world["base"] / "seed8"
    prepare_root(Storage.from_uri(str(elsewhere)), other)
    shutil.copyfile(elsewhere / "run.json", world["root"] / "run.json")  # valid checksum, another seed
    check = unchanged(world["root"], world["neighbour"])
    result = faultkit.run(_produce(world, "--repair"), world["flags"])
    assert result.returncode in (1, 2)
    result.error_line()
    check()


def _same_data(root: Path, reference: Path) -> None:
    """``root`` holds the frames and parts of ``reference``, byte for byte."""
    data = {rel: d for rel, d in faultkit.listing(reference).items() if rel.startswith(("T01_", "T07_", "manifest/"))}
    after = faultkit.listing(root)
    assert {rel: after.get(rel) for rel in data} == data


def test_repair_mends_a_part_whose_name_lies_about_its_rows(world, tiny):
    """Issue 33: ``_n2`` renamed ``_n72``. verify flagged it, but the repair it
    recommends refused ("holds 72 frames... a root never shrinks"): no way out. The
    name is not a row count to protect: status counts the rows and says so, repair
    renders the episode again, byte for byte."""
    root = world["root"]
    rel = part_of(root, "T01_CN_A", 0)
    lying = rel.replace("_n2.parquet", "_n72.parquet")
    os.rename(root / rel, root / lying)
    check_neighbour = unchanged(world["neighbour"])
    assert [p.path for p in verify(str(root)).problems if p.kind == "bad-part"] == [lying]
    status = faultkit.run(["status", str(root)], world["flags"] / "status")
    assert status.returncode == 0 and f"{lying} (its name says 72 rows, it holds 2)" in status.stderr
    assert "4 of 4 frames done" in status.stdout
    result = faultkit.run(_produce(world, "--repair", "--workers", "1"), world["flags"])
    assert result.returncode == 0, result.stderr
    assert verify(str(root)).ok and not (root / lying).exists()
    _same_data(root, tiny)
    check_neighbour()


def test_a_resume_keeps_the_true_part_beside_a_lying_copy(world, tiny):
    """Issue 33: ``_n2`` copied to ``_n3``. A plain resume deleted the true ``_n2``
    (as a killed writer's old name) and kept the false ``_n3``; then repair refused.
    Now the resume deletes neither, verify names both, and repair mends the episode."""
    root = world["root"]
    true = part_of(root, "T01_CN_A", 0)
    copy = true.replace("_n2.parquet", "_n3.parquet")
    shutil.copyfile(root / true, root / copy)
    parts = {rel: d for rel, d in faultkit.listing(root).items() if rel.startswith("manifest/")}
    check_neighbour = unchanged(world["neighbour"])
    result = faultkit.run(_produce(world), world["flags"])
    assert result.returncode == 0, result.stderr
    after = faultkit.listing(root)
    assert {rel: after.get(rel) for rel in parts} == parts  # no part deleted, none changed
    assert sorted(p.path for p in verify(str(root)).problems if p.kind == "bad-part") == sorted([true, copy])
    result = faultkit.run(_produce(world, "--repair", "--workers", "1"), world["flags"] / "repair")
    assert result.returncode == 0, result.stderr
    assert verify(str(root)).ok and not (root / copy).exists()
    _same_data(root, tiny)
    check_neighbour()


def test_repair_checks_what_it_will_write_before_it_deletes(world):
    """Issue 33: a frame file replaced by a folder holding a user's file. Repair deleted
    the episode's part and index, then failed (EISDIR, rc 1, a hint blaming the storage).
    Now it refuses first, in one line naming the folder; nothing changes, the file stays."""
    root = world["root"]
    frame = root / "T01_CN_A" / "e0000" / "rgb" / "0000_001_T01_CN_A.png"
    frame.unlink()
    frame.mkdir()
    (frame / "notes.txt").write_text("mine")
    check = unchanged(root, world["neighbour"])
    result = faultkit.run(_produce(world, "--repair"), world["flags"])
    assert result.returncode == 2, result.stderr
    line = result.error_line()
    assert f"{frame} is a folder (1 entry inside)" in line and "repair deleted nothing" in line
    check()


def test_a_folder_in_place_of_a_part_is_named_and_refused(world):
    """Issue 33: a part replaced by a folder. verify did not name it, and produce failed
    with EISDIR every time. Now verify names it, and produce and repair say what is in
    the way, in one line, exit 2, touching nothing."""
    root = world["root"]
    rel = part_of(root, "T01_CN_A", 0)
    (root / rel).unlink()
    (root / rel).mkdir()
    check = unchanged(root, world["neighbour"])
    assert [(p.path, p.detail) for p in verify(str(root)).problems if p.kind == "bad-part"] == [
        (rel, "a folder where a part file goes")]
    for extra in ((), ("--repair",)):
        result = faultkit.run(_produce(world, *extra), world["flags"] / "-".join(("run",) + extra))
        assert result.returncode == 2, result.stderr
        assert f"{root / rel} is a folder (0 entries inside), where T01_CN_A/e0000 writes a file" in result.error_line()
    check()


def test_repair_killed_before_rendering_then_rerun(world, tiny):
    """Repair deleted a damaged episode's files and was killed before it rendered
    them again: the next repair finishes the job, byte for byte as rendered first."""
    root = world["root"]
    reference = faultkit.listing(tiny)
    victim = next(root.glob("T07_HRN_A/e*/rgb/*.png"))
    victim.write_bytes(victim.read_bytes()[:-8] + b"damaged!")
    child = faultkit.start(_produce(world, "--repair", "--workers", "1"), world["flags"],
                           pause_at="pipeline.driver:_render_on_ray:1")
    child.wait_paused()
    child.kill()
    result = faultkit.run(_produce(world, "--repair", "--workers", "1"), world["flags"] / "again")
    assert result.returncode == 0, result.stderr
    assert verify(str(root)).ok
    after = faultkit.listing(root)
    data = {rel: d for rel, d in reference.items() if rel.startswith(("T01_", "T07_", "manifest/"))}
    assert {rel: after.get(rel) for rel in data} == data


def test_worker_stopped_past_its_lease_never_commits_after_a_repair(world, tiny, tmp_path):
    """Issue 21.3 with real signals: a producer's worker is stopped (SIGSTOP) just
    before it commits, and the producer with it, past the lease's expiry; a repair
    takes the root over and renders it whole; then both wake up (SIGCONT). The
    worker's commit fails on the lease generation: no part is written over the
    repair's, no file changes, and the producer says it lost its lease."""
    out = tmp_path / "fresh"
    args = ["produce", *PRODUCE, "--out", str(out), "--workers", "1"]
    ttl = {"IDDA_LEASE_TTL_S": "2"}
    marker = tmp_path / "stopped-worker"
    child = faultkit.start(args, world["flags"], env={**ttl, "IDDA_FAULT_INJECT": f"stop-before-commit:{marker}"})
    worker = faultkit.stopped_worker(marker, child)
    try:
        child.stop()  # the driver too: nobody refreshes its lease
        time.sleep(3)  # past the lease's expiry
        repair = faultkit.run([*args, "--repair"], world["flags"] / "repair", env=ttl)
        assert repair.returncode == 0, repair.stderr
        repaired = _data(out)
        written = _written(out)
    finally:
        child.cont()
        os.kill(worker, signal.SIGCONT)
    result = child.finish()
    assert result.returncode != 0 and "lease" in result.stderr.lower(), result.stderr[-2000:]
    assert "Traceback" not in result.stderr
    assert _data(out) == repaired
    assert _written(out) == written  # not even the same bytes again
    assert verify(str(out)).ok
    reference = {rel: d for rel, d in _data(tiny).items() if rel.startswith(("T01_", "T07_", "manifest/"))}
    assert {rel: repaired.get(rel) for rel in reference} == reference  # the repair's bytes: a plain render's


def test_snapshots_never_read_a_lease_writers_temp_files(tmp_path, monkeypatch):
    """The cell above failed once with FileNotFoundError on ``_lease/.producer-*.tmp``: its
    producer, stopped mid-refresh, left a lease's temp file that its later rename took away
    between the snapshot's listing and its read. Snapshots now never walk into ``_lease``."""
    (tmp_path / "_lease").mkdir()
    (tmp_path / "_lease" / ".producer-x.json.tmp").write_bytes(b"{}")
    (tmp_path / "T01_CN_A").mkdir()
    (tmp_path / "T01_CN_A" / "f.png").write_bytes(b"png")
    real_read, real_stat = Path.read_bytes, Path.stat

    def vanished(path: Path) -> Path:  # the temp file is gone as soon as it was listed
        if "_lease" in path.parts and path.name.endswith(".tmp"):
            raise FileNotFoundError(errno.ENOENT, "No such file or directory", str(path))
        return path

    monkeypatch.setattr(Path, "read_bytes", lambda path: real_read(vanished(path)))
    monkeypatch.setattr(Path, "stat", lambda path, **kw: real_stat(vanished(path), **kw))
    assert list(_data(tmp_path)) == ["T01_CN_A", "T01_CN_A/f.png"]
    assert list(_written(tmp_path)) == [tmp_path / "T01_CN_A" / "f.png"]


# ---------------------------------------------------------------------- extend ----
def test_extend_sigterm_says_how_to_resume(world):
    args = ["produce", "--domains", DOMAINS, "--frames-per-scenario", "3", "--width", "64", "--height", "36",
            "--seed", "7", "--world", "test", "--out", str(world["root"]), "--extend", "--workers", "1"]
    child = faultkit.start(args, world["flags"], pause_at="pipeline.driver:_render_on_ray:1")
    child.wait_paused()
    child.signal(signal.SIGTERM)
    child.release()
    result = child.finish()
    assert result.returncode == 143 and "Traceback" not in result.stderr
    assert "resume" in result.stderr.lower()


def test_an_isal_root_extended_keeps_isal(world, tmp_path):
    """Issue 33: a root made with ISA-L (before libdeflate) run with ``--extend``: run.json's
    encoder was rewritten to libdeflate and the new frames deflated by it, one root mixing
    two deflaters. Now the extended root keeps ISA-L for every frame, old and new."""
    from dataclasses import replace

    from roots.run_file import record_bytes
    from pipeline.episode_job import run_episode
    from pipeline.planner import make_plan
    from pipeline.settings import PlanConfig, RunConfig
    from pipeline.provenance import prepare_root
    from storage import Storage
    from tests.test_deflaters import ISAL_IDENTITY, _isal_pngs

    root = tmp_path / "isal"
    storage = Storage.from_uri(str(root))
    plan = PlanConfig(domains=DOMAINS, frames_per_scenario=2, width=64, height=36, seed=7)
    record = prepare_root(storage, RunConfig(plan=plan, world="test"))
    storage.write_bytes("run.json", record_bytes({**record, "encoder": ISAL_IDENTITY}))  # as the ISA-L version wrote it
    for spec in make_plan(plan).episodes:
        run_episode(replace(spec, png_deflater="isal"), storage, world="test")
    check_neighbour = unchanged(world["neighbour"])
    args = ["produce", "--domains", DOMAINS, "--frames-per-scenario", "3", "--width", "64", "--height", "36",
            "--seed", "7", "--world", "test", "--out", str(root), "--extend", "--workers", "1"]
    result = faultkit.run(args, world["flags"])
    assert result.returncode == 0, result.stderr
    assert json.loads((root / "run.json").read_text())["encoder"] == ISAL_IDENTITY
    assert _isal_pngs(root) == (24, 24)  # 6 frames x 4 PNG outputs, every one ISA-L's
    assert verify(str(root)).ok
    check_neighbour()


def test_extend_killed_then_rerun_grows_the_root(world):
    args = ["produce", "--domains", DOMAINS, "--frames-per-scenario", "3", "--width", "64", "--height", "36",
            "--seed", "7", "--world", "test", "--out", str(world["root"]), "--extend", "--workers", "1"]
    check_neighbour = unchanged(world["neighbour"])
    child = faultkit.start(args, world["flags"], pause_at="pipeline.driver:_render_on_ray:1")
    child.wait_paused()
    child.kill()
    assert verify(str(world["root"])).ok  # killed before rendering: still the 2-frame root, whole
    result = faultkit.run(args, world["flags"] / "again")
    assert result.returncode == 0, result.stderr
    report = verify(str(world["root"]))
    assert report.ok
    from manifests.reader import read_manifest

    assert len(read_manifest(str(world["root"]))) == 6
    check_neighbour()
