"""The railway: ballast bed, rails, sleepers, fences and catenary poles along the town."""

from __future__ import annotations

import numpy as np

from render_workers.worlds import meshes as M
from render_workers.worlds.builder import PALETTE, Kit
from render_workers.worlds.town_plan import OUTER_Z


def railway(kit: Kit) -> None:
    lay = kit.lay
    if lay.railway_y is None:
        return
    y = lay.railway_y
    x0, _, x1, _ = lay.bounds
    x0, x1 = x0 + 5, x1 - 5
    # ballast bed
    v, f = M.grid((x0, y - 2.2, 0.25), (x1 - x0, 0, 0), (0, 4.4, 0), int((x1 - x0) / 5), 3)
    kit.add("railway", v, f, PALETTE["ballast"], amount=0.2, scale=1.0, tiled=True)
    for sgn in (-1, 1):
        yy = y + sgn * 2.2
        p0 = np.array([x0, yy, OUTER_Z]) if sgn < 0 else np.array([x1, yy, OUTER_Z])
        u = np.array([x1 - x0, 0, 0]) * (1 if sgn < 0 else -1)
        v, f = M.quads(p0, u, np.array([0, 0, 0.5]))
        kit.add("railway", v, f, PALETTE["ballast"], amount=0.2, tiled=True)
        v, f = M.grid((x0, y + sgn * 0.75 - 0.04, 0.25), (x1 - x0, 0, 0), (0, 0.08, 0), int((x1 - x0) / 40), 1)
        cuts = np.linspace(x0, x1, int((x1 - x0) / 40) + 2)
        cen = np.stack([(cuts[:-1] + cuts[1:]) / 2, np.full(len(cuts) - 1, y + sgn * 0.75), np.full(len(cuts) - 1, 0.25)], 1)
        size = np.stack([np.diff(cuts), np.full(len(cuts) - 1, 0.08), np.full(len(cuts) - 1, 0.16)], 1)
        v2, f2 = M.boxes(cen, size)
        kit.add("railway", v2, f2, PALETTE["rail"], "metal", 0.05, tiled=True)
        kit.fence_line(np.array([x0, y + sgn * 6.0]), np.array([x1, y + sgn * 6.0]), OUTER_Z, 1.8, metal=True)
    s = np.arange(x0 + 1, x1 - 1, 1.5)
    p = np.stack([s, np.full_like(s, y), np.full_like(s, 0.25)], 1)
    v, f = M.boxes(p, np.array([[0.25, 2.4, 0.1]]))
    kit.add_colored("railway", v, f, M.noisy_colors(v, PALETTE["sleeper"], 0.1, 1.0, 3), tiled=True)
    # catenary poles
    s = np.arange(x0 + 10, x1 - 10, 45.0)
    for sx in s:
        kit.pole_with([sx, y + 3.2, OUTER_Z], 7.0, 0.12)
