"""Switch mutmut's mutants on one at a time against chosen tests, in one pytest process.

mutmut runs each mutant's covering tests in a fresh fork, after a test-timing
pass over every covering test: on a loaded machine a minute a mutant. This
runs only the tests named, collected once per mutant in one process (the
trampoline reads MUTANT_UNDER_TEST at every call): seconds a mutant.
Run it inside mutmut's copy, after ``python -m tests.mutants`` made it and
with ``tests/`` copied there (docs/mutants.md):

    cd .mutants/exports.export/mutants && cp ../../../tests/test_mutant_kills.py tests/
    ../../../.venv/bin/python ../../../tests/mutants_by_hand.py 'exports/export.py:*__mutmut_*1' \\
        tests/test_mutant_kills.py -k export

The first argument: a file of mutant names, one a line, or ``MODULE_FILE:PATTERN``
(fnmatch on mutmut's function names). Prints each mutant and "killed" or
"survived"; a clean run of the same tests must pass first.

``--renders DIR`` first: each root the tests render (``render_plan``) is rendered
once, kept in DIR and copied after, for a module rendering never calls (e.g.
``roots/verify.py``): the tests' rendered fixtures cost a copy, not seconds a mutant.
"""

from __future__ import annotations

import contextlib
import fnmatch
import hashlib
import io
import os
import re
import shutil
import sys

import pytest


def mutant_names(selection: str) -> list[str]:
    if os.path.exists(selection):
        with open(selection) as f:
            return [line.strip() for line in f if line.strip()]
    module_file, pattern = selection.split(":", 1)
    with open(module_file) as f:
        source = f.read()
    module = module_file.removesuffix(".py").replace("/", ".")
    return [f"{module}.{name}" for name in re.findall(r"^\s*def (x\S*?__mutmut_\d+)\(", source, re.M)
            if fnmatch.fnmatch(name, pattern)]


def run(name: str, args: list[str]) -> tuple[int, str]:
    """pytest's exit code with mutant ``name`` on ("" for none), and its output."""
    os.environ["MUTANT_UNDER_TEST"] = name
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        code = pytest.main(["-c", "pyproject.toml", "--rootdir=.", "-x", "-q", "-p", "no:cacheprovider", *args])
    return int(code), out.getvalue()


def _content(folder: str) -> str:
    """A digest of the files under ``folder`` (names and bytes)."""
    digest = hashlib.sha256()
    for where, dirs, files in sorted(os.walk(folder)):
        dirs.sort()
        for name in sorted(files):
            path = os.path.join(where, name)
            digest.update(os.path.relpath(path, folder).encode())
            with open(path, "rb") as f:
                digest.update(f.read())
    return digest.hexdigest()


def cache_renders(folder: str) -> None:
    """Render each (config, extend, what the root held before) once into ``folder``, copy it after."""
    sys.path.insert(0, os.getcwd())  # mutmut's copy of the packages, as pytest -c pyproject.toml imports them
    import pipeline.episode_job as episode_job

    render = episode_job.render_plan

    def render_once(storage, config, extend=False):
        root = storage.uri
        held = _content(root) if os.path.isdir(root) else None
        kept = os.path.join(folder, hashlib.sha256(repr((config, extend, held)).encode()).hexdigest()[:16])
        if not os.path.isdir(kept):
            render(storage, config, extend=extend)
            shutil.copytree(root, kept + ".tmp", symlinks=True)
            os.rename(kept + ".tmp", kept)
        else:
            shutil.copytree(kept, root, symlinks=True, dirs_exist_ok=True)

    episode_job.render_plan = render_once


def main(argv: list[str]) -> int:
    if argv[0] == "--renders":
        cache_renders(argv[1])
        argv = argv[2:]
    selection, args = argv[0], argv[1:]
    code, out = run("", args)
    if code != 0:
        sys.stdout.write(f"the clean run failed ({code}):\n{out[-3000:]}")
        return 2
    for name in mutant_names(selection):
        code, _ = run(name, args)
        print(name, {1: "killed", 0: "survived"}.get(code, f"pytest exit {code}"), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
