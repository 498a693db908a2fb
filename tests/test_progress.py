"""produce's progress: reported per frame by the workers (through a Ray
actor), from the start of the work, with the run's true rate; one line per
finished episode when stderr is not a terminal. No timing thresholds: the
displayed rate is compared with frames over the wall time measured here."""

from __future__ import annotations

import io
import re
import time

import pytest

from pipeline.cli.app import ProgressDisplay, format_progress
from pipeline.driver import ProduceConfig, Progress, produce
from pipeline.planner import PlanConfig
from pipeline.runmeta import RunConfig

pytestmark = pytest.mark.slow

FRAMES = 4  # per scenario: one episode each


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_progress_per_frame_with_the_true_rate(tmp_path):
    plan = PlanConfig(domains="T01_CN_A,T07_HRN_B", frames_per_scenario=FRAMES, width=64, height=36, seed=1)
    log, terminal = io.StringIO(), _Terminal()
    logged, drawn = ProgressDisplay(log), ProgressDisplay(terminal)
    seen: list[tuple[Progress, float, str]] = []
    t0 = time.perf_counter()

    def on_progress(p: Progress) -> None:
        seen.append((p, time.perf_counter() - t0, format_progress(p)))
        logged.update(p)
        drawn.update(p)

    report = produce(ProduceConfig(run=RunConfig(plan, world="test"), out=str(tmp_path / "out"), workers=1), on_progress)
    logged.close()
    drawn.close()
    total = 2 * FRAMES
    assert report.ok and report.rendered_frames == total

    frames = [p.frames_done for p, _, _ in seen]
    assert frames[0] == 0 and seen[0][0].frames_total == total  # shown before any frame is done
    assert [f for f in frames if f][0] == 1  # the first frame moves it, not the first episode
    assert frames == sorted(frames) and frames[-1] == total
    assert len(set(frames)) > 3  # it moved within episodes, not once per episode
    for p, wall, text in seen:
        if p.frames_done == 0:
            assert "?" in text.split("ETA ")[1]  # no rate, no ETA before the first frame
            continue
        shown = float(re.search(r"([\d,.]+) frame/s", text).group(1).replace(",", ""))
        measured = p.frames_done / wall
        assert shown == pytest.approx(measured, rel=0.2), (text, measured)
        eta = p.eta_s
        assert eta == pytest.approx((total - p.frames_done) / p.rate)

    lines = log.getvalue().splitlines()  # not a terminal: one line per finished episode
    assert len(lines) == 2
    assert "episodes 1/2" in lines[0] and f"rendering {total}/{total} frames (100%)" in lines[1]
    redraws = terminal.getvalue().split("\r")[1:]  # a terminal: the line redrawn at every update
    assert len(redraws) == len(seen) and terminal.getvalue().endswith("\n")
