"""The river: water and banks across the town, bridges' beams and railings."""

from __future__ import annotations

import numpy as np

from render_workers import meshes as M
from render_workers.kit import PALETTE, Kit
from render_workers.town_plan import CURB_H, OUTER_Z


def river_channel(kit, x0, x1, ztop) -> None:
    yc, w = kit.lay.river
    zw = -1.6
    bank = 3.0
    v, f = M.grid((x0, yc - w / 2, zw), (x1 - x0, 0, 0), (0, w, 0), max(1, int((x1 - x0) / 6)), 3)
    kit.add("ground", v, f, PALETTE["water"], "water", 0.1, 5.0, tiled=True)
    for sgn in (-1, 1):  # sloped banks, facing the water
        ya, yb = yc + sgn * w / 2, yc + sgn * (w / 2 + bank)
        v, f = M.grid((x0, ya, zw), (x1 - x0, 0, 0), (0, yb - ya, ztop - zw), max(1, int((x1 - x0) / 5)), 2)
        kit.paint("terrain", v, M.orient_up(v, f), "dirt", tiled=True)


def river(kit: Kit) -> None:
    """The river outside the grid, and the bridges' side beams and railings."""
    lay = kit.lay
    if not lay.river:
        return
    yc, w = lay.river
    rx0, _, rx1, _ = lay.rect
    bx0, _, bx1, _ = lay.bounds
    river_channel(kit, bx0, rx0, OUTER_Z)
    river_channel(kit, rx1, bx1, OUTER_Z)
    for x0, x1, z in kit.river_blocks():  # through the blocks between the bridges
        river_channel(kit, x0, x1, z)
    ylo, yhi = yc - w / 2 - 3.0, yc + w / 2 + 3.0
    hw, sw = lay.hw, lay.sidewalk_w or lay.verge_w
    # each north-south street crosses on a bridge: beams + railings on both edges
    for i, x in enumerate(lay.xs):
        for sgn in (-1, 1):
            edge = x + sgn * (hw + sw)
            kit.props_box("other", [edge - sgn * 0.2, (ylo + yhi) / 2, -1.3], [0.5, yhi - ylo, 1.3 + CURB_H], 0.0, (150, 145, 135))
            kit.fence_line(np.array([edge - sgn * 0.15, ylo]), np.array([edge - sgn * 0.15, yhi]), CURB_H if lay.sidewalk_w else 0.02, 1.1, metal=True)
