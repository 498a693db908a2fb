"""Per-frame condition columns: what weather a frame was rendered under.

Every manifest row carries six numbers (``CONDITIONS``), for every weather,
shifting or not, taken from the weather parameters the renderer used for that
frame (``domains.rows.Weather``; a shifting weather's are interpolated per
frame). ``idda query --min-condition/--max-condition NAME=VALUE`` filters on
them. Rows of roots written before the columns existed read them as null.

Fog is ``visibility_m`` (float64, domains.fog). Roots made before rules
(manifests.schema.OLD_RULES) record ``fog_density`` instead, the float32 share of
contrast lost per km they always had, and no ``visibility_m``; a query reads
their visibility from it (``with_visibility``), and a new root's fog_density is
null.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from domains.rows import Weather
from domains.fog import share_of_visibility, visibility_of_share


@dataclass(frozen=True)
class Condition:
    column: str  # manifest column
    unit: str
    meaning: str
    value: Callable[[Weather], float]  # the column's value for the weather a frame was rendered under
    dtype: str = "float32"  # the column's type in parts


def _param(name: str) -> Callable[[Weather], float]:
    return lambda weather: float(getattr(weather, name))


VISIBILITY = Condition("visibility_m", "m", "meteorological visibility: 5 % of contrast is left at this distance "
                       "(inf: no fog)", _param("visibility_m"), "float64")
CONDITIONS: tuple[Condition, ...] = (
    Condition("sun_altitude_deg", "deg", "sun height above the horizon (negative: below it, night)",
              _param("sun_elevation_deg")),
    Condition("cloudiness", "share 0-1", "cloud cover", _param("cloudiness")),
    Condition("precipitation", "share 0-1", "rain or snowfall intensity", _param("precipitation")),
    VISIBILITY,
    Condition("road_wetness", "share 0-1", "darkening and sheen of wet ground", _param("wetness")),
    Condition("snow_cover", "share 0-1", "share of up-facing ground, roofs and vegetation under snow",
              _param("snow_cover")),
)
# What roots made before rules record for fog (null in newer rows): float32, dense fogs read 1.0.
FOG_DENSITY = Condition("fog_density", "share per km 0-1", "contrast lost over 1000 m of air (roots made before "
                        "rules)", lambda weather: share_of_visibility(weather.visibility_m))
# The float32 condition columns of a part, in the order parts have always held them; visibility_m,
# added with rules, comes after every other column (manifests.schema), so no column moves.
PART_CONDITIONS: tuple[Condition, ...] = tuple(FOG_DENSITY if c is VISIBILITY else c for c in CONDITIONS)
CONDITION_BY_COLUMN = {c.column: c for c in CONDITIONS}
CONDITION_COLUMNS = tuple(c.column for c in CONDITIONS)


def frame_conditions(weather: Weather) -> dict[str, float]:
    """Every condition column of a frame rendered under ``weather`` (its parameters at that frame), the
    old fog_density too: the writer keeps those of its root's rules (manifests.writer.frame_row)."""
    return {c.column: c.value(weather) for c in (*CONDITIONS, FOG_DENSITY)}


def check_condition(name: str) -> str:
    if name == FOG_DENSITY.column:
        raise ValueError("fog is recorded as visibility_m (metres at which 5 % of contrast is left; read from "
                         "fog_density in older roots): e.g. --max-condition visibility_m=1000 for fog")
    if name not in CONDITION_BY_COLUMN:
        raise ValueError(f"unknown condition {name!r}; valid conditions: {', '.join(CONDITION_COLUMNS)}")
    return name


def with_visibility(table):
    """``table`` (manifest rows) with ``visibility_m`` read from ``fog_density`` where it is null and that
    is not (rows of roots made before rules); other rows as they are."""
    import pyarrow as pa
    import pyarrow.compute as pc

    if FOG_DENSITY.column not in table.column_names or VISIBILITY.column not in table.column_names:
        return table
    shares = table.column(FOG_DENSITY.column)
    if shares.null_count == len(table):
        return table
    derived = pa.array([None if f is None else visibility_of_share(f) for f in shares.to_pylist()], pa.float64())
    at = table.column_names.index(VISIBILITY.column)
    return table.set_column(at, VISIBILITY.column, pc.coalesce(table.column(VISIBILITY.column), derived))
