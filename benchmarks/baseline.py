"""The "before" side of the before/after benchmarks: a git revision exported to a temp dir.

``BENCH_BASELINE`` (default :data:`DEFAULT_BASELINE`, main before the issue-13
speed-ups) names the revision. Its tree is run with the same interpreter and
virtual environment, its modules first on ``PYTHONPATH``, so both sides see
the same libraries and only the project's code differs. Runs alternate
(before, after, before, after...) so that load from other jobs on the machine
falls on both sides alike; ``BENCH_ROUNDS`` sets how many pairs (default 2).
"""

from __future__ import annotations

import os
import subprocess
import sys
import tarfile
import tempfile
from contextlib import contextmanager
from pathlib import Path

DEFAULT_BASELINE = "1dea01e"  # main before issue 13 (PNG, post effects, start-up, scaling)
REPO = Path(__file__).resolve().parent.parent


def baseline_ref() -> str:
    return os.environ.get("BENCH_BASELINE", DEFAULT_BASELINE)


def rounds(default: int = 2) -> int:
    return max(1, int(os.environ.get("BENCH_ROUNDS", default)))


@contextmanager
def baseline_tree():
    """Yield ``(ref, directory holding the baseline's files, None)``.

    Where the revision cannot be exported (no git, unknown revision) it yields
    ``(ref, None, reason)`` and the benchmark reports the "before" side as not
    measured.
    """
    ref = baseline_ref()
    with tempfile.TemporaryDirectory(prefix="idda-baseline-") as tmp:
        archive = Path(tmp) / "tree.tar"
        try:
            subprocess.run(["git", "-C", str(REPO), "archive", "--format=tar", "-o", str(archive), ref],
                           check=True, capture_output=True, text=True, timeout=120)
        except (OSError, subprocess.SubprocessError) as exc:
            detail = getattr(exc, "stderr", "") or str(exc)
            yield ref, None, f"git archive {ref} failed: {detail.strip().splitlines()[-1] if detail.strip() else exc}"
            return
        tree = Path(tmp) / "tree"
        with tarfile.open(archive) as tar:
            tar.extractall(tree, filter="data")
        # byte-compiled as `make` compiles this tree, so neither side compiles its sources at every start
        # (PYTHONDONTWRITEBYTECODE) and the two differ by their code only
        subprocess.run([sys.executable, "-m", "compileall", "-q", "-j", "0", str(tree)], capture_output=True, timeout=600)
        yield ref, tree, None


def tree_env(tree: Path, **extra: str) -> dict[str, str]:
    """The environment that makes a subprocess import the project from ``tree``."""
    env = dict(os.environ)
    env["PYTHONPATH"] = str(tree) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    env.update(extra)
    return env
