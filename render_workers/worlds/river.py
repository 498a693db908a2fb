"""The river: water and banks across the town, bridges' beams and railings."""

from __future__ import annotations

import numpy as np

from render_workers.worlds import meshes as M
from render_workers.worlds.builder import PALETTE, Kit
from render_workers.worlds.town_plan import CURB_H, OUTER_Z, RIVER_BANK_M

WATER_Z = -1.6  # water level


def river_channel(kit, x0, x1, ztop) -> None:
    """Water and sloped banks (facing the water) between x0 and x1, banks rising to ``ztop``."""
    yc, w = kit.lay.river
    v, f = M.grid((x0, yc - w / 2, WATER_Z), (x1 - x0, 0, 0), (0, w, 0), max(1, int((x1 - x0) / 6)), 3)
    kit.add("ground", v, f, PALETTE["water"], "water", 0.1, 5.0, tiled=True)
    for sgn in (-1, 1):
        ya, yb = yc + sgn * w / 2, yc + sgn * (w / 2 + RIVER_BANK_M)
        v, f = M.grid((x0, ya, WATER_Z), (x1 - x0, 0, 0), (0, yb - ya, ztop - WATER_Z), max(1, int((x1 - x0) / 5)), 2)
        kit.paint("terrain", v, M.orient_up(v, f), "dirt", tiled=True)


def river(kit: Kit) -> None:
    """The river outside the grid and through the blocks, and the bridges' side beams and railings."""
    lay = kit.lay
    if not lay.river:
        return
    rx0, _, rx1, _ = lay.rect
    bx0, _, bx1, _ = lay.bounds
    river_channel(kit, bx0, rx0, OUTER_Z)
    river_channel(kit, rx1, bx1, OUTER_Z)
    for x0, x1, z in kit.river_blocks():  # through the blocks between the bridges
        river_channel(kit, x0, x1, z)
    ylo, yhi = lay.river_band
    hw, sw = lay.hw, lay.sidewalk_w or lay.verge_w
    deck = CURB_H if lay.sidewalk_w else 0.02
    # each north-south street crosses on a bridge: beams + railings on both edges
    for x in lay.xs:
        for sgn in (-1, 1):
            edge = x + sgn * (hw + sw)
            kit.props_box("other", [edge - sgn * 0.2, (ylo + yhi) / 2, -1.3], [0.5, yhi - ylo, 1.3 + CURB_H], 0.0, (150, 145, 135))
            kit.fence_line(np.array([edge - sgn * 0.15, ylo]), np.array([edge - sgn * 0.15, yhi]), deck, 1.1, metal=True)
