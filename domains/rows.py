"""Domain rows (towns, weathers, viewpoints) and the catalogs they form.

Every parameter of a row is declared once, here, with its meaning, unit and
accepted range (``param``); the domain file loader (``domains.catalog_file``)
checks values against them and ``idda catalog show`` prints them as comments.
The rows themselves live in data: the paper's 7 towns, 3 weathers and 5
viewpoints are ``domains/catalog.toml``; a user's file adds or overrides
entries (docs/catalog.md).

A ``Catalog`` is the three tables in order. A row's place in its table is
part of every seed derived from it (``domains.catalog.Scenario.key``), so
user entries are appended after the built-in ones and an override keeps the
place of the entry it replaces.
"""

from __future__ import annotations

import json
import math
import zlib
from dataclasses import MISSING, astuple, dataclass, field, fields
from functools import cached_property

RGB = tuple[int, int, int]
AXES: tuple[str, ...] = ("town", "weather", "viewpoint")  # the order of a scenario code's parts
# The grammar of codes (domains.catalog derives every parser of scenario codes, paths and parts from it):
# a code is letters and digits, any case, any length; no "_" (joins a scenario code's parts), no "-"
# (ranges), no "*" (wildcards).
CODE_CHARS = "[A-Za-z0-9]+"
CODE_SEPARATOR = "_"


def param(meaning: str, unit: str = "", lo: float | None = None, hi: float | None = None, ordered: bool = False,
          default=MISSING):
    """A row field with its documentation: meaning, unit, inclusive range [lo, hi] (numbers, and each
    element of a tuple); ``ordered``: a (min, max) pair whose first element may not exceed the second.
    ``default``: parameters added after the first catalog have one (it leaves older entries, and run
    records that lack the key, as they were), so a file may leave them out."""
    return field(default=default, metadata={"meaning": meaning, "unit": unit, "range": (lo, hi), "ordered": ordered})


@dataclass(frozen=True)
class Town:
    code: str = param("code in scenario codes (letters and digits)")
    name: str = param("CARLA map this town stands in for")
    road_km: float = param("drivable road length; sizes the town's shards", "km", 0.1, 100.0)
    style: str = param("name of its look in render_workers.worlds.styles.STYLES")
    lanes: int = param("lanes per direction on main roads", "lanes", 1, 4)
    block_m: float = param("typical block edge length (junction spacing)", "m", 20.0, 500.0)
    building_height_m: tuple[float, float] = param("min and max building height", "m", 2.0, 200.0, ordered=True)
    building_density: float = param("share of frontage with buildings", "share", 0.0, 1.0)
    vegetation_density: float = param("trees and hedges per frontage", "share", 0.0, 1.0)
    traffic_light_share: float = param("share of junctions that are signalised", "share", 0.0, 1.0)
    railway: bool = param("has a railway")
    bridges: bool = param("has bridges")
    tunnels: bool = param("has tunnels")
    roundabouts: bool = param("has roundabouts")
    freeway: bool = param("has a freeway")
    # Dense streets (issue 34), opt-in: real streets are crowded where ours are open. Above 0: facades at the
    # pavement in a continuous, taller frontage, cars parked along the kerbs, more people on the pavement,
    # lamp posts, sign poles and street clutter instead of street trees (render_workers.worlds: buildings,
    # streets, traffic). 0 = the town as designed, byte for byte.
    street_density: float = param("how crowded its streets are: parked cars, people, poles, signs and a "
                                  "continuous frontage at the pavement (0 = as designed)", "share", 0.0, 1.0,
                                  default=0.0)

    @property
    def stream(self) -> int:
        """Stable number of the town for seeding its generators (from its code, not its position)."""
        return zlib.crc32(self.code.encode())


@dataclass(frozen=True)
class Weather:
    code: str = param("code in scenario codes (letters and digits)")
    name: str = param("CARLA weather preset it stands in for")
    sun_elevation_deg: float = param("sun height above the horizon", "deg", -90.0, 90.0)
    sun_azimuth_deg: float = param("sun direction, from +x towards +y", "deg", 0.0, 360.0)
    light_color: tuple[float, float, float] = param("linear RGB of the sun light", "gain", 0.0, 1.0)
    light_intensity: float = param("directional light intensity", "pyrender units", 0.0, 20.0)
    ambient: float = param("ambient light share", "share", 0.0, 1.0)
    sky_zenith: RGB = param("sky colour straight up", "sRGB", 0, 255)
    sky_horizon: RGB = param("sky colour at the horizon", "sRGB", 0, 255)
    cloudiness: float = param("cloud cover", "share", 0.0, 1.0)
    rain: float = param("rain streak intensity", "share", 0.0, 1.0)
    wetness: float = param("darkening and specular sheen of the road", "share", 0.0, 1.0)
    puddles: float = param("share of road covered by reflective puddles", "share", 0.0, 1.0)
    # Fog as meteorological visibility (domains.fog): the distance at which 5 % of contrast is left.
    visibility_m: float = param("meteorological visibility: the distance at which fog leaves 5 % of a dark object's "
                                "contrast against the horizon (inf: no fog)", "m", 1.0, math.inf)
    grading: tuple[float, float, float] = param("per-channel colour grading gain", "gain", 0.0, 2.0)
    marker: str = param("matplotlib marker of the weather in plots")
    # Added with fog, night and snow (issue 25); the defaults leave the paper's three weathers as they were.
    snowfall: float = param("falling snow flake intensity", "share", 0.0, 1.0, default=0.0)
    snow_cover: float = param("snow on up-facing ground, roofs and vegetation", "share", 0.0, 1.0, default=0.0)
    street_lights: float = param("street lamps and lit windows (0 = off)", "share", 0.0, 1.0, default=0.0)
    car_lights: float = param("headlights and tail lights of the ego and other cars (0 = off)", "share",
                              0.0, 1.0, default=0.0)
    # A shift inside an episode (domains.ramps): frame i is rendered under the parameters of
    # shift_from blended towards shift_to by easing(i / (frames - 1)). Written `from` and `to` in files.
    shift_from: str = param("weather the episode starts in (\"\" = no shift)", default="")
    shift_to: str = param("weather the episode ends in", default="")
    easing: str = param("how the shift runs over the episode: linear or smoothstep", default="linear")
    # Structured domain randomization (issue 34), opt-in: every class's colour scaled per channel by
    # gains drawn per episode (render_workers.render.postfx.randomize), within 1 +- 0.45 x this (up to 2).
    # 0 = the colours as designed.
    randomize: float = param("per-episode random colour of every class (0 = off, 1 = gains within 1 +- 0.45, up to 2)",
                             "strength", 0.0, 2.0, default=0.0)
    # A real camera's look (issue 34), opt-in: exposure, white balance, filmic curve and muted colour
    # (postfx.tone), then vignetting, lens blur, chromatic aberration, noise and JPEG-like compression
    # (postfx.sensor); the frame is blended towards that look by this share. 0 = the frames as before.
    camera: float = param("a real camera's tone and sensor, blended in by this share (0 = off)", "share", 0.0, 1.0,
                          default=0.0)
    # Random textures (issue 34), opt-in: every class gets a world-anchored procedural pattern and a second
    # colour drawn per episode (render_workers.render.texturefx.retexture). 0 = the surfaces as designed.
    textures: float = param("per-episode random texture of every class (0 = off)", "share", 0.0, 1.0, default=0.0)
    # Leaf clusters on tree crowns (issue 34), opt-in: world-anchored clusters, gaps and leaves over the smooth
    # crowns (render_workers.render.texturefx.foliage). 0 = the crowns as designed.
    foliage: float = param("leaf clusters and gaps on tree crowns (0 = off)", "share", 0.0, 1.0, default=0.0)
    # Ambient occlusion (issue 34), opt-in: corners, kerbs and the ground under cars darkened by how much nearer
    # their surroundings are (render_workers.render.postfx.occlusion, from depth). 0 = no occlusion.
    occlusion: float = param("screen-space ambient occlusion from depth (0 = off)", "share", 0.0, 1.0, default=0.0)
    # The drawn looks redrawn per frame (issue 34), opt-in: the camera look's exposure and white balance and
    # randomize's colours, drawn anew for this share of frames instead of once per episode
    # (render_workers.render.postfx._look_rng). 0 = one look per episode, as before.
    frame_looks: float = param("share of frames that draw their own camera exposure and random colours "
                               "(0 = one per episode)", "share", 0.0, 1.0, default=0.0)
    # Reflections on vehicles (issue 34), opt-in: glossy paint and glass mirror a world-anchored street (sky,
    # a skyline of facades, the road) by Fresnel's law, from the surface's normal and the view direction
    # (render_workers.render.texturefx.reflections). 0 = the paint as designed.
    reflections: float = param("sky, facades and road mirrored on vehicles (0 = off, 1 = Fresnel's share, up to 2)",
                               "strength", 0.0, 2.0, default=0.0)

    @property
    def precipitation(self) -> float:
        """Rain or snowfall intensity, whichever is stronger (share 0-1)."""
        return max(self.rain, self.snowfall)


@dataclass(frozen=True)
class Viewpoint:
    code: str = param("code in scenario codes (letters and digits)")
    vehicle: str = param("ego vehicle the camera is mounted on")
    camera_height_m: float = param("camera height above the road", "m", 0.3, 6.0)
    hood_fraction: float = param("share of the image covered by the hood (0 = none)", "share", 0.0, 0.5)
    hood_color: RGB = param("hood paint colour", "sRGB", 0, 255)
    hood_curvature: float = param("bulge of the hood's top edge", "image heights", 0.0, 0.5)
    hood_drop_m: float = param("hood surface below the camera", "m", 0.0, 3.0)
    ego_size_m: tuple[float, float] = param("the ego vehicle's footprint (length, width)", "m", 0.5, 25.0)
    ego_speed_mps: tuple[float, float] = param("the ego's speed range off the freeway (uniform draw per episode)",
                                               "m/s", 0.0, 40.0, ordered=True)
    hfov_deg: float = param("the camera's horizontal field of view (the hood keeps its share of the image)",
                            "degrees", 10.0, 150.0, default=90.0)

    @property
    def hood_visible(self) -> bool:
        return self.hood_fraction > 0.0


ROW_TYPES: dict[str, type] = dict(zip(AXES, (Town, Weather, Viewpoint)))


def row_dict(row) -> dict:
    """A row as JSON or TOML holds it: field name -> value, tuples as lists, in field order."""
    return {f.name: list(v) if isinstance(v, tuple) else v for f, v in zip(fields(row), astuple(row))}


@dataclass(frozen=True)
class Catalog:
    """The three domain tables, in order (``AXES``)."""

    towns: tuple[Town, ...]
    weathers: tuple[Weather, ...]
    viewpoints: tuple[Viewpoint, ...]
    layer: tuple = ()  # the rows that came from a user file, per axis: ((axis, rows), ...), recorded in run.json

    def table(self, axis: str) -> tuple:
        return (self.towns, self.weathers, self.viewpoints)[AXES.index(axis)]

    @cached_property
    def _by_code(self) -> dict[str, dict]:
        return {axis: {row.code: row for row in self.table(axis)} for axis in AXES}

    @cached_property
    def _places(self) -> dict[str, dict[str, int]]:
        return {axis: {row.code: i for i, row in enumerate(self.table(axis))} for axis in AXES}

    def by_code(self, axis: str) -> dict:
        """code -> row of one axis, in table order."""
        return self._by_code[axis]

    def place(self, axis: str, code: str) -> int:
        """The row's position in its table (part of every seed derived from it)."""
        return self._places[axis][code]

    def with_rows(self, rows: dict[str, list]) -> "Catalog":
        """This catalog with ``rows`` (axis -> rows) added: a row whose code exists replaces that
        entry in its place, any other is appended. The rows become (part of) the user layer."""
        tables, layer = [], dict(self.layer)
        for axis in AXES:
            table = list(self.table(axis))
            places = {row.code: i for i, row in enumerate(table)}
            added = {row.code: row for row in layer.get(axis, ())}
            for row in rows.get(axis, ()):
                if row.code in places:
                    table[places[row.code]] = row
                else:
                    places[row.code] = len(table)
                    table.append(row)
                added[row.code] = row
            tables.append(tuple(table))
            if added:
                layer[axis] = tuple(added.values())
        return Catalog(*tables, layer=tuple((axis, layer[axis]) for axis in AXES if axis in layer))

    def layer_dict(self) -> dict:
        """The user layer as JSON holds it (run.json, plans): axis -> list of resolved rows; {} for none."""
        return {axis: [row_dict(row) for row in rows] for axis, rows in self.layer}

    def layer_json(self) -> str:
        """The user layer as canonical JSON text ("" for none): what a job spec carries to workers."""
        layer = self.layer_dict()
        return json.dumps(layer, separators=(",", ":")) if layer else ""
