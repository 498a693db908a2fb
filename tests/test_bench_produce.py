"""The production benchmark's machine CPU count: every process a run starts, read from /proc/stat."""

from __future__ import annotations

import time

from benchmarks.bench_produce import _cpu_cell, machine_busy_s


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
