"""Node loss never fails a run: on a three-node ``ray.cluster_utils.Cluster``
(head plus two workers) the worker nodes are removed mid-run, first the node that
holds the progress actor, then a plain one. The same produce() call finishes,
its report is ok, and the root is byte-identical to a local run's. A node that
hangs (SIGSTOP) is given up once Ray's health check marks it dead, its
episodes run elsewhere, and when it wakes it writes nothing into the root."""

from __future__ import annotations

import logging
import os
import signal
import threading
import time
from pathlib import Path

import pytest

from pipeline.settings import ProduceConfig
from pipeline.driver import produce
from pipeline.settings import PlanConfig, RunConfig
from tests.test_produce import tree_digest

pytestmark = pytest.mark.slow

# 8 scenarios, one 6-frame episode each: long enough that the removal lands mid-run.
PLAN = PlanConfig(domains="towns=T01,T07 weathers=CN,HRN viewpoints=A,B", frames_per_scenario=6, width=64, height=36, seed=3)
ACTOR_HOST = "progress_host"  # a custom resource only the doomed node has


def _config(out, **kw) -> ProduceConfig:
    return ProduceConfig(run=RunConfig(plan=PLAN, world="test"), out=str(out), max_retries=5, progress_interval_s=0.0, **kw)


@pytest.fixture(scope="module")
def local_reference(tmp_path_factory):
    """The plan rendered on this machine, without Ray (the same bytes as a local
    produce: tests/test_produce.py's reference checks that)."""
    from tests.roots import render_root

    out = tmp_path_factory.mktemp("chaos-reference") / "root"
    render_root(out, RunConfig(plan=PLAN, world="test"), compact=True)
    return out


def assert_same_root(out: Path, reference: Path) -> None:
    """``out`` holds the reference's files, byte for byte; else the message names the differing
    scenarios with what their parts say (seed, weather, counts) and their stats, beside the
    reference's, so a rare mismatch tells where it came from."""
    got, want = tree_digest(out), tree_digest(reference)
    if got == want:
        return
    import pyarrow.parquet as pq

    differing = sorted(k for k in set(got) | set(want) if got.get(k) != want.get(k))
    scenarios = sorted({k.split("/")[0] for k in differing if "/e0" in k})
    lines = []
    for scenario in scenarios:
        for name, root in (("run", out), ("reference", reference)):
            parts = sorted(root.glob(f"manifest/**/{scenario}_e*.parquet"))
            row = pq.read_table(parts[0]).slice(0, 1).to_pylist()[0] if parts else {}
            fields = {c: row.get(c) for c in ("seed", "n_vehicles", "n_pedestrians", "ego_speed_mps", "cloudiness",
                                              "precipitation", "visibility_m", "width", "height")}
            stats = [s.read_text()[:300] for s in sorted(root.glob(f"_stats/{scenario}_e*.json"))]
            lines.append(f"{scenario} {name}: {fields} stats {stats}")
    raise AssertionError(f"{len(differing)} files differ from the local run's ({', '.join(differing[:4])}, ...):\n"
                         + "\n".join(lines))


def test_losing_worker_nodes_one_after_the_other_does_not_fail_the_run(local_reference, tmp_path, monkeypatch):
    """Head plus two worker nodes; the node that holds the progress actor is removed once frames
    were reported, then the other worker once more frames came: the same produce() call finishes on
    the head alone, its report is ok and the root is the local run's, byte for byte. (One run for
    both losses: a cluster's start and a run cost a minute under load.)"""
    import ray
    from ray.cluster_utils import Cluster

    from pipeline import driver

    if ray.is_initialized():
        ray.shutdown()
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1})
    doomed = cluster.add_node(num_cpus=1, resources={ACTOR_HOST: 1})
    plain = cluster.add_node(num_cpus=1)
    cluster.wait_for_nodes()
    # place the progress actor where it will be lost
    monkeypatch.setattr(driver, "PROGRESS_ACTOR_OPTIONS", {**driver.PROGRESS_ACTOR_OPTIONS, "resources": {ACTOR_HOST: 0.01}})
    out = tmp_path / "cluster"
    result, seen = {}, []
    first, more = threading.Event(), threading.Event()

    def on_progress(p) -> None:
        seen.append(p)
        if p.frames_done > 0:
            first.set()
        if first.is_set() and removed and p.frames_done > removed[0]:
            more.set()

    def drive():
        try:
            result["report"] = produce(_config(out, address=cluster.address), on_progress)
        except BaseException as exc:  # surfaced below
            result["error"] = exc

    removed: list[int] = []  # frames done when the first node went
    thread = threading.Thread(target=drive)
    try:
        thread.start()
        assert first.wait(timeout=300), "no frame was reported"
        assert thread.is_alive(), "the run ended before a node could be removed"
        removed.append(seen[-1].frames_done)
        cluster.remove_node(doomed)  # the progress actor's node
        assert more.wait(timeout=300), "no frame was reported after the first node was lost"
        assert thread.is_alive(), "the run ended before the second node could be removed"
        cluster.remove_node(plain)
        thread.join(timeout=600)
        assert not thread.is_alive(), "the run did not finish after the nodes were removed"
    finally:
        if ray.is_initialized():
            ray.shutdown()
        cluster.shutdown()
    assert "error" not in result, repr(result.get("error"))
    frames = [p.frames_done for p in seen]
    assert frames == sorted(frames) and frames[-1] == result["report"].rendered_frames == 48
    report = result["report"]
    assert report.ok and report.rendered_episodes == 8
    assert_same_root(out, local_reference)


# A short health check: a node that stops answering is marked dead after about period x threshold (3 s).
HEALTH_CHECK = {"health_check_period_ms": 1000, "health_check_failure_threshold": 3, "health_check_timeout_ms": 1000,
                "health_check_initial_delay_ms": 1000}
HEAD_HOST = "head_host"  # a custom resource of the head only: the progress actor stays off the hung node


def _busy_worker(raylet_pid: int) -> bool:
    """Whether a worker process below ``raylet_pid`` runs an episode (Ray names it after the task)."""
    from tests.faultkit import descendants

    for pid in descendants(raylet_pid):
        try:
            if b"episode_task" in Path(f"/proc/{pid}/cmdline").read_bytes():
                return True
        except OSError:
            continue
    return False


def _every_file(root: Path) -> dict[str, tuple]:
    """Every file with its bytes' digest, inode and mtime: a rewrite with the same bytes shows too."""
    import hashlib

    out = {}
    for path in sorted(root.rglob("*")):
        if path.is_file():
            st = path.stat()
            out[path.relative_to(root).as_posix()] = (hashlib.sha256(path.read_bytes()).hexdigest(), st.st_ino, st.st_mtime_ns)
    return out


def test_a_hung_node_is_given_up_and_writes_nothing_when_it_wakes(local_reference, tmp_path, monkeypatch, caplog):
    """Issue 38: a worker node's raylet and its workers SIGSTOPped mid-episode stalled the
    run for minutes, and on SIGCONT the hung worker wrote frame files after the driver had
    exited. Now the driver gives the node up once Ray marks it dead, runs its episodes on
    the head, says so in one line, and the woken worker writes nothing (frame fence)."""
    import ray
    from ray._private import ray_constants
    from ray.cluster_utils import Cluster

    from pipeline import driver
    from tests.faultkit import descendants

    if ray.is_initialized():
        ray.shutdown()
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1, "resources": {HEAD_HOST: 1},
                                                            "_system_config": HEALTH_CHECK})
    node = cluster.add_node(num_cpus=1)
    cluster.wait_for_nodes()
    monkeypatch.setattr(driver, "PROGRESS_ACTOR_OPTIONS", {**driver.PROGRESS_ACTOR_OPTIONS, "resources": {HEAD_HOST: 0.01}})
    raylet = node.all_processes[ray_constants.PROCESS_TYPE_RAYLET][0].process.pid
    out = tmp_path / "cluster"
    result, stopped = {}, []
    caplog.set_level(logging.WARNING, logger="pipeline.driver")

    def drive():
        try:
            result["report"] = produce(_config(out, address=cluster.address), lambda p: None)
        except BaseException as exc:  # surfaced below
            result["error"] = exc

    thread = threading.Thread(target=drive)
    try:
        thread.start()
        deadline = time.monotonic() + 300
        while not _busy_worker(raylet):
            assert time.monotonic() < deadline and thread.is_alive(), "no episode ran on the worker node"
            time.sleep(0.05)
        stopped = [raylet, *descendants(raylet)]
        for pid in stopped:
            os.kill(pid, signal.SIGSTOP)
        thread.join(timeout=240)
        assert not thread.is_alive(), "the run did not finish after the node hung"
        before = _every_file(out)
        for pid in stopped:
            os.kill(pid, signal.SIGCONT)
        stopped = []
        time.sleep(5)  # the woken worker would write its next frame files now
        assert _every_file(out) == before
    finally:
        for pid in stopped:
            try:
                os.kill(pid, signal.SIGCONT)
            except ProcessLookupError:
                pass
        if ray.is_initialized():
            ray.shutdown()
        cluster.shutdown()
    assert "error" not in result, repr(result.get("error"))
    report = result["report"]
    assert report.ok and report.rendered_episodes == 8 and report.nodes_lost == 1
    lines = [r.getMessage() for r in caplog.records if " lost: " in r.getMessage()]
    assert len(lines) == 1 and lines[0].startswith("node ") and "retried elsewhere" in lines[0], lines
    assert_same_root(out, local_reference)


def test_the_checks_gate_lives_on_the_drivers_node_and_outlives_a_worker_node():
    """The checks gate (``ChecksGate``: the first episodes' part commits wait for its answer) is pinned to the
    driver's node: with the head's CPU busy, Ray would place a CPU-less actor on the worker node, and losing
    that node lost the gate, so every waiting commit failed. Here the gates stay on the head, the worker node
    goes, and they still answer."""
    import ray
    from ray.cluster_utils import Cluster

    from pipeline.driver import on_driver_node
    from pipeline.ray_task import ChecksGate

    class PlacedGate(ChecksGate):
        def node(self) -> str:
            return ray.get_runtime_context().get_node_id()

    if ray.is_initialized():
        ray.shutdown()
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1, "resources": {HEAD_HOST: 1}})
    try:
        worker = cluster.add_node(num_cpus=2)
        cluster.wait_for_nodes()
        ray.init(address=cluster.address)
        head = ray.get_runtime_context().get_node_id()
        busy = ray.remote(lambda: time.sleep(60)).options(num_cpus=1, resources={HEAD_HOST: 1}).remote()  # the head's CPU
        gates = [ray.remote(PlacedGate).options(**on_driver_node(ray)).remote() for _ in range(4)]
        assert ray.get([g.node.remote() for g in gates], timeout=60) == [head] * 4
        answers = [g.wait.remote() for g in gates]
        cluster.remove_node(worker)
        for g in gates:
            g.open.remote(True)
        assert ray.get(answers, timeout=60) == [True] * 4
        ray.cancel(busy, force=True)
    finally:
        if ray.is_initialized():
            ray.shutdown()
        cluster.shutdown()
