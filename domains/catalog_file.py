"""Domain files: TOML that declares towns, weathers and viewpoints (docs/catalog.md).

A file holds arrays of tables, one per axis: ``[[town]]``, ``[[weather]]``,
``[[viewpoint]]``. Each entry has a ``code`` and the row's parameters
(``domains.rows``). ``like = "CN"`` starts from another entry's
parameters (a built-in one, or one earlier in the same file) and the keys
given override them; an entry whose code exists already overrides only the
keys it gives. Every other entry gives every parameter.

Any mistake (unknown key, value of the wrong type or out of range, unknown
``like``, duplicate code, a code with ``_`` in it) raises one CatalogError
whose message names the file, the entry and the key.
"""

from __future__ import annotations

import json
import math
import re
import tomllib
import typing
from dataclasses import MISSING, fields
from functools import lru_cache

from domains.rows import AXES, CODE_CHARS, ROW_TYPES, Catalog, row_dict
from domains.fog import visibility_of_share
from domains.ramps import check_shift

CODE_PATTERN = re.compile(CODE_CHARS)
RIG_TABLE = "rig"  # a domain file's [[rig]] tables: sensor rigs (domains.rigs), chosen with --rig  # domains.rows: the one grammar of codes
HEADER = """\
# IDDA domain catalog: towns, weathers and viewpoints (docs/catalog.md).
# Each [[town]], [[weather]] or [[viewpoint]] entry has a code and its parameters;
# a comment above each parameter gives its meaning, unit and accepted range.
"""


class CatalogError(ValueError):
    """A domain file that cannot be loaded; the message names file, entry and key."""


def _hints(cls) -> dict:
    return typing.get_type_hints(cls)


def _scalar(kind, value, where: str, unbounded: bool = False):
    if kind is bool:
        if not isinstance(value, bool):
            raise CatalogError(f"{where}: expected true or false, got {value!r}")
        return value
    if kind is str:
        if not isinstance(value, str) or not value:
            raise CatalogError(f"{where}: expected a non-empty string, got {value!r}")
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise CatalogError(f"{where}: expected a number, got {value!r}")
    if kind is int:
        if not isinstance(value, int):
            raise CatalogError(f"{where}: expected a whole number, got {value!r}")
        return value
    if not math.isfinite(value) and not (value == math.inf and unbounded):
        raise CatalogError(f"{where}: expected a finite number, got {value!r}")
    return float(value)


def coerce(f, kind, value, where: str):
    """``value`` (as TOML or JSON holds it) as field ``f`` of type ``kind`` holds it; CatalogError if it cannot."""
    lo, hi = f.metadata["range"]
    if kind is str and value == "" and f.default == "":  # an optional text parameter left empty
        return value
    if typing.get_origin(kind) is tuple:
        parts = typing.get_args(kind)
        if not isinstance(value, (list, tuple)) or len(value) != len(parts):
            raise CatalogError(f"{where}: expected a list of {len(parts)} numbers, got {value!r}")
        out = tuple(_scalar(p, v, where) for p, v in zip(parts, value))
        if f.metadata["ordered"] and out[0] > out[1]:
            raise CatalogError(f"{where}: the first value (min) exceeds the second (max): {list(out)}")
    else:
        out = _scalar(kind, value, where, unbounded=hi == math.inf)  # e.g. visibility: inf is no fog
    if lo is not None:
        for v in out if isinstance(out, tuple) else (out,):
            if not lo <= v <= hi:
                raise CatalogError(f"{where}: {v!r} is out of range [{lo}, {hi}]")
    return out


def _check_code(code, where: str, known: dict[str, str]) -> str:
    if not isinstance(code, str) or not CODE_PATTERN.fullmatch(code):
        raise CatalogError(f"{where}: key 'code': {code!r} is not a code: use letters and digits only "
                           "('_' joins the parts of a scenario code)")
    other = known.get(code.upper())
    if other is not None and other != code:
        raise CatalogError(f"{where}: key 'code': {code!r} differs from {other!r} only in case")
    return code


# Keys a file writes for fields whose names are not TOML-friendly or clear: key -> field (weathers' shifts).
# A file has one spelling, the key (the field's name is refused there); a run's record (run.json, job
# specs: Catalog.layer_dict) holds field names.
KEY_ALIASES = {"from": "shift_from", "to": "shift_to"}
_FIELD_KEYS = {name: key for key, name in KEY_ALIASES.items()}


def file_key(name: str) -> str:
    """How a domain file spells the field ``name``."""
    return _FIELD_KEYS.get(name, name)


def _file_entry(entry: dict, where: str) -> dict:
    """An entry of a file with its keys as field names; a field name that files spell otherwise is refused."""
    for key in entry:
        if key in _FIELD_KEYS:
            raise CatalogError(f"{where}: key {key!r}: write it {_FIELD_KEYS[key]!r} (a domain file's spelling)")
    return {KEY_ALIASES.get(k, k): v for k, v in entry.items()}


def resolve_entry(axis: str, entry: dict, base: dict, where: str, record: bool = False):
    """One entry of a file as a row: its ``like`` (or the existing entry of its code) overridden by its keys.
    ``record``: the entry is a run's record, keyed by field names (a file's entry: by its keys, ``file_key``)."""
    cls = ROW_TYPES[axis]
    if not record:
        entry = _file_entry(entry, where)
    hints, by_name = _hints(cls), {f.name: f for f in fields(cls)}
    if axis == "weather" and "fog" in entry:  # the key of catalogs before fog was a visibility (domains.fog)
        fog = entry["fog"]
        hint = f" = {visibility_of_share(fog):.6g}" if isinstance(fog, (int, float)) and 0 <= fog <= 1 else ""
        raise CatalogError(f"{where}: key 'fog': fog is declared as visibility_m now (metres at which 5 % of "
                           f"contrast is left): fog = {fog!r} per km is visibility_m{hint}")
    unknown = [k for k in entry if k not in by_name and k != "like"]
    if unknown:
        shown = (unknown[0] if record else file_key(unknown[0]),
                 ", ".join(by_name if record else map(file_key, by_name)))
        raise CatalogError(f"{where}: key {shown[0]!r}: unknown key; valid keys: like, {shown[1]}")
    code = entry["code"]
    start: dict = {}
    if "like" in entry:
        like = entry["like"]
        if like not in base:
            valid = ", ".join(base)
            raise CatalogError(f"{where}: key 'like': unknown {axis} {like!r}; valid {axis}s: {valid}")
        start = row_dict(base[like])
    elif code in base:
        start = row_dict(base[code])
    defaults = {name: f.default for name, f in by_name.items() if f.default is not MISSING}
    values = {**defaults, **start, **{k: v for k, v in entry.items() if k != "like"}}
    missing = [name if record else file_key(name) for name in by_name if name not in values]
    if missing:
        raise CatalogError(f"{where}: key {missing[0]!r}: missing (give every parameter, or like = an existing "
                           f"{axis}); missing: {', '.join(missing)}")
    return cls(**{name: coerce(f, hints[name], values[name], f"{where}: key {name!r}") for name, f in by_name.items()})


def rows_from_data(data: dict, base: Catalog, source: str, record: bool = False) -> dict[str, list]:
    """axis -> resolved rows of a parsed file (TOML), or of the JSON layer of a run's record (``record``)."""
    if not isinstance(data, dict):
        raise CatalogError(f"{source}: expected tables {', '.join(AXES)}")
    unknown = [k for k in data if k not in AXES and (record or k != RIG_TABLE)]  # rigs: domains.rigs reads them
    if unknown:
        raise CatalogError(f"{source}: key {unknown[0]!r}: unknown table; valid tables: "
                           + ", ".join(f"[[{a}]]" for a in AXES + (() if record else (RIG_TABLE,))))
    rows: dict[str, list] = {}
    for axis in AXES:
        entries = data.get(axis, [])
        if not isinstance(entries, list):
            raise CatalogError(f"{source}: key {axis!r}: declare entries as [[{axis}]] tables")
        known = dict(base.by_code(axis))
        seen: set[str] = set()
        folded = {code.upper(): code for code in known}
        for n, entry in enumerate(entries, 1):
            where = f"{source}: {axis} #{n}"
            if not isinstance(entry, dict) or "code" not in entry:
                raise CatalogError(f"{where}: key 'code': missing (every entry has a code)")
            code = _check_code(entry["code"], where, folded)
            where = f"{source}: {axis} {code!r}"
            if code in seen:
                raise CatalogError(f"{where}: key 'code': duplicate code {code!r} (declared twice in this file)")
            row = resolve_entry(axis, entry, known, where, record)
            if axis == "weather" and (why := check_shift(row, known)):
                raise CatalogError(f"{where}: {why}")
            seen.add(code)
            folded[code.upper()] = code
            known[code] = row
            rows.setdefault(axis, []).append(row)
    return rows


def parse_text(text: str, source: str) -> dict:
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise CatalogError(f"{source}: not valid TOML: {exc}") from None


def catalog_from_text(text: str, source: str) -> Catalog:
    """A whole catalog from one file (the built-in one): no layer beneath it."""
    rows = rows_from_data(parse_text(text, source), Catalog((), (), ()), source)
    return Catalog(*(tuple(rows.get(axis, ())) for axis in AXES))


def with_file(base: Catalog, text: str, source: str) -> Catalog:
    """``base`` with a user file's entries added or overriding (its user layer records them)."""
    return base.with_rows(rows_from_data(parse_text(text, source), base, source))


@lru_cache(maxsize=16)
def with_layer_json(base: Catalog, layer: str, source: str = "the run's catalog") -> Catalog:
    """``base`` with a recorded user layer (``Catalog.layer_json``; "" for none)."""
    if not layer:
        return base
    return base.with_rows(rows_from_data(current_layer(json.loads(layer)), base, source, record=True))


def current_layer(layer):
    """A recorded user layer (run.json's "catalog", a dict) in today's keys: a weather's ``fog`` share per
    km, as runs recorded it before fog was a visibility, becomes its ``visibility_m`` (domains.fog)."""
    if not isinstance(layer, dict) or not isinstance(layer.get("weather"), list):
        return layer
    weathers = [{("visibility_m" if k == "fog" else k): (visibility_of_share(v) if k == "fog" else v)
                 for k, v in entry.items()} if isinstance(entry, dict) and "fog" in entry else entry
                for entry in layer["weather"]]
    return {**layer, "weather": weathers}


# --------------------------------------------------------------------------
# Writing: the resolved catalog as TOML with a comment per parameter
# --------------------------------------------------------------------------
def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return json.dumps(value)  # a TOML basic string
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    return repr(value)  # float repr round-trips, and always has '.' or 'e'


def _comment(f) -> str:
    meta = f.metadata
    parts = [meta["meaning"]]
    if meta["unit"]:
        parts.append(meta["unit"])
    lo, hi = meta["range"]
    if lo is not None:
        parts.append(f"range {lo} to {hi}" + (", min <= max" if meta["ordered"] else ""))
    if f.default is not MISSING:
        parts.append(f"default {f.default}")
    return "# " + "; ".join(parts)


def catalog_toml(catalog: Catalog) -> str:
    """The resolved catalog as a domain file: every entry with every parameter, each under its comment."""
    out = [HEADER]
    for axis in AXES:
        for row in catalog.table(axis):
            out.append(f"[[{axis}]]")
            for f in fields(row):
                out.append(_comment(f))
                out.append(f"{file_key(f.name)} = {_toml_value(getattr(row, f.name))}")
            out.append("")
    return "\n".join(out)
