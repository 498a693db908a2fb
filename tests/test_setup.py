"""A new user's first hour: the lean set-up and the documentation's links.
(The install line `idda shifts` gives without torch: tests/test_shifts.py.)"""

from __future__ import annotations

import re
import shutil
import subprocess
import tomllib
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

# What producing never needs: the test extra's heavy or test-only packages.
NOT_FOR_PRODUCING = ("torch", "polars", "duckdb", "moto", "boto3", "pytest", "hypothesis", "datasets",
                     "huggingface_hub", "pycocotools", "pandas", "webdataset", "rerun_sdk")


def _name(requirement: str) -> str:
    return re.split(r"[\s\[<>=!~;]", requirement, maxsplit=1)[0].lower().replace("-", "_")


def _project() -> dict:
    return tomllib.loads((REPO / "pyproject.toml").read_text())["project"]


def test_base_dependencies_are_what_producing_and_evaluating_need():
    base = {_name(r) for r in _project()["dependencies"]}
    assert not base & set(NOT_FOR_PRODUCING), base & set(NOT_FOR_PRODUCING)
    assert "cityscapesscripts" in base  # idda evaluate right after make produce
    test = {_name(r) for r in _project()["optional-dependencies"]["test"]}
    assert {"torch", "polars", "duckdb", "moto", "datasets", "webdataset", "rerun_sdk"} <= test
    assert [_name(r) for r in _project()["optional-dependencies"]["view"]] == ["rerun_sdk"]
    assert _project()["optional-dependencies"]["analysis"] == ["torch==2.13.0"]


def _make_dry_run(target: str, venv: Path) -> str:
    done = subprocess.run(["make", "-n", f"VENV={venv}", target], cwd=REPO, capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 0, done.stderr
    return done.stdout


@pytest.mark.skipif(shutil.which("make") is None, reason="needs make")
def test_make_produce_installs_the_base_and_make_test_adds_the_extras(tmp_path):
    venv = tmp_path / "venv"
    fresh = _make_dry_run("produce", venv)
    assert "pip install --quiet -e ." in fresh and "[test]" not in fresh and "idda produce" in fresh
    assert fresh.index("pip install --quiet -e .") < fresh.index("-m compileall") < fresh.index("idda produce")
    # After make produce (its stamp newer than pyproject.toml), make test adds only the extras.
    venv.mkdir()
    (venv / ".installed-produce").touch()
    after_produce = _make_dry_run("test", venv)
    assert "pip install --quiet -e '.[test]'" in after_produce and "-m venv" not in after_produce
    assert "pytest" in after_produce
    (venv / ".installed-test").touch()
    assert "pip install" not in _make_dry_run("test", venv)  # both stamps: nothing to install
    assert _make_dry_run("test", venv).index("-m compileall") < _make_dry_run("test", venv).index("-m pytest")
    assert "pip install" not in _make_dry_run("produce", venv)


@pytest.mark.skipif(shutil.which("make") is None, reason="needs make")
def test_make_mutants_installs_its_extra_and_make_test_never_runs_it(tmp_path):
    from tests.mutants import ALWAYS, DATA_PROTECTING, MODULES

    venv = tmp_path / "venv"
    venv.mkdir()
    (venv / ".installed-produce").touch()
    (venv / ".installed-test").touch()
    test = _make_dry_run("test", venv)
    assert "mutmut" not in test and "tests.mutants" not in test and "mutants]" not in test
    mutants = _make_dry_run("mutants", venv)
    assert "pip install --quiet -e '.[test,mutants]'" in mutants and "python -m tests.mutants" in mutants
    assert [_name(r) for r in _project()["optional-dependencies"]["mutants"]] == ["mutmut"]
    assert set(MODULES) == set(DATA_PROTECTING)  # every data-protecting module has its fast tests
    for module, tests in MODULES.items():
        assert (REPO / module).is_file() and all((REPO / t).is_file() for t in (*tests, *ALWAYS)), module



@pytest.mark.parametrize("argv", [["--sample", "*__mutmut_*1", "roots/lease.py"],
                                  ["roots/lease.py", "--sample", "*__mutmut_*1"]])
def test_a_sampled_mutants_run_runs_the_module_named_alone(monkeypatch, tmp_path, argv):
    """`--sample PATTERN module` (as docs/mutants.md writes it) mutates that module
    alone: the pattern never swallows the module, which ran every module for hours."""
    from tests import mutants

    ran = []
    monkeypatch.setattr(mutants, "WORK", tmp_path)
    monkeypatch.setattr(mutants, "run_module", lambda module, children, tests, only=None, sample=None:
                        ran.append((module, sample)) or {})
    assert mutants.main(argv) == 0
    assert ran == [("roots/lease.py", ["*__mutmut_*1"])]

# ------------------------------------------------------------------ docs ----
_LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")


def _slug(heading: str) -> str:
    """GitHub's anchor for a markdown heading."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def _anchors(path: Path) -> set[str]:
    return {_slug(line.lstrip("#")) for line in path.read_text().splitlines() if line.startswith("#")}


def _documents() -> list[Path]:
    return [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]


def test_every_relative_link_in_the_docs_points_to_a_file_and_heading():
    checked = 0
    for doc in _documents():
        in_code = False
        for line in doc.read_text().splitlines():
            if line.startswith("```"):
                in_code = not in_code
            if in_code:
                continue
            for target in _LINK.findall(line):
                if re.match(r"[a-z]+:", target):  # http:, https:, mailto:
                    continue
                rel, _, anchor = target.partition("#")
                path = (doc.parent / rel).resolve() if rel else doc
                assert path.exists(), f"{doc.relative_to(REPO)} links to missing {target}"
                if anchor:
                    assert anchor in _anchors(path), f"{doc.relative_to(REPO)} links to missing heading {target}"
                checked += 1
    assert checked >= 10  # the README's table of pages alone has ten


def test_readme_is_one_screen_and_links_every_docs_page():
    readme = (REPO / "README.md").read_text()
    assert len(readme.splitlines()) <= 100
    for page in sorted((REPO / "docs").glob("*.md")):
        if not page.name.startswith("bench_") and not page.name.startswith("notes-"):
            assert f"(docs/{page.name})" in readme, page.name
    for needed in ("make produce", "make test", "output/", "idda evaluate", "docs/images/contact_sheet_CN.png"):
        assert needed in readme, needed


def test_the_byte_code_step_compiles_every_package_of_the_project():
    """`make` compiles the sources it runs (PY_DIRS): every package pyproject.toml ships is among them."""
    import re

    dirs = re.search(r"^PY_DIRS := (.*)$", (REPO / "Makefile").read_text(), re.M).group(1).split()
    assert all((REPO / d / "__init__.py").is_file() for d in dirs)
    shipped = [p.rstrip("*") for p in tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]["find"]["include"]]
    assert set(shipped) <= set(dirs)
