"""Production on real Ray with real files: end to end, resume after a killed
driver, a killed worker, a removed node, verify/repair, bad roots, S3."""

from __future__ import annotations

import hashlib
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from outputs.table import DEFAULT_OUTPUTS as OUTPUTS
from manifests.reader import done_episodes, read_manifest
from manifests.schema import output_columns
from roots.verify import verify
from pipeline.cli import app
from pipeline.settings import ProduceConfig
from pipeline.driver import produce
from pipeline.planner import make_plan
from pipeline.settings import PlanConfig, RunConfig
from pipeline.provenance import RunConfigError
from storage import Storage, StorageError
from tests.faultkit import descendants as _descendants  # every process below a pid (Ray starts its own sessions)

pytestmark = pytest.mark.slow
runner = CliRunner()

# Small but real: 4 scenarios, one 4-frame episode each, at 64x36 in the test world.
DOMAINS = "towns=T01,T07 weathers=CN,HRN viewpoints=A"
PLAN = PlanConfig(domains=DOMAINS, frames_per_scenario=4, width=64, height=36, seed=7)
ARGS = ["--domains", DOMAINS, "--frames-per-scenario", "4", "--width", "64", "--height", "36", "--seed", "7", "--world", "test"]


def config(out, **kw) -> ProduceConfig:
    return ProduceConfig(run=RunConfig(plan=kw.pop("plan", PLAN), world="test"), out=str(out), workers=2, **kw)


def tree_digest(root: Path) -> dict[str, str]:
    """sha256 of every dataset file (frames and manifest parts) under root;
    leases (a killed driver leaves its own until it expires) are not data."""
    out = {}
    for path in sorted(root.rglob("*")):
        rel = path.relative_to(root).as_posix()
        if path.is_file() and not rel.startswith(("_stats/", "_lease/")) and rel != "run.json":
            out[rel] = hashlib.sha256(path.read_bytes()).hexdigest()
    return out


@pytest.fixture(scope="module")
def ray_local():
    import ray

    ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()


@pytest.fixture(scope="module")
def reference(ray_local, reference, tmp_path_factory) -> Path:
    """An uninterrupted run on Ray: what every other run must equal, byte for byte,
    and the same bytes as the session's plain render (conftest's ``reference``)."""
    out = tmp_path_factory.mktemp("produced")
    report = produce(config(out))
    assert report.ok and report.rendered_episodes == len(make_plan(PLAN).episodes)
    assert tree_digest(out) == tree_digest(reference)
    return out


def test_end_to_end_read_back(reference):
    plan = make_plan(PLAN)
    table = read_manifest(str(reference))
    assert len(table) == plan.total_frames == 16
    assert sorted(set(table.column("scenario").to_pylist())) == sorted(plan.scenarios())
    for output in OUTPUTS:
        path_col, bytes_col, sha_col = output_columns(output)
        for rel, size, sha in zip(*(table.column(c).to_pylist() for c in (path_col, bytes_col, sha_col))):
            data = (reference / rel).read_bytes()
            assert len(data) == size and hashlib.sha256(data).hexdigest() == sha
            scenario, episode = rel.split("/")[0], int(rel.split("/")[-1][:4])
            assert rel.startswith(f"{scenario}/e{episode:04d}/{output}/")  # a new root: one folder per episode
    row = table.to_pylist()[0]
    assert 20 <= row["n_vehicles"] <= 150 and 0 <= row["n_pedestrians"] <= 100
    assert sum(row[c] for c in table.column_names if c.startswith("px_")) == 64 * 36
    assert verify(str(reference)).ok


def test_rerun_skips_everything(ray_local, reference, tmp_path):
    copy = tmp_path / "copy"
    shutil.copytree(reference, copy)
    before = tree_digest(copy)
    report = produce(config(copy))
    assert report.rendered_episodes == 0 and report.skipped_episodes == report.planned_episodes
    assert tree_digest(copy) == before
    result = runner.invoke(app, ["produce", *ARGS, "--out", str(copy)])
    assert result.exit_code == 0 and "nothing to render; all 4 planned episodes are done" in result.output


def test_cli_status_verify_query_stats(reference, tmp_path):
    result = runner.invoke(app, ["status", str(reference)])
    assert result.exit_code == 0, result.output
    assert "16 of 16 frames done (100.0%)" in result.output
    result = runner.invoke(app, ["verify", str(reference)])
    # the last line (progress lines come first when verify runs past PROGRESS_EVERY, as under load)
    assert result.exit_code == 0 and result.output.splitlines()[-1].startswith("OK: checked 128 files"), result.output
    out = tmp_path / "worst.txt"
    result = runner.invoke(app, ["query", str(reference), "--preset", "worst-case", "--out", str(out)])
    assert result.exit_code == 2, result.output  # HRN_J / HRN_B were not produced: an empty selection
    assert "(total) has 40128 frame(s) fewer" in result.output and "error: no frames" in result.output
    assert not out.exists()
    result = runner.invoke(app, ["query", str(reference), "--domains", "towns=T07", "--per-scenario", "3", "--out", str(out)])
    assert result.exit_code == 0, result.output
    lines = out.read_text().splitlines()
    assert len(lines) == 6 and all((reference / p).exists() for line in lines for p in line.split())
    chart = tmp_path / "shares.png"
    result = runner.invoke(app, ["stats", str(reference), "--chart", str(chart)])
    assert result.exit_code == 0, result.output
    assert "sky" in result.output and chart.read_bytes()[:4] == b"\x89PNG"


def test_killed_driver_resumes_to_identical_output(reference, tmp_path):
    import re

    out = tmp_path / "killed"
    cmd = [sys.executable, "-m", "pipeline.cli", "produce", *ARGS, "--out", str(out), "--workers", "1"]
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    proc = subprocess.Popen(cmd, env=env, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.time() + 240
    storage = Storage.from_uri(str(out))
    while time.time() < deadline and proc.poll() is None:
        if (out / "run.json").exists() and len(done_episodes(storage)) >= 1:
            break
        time.sleep(0.2)
    assert proc.poll() is None, f"driver ended before it could be killed: {proc.stderr.read().decode()[-2000:]}"
    # Kill everything at once: the driver and its whole local Ray cluster, so
    # the worker busy with the next episode dies mid-write too.
    victims = [proc.pid, *_descendants(proc.pid)]
    for pid in victims:
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    proc.wait()
    time.sleep(1.0)
    done_before = len(done_episodes(storage))
    assert 1 <= done_before < len(make_plan(PLAN).episodes)
    # Run again (a fresh driver and a fresh local Ray), to the end.
    result = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]
    skipped = re.search(r"(\d+) of 4 episodes were already done", result.stdout)
    assert skipped and int(skipped.group(1)) == done_before, result.stdout
    assert tree_digest(out) == tree_digest(reference)
    assert read_manifest(str(out)).equals(read_manifest(str(reference)))


def test_killed_worker_is_retried_without_duplicates(ray_local, reference, tmp_path, monkeypatch):
    marker = tmp_path / "killed-once"
    monkeypatch.setenv("IDDA_FAULT_INJECT", f"kill-after:1:{marker}")
    out = tmp_path / "worker-killed"
    report = produce(config(out))
    assert marker.exists(), "the fault hook never fired"
    assert report.ok and report.rendered_episodes == 4
    table = read_manifest(str(out))
    ids = list(zip(table.column("scenario").to_pylist(), table.column("frame_id").to_pylist()))
    assert len(ids) == len(set(ids)) == 16
    assert tree_digest(out) == tree_digest(reference)


def test_two_drivers_on_one_root_do_not_corrupt_it(ray_local, reference, tmp_path):
    out = tmp_path / "shared"
    reports, errors = [], []

    def drive():
        try:
            reports.append(produce(config(out)))
        except Exception as exc:  # surfaced below
            errors.append(exc)

    threads = [threading.Thread(target=drive) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors and all(r.ok for r in reports)
    assert verify(str(out)).ok
    assert tree_digest(out) == tree_digest(reference)


def test_verify_finds_and_repair_fixes(ray_local, reference, tmp_path):
    root = tmp_path / "damaged"
    shutil.copytree(reference, root)
    table = read_manifest(str(root))
    corrupt = root / table.column("rgb_path")[0].as_py()
    missing = root / table.column("depth_raw_path")[len(table) - 1].as_py()
    corrupt.write_bytes(corrupt.read_bytes()[:-10] + b"0123456789")
    missing.unlink()
    result = runner.invoke(app, ["verify", str(root)])
    assert result.exit_code == 1
    assert "corrupt" in result.output and "missing" in result.output and "FAILED: 1 corrupt, 1 missing" in result.output
    report = produce(config(root, repair=True))
    assert len(report.repaired) == 2 and report.rendered_episodes == 2
    assert verify(str(root)).ok
    assert tree_digest(root) == tree_digest(reference)


def test_changed_config_is_refused_unless_extended(ray_local, reference, tmp_path):
    root = tmp_path / "extend"
    shutil.copytree(reference, root)
    bigger = PlanConfig(domains=DOMAINS + "", frames_per_scenario=4, width=64, height=36, seed=7)
    more = PlanConfig(domains="towns=T01,T07 weathers=CN,HRN viewpoints=A,B", frames_per_scenario=4, width=64, height=36, seed=7)
    assert produce(config(root, plan=bigger)).rendered_episodes == 0
    with pytest.raises(RunConfigError, match="pass --extend"):
        produce(config(root, plan=more))
    with pytest.raises(RunConfigError, match="different seed"):
        produce(config(root, plan=PlanConfig(domains=DOMAINS, frames_per_scenario=4, width=64, height=36, seed=8), extend=True))
    report = produce(config(root, plan=more, extend=True))
    assert report.rendered_episodes == 4 and report.skipped_episodes == 4
    assert verify(str(root)).ok


def test_resume_refuses_to_mix_encoders(ray_local, reference, tmp_path):
    from outputs.encoding import encoder_identity
    from roots.run_file import read_record, record_bytes
    from manifests.schema import RUN_FILE
    from tests.roots import part_of

    root = tmp_path / "encoders"
    shutil.copytree(reference, root)
    storage = Storage.from_uri(str(root))
    record = read_record(storage)
    assert record["encoder"] == encoder_identity()
    scenario, episode = sorted(done_episodes(storage))[0]
    storage.delete(part_of(storage, scenario, episode))  # one episode to resume
    storage.write_bytes(RUN_FILE, record_bytes({**record, "encoder": "png-other level 9, zlib 1.0"}))
    with pytest.raises(RunConfigError, match="another encoder.*png-other"):
        produce(config(root))
    assert (scenario, episode) not in done_episodes(storage)  # nothing was rendered


def test_unwritable_root_is_a_clear_error(tmp_path):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a directory")
    result = runner.invoke(app, ["produce", *ARGS, "--out", str(blocker / "out")])
    assert result.exit_code == 2
    assert result.output.startswith("error: ") and "not writable" in result.output
    assert len(result.output.strip().splitlines()) == 1


def test_full_disk_marks_nothing_done(tmp_path, monkeypatch):
    """A write failing mid-episode leaves the episode without a part."""
    from pipeline.episode_job import run_episode

    storage = Storage.from_uri(str(tmp_path / "full"))
    real = Storage.write_bytes
    calls = {"n": 0}

    def failing(self, rel, data, durable=True):
        calls["n"] += 1
        if calls["n"] > 7:  # the second frame's first image
            raise StorageError(f"cannot write {rel}: no space left on device (ENOSPC)")
        return real(self, rel, data)

    monkeypatch.setattr(Storage, "write_bytes", failing)
    spec = make_plan(PLAN).episodes[0]
    with pytest.raises(StorageError, match="no space left"):
        run_episode(spec, storage, world="test")
    assert done_episodes(storage) == set()


def test_s3_end_to_end(reference, tmp_path):
    import ray

    from tests.s3_server import local_s3_server

    if ray.is_initialized():
        ray.shutdown()
    with local_s3_server() as server:
        uri = server.uri("runs/small")
        report = produce(config(uri))
        assert report.ok and report.rendered_episodes == 4
        storage = Storage.from_uri(uri)
        table = read_manifest(storage)
        assert table.equals(read_manifest(str(reference)))
        assert verify(storage).ok
        ref = tree_digest(reference)
        for rel, digest in ref.items():
            if not rel.startswith("manifest/"):
                assert storage.sha256(rel) == digest
        result = runner.invoke(app, ["status", uri])
        assert result.exit_code == 0 and "16 of 16 frames done" in result.output
        assert "secret" not in result.output


def test_local_cluster_workers_run_at_the_drivers_priority(monkeypatch):
    """Ray starts workers at nice 15 (for shared machines); on the private cluster
    of a run they render at the driver's priority, as a plain loop would, and the
    daemons such a run has no use for (the API server, the monitors that only poll)
    never start, nor do task events (for a dashboard it has not; the driver flushed them at
    shutdown); Ray's own classes are as they were afterwards."""
    import ray
    import ray._private.node
    import ray._private.parameter

    from pipeline.driver import start_local_cluster

    if ray.is_initialized():
        ray.shutdown()
    monkeypatch.delenv("RAY_worker_niceness", raising=False)
    monkeypatch.delenv("RAY_task_events_report_interval_ms", raising=False)

    def niceness() -> tuple[int, str | None]:
        return os.nice(0), os.environ.get("RAY_task_events_report_interval_ms")

    api_server, params_init = ray._private.node.Node.start_api_server, ray._private.parameter.RayParams.__init__
    start_local_cluster(ray, 1)
    try:
        worker = ray.get(ray.remote(num_cpus=1)(niceness).remote())
        started = set(ray._private.worker._global_node.all_processes)
    finally:
        ray.shutdown()
    assert worker == (os.nice(0), "0")
    assert started == {"raylet", "gcs_server"}
    assert ray._private.node.Node.start_api_server is api_server
    assert ray._private.parameter.RayParams.__init__ is params_init


@pytest.mark.parametrize("runtime_envs", [True, False])
def test_local_cluster_runs_stand_ins_for_the_agents_it_has_no_use_for(monkeypatch, runtime_envs):
    """The private cluster's raylet starts a stand-in for its dashboard agent (no dashboard reads
    it; the real one imported for ~1 CPU-s while the raylet waited for its ports), and for its
    runtime-env agent too where no task will carry a runtime_env (``produce``'s own cluster): the
    agents' ports are written as a minimal agent writes them, tasks run, and the stand-ins end with
    their raylet; Ray's functions are as they were afterwards."""
    import psutil
    import ray
    import ray._private.services as services
    import ray._private.utils as utils
    from ray._raylet import RUNTIME_ENV_AGENT_PORT_NAME, get_port_filename

    from pipeline import cluster

    if ray.is_initialized():
        ray.shutdown()
    monkeypatch.delenv("RAY_enable_pipe_based_agent_to_parent_health_check", raising=False)
    before = (services.start_ray_process, services.get_node, utils.get_dashboard_dependency_error)
    cluster.start_local_cluster(ray, 1, runtime_envs=runtime_envs)
    try:
        node = ray._private.worker._global_node
        raylet = psutil.Process(node.all_processes["raylet"][0].process.pid)
        children = raylet.children()
        commands = [" ".join(child.cmdline()) for child in children]
        stand_ins = [child for child, command in zip(children, commands) if cluster.AGENT_STAND_IN in command]

        def port(name):
            return (Path(node.get_session_dir_path()) / get_port_filename(node.node_id, name)).read_text()

        agent_ports = [port(getattr(ray._raylet, name)) for name in cluster._AGENTS["--dashboard_agent_command="]]
        runtime_env_port = port(RUNTIME_ENV_AGENT_PORT_NAME)
        answer = ray.get(ray.remote(num_cpus=1)(lambda: os.getpid()).remote())
    finally:
        ray.shutdown()
    assert len(stand_ins) == (1 if runtime_envs else 2)
    assert not any("dashboard/agent.py" in command for command in commands)
    assert agent_ports == ["-1"] * 3 and answer != os.getpid()
    assert (runtime_env_port == "-1") is not runtime_envs  # Ray's own agent writes the port it serves
    _, alive = psutil.wait_procs(stand_ins, timeout=30)
    assert alive == []  # they read their raylet's end of the pipe and ended
    assert (services.start_ray_process, services.get_node, utils.get_dashboard_dependency_error) == before


def test_the_stand_in_replaces_only_the_agents_it_is_given(tmp_path):
    """The raylet's other arguments, an agent not given, and an agent command without the session dir
    and node id it needs (another Ray's), are left as they are; the stand-in's ports are Ray's own files."""
    import subprocess
    import sys

    import ray._raylet
    from ray._raylet import get_port_filename, persist_port

    from pipeline import cluster

    flag = "--dashboard_agent_command="
    agents = {flag: [getattr(ray._raylet, name) for name in cluster._AGENTS[flag]]}
    node_id = "ab" * 28
    agent = subprocess.list2cmdline(["python", "agent.py", f"--node-id={node_id}", f"--session-dir={tmp_path}",
                                     "--grpc-port=0", "--head"])
    stand_in = cluster._stand_in_argument(flag + agent, persist_port, agents)
    assert stand_in == flag + subprocess.list2cmdline([sys.executable, "-I", "-S", "-c", cluster.AGENT_STAND_IN])
    assert [(tmp_path / get_port_filename(node_id, port)).read_text() for port in agents[flag]] == ["-1"] * 3
    assert cluster._stand_in_argument("--node_manager_port=0", persist_port, agents) == "--node_manager_port=0"
    runtime_env = "--runtime_env_agent_command=" + agent
    assert cluster._stand_in_argument(runtime_env, persist_port, agents) == runtime_env
    other = flag + subprocess.list2cmdline(["python", "agent.py", "--grpc-port=0"])
    assert cluster._stand_in_argument(other, persist_port, agents) == other


def test_produce_starts_its_own_cluster_without_runtime_envs(monkeypatch, tmp_path):
    """``produce``'s own cluster stands in for the runtime-env agent, which is only safe because its
    tasks never carry a runtime_env: even with variables to forward they inherit the driver's
    environment, and a cluster it attaches to (or one already up) gets them as a runtime_env."""
    import ray

    from pipeline import driver

    asked = []
    monkeypatch.setattr(driver, "attach", lambda ray_, address, workers, runtime_envs=True: asked.append(runtime_envs))
    monkeypatch.setattr(ray, "is_initialized", lambda: False)
    driver._connect(ray, ProduceConfig(run=RunConfig(plan=PlanConfig(domains="T01_CN_A")), out=str(tmp_path)))
    assert asked == [False]
    monkeypatch.setenv("IDDA_WORLD_CACHE", str(tmp_path))
    config = ProduceConfig(run=RunConfig(plan=PlanConfig(domains="T01_CN_A")), out=str(tmp_path))
    assert "runtime_env" not in driver._task_options(config, 1, local=True, own_cluster=True)[0]
    forwarded = driver._task_options(config, 1, local=True, own_cluster=False)[0]["runtime_env"]["env_vars"]
    assert forwarded["IDDA_WORLD_CACHE"] == str(tmp_path)


def test_without_the_pipe_health_check_the_dashboard_agent_starts_as_ray_starts_it(monkeypatch):
    """The stand-in ends only through the pipe its raylet holds; where the user turned that check
    off, the raylet's agent is Ray's own."""
    import ray
    import ray._private.services as services

    from pipeline import cluster

    start = services.start_ray_process
    for value, replaced in (("false", False), ("0", False), ("true", True), ("1", True)):
        monkeypatch.setenv("RAY_enable_pipe_based_agent_to_parent_health_check", value)
        with cluster._lean_head(ray):
            assert (services.start_ray_process is not start) is replaced, value
        assert services.start_ray_process is start


def test_the_node_wait_reads_the_node_table_until_this_raylet_is_alive_in_it(monkeypatch):
    """``ray.init``'s wait for its new raylet: Ray's accessor slept a whole second after its first
    look; the node table is read again until this node is there and alive, then Ray's call
    (which finds it at once) answers; past Ray's own deadline, Ray's call says what is wrong."""
    from pipeline import cluster

    calls = []

    def state_class(tables):
        class State:
            def _initialize_global_state(self, options):
                calls.append(("options", options))

            def node_table(self):
                calls.append("table")
                table = tables.pop(0) if len(tables) > 1 else tables[0]
                if isinstance(table, Exception):
                    raise table
                return table

            def disconnect(self):
                calls.append("disconnect")

        return State

    def options(address):
        return f"options of {address}"

    monkeypatch.setattr(cluster, "_NODE_POLL_S", 0.001)
    tables = [[], RuntimeError("the GCS is still starting"), [{"NodeID": "other", "Alive": True}],
              [{"NodeID": "n1", "Alive": False}],
              [{"NodeID": "other", "Alive": True}, {"NodeID": "n1", "Alive": True}]]
    get = cluster._registered_node(state_class(tables), options, lambda address, node: ("record", address, node))
    assert get("gcs:1", "n1") == ("record", "gcs:1", "n1")
    assert calls == [("options", "options of gcs:1"), "table", "table", "table", "table", "table", "disconnect"]

    calls.clear()
    monkeypatch.setattr(cluster, "_NODE_WAIT_S", 0.05)

    def not_found(address, node):
        raise RuntimeError(f"GCS cannot find the node with node ID {node}")

    get = cluster._registered_node(state_class([[]]), options, not_found)
    with pytest.raises(RuntimeError, match="cannot find the node with node ID n1"):
        get("gcs:1", "n1")
    assert calls[0] == ("options", "options of gcs:1") and calls[-1] == "disconnect" and calls.count("table") > 1


def test_workers_that_fill_the_cores_run_opencv_on_one_thread(monkeypatch, tmp_path):
    """When the workers alone fill the machine's cores, each runs OpenCV on its own thread (its pool's
    helpers only competed with the other workers); fewer workers, a cluster, or a user's
    OPENCV_FOR_THREADS_NUM leave it as it is. The worker applies what the task is given."""
    import cv2
    import ray

    from pipeline.driver import CV_THREADS_WHEN_FULL, _task_options, start_local_cluster
    from pipeline.ray_task import episode_task
    from pipeline.settings import PlanConfig, ProduceConfig, RunConfig

    monkeypatch.delenv("OPENCV_FOR_THREADS_NUM", raising=False)
    config = ProduceConfig(run=RunConfig(PlanConfig(domains="T01_CN_A", frames_per_scenario=1, width=64, height=36), world="test"),
                           out=str(tmp_path / "out"))
    cores = os.cpu_count() or 1
    assert _task_options(config, cores, local=True, own_cluster=True)[2] == CV_THREADS_WHEN_FULL == 1
    assert _task_options(config, cores, local=False, own_cluster=False)[2] is None
    if cores > 1:
        assert _task_options(config, cores - 1, local=True, own_cluster=True)[2] is None
    monkeypatch.setenv("OPENCV_FOR_THREADS_NUM", "3")
    assert _task_options(config, cores, local=True, own_cluster=True)[2] is None

    monkeypatch.delenv("OPENCV_FOR_THREADS_NUM")
    if ray.is_initialized():
        ray.shutdown()

    def noting_threads(spec, storage, **kwargs):  # a stand-in episode that notes its worker's OpenCV threads
        from benchmarks.bench_control import standin_episode

        storage.write_bytes(f"cv_threads_{spec.scenario}", str(cv2.getNumThreads()).encode())
        return standin_episode(spec, storage, **kwargs)

    report = produce(config, episode_fn=noting_threads)  # its own local cluster, every core a worker
    assert report.ok and (tmp_path / "out" / "cv_threads_T01_CN_A").read_text() == "1"
    start_local_cluster(ray, 1)
    try:  # a worker given none keeps OpenCV's default, a thread per core
        task = ray.remote(num_cpus=1)(episode_task)
        given = ray.get(task.remote(None, None, "test", episode_fn=lambda spec, storage, **_: cv2.getNumThreads()))
    finally:
        ray.shutdown()
    assert given > 1 or cores == 1


@pytest.mark.parametrize("held, pending", [(6, None), (5, False), (4, True)])
def test_shrink_guard_refuses_even_one_frame_fewer(held, pending):
    """Issue 21.13e: a guard off by one never tried 6 -> 5 frames. A part holding
    one frame more than the plan asks for is refused; as many is done; fewer is redone."""
    from pipeline.driver import pending_episodes

    plan = make_plan(PlanConfig(domains="T01_CN_A", frames_per_scenario=5, width=64, height=36, seed=7))
    (spec,) = plan.episodes
    assert spec.frames == 5
    frames = {(spec.scenario, spec.episode): held}
    if pending is None:
        with pytest.raises(RunConfigError, match="holds 6 frames, the plan asks for 5; a root never shrinks"):
            pending_episodes(plan, frames)
    else:
        assert pending_episodes(plan, frames) == ([spec] if pending else [])


def test_a_resume_checking_its_footers_beside_its_first_episodes_gives_the_same_bytes(ray_local, reference, tmp_path,
                                                                                    monkeypatch):
    """Issue 35 item 5: a root without indexes, two episodes' parts and frames removed, resumed with
    its footer checks beside the first episodes (driver.LATE_CHECK_PARTS lowered to 1): the same
    files as a run in one go, its indexes included, and verify passes."""
    import pipeline.driver as driver
    from manifests.reader import part_files

    out = tmp_path / "late"
    shutil.copytree(reference, out)
    shutil.rmtree(out / "_index")
    for scenario in ("T01_CN_A", "T07_HRN_A"):
        (out / part_files(Storage.from_uri(str(out)))[scenario][0]).unlink()
        shutil.rmtree(out / scenario)
    late = []
    real = driver._late_checks
    monkeypatch.setattr(driver, "_late_checks", lambda *a, **k: late.append(real(*a, **k)) or late[-1])
    monkeypatch.setattr(driver, "LATE_CHECK_PARTS", 1)
    report = produce(config(out))
    assert late and late[0] is not None and [s.key for s in late[0].first] == ["T01_CN_A/e0000", "T07_HRN_A/e0000"]
    assert report.ok and report.rendered_episodes == 2 and report.skipped_episodes == 2
    assert tree_digest(out) == tree_digest(reference)
    assert verify(str(out)).ok


def test_a_local_cluster_that_does_not_start_is_one_line_and_exit_2(tmp_path, monkeypatch):
    """On a busy machine Ray's raylet may not register within Ray's fixed 30 s; ray.init then raises a bare
    Exception, which reached the user as a traceback. Now it is one line, exit 2, with no frame written
    and the lease released.
    (Ray's own failure is stood in for: a raylet that really times out costs 30 s.)"""
    import ray

    if ray.is_initialized():
        ray.shutdown()

    def slow_raylet(*args, **kwargs):
        raise Exception("The current node timed out during startup. This could happen because some of the "
                        "raylet failed to startup or the GCS has become overloaded.")

    monkeypatch.setattr(ray, "init", slow_raylet)
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    result = CliRunner().invoke(app, ["produce", "--domains", "T01_CN_A", "--frames-per-scenario", "1", "--width", "64",
                                      "--height", "36", "--world", "test", "--out", str(tmp_path / "out")])
    assert result.exit_code == 2, result.output
    lines = result.output.strip().splitlines()
    assert lines == ["error: could not start the local Ray cluster: its raylet did not register within Ray's 30 s "
                     "(a machine this busy starts it slowly); run the same command again"], result.output
    # the root was claimed (a resume picks it up) but holds no frame, and the run's lease is released
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["_lease", "idda-root.json", "run.json"]
    assert list((tmp_path / "out" / "_lease").iterdir()) == []

    def other(*args, **kwargs):
        raise Exception("something else")

    monkeypatch.setattr(ray, "init", other)  # any other failure of Ray's is not dressed up as this one
    with pytest.raises(Exception, match="something else"):
        from pipeline.cluster import start_local_cluster

        start_local_cluster(ray, 1)


def test_what_ray_writes_to_stderr_while_shutting_down_goes_to_the_session_logs(tmp_path, capfd):
    """After a stop, the driver's core worker logs an ERROR line straight to file descriptor 2 per task it
    can no longer report ("Failed to push error to driver ..."), between idda's own last lines:
    `shutdown` puts such lines in the session's logs dir, and gives stderr back afterwards.
    (Ray's native line is stood in for: it comes only when a stop and a task's end race.)"""
    import types

    from pipeline.cluster import SHUTDOWN_LOG, shutdown

    def native_shutdown():
        os.write(2, b"[E task_manager.cc:1545] Failed to push error to driver for task 1f\n")

    node = types.SimpleNamespace(get_logs_dir_path=lambda: str(tmp_path))
    fake = types.SimpleNamespace(shutdown=native_shutdown,
                                 _private=types.SimpleNamespace(worker=types.SimpleNamespace(_global_node=node)))
    shutdown(fake)
    os.write(2, b"stopped by SIGHUP\n")  # idda's own line after it: the terminal's again
    assert capfd.readouterr().err == "stopped by SIGHUP\n"
    assert "Failed to push error" in (tmp_path / SHUTDOWN_LOG).read_text()

    fake._private.worker._global_node = None  # no session (another Ray version, Ray Client): dropped
    shutdown(fake)
    assert capfd.readouterr().err == ""
