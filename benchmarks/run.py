"""`make bench`: run every benchmark; each writes its figures to docs/.

Select some with BENCH=plan,render (default: all)."""

from __future__ import annotations

import importlib
import logging
import os
import sys
import time

BENCHMARKS = ("plan", "render", "produce", "manifest", "control", "control_root", "verify", "outputs", "export", "rigs")  # `make report` renders the worlds sample


def main() -> int:
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    log = logging.getLogger("bench")
    chosen = [b for b in os.environ.get("BENCH", ",".join(BENCHMARKS)).split(",") if b]
    unknown = sorted(set(chosen) - set(BENCHMARKS))
    if unknown:
        log.error("unknown benchmark(s) %s; valid: %s", ", ".join(unknown), ", ".join(BENCHMARKS))
        return 2
    for name in chosen:
        try:
            module = importlib.import_module(f"benchmarks.bench_{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"benchmarks.bench_{name}":
                log.warning("benchmark %s is not available yet; skipped", name)
                continue
            raise
        start = time.perf_counter()
        log.info("== %s", name)
        module.main(out_dir="docs")
        log.info("   done in %.1f s; figures in docs/bench_%s.md", time.perf_counter() - start, name)
    return 0


if __name__ == "__main__":
    sys.exit(main())
