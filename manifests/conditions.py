"""Per-frame condition columns: what weather a frame was rendered under.

Every manifest row carries six numbers (``CONDITIONS``), for every weather,
shifting or not, taken from the weather parameters the renderer used for that
frame (``manifests.domains.Weather``; a shifting weather's are interpolated per
frame). ``idda query --min-condition/--max-condition NAME=VALUE`` filters on
them. Rows of roots written before the columns existed read them as null.
"""

from __future__ import annotations

from dataclasses import dataclass

from manifests.domains import Weather


@dataclass(frozen=True)
class Condition:
    column: str  # manifest column
    unit: str
    meaning: str
    source: str  # the Weather parameter it reports

    def value(self, weather: Weather) -> float:
        return float(getattr(weather, self.source))


CONDITIONS: tuple[Condition, ...] = (
    Condition("sun_altitude_deg", "deg", "sun height above the horizon (negative: below it, night)",
              "sun_elevation_deg"),
    Condition("cloudiness", "share 0-1", "cloud cover", "cloudiness"),
    Condition("precipitation", "share 0-1", "rain or snowfall intensity", "precipitation"),
    Condition("fog_density", "share per km 0-1", "contrast lost over 1000 m of air", "fog"),
    Condition("road_wetness", "share 0-1", "darkening and sheen of wet ground", "wetness"),
    Condition("snow_cover", "share 0-1", "share of up-facing ground, roofs and vegetation under snow", "snow_cover"),
)
CONDITION_BY_COLUMN = {c.column: c for c in CONDITIONS}
CONDITION_COLUMNS = tuple(c.column for c in CONDITIONS)


def frame_conditions(weather: Weather) -> dict[str, float]:
    """The condition columns of a frame rendered under ``weather`` (its parameters at that frame)."""
    return {c.column: c.value(weather) for c in CONDITIONS}


def check_condition(name: str) -> str:
    if name not in CONDITION_BY_COLUMN:
        raise ValueError(f"unknown condition {name!r}; valid conditions: {', '.join(CONDITION_COLUMNS)}")
    return name
