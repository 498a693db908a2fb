"""The output root's integrity (issue 10): whatever the user or the machine
does, nothing is lost and nothing false is reported. Real Ray, real files."""

from __future__ import annotations

import glob
import io
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from manifests.reader import done_episodes, read_manifest
from manifests.schema import index_path
from roots.verify import verify
from pipeline.cli import app
from pipeline.driver import produce
from pipeline.settings import PlanConfig
from pipeline.provenance import RunConfigError
from storage import Storage, StorageError
from tests import faultkit
from tests.roots import part_of
from tests.test_produce import ARGS, DOMAINS, _descendants, config, ray_local, tree_digest  # noqa: F401 (fixtures)

pytestmark = pytest.mark.slow
runner = CliRunner()
REPO = Path(__file__).resolve().parents[1]


def one_line_error(result) -> str:
    """The single 'error: ...' line of a failed command (and no traceback)."""
    lines = result.output.strip().splitlines()
    assert result.exit_code == 2, result.output
    assert len(lines) == 1 and lines[0].startswith("error: "), result.output
    assert "Traceback" not in result.output
    return lines[0]


@pytest.fixture()
def copy(reference, tmp_path) -> Path:
    root = tmp_path / "root"
    shutil.copytree(reference, root)
    return root


# -- 2. verify and repair see a damaged manifest ----------------------------------
def test_truncated_part_is_found_and_repaired(ray_local, reference, copy):
    part = copy / part_of(copy, "T01_CN_A", 0)
    with open(part, "r+b") as f:
        f.truncate(200)
    result = runner.invoke(app, ["verify", str(copy)])
    assert result.exit_code == 1 and "bad-part" in result.output and part.relative_to(copy).as_posix() in result.output
    report = produce(config(copy, repair=True))
    assert report.rendered_episodes == 1 and verify(str(copy)).ok
    assert tree_digest(copy) == tree_digest(reference)


def test_flipped_index_is_found_repaired_and_never_breaks_query(ray_local, reference, copy):
    index = copy / index_path("T07_HRN_A")
    data = bytearray(index.read_bytes())
    data[len(data) // 2] ^= 0xFF
    index.write_bytes(bytes(data))
    result = runner.invoke(app, ["query", str(copy), "--domains", "T07_*_*"])
    assert result.exit_code == 0, result.output  # the damaged index is skipped, its parts read
    assert "8 frames selected" in result.output
    result = runner.invoke(app, ["verify", str(copy)])
    assert result.exit_code == 1 and "bad-index" in result.output and index_path("T07_HRN_A") in result.output
    report = produce(config(copy, repair=True))
    assert report.rendered_episodes == 0 and verify(str(copy)).ok
    assert tree_digest(copy) == tree_digest(reference)


def test_damaged_part_makes_query_name_the_file(copy):
    part = copy / part_of(copy, "T01_HRN_A", 0)
    (copy / index_path("T01_HRN_A")).unlink()  # readers must read the part itself
    import pyarrow.parquet as pq

    chunk = pq.ParquetFile(part).metadata.row_group(0).column(0)  # frame_id: every query reads it
    data = bytearray(part.read_bytes())
    data[chunk.data_page_offset + chunk.total_compressed_size // 2] ^= 0xFF
    part.write_bytes(bytes(data))
    line = one_line_error(runner.invoke(app, ["query", str(copy)]))
    assert part.relative_to(copy).as_posix() in line and "--repair" in line


# -- 3. --extend with more frames -------------------------------------------------------
def test_extend_with_more_frames_renders_the_short_episode(ray_local, reference, tmp_path):
    root = tmp_path / "extend"
    shutil.copytree(reference, root)
    more = PlanConfig(domains=DOMAINS, frames_per_scenario=6, width=64, height=36, seed=7)
    report = produce(config(root, plan=more, extend=True))
    assert report.skipped_episodes == 0 and report.rendered_episodes == 4 and report.rendered_frames == 24
    result = runner.invoke(app, ["status", str(root)])
    assert "24 of 24 frames done" in result.output, result.output
    assert len(read_manifest(str(root))) == 24 and verify(str(root)).ok
    clean = tmp_path / "clean"
    assert produce(config(clean, plan=more)).ok
    assert tree_digest(root) == tree_digest(clean)
    # The same seed gives the same first frames: the 4-frame run's files are a prefix.
    old = read_manifest(str(reference)).column("rgb_sha256").to_pylist()
    new = read_manifest(str(clean))
    assert set(old) <= set(new.column("rgb_sha256").to_pylist())
    before = tree_digest(root)
    for frames in (5, 3):  # one frame fewer too (issue 21.13e: a guard off by one never tried 6 -> 5)
        fewer = PlanConfig(domains=DOMAINS, frames_per_scenario=frames, width=64, height=36, seed=7)
        with pytest.raises(RunConfigError, match="never shrinks"):
            produce(config(root, plan=fewer, extend=True))
    assert tree_digest(root) == before


def test_status_counts_only_the_frames_a_part_holds(reference, tmp_path):
    root = tmp_path / "short"
    shutil.copytree(reference, root)
    record = json.loads((root / "run.json").read_text())
    from roots.run_file import record_bytes

    record["config"]["frames_per_scenario"] = 6  # as an --extend run that was killed at once leaves it
    (root / "run.json").write_bytes(record_bytes(record))
    result = runner.invoke(app, ["status", str(root)])
    assert result.exit_code == 0, result.output
    assert "16 of 24 frames done" in result.output and " done" not in result.output.splitlines()[1]


# -- 4. a lease for destructive operations ---------------------------------------------
def test_repair_refuses_beside_a_running_producer(ray_local, copy):
    from roots.lease import register_producer

    storage = Storage.from_uri(str(copy))
    producer = register_producer(storage)
    try:
        line = one_line_error(runner.invoke(app, ["produce", *ARGS, "--out", str(copy), "--repair"]))
        assert "being written by another producer" in line
    finally:
        producer.release()
    assert runner.invoke(app, ["produce", *ARGS, "--out", str(copy), "--repair"]).exit_code == 0


def test_repair_beside_a_real_producer_deletes_nothing(reference, tmp_path):
    """A producer in its own process; a repair started while it runs refuses,
    and the producer's run ends complete."""
    out = tmp_path / "busy"
    big = ["--domains", DOMAINS, "--frames-per-scenario", "12", "--width", "64", "--height", "36", "--seed", "7",
           "--world", "test", "--workers", "1"]
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    cmd = [sys.executable, "-m", "pipeline.cli", "produce", *big, "--out", str(out)]
    proc = subprocess.Popen(cmd, env=env, start_new_session=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.time() + 240
        while time.time() < deadline and proc.poll() is None and not list(out.glob("T01_CN_A/e*/rgb/*.png")):
            time.sleep(0.2)
        assert proc.poll() is None, proc.stderr.read()[-2000:]
        repair = subprocess.run([*cmd, "--repair"], env=env, capture_output=True, text=True, timeout=300)
        assert repair.returncode == 2 and "being written by another producer" in repair.stderr, repair.stderr[-2000:]
        assert "Traceback" not in repair.stderr
        stdout, stderr = proc.communicate(timeout=600)
        assert proc.returncode == 0, stderr[-2000:]
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert verify(str(out)).ok


def test_exclusive_lease_one_holder_local_and_s3(tmp_path):
    from roots.lease import LeaseError, acquire_exclusive

    from tests.s3_server import local_s3_server

    def contend(storage) -> list[str]:
        won, lost = [], []

        def take(i):
            try:
                won.append(acquire_exclusive(storage, f"repair-{i}"))
            except LeaseError as exc:
                lost.append(str(exc))

        threads = [threading.Thread(target=take, args=(i,)) for i in range(3)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert len(won) == 1 and len(lost) == 2 and all("is locked: repair-" in m for m in lost)
        won[0].release()
        acquire_exclusive(storage, "compaction").release()  # free again
        return lost

    contend(Storage.from_uri(str(tmp_path / "local")))
    with local_s3_server() as server:
        contend(Storage.from_uri(server.uri("leases")))
    # A lease whose holder died (expired) is taken over.
    storage = Storage.from_uri(str(tmp_path / "local"))
    acquire_exclusive(storage, "repair", ttl_s=0.01)._stop.set()
    time.sleep(0.05)
    acquire_exclusive(storage, "repair").release()


# -- 5. the root's contract ------------------------------------------------------------
def test_unrelated_non_empty_directory_is_refused_as_out(tmp_path):
    out = tmp_path / "photos"
    out.mkdir()
    (out / "holiday.jpg").write_bytes(b"\xff\xd8 not ours")
    line = one_line_error(runner.invoke(app, ["produce", *ARGS, "--out", str(out)]))
    assert "not an idda output root" in line
    assert sorted(p.name for p in out.iterdir()) == ["holiday.jpg"]


def test_card_keeps_a_users_readme(copy):
    from pipeline.cli.data import register

    register(app)
    (copy / "README.md").write_text("# my notes\n")
    line = one_line_error(runner.invoke(app, ["card", str(copy)]))
    assert "not written by `idda card`" in line and (copy / "README.md").read_text() == "# my notes\n"
    (copy / "README.md").unlink()
    assert runner.invoke(app, ["card", str(copy)]).exit_code == 0
    assert runner.invoke(app, ["card", str(copy)]).exit_code == 0  # our own card is replaced


def test_repair_removes_only_our_files(ray_local, reference, copy):
    foreign = [copy / "T01_CN_A" / "notes.txt", copy / "T01_CN_A" / "e0000" / "rgb" / "my_crop.png",
               copy / "T07_CN_A" / "x.bin", copy / "T07_CN_A" / "e0000" / "notes.txt",
               copy / "T01_CN_A" / "rgb" / "0009_000_T01_CN_A.png",  # ours by name in the flat layout, not this root's
               copy / "T01_CN_A" / "e0001" / "rgb" / "0002_000_T01_CN_A.png"]  # another episode's name in e0001
    for path in foreign:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text("user data")
    stray = copy / "T01_CN_A" / "e0000" / "rgb" / "0000_009_T01_CN_A.png"  # inside an episode's folder
    stray.write_bytes(b"ours by name")
    report = verify(str(copy))
    assert [p.path for p in report.problems] == ["T01_CN_A/e0000/rgb/0000_009_T01_CN_A.png"]
    assert produce(config(copy, repair=True)).ok
    assert all(p.read_text() == "user data" for p in foreign) and not stray.exists()


def test_lost_run_json_cannot_hide_another_resolution_or_seed(ray_local, copy):
    (copy / "run.json").unlink()
    args = [a for a in ARGS]
    other_size = args[:]
    other_size[other_size.index("--width") + 1] = "128"
    line = one_line_error(runner.invoke(app, ["produce", *other_size, "--out", str(copy)]))
    assert "holds frames at 64x36" in line
    other_seed = args[:]
    other_seed[other_seed.index("--seed") + 1] = "8"
    line = one_line_error(runner.invoke(app, ["produce", *other_seed, "--out", str(copy)]))
    assert "another run seed" in line
    assert not (copy / "run.json").exists()


# -- 6. one line, never a traceback or a hang -------------------------------------------
def test_absurd_frame_count_is_one_line():
    line = one_line_error(runner.invoke(app, ["plan", "-d", "T01_CN_A", "--frames-per-scenario", "10000000000"]))
    assert "at most 2,140,000" in line


@pytest.mark.parametrize("body", ["[]", '{"config": 3}', '{"config": {"width": "wide"}}', '{"config": {}}'])
def test_wrong_shaped_run_json_is_one_line(copy, body):
    (copy / "run.json").write_text(body)
    for command in (["status", str(copy)], ["produce", *ARGS, "--out", str(copy)]):
        line = one_line_error(runner.invoke(app, command))
        assert "run.json" in line


def test_directory_as_run_json_and_odd_driver_json(copy):
    (copy / "_stats" / "driver.json").write_text('["not", "a", "dict"]')
    assert runner.invoke(app, ["status", str(copy)]).exit_code == 0
    (copy / "run.json").unlink()
    (copy / "run.json").mkdir()
    for command in (["status", str(copy)], ["produce", *ARGS, "--out", str(copy)]):
        line = one_line_error(runner.invoke(app, command))
        assert "not a regular file" in line


def test_directory_and_fifo_in_place_of_frames(copy):
    table = read_manifest(str(copy))
    as_dir = copy / table.column("rgb_path")[0].as_py()
    as_fifo = copy / table.column("depth_raw_path")[1].as_py()
    as_dir.unlink()
    as_dir.mkdir()
    as_fifo.unlink()
    os.mkfifo(as_fifo)
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    result = subprocess.run([sys.executable, "-m", "pipeline.cli", "verify", str(copy)], env=env,
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 1, result.stderr
    assert "FAILED: 2 corrupt" in result.stdout and "not a regular file" in result.stdout
    assert "Traceback" not in result.stderr


def test_sigint_exits_130_and_says_how_to_resume(tmp_path):
    # Ctrl-C while the driver takes in its first finished episode (paused there: the run cannot end first)
    out = tmp_path / "interrupted"
    child = faultkit.start(["produce", *ARGS, "--out", str(out), "--workers", "1"], tmp_path / "flags",
                           pause_at="pipeline.driver:_collect:1")
    child.wait_paused()
    victims = _descendants(child.proc.pid)
    child.signal(signal.SIGINT)
    result = child.finish()
    assert result.returncode == 130, result.stderr[-2000:]
    assert "interrupted:" in result.stderr and "run the same command again to resume" in result.stderr
    assert "Traceback" not in result.stderr
    deadline = time.time() + 15
    while time.time() < deadline and any(_alive(p) for p in victims):
        time.sleep(0.5)
    assert not [p for p in victims if _alive(p)], "the local cluster outlived the interrupted driver"


def test_full_disk_fails_fast_in_one_line(tmp_path):
    out = tmp_path / "full"
    env = {**os.environ, "PYTHONPATH": str(REPO), "IDDA_FAULT_INJECT": "enospc-after:1"}
    cmd = [sys.executable, "-m", "pipeline.cli", "produce", *ARGS, "--out", str(out), "--workers", "1"]
    result = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert result.returncode == 2, result.stderr[-3000:]
    assert lines[-1].startswith("error: ") and "no space left on device" in lines[-1] and "retrying cannot help" in lines[-1]
    assert "Traceback" not in result.stderr and "RayTaskError" not in result.stderr
    assert done_episodes(Storage.from_uri(str(out))) == set()


def test_stats_and_card_on_a_read_only_root(copy, tmp_path, monkeypatch):
    from pipeline.cli.data import register

    register(app)
    before = tree_digest(copy)

    def read_only(self, rel, data, durable=True):
        raise StorageError(f"cannot write {rel}: read-only file system (EROFS)", cause="read-only file system (EROFS)", fatal=True)

    monkeypatch.setattr(Storage, "write_bytes", read_only)
    monkeypatch.chdir(tmp_path)  # stats writes its chart here, never into the root
    result = runner.invoke(app, ["stats", str(copy)])
    assert result.exit_code == 0 and "sky" in result.output and (tmp_path / "class_shares.png").is_file(), result.output
    line = one_line_error(runner.invoke(app, ["card", str(copy)]))
    assert "not writable" in line and "read-only" in line
    assert tree_digest(copy) == before


# -- 7. cleanup --------------------------------------------------------------------------
def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def test_local_cluster_dies_with_a_killed_driver(tmp_path):
    out = tmp_path / "orphaned"
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    cmd = [sys.executable, "-m", "pipeline.cli", "produce", *ARGS, "--out", str(out), "--workers", "1"]
    proc = subprocess.Popen(cmd, env=env, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    storage = Storage.from_uri(str(out))
    deadline = time.time() + 240
    while time.time() < deadline and proc.poll() is None and not done_episodes(storage):
        time.sleep(0.2)
    victims = _descendants(proc.pid)
    counts = glob.glob(os.path.join(tempfile.gettempdir(), f"idda-progress-{proc.pid}-*"))  # the tasks' progress counts
    assert proc.poll() is None and victims and counts
    os.kill(proc.pid, signal.SIGKILL)  # the driver alone: its cluster must follow
    proc.wait()
    deadline = time.time() + 15
    while time.time() < deadline and (any(_alive(p) for p in victims) or any(map(os.path.exists, counts))):
        time.sleep(0.5)
    left = [p for p in victims if _alive(p)]
    for pid in left:  # do not leave them behind for the next test
        os.kill(pid, signal.SIGKILL)
    assert not left, f"{len(left)} Ray processes outlived the driver by 15 s"
    assert not any(map(os.path.exists, counts)), "the driver's progress folder outlived it"


def test_ray_is_shut_down_after_a_failed_run(tmp_path, monkeypatch):
    import ray

    if ray.is_initialized():
        ray.shutdown()
    monkeypatch.setenv("IDDA_FAULT_INJECT", "enospc-after:0")
    with pytest.raises(StorageError, match="no space left"):
        produce(config(tmp_path / "failed"))
    assert not ray.is_initialized()


# -- 21.13c/d: verify's own checks, each one alone --------------------------------------
def _first_part(root: Path) -> Path:
    return root / part_of(root, "T01_CN_A", 0)


def _only_that_part_is_bad(report) -> str:
    """The one bad part's detail; its frames are then extra (no good part lists them), nothing else is wrong."""
    bad = [p for p in report.problems if p.kind != "extra"]
    assert [(p.kind, p.path.rpartition("/")[2].partition("_n")[0]) for p in bad] == [("bad-part", "T01_CN_A_e0000")], report.problems
    assert all(p.path.startswith("T01_CN_A/") for p in report.problems if p.kind == "extra")
    return bad[0].detail


def test_verify_finds_a_rewritten_footer_statistic(copy):
    """Issue 21.13c: with the re-encode comparison off, a part whose footer
    statistic was rewritten (rows and page checksums intact) passed verify."""
    import pyarrow.parquet as pq

    part = _first_part(copy)
    data = part.read_bytes()
    seed = pq.read_table(part).column("seed")[0].as_py()
    footer_len = int.from_bytes(data[-8:-4], "little")
    start = len(data) - 8 - footer_len
    old = seed.to_bytes(8, "little", signed=True)
    at = data.index(old, start)  # the first of the seed column's min/max statistics
    forged = data[:at] + (seed + 1).to_bytes(8, "little", signed=True) + data[at + 8:]
    part.write_bytes(forged)
    assert pq.read_table(part).equals(pq.read_table(io.BytesIO(data)))  # the rows read back the same
    assert "re-encoded" in _only_that_part_is_bad(verify(str(copy)))
    result = runner.invoke(app, ["verify", str(copy)])
    assert result.exit_code == 1 and "bad-part" in result.output


def test_verify_finds_a_part_from_a_run_with_another_seed(copy):
    """Issue 21.13d: with the episode-seed check off, a part copied from a
    --seed 8 run (well-formed, same files) passed verify."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from domains.catalog import SCENARIO_BY_CODE
    from roots.episode_spec import episode_seed
    from manifests.writer import part_bytes

    part = _first_part(copy)
    table = pq.read_table(part)
    other = episode_seed(8, SCENARIO_BY_CODE["T01_CN_A"], 0)
    column = table.schema.get_field_index("seed")
    table = table.set_column(column, table.field("seed"), pa.array([other] * len(table), type=table.field("seed").type))
    part.write_bytes(part_bytes(table))  # as that run's writer would have written it
    assert "episode seed" in _only_that_part_is_bad(verify(str(copy)))


def test_verify_accepts_a_part_written_as_before_and_still_finds_a_forged_one(copy):
    """Parts are now written without the stored Arrow schema; a part written
    before (with it, by this same pyarrow) is intact, and one forged in that
    encoding is still found by the re-encode comparison."""
    import pyarrow.parquet as pq

    from manifests.writer import part_bytes

    from manifests.schema import RULE_PART_SCHEMA, as_plain_lists

    part = _first_part(copy)
    table = pq.read_table(part).cast(RULE_PART_SCHEMA)  # list columns by the schema's own field names, as a writer has them (a front root's part: no rig columns)
    assert part.read_bytes() == part_bytes(table)  # as this writer writes now
    legacy = part_bytes(as_plain_lists(table), store_schema=True)  # K and the poses were plain lists then
    assert legacy != part.read_bytes() and b"ARROW:schema" in legacy
    part.write_bytes(legacy)
    assert verify(str(copy)).ok
    seed = table.column("seed")[0].as_py()
    at = legacy.index(seed.to_bytes(8, "little", signed=True), len(legacy) - 8 - int.from_bytes(legacy[-8:-4], "little"))
    part.write_bytes(legacy[:at] + (seed + 1).to_bytes(8, "little", signed=True) + legacy[at + 8:])
    assert "re-encoded" in _only_that_part_is_bad(verify(str(copy)))
