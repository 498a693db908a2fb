"""Procedural towns: one data-driven builder for all seven IDDA towns.

``build_world(town_code, seed)`` reads the town's row in
``domains.catalog.TOWNS`` and its style row in ``STYLES``, lays out the plan
(``render_workers.worlds.town_plan``) and runs the features in :data:`FEATURES` over
one :class:`~render_workers.worlds.builder.Kit`. Each feature is a function of the kit in
its own module and decides from the plan and the style whether it applies
(a freeway only where the plan has one, farmland only without sidewalks...);
nothing here or there reads a town's code. A new town is a catalog row (and
a style row); a new kind of thing is a feature module added to the list.

Static geometry is merged into one Part per (200 m tile, class, material).
The ``World`` carries the lane loops, zebra crossings and walking lanes that
``render_workers.worlds.traffic`` populates.
"""

from __future__ import annotations


import numpy as np

from domains.catalog import Town, town as town_row
from render_workers.worlds import buildings, countryside, freeway, railway, river, streets
from render_workers.worlds.builder import Kit
from render_workers.worlds.scene import World
from render_workers.worlds.styles import look
from render_workers.worlds.textures import TEXTURE_MEAN, town_textures
from render_workers.worlds.town_plan import Layout, crosswalks, layout, loops, plan, walk_lanes, walkways

__all__ = ["FEATURES", "build_town", "build_world", "building_footprints", "class_albedo", "layout", "plan"]

# In order: later features may sit on earlier ones (furniture on sidewalks).
FEATURES = (
    streets.streets,
    streets.sidewalks,
    buildings.town_blocks,
    buildings.outer_row,  # dense streets only
    countryside.farmland_blocks,
    streets.furniture,
    river.river,
    freeway.freeway,
    railway.railway,
    countryside.outskirts,
)


def _built(t: Town, seed: int):
    """The town's merged parts, building footprints and luminaires (not cached here:
    ``render_workers.render.episode.cached_world`` is the process's one world cache)."""
    kit = Kit(plan(t, seed))
    for feature in FEATURES:
        feature(kit)
    return kit.batch.parts(), tuple(kit.buildings), np.array(kit.lights, dtype=np.float64).reshape(-1, 3)


def building_footprints(town_code: str, seed: int) -> np.ndarray:
    """(N, 5) building footprints: centre x, y, size along, size across, yaw."""
    return np.array(_built(town_row(town_code), seed)[1], dtype=np.float64).reshape(-1, 5)


def build_town(t: Town, seed: int) -> World:
    """A town row's static geometry, lanes and walkways, deterministic from ``seed``."""
    lay: Layout = plan(t, seed)
    parts, _, lights = _built(t, seed)
    lane_loops = loops(lay)
    return World(
        town=t.code,
        seed=seed,
        static=parts,
        lanes=tuple(loop.path for loop in lane_loops),
        walkways=walkways(lay),
        bounds=lay.bounds,
        loops=lane_loops,
        crosswalks=crosswalks(lay),
        walk_lanes=walk_lanes(lay),
        textures=town_textures(look(t), seed, t.stream),
        lights=lights,
        street_density=t.street_density,
    )


def build_world(town_code: str, seed: int) -> World:
    """The catalog town ``town_code``'s world."""
    return build_town(town_row(town_code), seed)


def class_albedo(world: World) -> dict[int, np.ndarray]:
    """Each class's mean albedo (sRGB 0-255) over its static surface, weighted by
    triangle area, textures counted at their mean: how a town looks class by
    class, the statistic its style is told apart by (towns that share a class's
    colours share its look to a segmentation network)."""
    sums: dict[int, np.ndarray] = {}
    areas: dict[int, float] = {}
    for part in world.static:
        mesh = part.mesh
        face_rgb = mesh.visual.vertex_colors[:, :3].astype(np.float64)[mesh.faces].mean(axis=1)
        area = mesh.area_faces
        rgb = (face_rgb * area[:, None]).sum(axis=0) * (TEXTURE_MEAN if part.texture else 1.0)
        sums[part.class_id] = sums.get(part.class_id, 0.0) + rgb
        areas[part.class_id] = areas.get(part.class_id, 0.0) + float(area.sum())
    return {c: sums[c] / areas[c] for c in sorted(sums) if areas[c] > 0}
