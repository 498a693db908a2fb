"""produce's progress: reported per frame by the workers (through a Ray
actor), from the start of the work; "estimating" until a window of frames
gives a rate, then the window's rate and ETA; one line per finished episode
when stderr is not a terminal. No timing thresholds: the displayed rate is
compared with the window's frames over the elapsed times the run reported."""

from __future__ import annotations

import io
import re
import time

import pytest

from pipeline.cli import RATE_WINDOW, ProgressDisplay, RateWindow, format_progress
from pipeline.driver import ProduceConfig, Progress, produce
from pipeline.planner import PlanConfig
from pipeline.runmeta import RunConfig

FRAMES = 4  # per scenario: one episode each
WINDOW = 3  # frames: small, so this short run shows a rate


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


@pytest.mark.slow
def test_progress_per_frame_then_the_window_rate(tmp_path):
    plan = PlanConfig(domains="T01_CN_A,T07_HRN_B", frames_per_scenario=FRAMES, width=64, height=36, seed=1)
    log, terminal = io.StringIO(), _Terminal()
    logged, drawn = ProgressDisplay(log, window=WINDOW), ProgressDisplay(terminal, window=WINDOW)
    seen: list[tuple[Progress, str]] = []

    def on_progress(p: Progress) -> None:
        logged.update(p)
        drawn.update(p)
        seen.append((p, format_progress(p, drawn.window.rate)))

    report = produce(ProduceConfig(run=RunConfig(plan, world="test"), out=str(tmp_path / "out"), workers=1), on_progress)
    logged.close()
    drawn.close()
    total = 2 * FRAMES
    assert report.ok and report.rendered_frames == total

    frames = [p.frames_done for p, _ in seen]
    assert frames[0] == 0 and seen[0][0].frames_total == total  # shown before any frame is done
    assert [f for f in frames if f][0] == 1  # the first frame moves it, not the first episode
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
