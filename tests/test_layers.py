"""Import arrows point one way, package by package:

    storage <- manifests <- render_workers (worlds <- render) <- exports, analysis <- pipeline <- reports

Checked statically (every import statement, including the ones inside
functions), so a late import cannot hide a loop. Only ``pipeline`` and the
consumer layer ``analysis`` (``ray_dataset``) may import Ray; ``render_workers``
imports no Ray, and its ``worlds`` imports neither GL nor the renderer."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
OURS = ("storage", "manifests", "render_workers", "exports", "analysis", "pipeline", "reports")
# what each package may import of ours (besides itself)
ALLOWED = {
    "storage": set(),
    "manifests": {"storage"},
    "render_workers": {"storage", "manifests"},
    "exports": {"storage", "manifests", "render_workers"},
    "analysis": {"storage", "manifests", "render_workers"},
    "pipeline": {"storage", "manifests", "render_workers", "exports", "analysis"},
    "reports": {"storage", "manifests", "render_workers", "exports", "analysis", "pipeline"},
}
MAY_IMPORT_RAY = {"analysis", "pipeline", "reports"}
GL = {"pyrender", "OpenGL", "pyglet"}


def imports(path: Path, depth: int = 1) -> set[str]:
    """Module names (their first ``depth`` parts) imported anywhere in ``path``."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names.update(".".join(alias.name.split(".")[:depth]) for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            module = node.module.split(".")
            names.add(".".join(module[:depth]))
            if len(module) < depth:  # from render_workers import render
                names.update(".".join([*module, alias.name][:depth]) for alias in node.names)
    return names


@pytest.mark.parametrize("package", OURS)
def test_imports_point_one_way(package):
    wrong = []
    for path in sorted((ROOT / package).rglob("*.py")):
        for name in imports(path):
            if name in OURS and name != package and name not in ALLOWED[package]:
                wrong.append(f"{path.relative_to(ROOT)} imports {name}")
            if name == "ray" and package not in MAY_IMPORT_RAY:
                wrong.append(f"{path.relative_to(ROOT)} imports ray")
    assert not wrong, "\n".join(wrong)


def test_worlds_import_no_gl_and_no_renderer():
    wrong = []
    for path in sorted((ROOT / "render_workers" / "worlds").rglob("*.py")):
        found = imports(path, depth=2) | imports(path)
        bad = sorted(n for n in found if n.split(".")[0] in GL or n == "render_workers.render")
        wrong += [f"{path.relative_to(ROOT)} imports {n}" for n in bad]
    assert not wrong, "\n".join(wrong)


def test_the_house_has_the_stage_packages():
    for package in ("render_workers/worlds", "render_workers/render", "exports", "analysis", "reports", "pipeline/cli"):
        assert (ROOT / package / "__init__.py").is_file(), package
    assert not (ROOT / "training").exists()


def test_the_checker_sees_late_imports(tmp_path):
    path = tmp_path / "m.py"
    path.write_text("def f():\n    from pipeline import cli\n    import ray.data\n    from render_workers import render\n")
    assert imports(path) == {"pipeline", "ray", "render_workers"}
    assert "render_workers.render" in imports(path, depth=2)


def test_the_house_page_matches_the_code():
    """docs/house.md's graph is the code's (regenerate with `python -m reports.house`)."""
    from reports import house

    page = (ROOT / "docs" / "house.md").read_text()
    assert page == house.markdown(house.edges()), "docs/house.md is stale: run `python -m reports.house`"
    assert (ROOT / "docs" / "images" / "house.png").stat().st_size > 10_000
