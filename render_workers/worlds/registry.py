"""The world builders by name, in a module light enough for the driver to
validate ``--world`` without importing the renderer, trimesh or scipy."""

from __future__ import annotations

# World builders by name: the modules providing build_world(town_code, seed) and
# populate(world, viewpoint_code, episode_seed). Imported on first use.
WORLDS: dict[str, tuple[str, str]] = {
    "procedural": ("render_workers.worlds.world", "render_workers.worlds.traffic"),
    "test": ("render_workers.worlds.testworld", "render_workers.worlds.testworld"),
}
DEFAULT_WORLD = "procedural"


def check_world(name: str) -> None:
    """ValueError naming the valid worlds unless ``name`` is registered."""
    if name not in WORLDS:
        raise ValueError(f"unknown world {name!r}; valid worlds: {', '.join(WORLDS)}")
