"""Node loss never fails a run: on a three-node ``ray.cluster_utils.Cluster``
(head plus two workers) a worker node is removed mid-run, once the node that
holds the progress actor, once a plain one. The same produce() call finishes,
its report is ok, and the root is byte-identical to a local run's."""

from __future__ import annotations

import threading

import pytest

from pipeline.settings import ProduceConfig
from pipeline.driver import produce
from pipeline.planner import PlanConfig
from pipeline.settings import RunConfig
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
    return tree_digest(out)


def _run_and_remove(tmp_path, monkeypatch, actor_on_doomed: bool):
    """Run on head + two workers; remove one worker once frames were reported; return (report, digest)."""
    import ray
    from ray.cluster_utils import Cluster

    from pipeline import driver

    if ray.is_initialized():
        ray.shutdown()
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1})
    doomed = cluster.add_node(num_cpus=1, resources={ACTOR_HOST: 1})
    cluster.add_node(num_cpus=1)
    cluster.wait_for_nodes()
    if actor_on_doomed:  # place the progress actor where it will be lost
        monkeypatch.setattr(driver, "PROGRESS_ACTOR_OPTIONS", {**driver.PROGRESS_ACTOR_OPTIONS, "resources": {ACTOR_HOST: 0.01}})
    out = tmp_path / "cluster"
    result, moving = {}, threading.Event()
    seen = []

    def on_progress(p) -> None:
        seen.append(p)
        if p.frames_done > 0:
            moving.set()

    def drive():
        try:
            result["report"] = produce(_config(out, address=cluster.address), on_progress)
        except BaseException as exc:  # surfaced below
            result["error"] = exc

    thread = threading.Thread(target=drive)
    try:
        thread.start()
        assert moving.wait(timeout=300), "no frame was reported"
        assert thread.is_alive(), "the run ended before a node could be removed"
        cluster.remove_node(doomed)
        thread.join(timeout=600)
        assert not thread.is_alive(), "the run did not finish after the node was removed"
    finally:
        if ray.is_initialized():
            ray.shutdown()
        cluster.shutdown()
    assert "error" not in result, repr(result.get("error"))
    frames = [p.frames_done for p in seen]
    assert frames == sorted(frames) and frames[-1] == result["report"].rendered_frames == 48
    return result["report"], tree_digest(out)


def test_losing_the_progress_actors_node_does_not_fail_the_run(local_reference, tmp_path, monkeypatch):
    report, digest = _run_and_remove(tmp_path, monkeypatch, actor_on_doomed=True)
    assert report.ok and report.rendered_episodes == 8
    assert digest == local_reference


def test_losing_a_worker_node_does_not_fail_the_run(local_reference, tmp_path, monkeypatch):
    report, digest = _run_and_remove(tmp_path, monkeypatch, actor_on_doomed=False)
    assert report.ok and report.rendered_episodes == 8
    assert digest == local_reference
