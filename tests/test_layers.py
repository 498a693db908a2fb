"""Import arrows point one way, package by package (the floors of docs/house.md):

    storage <- domains <- outputs <- manifests <- roots <- render_workers (worlds <- render)
        <- exports, analysis <- pipeline <- reports

Checked statically (every import statement, including the ones inside
functions), so a late import cannot hide a loop; no modules import each other
in a circle, late imports included, and few imports are left inside functions.
Only ``pipeline`` and the consumer layer ``analysis`` (``ray_dataset``) may
import Ray; ``render_workers`` imports no Ray, and its ``worlds`` imports
neither GL nor the renderer, and of ours only ``domains``."""

from __future__ import annotations

import ast
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# The floors, bottom to top; a package imports only from the floors below its own.
FLOORS = (("storage",), ("domains",), ("outputs",), ("manifests",), ("roots",), ("render_workers",),
          ("exports", "analysis"), ("pipeline",), ("reports",))
OURS = tuple(package for floor in FLOORS for package in floor)
# what each package may import of ours (besides itself): every package of the floors below
ALLOWED = {package: {p for lower in FLOORS[:level] for p in lower}
           for level, floor in enumerate(FLOORS) for package in floor}
MAX_DEFERRED = 40  # imports of our modules inside functions (issue 36: 207 before; docs/house.md lists them)
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
        # the world cache's digest covers render_workers/worlds/ and domains/: nothing else of ours may shape a world
        bad += sorted(n for n in imports(path) if n in OURS and n not in ("render_workers", "domains"))
        wrong += [f"{path.relative_to(ROOT)} imports {n}" for n in bad]
    assert not wrong, "\n".join(wrong)


def test_the_floors_are_the_packages():
    """Every top-level package of ours is on a floor (a new one must be placed), and pyproject ships each."""
    packages = {p.parent.name for p in ROOT.glob("*/__init__.py")} - {"tests", "benchmarks"}
    assert packages == set(OURS)
    include = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]["find"]["include"]
    assert {name.rstrip("*") for name in include} == set(OURS) - {"reports"}


def test_no_import_circles():
    """No modules import each other, directly or round a loop, imports inside functions included."""
    from reports import house

    assert house.circles() == []


def test_few_imports_inside_functions():
    """Imports of our modules sit at the top of the module; the few left inside functions (optional heavy
    dependencies on the way, the Ray worker's light module) stay under MAX_DEFERRED. Benchmarks are counted
    apart: their probes run inside another revision's tree and import it there."""
    from reports import house

    late = house.deferred()
    assert len(late) < MAX_DEFERRED, "\n".join(f"{i.importer}:{i.line} imports {i.imported}" for i in late)


def test_the_checker_sees_circles_and_deferred_imports(tmp_path):
    from reports import house

    for name, text in {"storage/__init__.py": "", "storage/a.py": "from storage.b import x\n",
                       "storage/b.py": "def f():\n    from storage import a\n"}.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(text)
    found = house.imports(tmp_path)
    assert house.circles(found) == [["storage.a", "storage.b"]]
    assert [(i.importer, i.imported) for i in house.deferred(found)] == [("storage.b", "storage.a")]
    assert house.deferred(found, benchmarks=True) == []


def test_the_house_has_the_stage_packages():
    for package in ("domains", "outputs", "roots", "render_workers/worlds", "render_workers/render", "exports",
                    "analysis", "reports", "pipeline/cli"):
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
    assert page == house.markdown(house.edges(), house.imports()), "docs/house.md is stale: run `python -m reports.house`"
    assert (ROOT / "docs" / "images" / "house.png").stat().st_size > 10_000
