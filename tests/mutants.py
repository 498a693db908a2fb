"""`make mutants`: mutation testing of the data-protecting modules with mutmut.

Each module in MODULES is mutated on its own, in a scratch folder
``.mutants/<name>/`` (mutmut copies the packages there and runs pytest in
its copy), against the fast tests that exercise it: one mutant's run takes
seconds. Tests that start Ray or the local S3 server, or are marked slow,
are left out (mutmut forks a process per mutant; neither survives a fork). The score per module
goes to stdout and ``.mutants/scores.json``; docs/mutants.md keeps the last
one and says why each survivor lives.

    python -m tests.mutants [--max-children N] [--before] [--survivors] [--sample PATTERN] [module ...]

``--before`` leaves out the tests written against survivors (the score
before them); ``--survivors`` reruns only the last run's survivors, timeouts
and unfinished mutants with today's tests (mutmut's runs take minutes each);
``--sample`` runs only the mutants whose names match (fnmatch), e.g.
``'*__mutmut_*1'``: mutants 1, 11, 21... of every function, one in ten, and
scores that sample alone.

Also a pytest plugin (``-p tests.mutants``, which mutmut is told to load):
it deselects those tests.
"""

from __future__ import annotations

import argparse
import fnmatch
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
WORK = REPO / ".mutants"
PACKAGES = ("storage", "domains", "outputs", "manifests", "roots", "pipeline", "exports", "render_workers", "analysis")
# Fixtures that start Ray (a local cluster) or the local S3 server: those tests are left out.
LEFT_OUT_FIXTURES = {"ray_local", "ray_cluster", "cluster", "s3_server"}

# The modules that keep data safe (atomic writes, checksums, the root's contract, leases, the run
# record, the manifest writer and reader, verify, repair, export, the episode commit, run.json's rules).
DATA_PROTECTING = ("storage/atomic.py", "storage/checksum.py", "roots/contract.py", "roots/lease.py",
                   "roots/run_file.py", "manifests/writer.py", "manifests/reader.py", "roots/verify.py",
                   "pipeline/repair.py", "exports/export.py", "pipeline/episode_job.py", "pipeline/provenance.py")
# The tests written against mutants (issue 33's hand-made bugs, then mutmut's survivors): run for every module.
ALWAYS = ("tests/test_caught_bugs.py", "tests/test_mutant_kills.py")
# module -> the fast tests that exercise it (besides ALWAYS); modules in the order they are worth running
MODULES: dict[str, tuple[str, ...]] = {
    "storage/atomic.py": ("tests/test_storage.py", "tests/test_durability.py"),
    "roots/lease.py": ("tests/test_control_plane.py",),
    "roots/run_file.py": ("tests/test_layout.py",),
    "pipeline/provenance.py": ("tests/test_layout.py", "tests/test_pairing.py"),
    "pipeline/repair.py": (),
    "exports/export.py": ("tests/test_export.py", "tests/test_durability.py"),
    "pipeline/episode_job.py": ("tests/test_episode.py", "tests/test_control_plane.py", "tests/test_durability.py"),
    "manifests/writer.py": ("tests/test_part_names.py", "tests/test_manifest_query.py"),
    "manifests/reader.py": ("tests/test_manifest_query.py", "tests/test_part_names.py", "tests/test_control_plane.py",
                            "tests/test_footer_pool.py"),
    "roots/verify.py": ("tests/test_part_names.py", "tests/test_layout.py", "tests/test_outputs_subsets.py"),
    "roots/contract.py": ("tests/test_export.py", "tests/test_layout.py", "tests/test_control_plane.py"),
    "storage/checksum.py": ("tests/test_storage.py",),
}
STATUS = {1: "killed", 3: "killed", 37: "killed", 0: "survived", 5: "no tests", 33: "no tests", 34: "skipped",
          36: "timeout", 24: "timeout", -24: "timeout", 152: "timeout", 255: "timeout", None: "not checked"}


def _left_out(item) -> bool:
    """Ray, the local S3 server (its thread does not survive mutmut's fork), or slow."""
    fixtures = set(getattr(item, "fixturenames", ()))
    params = getattr(getattr(item, "callspec", None), "params", {})
    return bool(fixtures & LEFT_OUT_FIXTURES or "s3" in params.values() or item.get_closest_marker("slow"))


def pytest_collection_modifyitems(config, items):
    """Leave out the tests that start Ray or the S3 server, or are marked slow."""
    keep, drop = [], []
    for item in items:
        (drop if _left_out(item) else keep).append(item)
    if drop:
        config.hook.pytest_deselected(items=drop)
        items[:] = keep


def _name(module: str) -> str:
    return module.removesuffix(".py").replace("/", ".")


def _config(module: str, tests: list[str]) -> str:
    """pyproject.toml for one module's run: the project's own, plus mutmut's section."""
    text = (REPO / "pyproject.toml").read_text()
    return text + "\n[tool.mutmut]\n" + "\n".join([
        f"source_paths = {json.dumps(list(PACKAGES))}",
        f"only_mutate = {json.dumps([module])}",
        f"pytest_add_cli_args_test_selection = {json.dumps(tests)}",
        'pytest_add_cli_args = ["-p", "tests.mutants", "-p", "no:cacheprovider", "-x", "-q"]',
        "use_git_change_detection = false",
        # a fork server that has collected the tests but run none: a test's threads (pools,
        # lease refreshers) are never forked half-held, which hangs a forked child
        'process_isolation = "forkserver"',
        # wall limit 3 x (the covering tests' time + 60 s): a loaded machine must not pass for a hang
        "timeout_multiplier = 3.0",
        "timeout_constant = 60.0",
    ]) + "\n"


def statuses(folder: Path, module: str) -> dict[str, str]:
    """Each mutant of ``module`` and its status, from mutmut's own record of the run."""
    meta = folder / "mutants" / (module + ".meta")
    codes = json.loads(meta.read_text())["exit_code_by_key"] if meta.exists() else {}
    return {key: STATUS.get(code, "suspicious") for key, code in sorted(codes.items())}


def summary(status: dict[str, str]) -> dict:
    """Caught (killed, or hung past its time limit) out of all; the rest by status."""
    caught = sum(s in ("killed", "timeout") for s in status.values())
    rest: dict[str, list[str]] = {}
    for key, s in status.items():
        if s not in ("killed", "timeout"):
            rest.setdefault(s, []).append(key)
    return {"caught": caught, "timeout": sum(s == "timeout" for s in status.values()), "total": len(status), **rest}


def run_module(module: str, max_children: int, tests: list[str], only: list[str] | None = None,
               sample: list[str] | None = None) -> dict[str, str]:
    """Mutate ``module`` against ``tests``; ``only``: rerun just these mutants of the last run (kept);
    ``sample``: run only the mutants matching these patterns (mutmut's test timings, if any, are kept)."""
    folder = WORK / _name(module)
    if only is None and sample is None and folder.exists():
        shutil.rmtree(folder)
    folder.mkdir(parents=True, exist_ok=True)
    for name in (*PACKAGES, "tests"):
        link = folder / name
        if not link.is_symlink():
            link.symlink_to(REPO / name)
    (folder / "pyproject.toml").write_text(_config(module, tests))
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    mutmut = Path(sys.executable).parent / "mutmut"
    subprocess.run([str(mutmut), "run", "--max-children", str(max_children), *(only or sample or [])], cwd=folder,
                   env=env, check=False)
    found = statuses(folder, module)
    if sample is not None:
        return {key: s for key, s in found.items() if any(fnmatch.fnmatch(key, p) for p in sample)}
    return found if only is None else {key: found[key] for key in only}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tests.mutants", description=__doc__.split("\n\n")[0])
    parser.add_argument("modules", nargs="*", help=f"modules to mutate (default: all, in order: {', '.join(MODULES)})")
    parser.add_argument("--max-children", type=int, default=max(1, (os.cpu_count() or 2) // 2))
    parser.add_argument("--before", action="store_true",
                        help=f"leave {ALWAYS[-1]} out: the score before the tests written against survivors")
    parser.add_argument("--survivors", action="store_true",
                        help="rerun only the last run's survivors, timeouts and unfinished mutants, with today's tests")
    # one pattern per --sample (repeat it for more): a list would swallow the modules that follow it
    parser.add_argument("--sample", action="append", metavar="PATTERN",
                        help="run and score only the mutants whose names match, e.g. '*__mutmut_*1' (one in ten)")
    args = parser.parse_args(argv)
    unknown = [m for m in args.modules if m not in MODULES]
    if unknown:
        parser.error(f"unknown modules {unknown}; known: {', '.join(MODULES)}")
    scores_file = WORK / ("scores-before.json" if args.before else "scores.json")
    scores = json.loads(scores_file.read_text()) if scores_file.exists() else {}
    for module in args.modules or list(MODULES):
        tests = [*MODULES[module], *(ALWAYS[:-1] if args.before else ALWAYS)]
        last = scores.get(module, {})
        if args.survivors:
            if not last:
                last = json.loads((WORK / "scores-before.json").read_text()).get(module, {})
            again = [key for key, s in last.items() if s != "killed"]  # a timeout is checked again: load can fake one
            scores[module] = {**last, **(run_module(module, args.max_children, tests, again) if again else {})}
        else:
            scores[module] = run_module(module, args.max_children, tests, sample=args.sample)
        WORK.mkdir(exist_ok=True)
        now = json.loads(scores_file.read_text()) if scores_file.exists() else {}  # another module's run may have ended
        scores = {**now, module: scores[module]}
        scores_file.write_text(json.dumps(scores, indent=2) + "\n")
    for module, status in scores.items():
        row = summary(status)
        share = row["caught"] / row["total"] if row["total"] else 0.0
        rest = "; ".join(f"{s}: {' '.join(k)}" for s, k in row.items() if isinstance(k, list))
        print(f"{module:24} {row['caught']:4d} / {row['total']:4d} caught ({share:.0%}; {row['timeout']} by timeout)"
              f"{'; ' + rest if rest else ''}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
