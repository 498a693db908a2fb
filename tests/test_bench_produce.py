"""The production benchmark's machine CPU count (every process a run starts, read from /proc/stat) and its
timeline of a run's stored frames."""

from __future__ import annotations

import os
import time

import cv2
import pytest

from benchmarks.bench_produce import _cpu_cell, _timeline_section, frame_timeline, machine_busy_s, plot_timelines


def test_the_machine_busy_count_takes_in_what_a_process_spends():
    start, cpu = machine_busy_s(), time.process_time()
    while time.process_time() - cpu < 0.5:  # half a CPU-second of our own
        sum(range(1000))
    spent = machine_busy_s() - start
    assert spent >= 0.4  # the machine was busy at least that long (others may add to it)


def test_a_record_without_the_count_shows_a_dash():
    runs = [{"machine_cpu_s_per_frame": 0.6}, {"machine_cpu_s_per_frame": None}, {}, {"machine_cpu_s_per_frame": 0.5}]
    assert _cpu_cell(runs) == "0.550"
    assert _cpu_cell([{}]) == "-"


def _stored(root, rel: str, at: float) -> None:
    path = root / rel
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"x")
    os.utime(path, (at, at))


def test_the_timeline_takes_the_rgb_files_times_and_the_steady_rate_between_the_10_and_90_percent_marks(tmp_path):
    since = 1_000_000.0
    for i in range(20):  # 2 frames a second from 5 s on, in two episodes' folders
        _stored(tmp_path, f"T0{1 + i % 2}_CN_A/e0000/rgb/{i:04d}.png", since + 5 + i * 0.5)
        _stored(tmp_path, f"T0{1 + i % 2}_CN_A/e0000/depth_raw/{i:04d}.png", since + 1 + i)  # not an rgb file
    _stored(tmp_path, "rgb_notes.png", since + 99)  # not in an rgb folder
    timeline = frame_timeline(tmp_path, since)
    assert timeline["first_s"] == pytest.approx(5.0) and timeline["last_s"] == pytest.approx(14.5)
    assert len(timeline["times_s"]) == 20 and timeline["times_s"] == sorted(timeline["times_s"])
    assert timeline["steady_fps"] == pytest.approx(2.0)  # files 2..17: 15 frames in 7.5 s


def test_a_root_without_rgb_files_has_an_empty_timeline(tmp_path):
    _stored(tmp_path, "T01_CN_A/e0000/depth_raw/0000.png", 5.0)
    assert frame_timeline(tmp_path, 0.0) == {"times_s": [], "first_s": None, "last_s": None, "steady_fps": None}


def test_the_timelines_are_tabled_and_drawn(tmp_path):
    def run(first: float, rate: float, n: int) -> dict:
        times = [first + i / rate for i in range(n)]
        return {"reported_fps": n / (times[-1] + 0.5), "command_wall_s": times[-1] + 0.5,
                "timeline": {"times_s": times, "first_s": first, "last_s": times[-1], "steady_fps": rate}}

    e2e = {"baseline": "93dc98a", "before": [run(8.0, 3.0, 120)] * 3, "after": [run(5.0, 6.0, 120), run(6.0, 5.0, 120)],
           "after_warm": run(4.0, 6.0, 120), "after_long": run(5.0, 6.0, 600), "long_frames_per_scenario": 300}
    table = "\n".join(_timeline_section(e2e))
    assert "| before | 8.00 | 3.00 |" in table and "| after | 5.50 | 5.50 |" in table
    assert "| after, 600 frames (one run) | 5.00 | 6.00 |" in table
    plot_timelines(e2e, tmp_path / "timeline.png")
    image = cv2.imread(str(tmp_path / "timeline.png"))
    assert image is not None and image.shape[1] > 500
