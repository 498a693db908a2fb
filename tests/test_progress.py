"""produce's progress: reported by the workers (on a cluster through a Ray actor, batched
and with at most one report in flight per task; on the local cluster a run starts for
itself, through count files the driver reads), from the start of the work;
"estimating" until a window of frames gives a rate, then the window's rate and
ETA; one line per finished episode when stderr is not a terminal. No timing
thresholds: the displayed rate is compared with the window's frames over the
elapsed times the run reported."""

from __future__ import annotations

import io
import os
import re
import subprocess
import sys
import tempfile
import time

import pytest

from pipeline.cli.progress import RATE_WINDOW, ProgressDisplay, RateWindow, format_progress
from pipeline.settings import ProduceConfig
from pipeline.driver import Progress, produce
from pipeline.ray_task import FileCounts, FrameCounter, FrameReporter
from pipeline.settings import PlanConfig, RunConfig

FRAMES = 4  # per scenario: one episode each
WINDOW = 3  # frames: small, so this short run shows a rate


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


@pytest.mark.slow
def test_progress_per_frame_then_the_window_rate(tmp_path, monkeypatch):
    plan = PlanConfig(domains="T01_CN_A,T07_HRN_B", frames_per_scenario=FRAMES, width=64, height=36, seed=1)
    log, terminal = io.StringIO(), _Terminal()
    logged, drawn = ProgressDisplay(log, window=WINDOW), ProgressDisplay(terminal, window=WINDOW)
    seen: list[tuple[Progress, str]] = []
    titles: set[str] = set()  # of the run's Ray worker processes, while frames are counted
    scratch = tmp_path / "tmp"  # the driver's temporary folders go here (other tests make theirs elsewhere)
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))
    folders: set[str] = set()
    # count folders left by drivers killed with their watchers: a gone one's is removed, a live one's kept
    ended = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    orphan, alive = scratch / f"idda-progress-{int(ended.stdout)}-x1", scratch / f"idda-progress-{os.getppid()}-x2"
    for folder in (orphan, alive):
        folder.mkdir()
        (folder / "T01_CN_A%2Fe0000").write_text("3")

    def on_progress(p: Progress) -> None:
        logged.update(p)
        drawn.update(p)
        seen.append((p, format_progress(p, drawn.window.rate)))
        if 0 < p.frames_done < total:
            titles.update(_worker_titles())
            folders.update(set(os.listdir(scratch)) - {alive.name})

    total = 2 * FRAMES
    config = ProduceConfig(run=RunConfig(plan, world="test"), out=str(tmp_path / "out"), workers=1, progress_interval_s=0.0)
    report = produce(config, on_progress)
    logged.close()
    drawn.close()
    assert report.ok and report.rendered_frames == total
    # The local cluster the run started for itself: counts through files, no progress actor,
    # and the files' folder removed at the end.
    assert any("episode_task" in t for t in titles) and not any("FrameCounter" in t for t in titles), titles
    assert any(f.startswith("idda-progress-") for f in folders) and os.listdir(scratch) == [alive.name]

    frames = [p.frames_done for p, _ in seen]
    assert frames[0] == 0 and seen[0][0].frames_total == total  # shown before any frame is done
    assert 0 < [f for f in frames if f][0] < FRAMES  # frames move it, not the first episode's end
    assert frames == sorted(frames) and frames[-1] == total
    assert len(set(frames)) > 3  # it moved within episodes, not once per episode
    first = next(p for p, _ in seen if p.frames_done)
    for p, text in seen:
        if p.frames_done < first.frames_done + WINDOW:
            assert "estimating rate and ETA" in text and "ETA " not in text.replace("rate and ETA", "")
            continue
        # Each count at the time it was first reported (a finished episode repeats the count).
        at = {q.frames_done: q.elapsed_s for q, _ in reversed(seen)}
        start = max(f for f in at if 0 < f <= p.frames_done - WINDOW)
        window_rate = (p.frames_done - start) / (at[p.frames_done] - at[start])
        shown = float(re.search(r"([\d,.]+) frame/s", text).group(1).replace(",", ""))
        assert shown == pytest.approx(window_rate, rel=0.01, abs=0.01), (text, window_rate)

    lines = log.getvalue().splitlines()  # not a terminal: one line per finished episode
    assert len(lines) == 2
    assert "episodes 1/2" in lines[0] and f"rendering {total}/{total} frames (100%)" in lines[1]
    redraws = terminal.getvalue().split("\r")[1:]  # a terminal: the line redrawn at every update
    assert len(redraws) == len(seen) and terminal.getvalue().endswith("\n")


def _worker_titles() -> set[str]:
    """The process titles (``ray::...``) of this process's Ray workers."""
    from pipeline.reaper import _proc_table, descendants

    titles = set()
    for pid in descendants(os.getpid(), _proc_table()):
        try:
            with open(f"/proc/{pid}/cmdline", "rb") as f:
                titles.add(f.read().replace(b"\0", b" ").decode(errors="replace").strip())
        except OSError:
            continue
    return {t for t in titles if t.startswith("ray::")}


def test_count_files_batched_per_interval_and_best_effort(tmp_path):
    counts = FileCounts(str(tmp_path))
    report = FrameReporter(counts, "T01_CN_A_e0000", interval_s=3600.0)
    for n in range(1, 101):
        report(n)
    assert counts.read(["T01_CN_A_e0000", "T01_CN_A_e0001"]) == {"T01_CN_A_e0000": 1}  # one write per interval
    every = FrameReporter(counts, "T01_CN_A_e0000", interval_s=0.0)
    every(7)
    assert counts.read(["T01_CN_A_e0000"]) == {"T01_CN_A_e0000": 7} and os.listdir(tmp_path) == ["T01_CN_A_e0000"]
    counts.forget("T01_CN_A_e0000")
    assert counts.read(["T01_CN_A_e0000"]) == {} and os.listdir(tmp_path) == []
    gone = FrameReporter(FileCounts(str(tmp_path / "gone")), "e", interval_s=0.0)
    for n in range(1, 11):  # progress is best effort: a folder that is gone never fails the episode
        gone(n)


def test_driver_reads_the_highest_count_of_running_episodes_and_removes_the_rest():
    from types import SimpleNamespace

    from pipeline.driver import _FileFrames

    live = _FileFrames(None, interval_s=0.0)
    a, b = SimpleNamespace(key="a", frames=10), SimpleNamespace(key="b/1", frames=10)
    try:
        live.counter.write("a", 4)
        live.counter.write("b/1", 2)
        assert live.frames(0, [a, b]) == 6 and live.wait_s() <= 0.01
        live._due = 0.0
        live.counter.write("a", 1)  # a retried attempt starting over: its count does not go back
        live.counter.write("b/1", 4)
        assert live.frames(0, [a, b]) == 8
        live._due = 0.0
        live.counter.write("b/1", 5)
        assert live.frames(10, [b]) == 15  # "a" finished (10 frames): its file is removed
        assert sorted(os.listdir(live.counter.folder)) == ["b%2F1"]
    finally:
        live.close()
    assert not os.path.exists(live.counter.folder)


class _GatedCounter(FrameCounter):
    """The progress actor, holding every report until ``release``."""

    def __init__(self) -> None:
        import asyncio

        super().__init__()
        self.gate = asyncio.Event()

    async def frame(self, key: str, n: int, node: str | None = None) -> None:
        await self.gate.wait()
        await super().frame(key, n, node)

    async def release(self) -> None:
        self.gate.set()


class _Sent:
    """An actor handle that counts the reports sent through it (``handle.frame.remote``)."""

    def __init__(self, actor) -> None:
        self.actor, self.sent, self.last = actor, 0, None

    @property
    def frame(self):
        return self

    def remote(self, key: str, n: int, node: str | None = None):
        self.sent += 1
        self.last = n
        return self.actor.frame.remote(key, n, node)


@pytest.fixture(scope="module")
def ray_one_cpu():
    import ray

    if ray.is_initialized():
        ray.shutdown()
    ray.init(address="local", num_cpus=1, include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()


def _until(condition, action=lambda: None, limit_s: float = 60.0) -> None:
    deadline = time.monotonic() + limit_s
    while not condition():
        assert time.monotonic() < deadline, "condition never held"
        action()
        time.sleep(0.01)


def test_a_task_never_has_more_than_one_report_in_flight(ray_one_cpu):
    ray = ray_one_cpu
    actor = ray.remote(_GatedCounter).remote()
    handle = _Sent(actor)
    report = FrameReporter(handle, "T01_CN_A_e0000", interval_s=0.0)
    for n in range(1, 10_001):  # the actor acks nothing: every report after the first is coalesced
        report(n)
    assert handle.sent == 1 and handle.last == 1
    ray.get(actor.release.remote())
    frames = iter(range(10_001, 10**9))
    _until(lambda: handle.sent == 2, lambda: report(next(frames)))  # acked: the next count goes out
    assert handle.last > 10_000  # the latest count, not a queued old one
    _until(lambda: ray.get(actor.counts.remote(["T01_CN_A_e0000"], -1, 0.0))[1] == {"T01_CN_A_e0000": handle.last})


def test_reports_are_batched_per_interval_and_survive_a_dead_actor(ray_one_cpu):
    ray = ray_one_cpu
    actor = ray.remote(_GatedCounter).remote()
    ray.get(actor.release.remote())
    handle = _Sent(actor)
    report = FrameReporter(handle, "e", interval_s=3600.0)
    for n in range(1, 1001):
        report(n)
    assert handle.sent == 1  # one report within the interval
    ray.kill(actor, no_restart=True)
    dead = FrameReporter(actor, "e", interval_s=0.0)
    for n in range(1, 101):  # progress is best effort: a dead actor never fails the episode
        dead(n)


def test_counter_forgets_finished_episodes():
    import asyncio

    async def scenario():
        counter = FrameCounter()
        await counter.frame("a", 3, "node1")
        await counter.frame("b", 0, "node2")  # a task's first report, at its start: its node
        await counter.frame("b", 2, "node2")
        await counter.frame("a", 1, "node3")  # a retried attempt starting over does not lower the count
        version, counts, nodes = await counter.counts(["a", "b"], -1, 0.0)
        assert counts == {"a": 3, "b": 2} and nodes == {"a": "node3", "b": "node2"}  # the node it runs on now
        version, counts, nodes = await counter.counts(["b"], version, 0.0)  # "a" finished: dropped
        assert counts == {"b": 2} and counter._done == {"b": 2} and nodes == {"b": "node2"}

    asyncio.run(scenario())


def test_stand_in_episodes_through_the_driver(tmp_path):
    """The control-plane benchmark's path, small: the real driver, a stand-in episode function."""
    import ray

    from benchmarks.bench_control import standin_episode
    from manifests.reader import done_episodes, read_manifest
    from pipeline.planner import make_plan
    from storage import Storage

    if ray.is_initialized():
        ray.shutdown()
    plan = PlanConfig(domains="towns=T01,T02 weathers=CN viewpoints=A,B", frames_per_scenario=150, seed=2)
    seen: list[Progress] = []
    config = ProduceConfig(run=RunConfig(plan, world="test"), out=str(tmp_path / "out"), workers=2, progress_interval_s=0.0)
    report = produce(config, seen.append, episode_fn=standin_episode)
    planned = make_plan(plan)
    assert report.ok and report.rendered_episodes == len(planned.episodes) and report.rendered_frames == planned.total_frames
    storage = Storage.from_uri(str(tmp_path / "out"))
    assert done_episodes(storage) == {(e.scenario, e.episode) for e in planned.episodes}
    table = read_manifest(storage)
    assert len(table) == planned.total_frames and table.column("rgb_path").null_count == len(table)
    frames = [p.frames_done for p in seen]
    assert frames == sorted(frames) and frames[0] == 0 and frames[-1] == planned.total_frames
    assert seen[-1].episodes_done == len(planned.episodes)
    assert sum(row["frames"] for row in report.per_scenario.values()) == planned.total_frames


class _P:
    """A Progress as the driver sends it (only the fields the display reads)."""

    def __init__(self, frames_done, elapsed_s, frames_total=1000, episodes_done=0):
        self.frames_done, self.elapsed_s, self.frames_total = frames_done, elapsed_s, frames_total
        self.episodes_done, self.episodes_total, self.failed = episodes_done, 10, 0


def test_estimating_until_a_window_of_frames_then_the_window_rate():
    """A run that spends 100 s starting (Ray, world builds), then renders one
    frame a second: the average from the start says 0.09 frame/s and an ETA of
    hours; the window says 1 frame/s and the true ETA."""
    window = RateWindow(size=10)
    for frame in range(1, 11):  # the first frame at 100 s, then one a second
        window.add(frame, 99.0 + frame)
        assert window.rate is None  # 9 frames after the first: still estimating
        assert "estimating rate and ETA" in format_progress(_P(frame, 99.0 + frame), window.rate)
    window.add(11, 110.0)
    assert window.rate == pytest.approx(1.0)
    text = format_progress(_P(11, 110.0), window.rate)
    assert "1.00 frame/s, ETA 16m 29s" in text  # 989 frames left at 1 frame/s (the run's average: 2h 44m)
    for frame in range(12, 40):  # the machine slows to one frame every 2 s: the window follows
        window.add(frame, 110.0 + 2 * (frame - 11))
    assert window.rate == pytest.approx(0.5)
    window.add(39, 500.0)  # a repeated count changes nothing
    assert window.rate == pytest.approx(0.5)


def test_the_display_uses_the_window():
    terminal = _Terminal()
    display = ProgressDisplay(terminal, window=RATE_WINDOW)
    display.update(_P(0, 50.0))
    for frame in range(1, RATE_WINDOW + 2):
        display.update(_P(frame, 60.0 + 0.5 * frame))
    display.close()
    lines = terminal.getvalue().split("\r")[1:]
    assert all("estimating rate and ETA" in line for line in lines[:-1])
    assert "2.00 frame/s" in lines[-1]
