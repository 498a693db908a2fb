"""Planning cost at full scale: time and memory, against frame count."""

from __future__ import annotations

import json
import statistics
import time
import tracemalloc
from pathlib import Path

from pipeline.planner import PlanConfig, make_plan


def _measure(config: PlanConfig, repeats: int = 5) -> dict:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        plan = make_plan(config)
        times.append(time.perf_counter() - start)
    tracemalloc.start()
    plan = make_plan(config)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return {
        "scale": config.scale,
        "frames": plan.total_frames,
        "episodes": len(plan.episodes),
        "median_s": statistics.median(times),
        "peak_mib": peak / 2**20,
    }


def main(out_dir: str = "docs") -> dict:
    rows = [_measure(PlanConfig(scale=s)) for s in (0.01, 0.1, 1.0)]
    result = {"command": "make bench (benchmarks/bench_plan.py)", "rows": rows}
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench_plan.json").write_text(json.dumps(result, indent=2) + "\n")
    lines = [
        "# Planning benchmark",
        "",
        "`make bench` (benchmarks/bench_plan.py): `make_plan` over all 105 scenarios, median of 5 runs;",
        "peak memory by tracemalloc. The plan holds episodes, not frames, so memory follows the",
        "episode count (at most ~80x fewer rows than frames).",
        "",
        "| scale | frames | episodes | median time (s) | peak memory (MiB) | bytes per frame |",
        "|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['scale']} | {r['frames']:,} | {r['episodes']:,} | {r['median_s']:.3f} | "
            f"{r['peak_mib']:.1f} | {r['peak_mib'] * 2**20 / r['frames']:.1f} |"
        )
    (out / "bench_plan.md").write_text("\n".join(lines) + "\n")
    return result


if __name__ == "__main__":
    main()
