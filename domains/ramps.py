"""Shifts inside an episode: a weather that runs from one condition to another (issue 25).

A weather entry with ``from`` and ``to`` (fields ``shift_from``, ``shift_to``)
and an ``easing`` renders frame ``i`` of ``n`` under the parameters of
``from`` blended towards ``to`` by ``easing(i / (n - 1))``: numbers and colours
linearly (sRGB colours rounded), so the sun sets and the sky darkens; fog thickens
evenly in the contrast it leaves (domains.fog.blend_visibility).
Its own code, name and marker stay. Built in: CNtoNT, CNtoFG, CNtoHRN. The
renderer takes each frame's weather (light, sky, post effects), and the
frame's condition columns carry its values (``domains.conditions``).
"""

from __future__ import annotations

import typing
from dataclasses import fields, replace

from domains.rows import Weather
from domains.fog import blend_share, blend_visibility

EASINGS: dict[str, typing.Callable[[float], float]] = {
    "linear": lambda x: x,
    "smoothstep": lambda x: x * x * (3.0 - 2.0 * x),
}
_KEPT = ("code", "name", "marker", "shift_from", "shift_to", "easing")  # not blended: the entry's own
_HINTS = typing.get_type_hints(Weather)


def check_shift(row: Weather, weathers: dict[str, Weather]) -> str | None:
    """Why ``row``'s shift cannot run (unknown or shifting ends, unknown easing), or None."""
    if not row.shift_from and not row.shift_to:
        return None
    for key, code in (("from", row.shift_from), ("to", row.shift_to)):
        if not code:
            return f"key {key!r}: missing: a shift names the weather it starts in ('from') and the one it ends in ('to')"
    for key, code in (("from", row.shift_from), ("to", row.shift_to)):
        end = weathers.get(code)
        if end is None:
            return f"key {key!r}: unknown weather {code!r}; valid weathers: {', '.join(weathers)}"
        if end.shift_from:
            return f"key {key!r}: {code!r} shifts itself; a shift runs between two fixed weathers"
    if row.easing not in EASINGS:
        return f"key 'easing': unknown easing {row.easing!r}; valid easings: {', '.join(EASINGS)}"
    return None


def _blend(a, b, s: float, kind):
    if typing.get_origin(kind) is tuple:
        return tuple(_blend(x, y, s, part) for x, y, part in zip(a, b, typing.get_args(kind)))
    value = a + (b - a) * s
    return int(round(value)) if kind is int else float(value)


def blend(row: Weather, start: Weather, end: Weather, s: float, old_rules: bool = False) -> Weather:
    """``row`` with every parameter (but its own code, name, marker and shift) at ``s`` from start to end:
    visibility in the contrast it leaves (domains.fog.blend_visibility); ``old_rules`` (a root made
    before rules) as its fog share per km, linearly (blend_share)."""
    changes = {f.name: _blend(getattr(start, f.name), getattr(end, f.name), s, _HINTS[f.name])
               for f in fields(Weather) if f.name not in _KEPT}
    changes["visibility_m"] = (blend_share if old_rules else blend_visibility)(start.visibility_m, end.visibility_m, s)
    return replace(row, **changes)


def weather_at(row: Weather, index: int, frames: int, lookup: typing.Callable[[str], Weather],
               old_rules: bool = False) -> Weather:
    """The weather frame ``index`` of ``frames`` is rendered under: ``row`` itself unless it shifts;
    ``old_rules``: as a root made before rules blends fog (``blend``)."""
    if not row.shift_from:
        return row
    s = EASINGS[row.easing](index / max(1, frames - 1))
    return blend(row, lookup(row.shift_from), lookup(row.shift_to), s, old_rules)
