"""The one domain-selection grammar, used by ``DOMAINS=`` and ``--domains``.

A selection is a list of clauses separated by spaces or semicolons:

* ``all`` selects all 105 scenarios. An empty selection (``""``, or only
  spaces, commas and semicolons) is an error, never "everything": a shell
  variable that came out empty must not turn a run into all 105 scenarios.
* Scenario codes, comma-separated, e.g. ``T01_CS_A,T01_CS_J``. Any part may be
  ``*``: ``T07_HRN_*`` is the five viewpoints of T07 in hard rain.
* Axis filters ``towns=...``, ``weathers=...``, ``viewpoints=...`` (singular
  forms work too). Values are comma-separated codes; a range ``T01-T06``
  covers the codes between two ends in table order.

Code clauses are united; axis filters then intersect that set (or all
scenarios, when no code is given). So ``towns=T01-T06 weathers=CN
viewpoints=A,M`` is the paper's best-case pool, and ``T01_*_* viewpoints=A``
is T01 in every weather from the Audi.
"""

from __future__ import annotations

import re

from manifests.catalog import (
    ALL_SCENARIOS,
    AXES,
    AXIS_TABLES,
    CODE_SEPARATOR,
    Scenario,
)

# One-line help for --domains, shared by every command.
SELECTION_HELP = (
    "Scenarios to use: 'all', codes like T01_CS_A (parts may be *), or filters like "
    "'towns=T01-T06 weathers=CN viewpoints=A,M'."
)

_AXES = {f"{axis}s": (axis, [row.code for row in rows]) for axis, rows in AXIS_TABLES.items()}
_ALIASES = {name: name for name in _AXES} | {name[:-1]: name for name in _AXES}


def _expand_values(axis: str, text: str) -> set[str]:
    singular, codes = _AXES[axis]
    if not text:
        raise ValueError(f"empty value list for {axis}=; valid {singular}s: {', '.join(codes)}")
    chosen: set[str] = set()
    for item in text.split(","):
        item = item.strip().upper()
        if "-" in item:
            lo, _, hi = item.partition("-")
            for end in (lo, hi):
                if end not in codes:
                    raise ValueError(
                        f"unknown {singular} {end!r} in range {item!r}; valid {singular}s: {', '.join(codes)}"
                    )
            i, j = codes.index(lo), codes.index(hi)
            if i > j:
                raise ValueError(f"empty {singular} range {item!r}: {lo} comes after {hi}")
            chosen.update(codes[i : j + 1])
        elif item in codes:
            chosen.add(item)
        else:
            raise ValueError(f"unknown {singular} {item!r}; valid {singular}s: {', '.join(codes)}")
    return chosen


def _match_code(pattern: str) -> list[Scenario]:
    parts = pattern.upper().split(CODE_SEPARATOR)
    if len(parts) != len(AXES) or not all(parts):
        raise ValueError(
            f"malformed scenario code {pattern!r}; expected TOWN_WEATHER_VIEWPOINT such as T01_CS_A "
            "(parts may be *), or an axis filter such as towns=T01-T06"
        )
    for part, (axis, (singular, codes)) in zip(parts, _AXES.items()):
        if part != "*" and part not in codes:
            raise ValueError(
                f"unknown {singular} {part!r} in {pattern!r}; valid {singular}s: {', '.join(codes)}"
            )
    return [
        s
        for s in ALL_SCENARIOS
        if all(
            p in ("*", c) for p, c in zip(parts, (s.town.code, s.weather.code, s.viewpoint.code))
        )
    ]


def parse_selection(text: str) -> list[Scenario]:
    """Scenarios chosen by a selection string, in catalog order.

    Raises ValueError with one readable line for any malformed clause.
    """
    clauses = [c for c in re.split(r"[\s;]+", text.strip()) if c]
    from_codes: set[str] | None = None
    filters: dict[str, set[str]] = {}
    for clause in clauses:
        if clause.lower() == "all":
            from_codes = (from_codes or set()) | {s.code for s in ALL_SCENARIOS}
        elif "=" in clause:
            key, _, value = clause.partition("=")
            axis = _ALIASES.get(key.strip().lower())
            if axis is None:
                raise ValueError(
                    f"unknown selection axis {key!r}; valid axes: towns, weathers, viewpoints"
                )
            if axis in filters:
                raise ValueError(f"axis {axis} given twice in selection {text!r}")
            filters[axis] = _expand_values(axis, value)
        else:
            for pattern in clause.split(","):
                if pattern:
                    from_codes = (from_codes or set()) | {s.code for s in _match_code(pattern)}
    if from_codes is None and not filters:
        raise ValueError(
            f"empty selection {text!r}: name scenarios (e.g. T01_CS_A or towns=T01), or 'all' for every scenario"
        )
    chosen = [s for s in ALL_SCENARIOS if from_codes is None or s.code in from_codes]
    axis_of = {"towns": "town", "weathers": "weather", "viewpoints": "viewpoint"}
    for axis, allowed in filters.items():
        chosen = [s for s in chosen if getattr(s, axis_of[axis]).code in allowed]
    if not chosen:
        raise ValueError(f"selection {text!r} matches no scenario")
    return chosen
