"""What stands before a resume's first episode (issue 35 item 5): on a root
without indexes the parts' footers, then Ray's start, and never an index fold
(folds run beside the rendering and after it); a root with nothing left to
render never starts Ray. Events are ordered, not timed."""

from __future__ import annotations

import pytest

import pipeline.driver as driver
from manifests.reader import ManifestScan, index_files
from manifests.synthetic import write_parts
from pipeline.planner import make_plan
from pipeline.settings import PlanConfig, RunConfig
from pipeline.provenance import prepare_root
from storage import Storage

PLAN = PlanConfig(domains="T01_CN_A,T01_CN_M", frames_per_scenario=150, seed=3)


def _parts_only_root(path, leave_out: int) -> Storage:
    """A root holding synthetic parts of PLAN's episodes but the last ``leave_out``, and no index."""
    from roots.contract import claim_root

    storage = Storage.from_uri(str(path))
    claim_root(storage)
    prepare_root(storage, RunConfig(PLAN, world="test"))
    episodes = make_plan(PLAN).episodes
    write_parts(storage, episodes[:len(episodes) - leave_out], threads=2)
    assert not index_files(storage)
    return storage


def _record(monkeypatch) -> list[str]:
    """Events in order: the footers' reading, Ray's start, the first finished episode, each index fold."""
    events: list[str] = []
    real_summaries, real_connect, real_compact = ManifestScan.summaries, driver._connect, driver.compact

    def summaries(self, storage, *args, **kwargs):
        events.append("footers start")
        found = real_summaries(self, storage, *args, **kwargs)
        events.append("footers done")
        return found

    def connect(ray, config):
        events.append("ray start")
        return real_connect(ray, config)

    def compact(*args, **kwargs):
        events.append("fold start")
        return real_compact(*args, **kwargs)

    monkeypatch.setattr(ManifestScan, "summaries", summaries)
    monkeypatch.setattr(driver, "_connect", connect)
    monkeypatch.setattr(driver, "compact", compact)
    return events


@pytest.mark.slow
def test_the_first_episode_runs_before_any_index_fold(tmp_path, monkeypatch):
    import ray

    from benchmarks.bench_control import standin_episode

    if ray.is_initialized():
        ray.shutdown()
    storage = _parts_only_root(tmp_path / "out", leave_out=2)
    events = _record(monkeypatch)

    def progress(p: driver.Progress) -> None:
        if p.episodes_done and "first episode done" not in events:
            events.append("first episode done")

    config = driver.ProduceConfig(run=RunConfig(PLAN, world="test"), out=storage.uri, workers=1, progress_interval_s=0.0)
    report = driver.produce(config, progress, episode_fn=standin_episode)
    assert report.ok and report.rendered_episodes == 2 and not ray.is_initialized()
    assert events == ["footers start", "footers done", "ray start", "first episode done", "fold start"]
    assert sorted(index_files(storage)) == ["T01_CN_A", "T01_CN_M"]  # folded at the end


def test_nothing_to_render_starts_no_ray(tmp_path, monkeypatch):
    """Every planned part is there: the footers are read, the indexes folded, and Ray never starts."""
    import ray

    if ray.is_initialized():
        ray.shutdown()
    storage = _parts_only_root(tmp_path / "out", leave_out=0)
    events = _record(monkeypatch)
    report = driver.produce(driver.ProduceConfig(run=RunConfig(PLAN, world="test"), out=storage.uri, workers=1))
    assert report.ok and report.rendered_episodes == 0 and report.skipped_episodes == len(make_plan(PLAN).episodes)
    assert events == ["footers start", "footers done", "fold start"] and not ray.is_initialized()
