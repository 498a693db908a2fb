"""What stands before a resume's first episode (issue 35 item 5): never an index
fold (folds run beside the rendering and after it); on a big root without indexes
not even the parts' footers, read beside the first episodes, whose part commits
wait for the checks; a root with nothing left to render never starts Ray. Events
are ordered, not timed."""

from __future__ import annotations

import os
import time

import pytest

import pipeline.driver as driver
from manifests.part_file import MisfiledParts
from manifests.reader import ManifestScan, index_files, part_files, read_manifest, scan
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


def _produce_noting(storage, events: list[str], episode_fn) -> driver.ProduceReport:
    """``produce()`` of PLAN with one worker, noting "first episode done" in ``events``."""
    def progress(p: driver.Progress) -> None:
        if p.episodes_done and "first episode done" not in events:
            events.append("first episode done")

    config = driver.ProduceConfig(run=RunConfig(PLAN, world="test"), out=storage.uri, workers=1, progress_interval_s=0.0)
    return driver.produce(config, progress, episode_fn=episode_fn)


def _marks(storage) -> str:
    """Where the stand-ins below note what they reached: a folder beside the root."""
    return os.path.join(os.path.dirname(storage.uri), "marks")


def marking_episode(spec, storage, world="test", on_frame=None, fence=None):
    """``standin_episode`` (real rows, the real fenced commit), noting in ``_marks`` when it starts."""
    from benchmarks.bench_control import standin_episode

    os.makedirs(_marks(storage), exist_ok=True)
    open(os.path.join(_marks(storage), f"started-{spec.scenario}-{spec.episode}"), "w").close()
    return standin_episode(spec, storage, world, on_frame, fence)


def _waiting_footers(monkeypatch, storage, events: list[str], hold_s: float = 0.0) -> None:
    """The parts' footers are read only once an episode has started (at most 60 s later), and
    ``hold_s`` after that; ``events`` says whether one had started. Outside ``_record``'s spy."""
    real = ManifestScan.summaries

    def summaries(self, storage_, *args, **kwargs):
        deadline = time.monotonic() + 60
        while not (os.path.isdir(_marks(storage)) and os.listdir(_marks(storage))) and time.monotonic() < deadline:
            time.sleep(0.05)
        events.append("an episode started" if os.path.isdir(_marks(storage)) else "no episode started")
        time.sleep(hold_s)
        return real(self, storage_, *args, **kwargs)

    monkeypatch.setattr(ManifestScan, "summaries", summaries)


@pytest.mark.slow
def test_a_root_without_indexes_renders_before_reading_its_footers(tmp_path, monkeypatch):
    """The fix of item 5: past driver.LATE_CHECK_PARTS parts outside an index (1 here), the episodes
    the listing shows pending start before the footers are read; the indexes are right at the end."""
    import ray

    if ray.is_initialized():
        ray.shutdown()
    storage = _parts_only_root(tmp_path / "out", leave_out=2)
    events = _record(monkeypatch)
    _waiting_footers(monkeypatch, storage, events)
    monkeypatch.setattr(driver, "LATE_CHECK_PARTS", 1)
    report = _produce_noting(storage, events, marking_episode)
    assert report.ok and report.rendered_episodes == 2 and not ray.is_initialized()
    assert report.skipped_episodes == len(make_plan(PLAN).episodes) - 2
    # the first episode is done after the footers (its commit waits for the checks: the next test
    # shows that hold, which this order alone does not, the footers of four parts being quick)
    assert events == ["ray start", "an episode started", "footers start", "footers done", "first episode done",
                      "fold start"]
    assert sorted(scan(storage).current) == ["T01_CN_A", "T01_CN_M"]  # folded at the end, and current
    parts = sum(len(eps) for eps in part_files(storage).values())
    assert parts == len(make_plan(PLAN).episodes)
    assert len(read_manifest(storage)) == sum(spec.frames for spec in make_plan(PLAN).episodes)


@pytest.mark.slow
def test_a_root_its_late_checks_refuse_gets_no_part(tmp_path, monkeypatch):
    """Two parts of a scenario swapped (damage) in a root without indexes: the run stops with MisfiledParts, and
    the episodes that started before the footers were read commit nothing (their commit waited)."""
    import ray

    from tests import faultkit

    if ray.is_initialized():
        ray.shutdown()
    storage = _parts_only_root(tmp_path / "out", leave_out=2)
    a, b = part_files(storage)["T01_CN_A"][0], part_files(storage)["T01_CN_A"][1]
    faultkit.swap(tmp_path / "out" / a, tmp_path / "out" / b)
    before = part_files(storage)
    events = _record(monkeypatch)
    _waiting_footers(monkeypatch, storage, events, hold_s=2.0)  # time enough for a commit not held back
    monkeypatch.setattr(driver, "LATE_CHECK_PARTS", 1)
    config = driver.ProduceConfig(run=RunConfig(PLAN, world="test"), out=storage.uri, workers=1)
    with pytest.raises(MisfiledParts):
        driver.produce(config, episode_fn=marking_episode)
    assert events == ["ray start", "an episode started", "footers start", "footers done"]
    assert not ray.is_initialized()
    assert part_files(storage) == before  # nothing committed


@pytest.mark.slow
def test_the_first_episode_runs_before_any_index_fold(tmp_path, monkeypatch):
    import ray

    from benchmarks.bench_control import standin_episode

    if ray.is_initialized():
        ray.shutdown()
    storage = _parts_only_root(tmp_path / "out", leave_out=2)
    events = _record(monkeypatch)
    report = _produce_noting(storage, events, standin_episode)
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
