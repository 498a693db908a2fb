"""The world builders' names, in a module light enough for the driver and the CLI to
validate ``--world`` without importing the builders (trimesh, scipy). The builders
themselves are bound by import in ``render_workers.render.episode`` (``BUILDERS``:
``build_world(town_code, seed)`` and ``populate(world, viewpoint_code, episode_seed)``
per name); a test checks that both name the same worlds."""

from __future__ import annotations

WORLDS: tuple[str, ...] = ("procedural", "test")
DEFAULT_WORLD = "procedural"


def check_world(name: str) -> None:
    """ValueError naming the valid worlds unless ``name`` is registered."""
    if name not in WORLDS:
        raise ValueError(f"unknown world {name!r}; valid worlds: {', '.join(WORLDS)}")
