"""The one domain-selection grammar, used by ``DOMAINS=`` and ``--domains``.

A selection is a list of clauses separated by spaces or semicolons:

* ``all`` selects the paper's 105 scenarios (the built-in catalog), also when
  a domain file is in force; ``catalog`` selects every scenario of the catalog
  in force, the built-in entries and a ``--catalog`` file's. An empty selection (``""``, or only
  spaces, commas and semicolons) is an error, never "everything": a shell
  variable that came out empty must not turn a run into all 105 scenarios.
* Scenario codes, comma-separated, e.g. ``T01_CS_A,T01_CS_J``. Any part may be
  ``*``: ``T07_HRN_*`` is the five viewpoints of T07 in hard rain.
* The built-in weathers beyond the paper (``domains.catalog.EXTRA_WEATHERS``:
  FG, NT, SN, ...) are selected only when named (``T01_FG_A``, ``weathers=NT``)
  or by ``catalog``: a ``*`` or an axis left open covers the paper's weathers and
  a domain file's, so selections written before they existed choose the same.
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

from domains.catalog import ALL_SCENARIOS, AXES, CODE_SEPARATOR, EXTRA_WEATHERS, Scenario, active, all_scenarios

# One-line help for --domains, shared by every command.
SELECTION_HELP = (
    "Scenarios to use: 'all' (the paper's 105), 'catalog' (every scenario of the catalog in force), codes like T01_CS_A (parts may be *), or filters like "
    "'towns=T01-T06 weathers=CN viewpoints=A,M'."
)

_ALIASES = {f"{axis}s": f"{axis}s" for axis in AXES} | {axis: f"{axis}s" for axis in AXES}
WHOLE_CATALOG = "catalog"  # the word that selects every scenario of the catalog in force


def _axes() -> dict[str, tuple[str, list[str]]]:
    """plural axis name -> (singular, codes in table order) of the catalog in force."""
    cat = active()
    return {f"{axis}s": (axis, list(cat.by_code(axis))) for axis in AXES}


def _canonical(item: str, codes: list[str]) -> str:
    """``item`` as spelled in the catalog (codes match whatever their case); unchanged if unknown."""
    folded = {code.upper(): code for code in codes}
    return folded.get(item.upper(), item)


def _expand_values(axis: str, text: str) -> set[str]:
    singular, codes = _axes()[axis]
    if not text:
        raise ValueError(f"empty value list for {axis}=; valid {singular}s: {', '.join(codes)}")
    chosen: set[str] = set()
    for item in text.split(","):
        item = _canonical(item.strip(), codes)
        if "-" in item:
            lo, _, hi = (_canonical(end, codes) for end in item.partition("-"))
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
    axes = _axes()
    parts = [_canonical(part, codes) for part, (_, codes) in zip(pattern.split(CODE_SEPARATOR), axes.values())]
    parts += pattern.split(CODE_SEPARATOR)[len(parts):]
    if len(parts) != len(AXES) or not all(parts):
        raise ValueError(
            f"malformed scenario code {pattern!r}; expected TOWN_WEATHER_VIEWPOINT such as T01_CS_A "
            "(parts may be *), or an axis filter such as towns=T01-T06"
        )
    for part, (axis, (singular, codes)) in zip(parts, axes.items()):
        if part != "*" and part not in codes:
            raise ValueError(
                f"unknown {singular} {part!r} in {pattern!r}; valid {singular}s: {', '.join(codes)}"
            )
    return [
        s
        for s in all_scenarios()
        if all(
            p in ("*", c) for p, c in zip(parts, (s.town.code, s.weather.code, s.viewpoint.code))
        ) and (parts[1] != "*" or s.weather.code not in EXTRA_WEATHERS)
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
        elif clause.lower() == WHOLE_CATALOG:
            from_codes = (from_codes or set()) | {s.code for s in all_scenarios()}
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
            f"empty selection {text!r}: name scenarios (e.g. T01_CS_A or towns=T01), 'all' for the paper's 105 "
            f"or '{WHOLE_CATALOG}' for every scenario of the catalog"
        )
    named = filters.get("weathers", set())
    chosen = [s for s in all_scenarios() if s.code in from_codes] if from_codes is not None else [
        s for s in all_scenarios() if s.weather.code not in EXTRA_WEATHERS or s.weather.code in named]
    axis_of = {"towns": "town", "weathers": "weather", "viewpoints": "viewpoint"}
    for axis, allowed in filters.items():
        chosen = [s for s in chosen if getattr(s, axis_of[axis]).code in allowed]
    if not chosen:
        raise ValueError(f"selection {text!r} matches no scenario")
    return chosen
