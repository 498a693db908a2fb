"""Fog as a physical quantity: meteorological visibility in metres (issue 32).

Visibility ``V`` is the distance at which fog leaves 5 % of a dark object's contrast against the
horizon (the meteorological optical range, Koschmieder's law): the extinction coefficient is
``beta = ln(20) / V`` per metre and the contrast left at a distance ``d`` is ``exp(-beta * d) =
0.05 ** (d / V)``; ``V = inf`` is air without fog. Weathers declare ``visibility_m`` and manifest rows
record it as float64 (``domains.conditions``).

Catalogs before declared fog as the share of contrast lost per 1000 m and rows recorded it as a
float32 ``fog_density``, where a dense fog such as 0.9999999999 reads 1.0. A share ``f`` is
``beta = -ln(1 - f) / 1000`` (the renderer's formula then, the share capped at 1 - 1e-12), so FG is
260 m; roots made before rules (manifests.schema.OLD_RULES) keep recording and blending the share.

A shift (domains.ramps) blends visibility in the contrast it leaves at the foggier end's
visibility, linearly: that contrast runs evenly from the clear end's to 5 %, and the contrast at
any other distance, a power of it, runs smoothly too. Blending the share linearly (the old rule)
kept the frames clear until the last one, where the share's log runs off to its end at once.
"""

from __future__ import annotations

import math

LN20 = math.log(20.0)  # -ln(0.05): the contrast threshold that defines visibility
MAX_SHARE = 1.0 - 1e-12  # the densest share per km the renderer took before (1 would leave no contrast at 0 m)


def extinction(visibility_m: float) -> float:
    """The extinction coefficient (1/m) of a visibility; 0 for no fog (``inf``)."""
    return 0.0 if math.isinf(visibility_m) else LN20 / visibility_m


def contrast_at(visibility_m: float, distance_m: float) -> float:
    """The share of contrast fog of ``visibility_m`` leaves at ``distance_m``."""
    return math.exp(-extinction(visibility_m) * distance_m)


def visibility_of_share(share: float) -> float:
    """The visibility of an old fog share per km (its extinction as the renderer computed it)."""
    beta = -math.log(1.0 - min(share, MAX_SHARE)) / 1000.0
    return math.inf if beta == 0.0 else LN20 / beta


def share_of_visibility(visibility_m: float) -> float:
    """The old fog share per km of a visibility: what roots made before rules record as fog_density."""
    return -math.expm1(-1000.0 * extinction(visibility_m))


def blend_visibility(start: float, end: float, s: float) -> float:
    """The visibility ``s`` (0-1) of the way from ``start`` to ``end``: the contrast left at the
    foggier end's visibility runs linearly between the ends' (``start`` at 0, ``end`` at 1)."""
    if s <= 0.0 or start == end:
        return start
    if s >= 1.0:
        return end
    reference = min(start, end)  # finite: the ends differ
    c0, c1 = contrast_at(start, reference), contrast_at(end, reference)
    contrast = c0 + (c1 - c0) * s
    return math.inf if contrast >= 1.0 else LN20 * reference / -math.log(contrast)


def blend_share(start: float, end: float, s: float) -> float:
    """The old rule (roots made before rules): the share per km blended linearly, as a visibility."""
    f0, f1 = share_of_visibility(start), share_of_visibility(end)
    return visibility_of_share(f0 + (f1 - f0) * s)
