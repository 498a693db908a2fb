"""Import arrows point one way: storage <- manifests <- render_workers <- training <- pipeline.

Checked statically (every import statement, including the ones inside
functions), so a late import cannot hide a loop. Only ``training`` and
``pipeline`` may import Ray."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
OURS = ("storage", "manifests", "render_workers", "training", "pipeline")
# what each package may import of ours (besides itself)
ALLOWED = {
    "storage": set(),
    "manifests": {"storage"},
    "render_workers": {"storage", "manifests"},
    "training": {"storage", "manifests", "render_workers"},
    "pipeline": {"storage", "manifests", "render_workers", "training"},
}
MAY_IMPORT_RAY = {"training", "pipeline"}


def imports(path: Path) -> set[str]:
    """Top-level module names imported anywhere in ``path``."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
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


def test_the_checker_sees_late_imports(tmp_path):
    path = tmp_path / "m.py"
    path.write_text("def f():\n    from pipeline import cli\n    import ray.data\n")
    assert imports(path) == {"pipeline", "ray"}
