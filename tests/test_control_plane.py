"""The manifest control plane: O(parts) scans, incremental and self-checking
indexes, lease fencing and takeover, a race-free root creation, S3 request
counts. Real files, real Parquet, read back through the public reader."""

from __future__ import annotations

import json
import logging
import os
import shutil
import socket
import subprocess
import sys
import threading
import time
from dataclasses import replace

import pytest

from roots.lease import (
    EXCLUSIVE,
    PRODUCER_PREFIX,
    LeaseLost,
    acquire_exclusive,
    live_producers,
    read_generation,
    register_producer,
)
from manifests.reader import (
    compact,
    done_episodes,
    episode_frames,
    part_summaries,
    read_manifest,
    scan,
)
from roots.contract import ROOT_MARKER, claim_root
from manifests.schema import index_path
from tests.faultkit import REPO
from tests.roots import part_of, to_old_names
from manifests.synthetic import episode_table, write_parts
from manifests.writer import write_part
from pipeline.planner import make_plan
from pipeline.settings import PlanConfig, RunConfig
from pipeline.provenance import check_rows, prepare_root
from pipeline.status import root_status
from storage import Storage

# Three scenarios of 2-3 episodes: small, and every code path of a big root.
PLAN = PlanConfig(domains="towns=T01,T02,T07 weathers=CN viewpoints=A", frames_per_scenario=150, width=64, height=36, seed=3)
# More parts than requests: two scenarios, 13 episodes each.
MANY = PlanConfig(domains="towns=T01 weathers=CN viewpoints=A,M", frames_per_scenario=800, width=64, height=36, seed=3)


def synthetic_root(uri: str, plan_config: PlanConfig = PLAN) -> Storage:
    storage = Storage.from_uri(uri)
    claim_root(storage)
    prepare_root(storage, RunConfig(plan=plan_config, world="test"))
    write_parts(storage, make_plan(plan_config).episodes)
    return storage


def expected_frames(plan_config: PlanConfig = PLAN) -> dict:
    return {(e.scenario, e.episode): e.frames for e in make_plan(plan_config).episodes}


@pytest.fixture(scope="module")
def ray_local():
    import ray

    ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()


def longer(spec, frames: int):
    return replace(spec, frames=frames)


# ------------------------------------------------------------- O(parts) scans ----


def test_scan_reads_footers_not_rows(tmp_path):
    """Resume's checks (frames per episode, seeds, resolution, rgb format) come
    from footers: a part whose data pages are damaged but whose footer is whole
    still scans. Reading rows (O(rows), 3.3 GB at full scale) would fail on it."""
    storage = synthetic_root(str(tmp_path / "root"))
    spec = make_plan(PLAN).episodes[0]
    path = tmp_path / "root" / part_of(tmp_path / "root", spec.scenario, spec.episode)
    data = bytearray(path.read_bytes())
    data[8:4008] = bytes(4000)  # the first data pages; the footer sits at the end
    path.write_bytes(bytes(data))
    assert episode_frames(storage) == expected_frames()
    check_rows(storage, RunConfig(plan=PLAN, world="test"))  # reads no row: passes
    summary = part_summaries(storage)[(spec.scenario, spec.episode)]
    assert summary.rows == spec.frames and summary.seeds == (spec.seed,) and summary.resolutions == ((64, 36),)
    assert summary.rgb == ("png",)


def test_check_rows_from_summaries_still_refuses_other_seeds(tmp_path):
    storage = synthetic_root(str(tmp_path / "root"))
    other = replace(PLAN, seed=4)
    with pytest.raises(Exception, match="another run seed"):
        check_rows(storage, RunConfig(plan=other, world="test"))
    with pytest.raises(Exception, match="holds frames at 64x36"):
        check_rows(storage, RunConfig(plan=replace(PLAN, width=128, height=72), world="test"))
    compact(storage)  # the same checks from the indexes' summaries
    with pytest.raises(Exception, match="another run seed"):
        check_rows(storage, RunConfig(plan=other, world="test"))


def test_a_swapped_part_is_misfiled_not_done_from_its_footer_or_its_index(tmp_path):
    """A part's summary names the scenarios and episodes of its rows: two parts
    exchanged are not done, refused by produce, and never folded into an index."""
    import shutil

    from manifests.reader import PartSummary, refuse_misfiled
    from manifests.part_file import MisfiledParts

    storage = synthetic_root(str(tmp_path / "root"))
    a, b = make_plan(PLAN).episodes[0], make_plan(PLAN).episodes[-1]
    assert a.scenario != b.scenario
    pa_, pb = (tmp_path / "root" / part_of(tmp_path / "root", s.scenario, s.episode) for s in (a, b))
    shutil.move(pa_, tmp_path / "x")
    shutil.move(pb, pa_)
    shutil.move(tmp_path / "x", pb)
    frames = episode_frames(storage, part_summaries(storage))  # what produce counts as done
    assert frames[(a.scenario, a.episode)] == frames[(b.scenario, b.episode)] == 0
    with pytest.raises(MisfiledParts, match=a.scenario):
        refuse_misfiled(storage, part_summaries(storage))
    assert a.scenario not in compact(storage) and b.scenario not in compact(storage)
    assert not (tmp_path / "root" / index_path(a.scenario)).exists()
    # an index written before summaries named their rows still reads (unknown, so trusted)
    episode, old = PartSummary.from_json([3, 100, 7, [1], [[64, 36]], ["png"]])
    assert episode == 3 and old.scenarios is None and not old.misfiled("T01_CN_A", 4)


def test_current_indexes_answer_without_reading_parts(tmp_path):
    """Where a scenario's index is current, status and resume read it alone:
    unreadable parts (same size, so the listing still matches) are never opened."""
    storage = synthetic_root(str(tmp_path / "root"))
    assert compact(storage) == sorted(PLAN_SCENARIOS())
    for spec in make_plan(PLAN).episodes:
        path = tmp_path / "root" / part_of(tmp_path / "root", spec.scenario, spec.episode)
        path.write_bytes(bytes(path.stat().st_size))  # zeros: any read of it would fail
    assert set(scan(storage).current) == set(PLAN_SCENARIOS())
    assert episode_frames(storage) == expected_frames()
    status = root_status(storage)
    assert status.frames_done == status.frames_total == sum(expected_frames().values())


def PLAN_SCENARIOS() -> list[str]:
    return sorted({e.scenario for e in make_plan(PLAN).episodes})


# ------------------------------------------------------ incremental indexes ----


def test_fold_reads_only_new_parts_and_equals_a_full_rebuild(tmp_path):
    plan = make_plan(PLAN)
    first, rest = plan.episodes[:6], plan.episodes[6:]
    full = synthetic_root(str(tmp_path / "full"))
    compact(full)
    storage = Storage.from_uri(str(tmp_path / "inc"))
    claim_root(storage)
    prepare_root(storage, RunConfig(plan=PLAN, world="test"))
    write_parts(storage, first)
    compact(storage)
    for spec in first:  # folded already: a second fold must not read them again
        os.chmod(tmp_path / "inc" / part_of(tmp_path / "inc", spec.scenario, spec.episode), 0)
    try:
        write_parts(storage, rest)
        assert compact(storage) == sorted({e.scenario for e in rest})
    finally:
        for spec in first:
            os.chmod(tmp_path / "inc" / part_of(tmp_path / "inc", spec.scenario, spec.episode), 0o644)
    for scenario in PLAN_SCENARIOS():
        assert (tmp_path / "inc" / index_path(scenario)).read_bytes() == (tmp_path / "full" / index_path(scenario)).read_bytes()
    assert compact(storage) == []  # all current
    assert read_manifest(storage).equals(read_manifest(full))


def test_a_fold_imports_neither_pyarrow_dataset_nor_pandas(tmp_path):
    """The fold at the end of a run is on its critical path: importing pandas (which pyarrow's dataset
    module and its conversions of Python objects do) added a quarter of a second to every run. The
    indexes a fresh process folds are those of the process that imported them."""
    root = synthetic_root(str(tmp_path / "root"))
    expected = {}
    compact(root)
    for scenario in PLAN_SCENARIOS():
        expected[scenario] = (tmp_path / "root" / index_path(scenario)).read_bytes()
        (tmp_path / "root" / index_path(scenario)).unlink()
    child = ("import sys; from manifests.reader import compact; folded = compact(sys.argv[1]); "
             "print(len(folded), 'pandas' in sys.modules, 'pyarrow.dataset' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", child, str(tmp_path / "root")], capture_output=True, text=True,
                         check=True, cwd=str(REPO), env={**os.environ, "PYTHONPATH": str(REPO)}).stdout.split()
    assert out == [str(len(expected)), "False", "False"]
    for scenario, data in expected.items():
        assert (tmp_path / "root" / index_path(scenario)).read_bytes() == data


def test_a_part_is_read_as_pyarrow_reads_it_against_a_schema(tmp_path):
    """read_part_file without pyarrow.dataset: columns the file lacks come back null, others are dropped,
    types are cast to the schema's, and the schema's metadata is kept, as pq.read_table(schema=) gives."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from manifests.part_file import ManifestError, read_part_file

    schema = pa.schema([("frame", pa.int64()), ("name", pa.string()), ("missing", pa.float32())],
                       metadata={b"k": b"v"})
    table = pa.table({"extra": pa.array([1.5, 2.5]), "name": pa.array(["a", None]),
                      "frame": pa.array([3, 4], pa.int32())})
    pq.write_table(table, tmp_path / "p.parquet")
    storage = Storage.from_uri(str(tmp_path))
    for wanted in (schema, None):
        ours = read_part_file(storage, "p.parquet", wanted)
        theirs = pq.read_table(tmp_path / "p.parquet", schema=wanted)
        assert ours.equals(theirs, check_metadata=True)
    assert read_part_file(storage, "p.parquet", schema).column("missing").null_count == 2
    bad = pa.schema([("name", pa.int64())])  # "a" is no integer
    with pytest.raises(ManifestError, match="p.parquet"):
        read_part_file(storage, "p.parquet", bad)


def test_produce_folds_indexes_while_it_runs(ray_local, tmp_path):
    """A run keeps its indexes current as it goes (every index_every_s), not
    only at the end: a killed run leaves them at most that stale."""
    from pipeline.settings import ProduceConfig
    from pipeline.driver import produce

    plan = PlanConfig(domains="towns=T01 weathers=CN viewpoints=A,M", frames_per_scenario=3, width=64, height=36, seed=5)
    out = tmp_path / "root"
    seen = []

    def progress(p) -> None:  # called in the driver; the fold runs beside it
        if p.episodes_done >= 1 and not seen:  # one episode in flight at a time: the other is not done
            deadline = time.time() + 60
            while time.time() < deadline and not list((out / "_index").glob("*.parquet")):
                time.sleep(0.05)
            seen.append(len(list((out / "_index").glob("*.parquet"))) == 1)

    config = ProduceConfig(run=RunConfig(plan=plan, world="test"), out=str(out), workers=1, max_in_flight=1,
                           index_every_s=0.1)
    report = produce(config, progress=progress)
    assert report.ok and report.rendered_episodes == len(make_plan(plan).episodes) > 1
    assert seen == [True]  # the index existed mid-run, before the last episode was done
    assert scan(Storage.from_uri(str(out))).current.keys() == {"T01_CN_A", "T01_CN_M"}


# ------------------------------------- issue 21.5: an index never shrinks a root ----


def test_index_built_before_an_extend_is_bypassed(tmp_path):
    """A producer with --extend rewrites a part with more frames beside one
    whose compaction had indexed the old part: the index records the parts it
    was built from (their sizes), so it is bypassed, and the root reports the
    new frames, never fewer."""
    storage = synthetic_root(str(tmp_path / "root"))
    compact(storage)
    spec = make_plan(PLAN).episodes[0]
    write_part(storage, spec.scenario, spec.episode, episode_table(longer(spec, spec.frames + 3)))
    frames = episode_frames(storage)
    assert frames[(spec.scenario, spec.episode)] == spec.frames + 3
    assert spec.scenario not in scan(storage).current
    assert len(read_manifest(storage)) == sum(expected_frames().values()) + 3
    assert compact(storage) == [spec.scenario]  # the fold brings it back in
    assert scan(storage).current.keys() == set(PLAN_SCENARIOS())
    assert episode_frames(storage)[(spec.scenario, spec.episode)] == spec.frames + 3


def test_index_written_late_by_a_slow_compaction_is_bypassed(tmp_path):
    """The race itself: a compaction read the old parts, another producer then
    extended one, and the compaction wrote its index last."""
    from manifests.reader import _fold, part_listing

    storage = synthetic_root(str(tmp_path / "root"))
    spec = make_plan(PLAN).episodes[0]
    stale = _fold(storage, spec.scenario, part_listing(storage)[spec.scenario], None)
    write_part(storage, spec.scenario, spec.episode, episode_table(longer(spec, spec.frames + 2)))
    storage.write_bytes(index_path(spec.scenario), stale)
    assert episode_frames(storage)[(spec.scenario, spec.episode)] == spec.frames + 2
    assert len(read_manifest(storage)) == sum(expected_frames().values()) + 2


# --------------------------------------------- issue 21.3: lease fencing ----


def test_part_commit_fails_after_the_lease_was_taken_over(tmp_path):
    """A producer stopped past its lease's expiry; a repair took the lease over
    and deleted the in-progress episode's frames; the producer wakes up and
    tries to commit: the commit fails, no part is written, and the producer's
    refresh does not bring its lease back."""
    from pipeline.episode_job import run_episode

    storage = Storage.from_uri(str(tmp_path / "root"))
    claim_root(storage)
    spec = make_plan(PlanConfig(domains="T01_CN_A", frames_per_scenario=3, width=64, height=36)).episodes[0]
    producer = register_producer(storage, ttl_s=0.5)
    producer._stop.set()  # "SIGSTOP": it refreshes no more
    producer._thread.join()
    took_over = []

    def on_frame(n: int) -> None:
        if n == 1:  # mid-episode, the producer is stopped; meanwhile:
            time.sleep(0.6)  # its lease expires
            with acquire_exclusive(storage, "repair"):
                assert live_producers(storage) == []  # the dead lease is taken over
                for path in (tmp_path / "root" / spec.scenario).rglob("*.png"):
                    path.unlink()  # repair deletes the in-progress frames as strays
            took_over.append(True)
            producer.refresh()  # it wakes up: its refresh thread runs first

    with pytest.raises(LeaseLost, match="lost the lease"):
        run_episode(spec, storage, world="test", on_frame=on_frame, fence=producer.fence)
    assert took_over == [True] and producer.lost
    assert not storage.exists(producer.rel)  # not revived
    assert done_episodes(storage) == set()
    assert read_generation(storage) == 1


def test_no_frame_file_is_written_once_the_lease_is_gone(tmp_path):
    """Issue 38: a worker on a hung node woke after its driver had finished and wrote 48
    frame files into the root. Frame files are fenced like parts: once the producer's
    lease is gone (the driver released it), a worker that was stopped for longer than
    FENCE_EVERY_S writes no further frame file, no stats and no part."""
    from pipeline.episode_job import FENCE_EVERY_S, run_episode

    storage = Storage.from_uri(str(tmp_path / "root"))
    claim_root(storage)
    spec = make_plan(PlanConfig(domains="T01_CN_A", frames_per_scenario=3, width=64, height=36)).episodes[0]
    producer = register_producer(storage, ttl_s=60)

    def on_frame(n: int) -> None:
        if n == 1:  # the worker is stopped; meanwhile its driver finishes and releases the lease
            producer.release()
            time.sleep(FENCE_EVERY_S + 0.1)

    with pytest.raises(LeaseLost, match="lost the lease"):
        run_episode(spec, storage, world="test", on_frame=on_frame, fence=producer.fence)
    written = sorted(p.name for p in (tmp_path / "root").rglob("*") if p.is_file())
    assert written and all(name.startswith("0000_000_") for name in written if name != ROOT_MARKER), written
    assert done_episodes(storage) == set() and not storage.list_files("_stats/")


def test_fence_holds_when_the_lease_is_revived_by_a_racing_refresh(tmp_path):
    """A refresh that read its lease just before the takeover and wrote it
    back just after: the generation was bumped, so the commit still fails."""
    from pipeline.episode_job import commit_part

    storage = Storage.from_uri(str(tmp_path / "root"))
    claim_root(storage)
    spec = make_plan(PlanConfig(domains="T01_CN_A", frames_per_scenario=3, width=64, height=36)).episodes[0]
    producer = register_producer(storage, ttl_s=0.3)
    producer._stop.set()
    producer._thread.join()
    body = storage.read_bytes(producer.rel)
    time.sleep(0.4)
    with acquire_exclusive(storage, "repair"):
        live_producers(storage)
    storage.write_bytes(producer.rel, body)  # the late write of the racing refresh
    with pytest.raises(LeaseLost, match="generation 0 -> 1"):
        commit_part(storage, spec, episode_table(spec).to_pylist(), producer.fence)
    assert done_episodes(storage) == set()


def test_produce_stops_and_says_so_when_its_lease_is_lost(ray_local, tmp_path):
    from roots.lease import bump_generation
    from pipeline.settings import ProduceConfig
    from pipeline.driver import produce
    from storage import StorageError

    plan = PlanConfig(domains="T01_CN_A", frames_per_scenario=4, width=64, height=36, seed=5)
    out = tmp_path / "root"
    bumped = []

    def progress(p) -> None:  # at the start of rendering: another operator takes the root over
        if not bumped:
            bump_generation(Storage.from_uri(str(out)))
            bumped.append(True)

    config = ProduceConfig(run=RunConfig(plan=plan, world="test"), out=str(out), workers=1)
    with pytest.raises(StorageError, match="lost the lease"):
        produce(config, progress=progress)
    assert done_episodes(Storage.from_uri(str(out))) == set()


# ------------------------------- issue 21.9b: a dead process's lease on this host ----


def _dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def _lease_of(pid: int, purpose: str) -> bytes:
    return json.dumps({"owner": f"gone-{pid}", "host": socket.gethostname(), "pid": pid,
                       "pidns": os.readlink("/proc/self/ns/pid"), "purpose": purpose,
                       "expires": time.time() + 3600, "generation": 0}).encode()


def test_lease_of_a_process_gone_from_this_host_is_taken_over_at_once(tmp_path, caplog):
    storage = Storage.from_uri(str(tmp_path / "root"))
    claim_root(storage)
    pid = _dead_pid()
    storage.write_bytes(EXCLUSIVE, _lease_of(pid, "compaction"))
    storage.write_bytes(f"{PRODUCER_PREFIX}gone-{pid}.json", _lease_of(pid, "produce"))
    caplog.set_level(logging.WARNING, logger="roots.lease")
    start = time.monotonic()
    with acquire_exclusive(storage, "repair", wait_s=0):
        assert live_producers(storage) == []
    assert time.monotonic() - start < 60  # at once, not after the 120 s TTL (no wait_s anyway)
    said = [r.getMessage() for r in caplog.records]
    assert any(f"its process {pid} on this host is gone" in m and "compaction" in m for m in said)
    assert any(f"its process {pid} on this host is gone" in m and "produce" in m for m in said)
    assert storage.list_files(PRODUCER_PREFIX) == []


def test_lease_of_a_live_process_is_not_taken_over(tmp_path):
    from roots.lease import LeaseError

    storage = Storage.from_uri(str(tmp_path / "root"))
    claim_root(storage)
    storage.write_bytes(EXCLUSIVE, _lease_of(os.getpid(), "compaction"))
    with pytest.raises(LeaseError, match="locked"):
        acquire_exclusive(storage, "repair", wait_s=0)


# ------------------------- issue 38: verify never changes the root; a rerun clears dead leases ----


def _killed_driver_lease(root) -> str:
    """Register a producer on ``root`` in a child process and SIGKILL it: its lease stays; returns its path."""
    import signal

    code = ("import sys, time\nfrom roots.lease import register_producer\nfrom storage import Storage\n"
            "lease = register_producer(Storage.from_uri(sys.argv[1]))\nprint(lease.rel, flush=True)\ntime.sleep(300)\n")
    env = {**os.environ, "PYTHONPATH": os.path.dirname(os.path.dirname(os.path.abspath(__file__)))}
    child = subprocess.Popen([sys.executable, "-c", code, str(root)], stdout=subprocess.PIPE, text=True, env=env)
    try:
        rel = child.stdout.readline().strip()
    finally:
        os.kill(child.pid, signal.SIGKILL)
        child.wait()
    assert rel.startswith(PRODUCER_PREFIX)
    return rel


def _every_file(root) -> dict[str, str]:
    import hashlib
    from pathlib import Path

    return {p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(Path(root).rglob("*")) if p.is_file()}


SMALL = PlanConfig(domains="T01_CN_A", frames_per_scenario=2, width=64, height=36, seed=7)


@pytest.fixture(scope="module")
def small_root(tmp_path_factory):
    """One episode of two frames rendered without Ray, indexed: copy it before changing it."""
    from tests.roots import render_root

    root = tmp_path_factory.mktemp("small") / "root"
    render_root(root, RunConfig(plan=SMALL, world="test"), compact=True)
    return root


def test_verify_leaves_a_dead_drivers_lease_and_a_rerun_removes_it(small_root, tmp_path):
    """Issue 38: `idda verify` deleted a SIGKILLed driver's lease and bumped
    generation.json. Verify only looks: every file of the root, leases and
    generation included, is byte for byte what it was. The rerun that takes
    the root over removes the dead lease, without a generation bump."""
    from typer.testing import CliRunner

    from pipeline.cli import app
    from pipeline.settings import ProduceConfig
    from pipeline.driver import produce

    root = tmp_path / "root"
    shutil.copytree(small_root, root)
    storage = Storage.from_uri(str(root))
    storage.write_bytes("_lease/generation.json", json.dumps({"generation": 4}).encode())
    dead = _killed_driver_lease(root)
    before = _every_file(root)
    assert dead in before and "_lease/generation.json" in before
    result = CliRunner().invoke(app, ["verify", str(root), "--no-ray"])
    assert result.exit_code == 0 and "OK: " in result.output, result.output
    assert _every_file(root) == before
    report = produce(ProduceConfig(run=RunConfig(plan=SMALL, world="test"), out=str(root)))  # all done: no Ray
    assert report.skipped_episodes == 1 and report.rendered_episodes == 0
    assert storage.list_files(PRODUCER_PREFIX) == []  # the dead lease is gone, and the rerun's own released
    assert read_generation(storage) == 4


def test_verify_lists_foreign_files_and_fails_on_them_only_with_strict(small_root, tmp_path):
    """Issue 38: a file whose name does not follow the layout was not reported.
    Verify lists such files (top level, inside a scenario's folder, under
    manifest/) without failing; --strict fails on them; the root's own names
    (the card's files included) and hidden names are not listed."""
    from typer.testing import CliRunner

    from pipeline.cli import app

    root = tmp_path / "root"
    shutil.copytree(small_root, root)
    foreign = ["T01_CN_A/e0000/rgb/thumbs.db", "T01_CN_A/notes.txt", "manifest/town=T01/readme.txt", "notes.txt",
               "scratch"]
    for rel in foreign[:-1]:
        (root / rel).write_text("not ours")
    (root / "scratch").mkdir()
    (root / "scratch" / "a.bin").write_bytes(b"x")
    for rel in ("README.md", "class_shares.png", "preview/T01_CN_A.png", ".DS_Store", "T01_CN_A/.DS_Store"):
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_bytes(b"x")
    before = _every_file(root)
    result = CliRunner().invoke(app, ["verify", str(root), "--no-ray"])
    assert result.exit_code == 0, result.output
    listed = [line.split(None, 1)[1] for line in result.output.splitlines() if line.startswith("foreign ")]
    assert listed == sorted(foreign)
    assert "OK: " in result.output and "5 foreign files" in result.output
    strict = CliRunner().invoke(app, ["verify", str(root), "--no-ray", "--strict"])
    assert strict.exit_code == 1 and "FAILED (--strict): " in strict.output, strict.output
    assert _every_file(root) == before


def test_a_root_that_holds_no_frame_says_so_when_the_size_differs(tmp_path):
    """Issue 38: a run that wrote only the marker and run.json (killed at once) made a
    later run of another size say the root "holds frames made with a different width"."""
    from pipeline.provenance import RunConfigError

    storage = Storage.from_uri(str(tmp_path / "root"))
    claim_root(storage)
    prepare_root(storage, RunConfig(plan=SMALL, world="test"))
    other = RunConfig(plan=replace(SMALL, width=96), world="test")
    with pytest.raises(RunConfigError, match="holds no frames, but its run.json records a run with another width"):
        prepare_root(storage, other)
    (tmp_path / "root" / "T01_CN_A").mkdir()  # a frame folder: frames may be there
    with pytest.raises(RunConfigError, match="holds frames made with a different width"):
        prepare_root(storage, other)


# ---------------------------------------- issue 21.12: racing root creation ----


def test_racing_drivers_create_one_root(tmp_path):
    """Eight threads create the same fresh root at once, a hundred times over (main failed about once in fifty)."""
    failures = []
    for attempt in range(100):
        uri = str(tmp_path / f"root{attempt}")
        barrier = threading.Barrier(8)

        def create() -> None:
            storage = Storage.from_uri(uri)
            barrier.wait()
            try:
                claim_root(storage)
                prepare_root(storage, RunConfig(plan=PLAN, world="test"))
            except Exception as exc:  # noqa: BLE001 - every failure is the finding
                failures.append(repr(exc))

        threads = [threading.Thread(target=create) for _ in range(8)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert (tmp_path / f"root{attempt}" / ROOT_MARKER).is_file()
    assert failures == []


# ------------------------------------------------------ S3 request counts ----


def test_s3_status_and_resume_scan_cost_o_scenarios_requests():
    """On S3 (a local server counting requests), a root whose indexes are
    current scans in a few requests per scenario, whatever its part count,
    with the right counts; without indexes, about one footer read per part
    (an old root's part names carry no row count: tests/test_part_names.py)."""
    from tests.s3_counter import counting_s3_server

    with counting_s3_server() as (server, counter):
        storage = synthetic_root(server.uri("root"), MANY)
        to_old_names(storage)
        parts = len(make_plan(MANY).episodes)
        counter.reset()
        assert episode_frames(storage) == expected_frames(MANY)
        unindexed = counter.total()
        compact(storage)
        counter.reset()
        assert episode_frames(storage) == expected_frames(MANY)
        indexed = counter.total()
        counter.reset()
        status = root_status(storage)
        status_requests = counter.total()
    assert status.frames_done == status.frames_total == sum(expected_frames(MANY).values())
    # listing: manifest/ one LIST per folder (manifest, town, weather, 2 viewpoints) and _index/ one;
    # footers: at most three requests per index
    listing, scenarios = 1 + 1 + 1 + 2 + 1, 2
    assert indexed <= listing + 3 * scenarios < parts
    assert status_requests <= indexed + 6  # plus run.json and _stats/driver.json (a stat and a read each)
    assert unindexed >= parts  # the footers themselves: this is what the indexes save


def test_s3_footers_cost_one_get_each_and_no_head():
    """Issue 22: a part's or an index's footer is read at the size its listing
    showed, so S3 sees one ranged GET per footer and no HEAD request (before:
    a HEAD and a GET each); a resume with nothing to render lists and reads
    the indexes once, not again for its fold."""
    import pipeline.driver as driver
    from tests.s3_counter import counting_s3_server

    with counting_s3_server() as (server, counter):
        storage = synthetic_root(server.uri("root"), MANY)
        to_old_names(storage)  # names without row counts: the footers are read
        parts = len(make_plan(MANY).episodes)
        listing = 1 + 1 + 1  # manifest/ (delimited), its one town's tree (flat, one page), _index/
        counter.reset()
        assert episode_frames(storage) == expected_frames(MANY)
        scanned = counter.counts()
        counter.reset()
        status = root_status(storage)
        status_requests = counter.total()
        compact(storage)
        counter.reset()
        assert part_summaries(storage)
        indexed = counter.counts()
        counter.reset()
        report = driver.produce(driver.ProduceConfig(run=RunConfig(plan=MANY, world="test"), out=storage.uri))
        resumed = counter.counts()
    assert status.frames_done == status.frames_total and report.skipped_episodes == parts
    assert scanned == {"GET": parts + listing}  # one GET per footer, every LIST page, no HEAD
    assert status_requests <= parts + listing + 6  # plus the root marker, run.json and _stats/driver.json
    assert indexed == {"GET": 2 + listing}  # the two indexes' footers
    # one scan (listing and index footers) for the check and the fold; the lease, run.json and the write probe
    assert resumed.get("GET", 0) <= 2 + listing + 4 and sum(resumed.values()) <= 2 + listing + 20, resumed
