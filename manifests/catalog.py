"""The dataset's vocabulary: classes, towns, weathers and viewpoints.

Each axis is one table of frozen rows. Everything else (palettes, lookup
tables, Cityscapes maps, scenario codes, the manifest's column names) is
derived from these tables, so nothing else in the code base hard-codes an id.

Sources: the IDDA paper (classes, towns T01/T02, weathers, viewpoints) and
CARLA / cityscapesScripts conventions, as collected in ``shared/REFERENCE.md``.
Values the paper does not give (T03-T07 road lengths, sun angles, hood shapes)
are our documented assumptions; see ``docs/assumptions.md``.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass
from functools import cached_property
from typing import Iterable

import numpy as np

RGB = tuple[int, int, int]

# The axes of a scenario, in the order of its code ``<town>_<weather>_<viewpoint>``
# (e.g. T01_CS_A) and of the manifest's hive partitions. The code is parsed by
# split_code and formatted by format_code, and nowhere else.
AXES: tuple[str, ...] = ("town", "weather", "viewpoint")
CODE_SEPARATOR = "_"


def lookup(table: dict, key: str, what: str, plural: str | None = None):
    """``table[key]``; an unknown key raises ValueError naming the valid keys."""
    try:
        return table[key]
    except KeyError:
        valid = ", ".join(table)
        raise ValueError(f"unknown {what} {key!r}; valid {plural or what + 's'}: {valid}") from None


# --------------------------------------------------------------------------
# Classes
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class Label:
    id: int  # IDDA class id, stored in the red channel of semantic_raw
    name: str  # human-readable name, unique
    color: RGB  # colour in semantic_color (paper's Fig. "pixeldistr")
    evaluated: bool  # False for the paper's excluded classes (*)
    cityscapes_id: int  # Cityscapes label id written by the cityscapes export
    train_id: int  # Cityscapes trainId (255 = ignored in training/eval)
    instances: bool = False  # objects of this class get instance ids, boxes and a count column

    @property
    def column(self) -> str:
        """Manifest column holding this class's per-frame pixel count."""
        return "px_" + self.name.replace(" ", "_")

    @property
    def object_column(self) -> str:
        """Manifest column holding this class's per-frame count of visible objects."""
        return "obj_" + self.name.replace(" ", "_")


LABELS: tuple[Label, ...] = (
    #     id  name             colour            eval   cs_id  trainId  instances
    Label(0, "unlabeled", (0, 0, 0), False, 0, 255),
    Label(1, "building", (70, 70, 70), True, 11, 2),
    Label(2, "fence", (190, 153, 153), True, 13, 4),
    Label(3, "other", (72, 0, 90), False, 0, 255),
    Label(4, "pedestrian", (220, 20, 60), True, 24, 11, True),
    Label(5, "pole", (153, 153, 153), True, 17, 5),
    Label(6, "road line", (157, 234, 50), False, 0, 255),
    Label(7, "road", (128, 64, 128), True, 7, 0),
    Label(8, "sidewalk", (244, 35, 232), True, 8, 1),
    Label(9, "vegetation", (107, 142, 35), True, 21, 8),
    Label(10, "vehicle", (0, 0, 142), True, 26, 13, True),
    Label(11, "wall", (102, 102, 156), True, 12, 3),
    Label(12, "traffic sign", (220, 220, 0), True, 20, 7, True),
    Label(13, "traffic light", (250, 170, 30), True, 19, 6, True),
    Label(14, "guard rail", (180, 165, 180), False, 14, 255),
    Label(15, "dynamic", (111, 74, 0), False, 5, 255),
    Label(16, "bicycle", (119, 11, 32), True, 33, 18, True),
    Label(17, "motorcycle", (0, 0, 230), True, 32, 17, True),
    Label(18, "rider", (255, 0, 0), True, 25, 12, True),
    Label(19, "terrain", (152, 251, 152), True, 22, 9),
    Label(20, "sky", (70, 130, 180), True, 23, 10),
    Label(21, "railway", (230, 150, 140), False, 10, 255),
    Label(22, "ground", (81, 0, 81), False, 6, 255),
    Label(23, "static", (0, 0, 0), False, 4, 255),
)

NUM_CLASSES = len(LABELS)
NAME2LABEL = {label.name: label for label in LABELS}
CLASS_IDS = {label.name: label.id for label in LABELS}  # class name -> id
EVALUATED_IDS = tuple(label.id for label in LABELS if label.evaluated)
INSTANCE_LABELS = tuple(label for label in LABELS if label.instances)

# uint8 palette: PALETTE[class_id] -> RGB colour.
PALETTE = np.array([label.color for label in LABELS], dtype=np.uint8)
# Lookup tables from IDDA id to Cityscapes label id / trainId (256 entries so
# that any uint8 image can be indexed; unknown ids map to "ignore").
CITYSCAPES_ID_LUT = np.zeros(256, dtype=np.uint8)
TRAIN_ID_LUT = np.full(256, 255, dtype=np.uint8)
for _label in LABELS:
    CITYSCAPES_ID_LUT[_label.id] = _label.cityscapes_id
    TRAIN_ID_LUT[_label.id] = _label.train_id
del _label


def class_id(name: str) -> int:
    """Class id for a class name; raises ValueError listing valid names."""
    return lookup(CLASS_IDS, name, "class", "classes")


# --------------------------------------------------------------------------
# Towns
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class Town:
    code: str  # T01..T07, as in IDDA scenario codes
    name: str  # CARLA map this town stands in for
    road_km: float  # drivable road length; sizes the town's shards
    style: str  # name of its look in render_workers.worlds.styles.STYLES
    lanes: int  # lanes per direction on main roads
    block_m: float  # typical block edge length (junction spacing)
    building_height_m: tuple[float, float]  # min / max building height
    building_density: float  # 0..1, share of frontage with buildings
    vegetation_density: float  # 0..1, trees and hedges per frontage
    traffic_light_share: float  # share of junctions that are signalised
    railway: bool
    bridges: bool
    tunnels: bool
    roundabouts: bool
    freeway: bool

    @property
    def stream(self) -> int:
        """Stable number of the town for seeding its generators (from its code, not its position)."""
        return zlib.crc32(self.code.encode())


TOWNS: tuple[Town, ...] = (
    #    code   name      km   style                    lanes block  heights       bld  veg   tl    rail   bridge tunnel round  freeway
    Town("T01", "Town01", 2.9, "european old town", 1, 80.0, (6.0, 14.0), 0.70, 0.45, 0.7, False, True, False, False, False),
    Town("T02", "Town02", 1.4, "european village", 1, 60.0, (5.0, 11.0), 0.75, 0.40, 0.7, False, True, False, False, False),
    Town("T03", "Town03", 4.1, "modern downtown", 2, 90.0, (12.0, 45.0), 0.85, 0.25, 0.9, True, True, True, True, True),
    Town("T04", "Town04", 6.0, "mountain town", 2, 110.0, (7.0, 16.0), 0.60, 0.50, 0.8, False, True, True, False, True),
    Town("T05", "Town05", 3.9, "glass city", 2, 90.0, (18.0, 60.0), 0.85, 0.25, 0.9, False, True, True, True, True),
    Town("T06", "Town06", 5.2, "suburban industrial", 2, 120.0, (5.0, 12.0), 0.65, 0.40, 0.8, False, True, False, True, True),
    Town("T07", "Town07", 11.0, "farmland", 1, 150.0, (4.0, 9.0), 0.15, 0.8, 0.15, False, True, False, False, False),
)


# --------------------------------------------------------------------------
# Weathers
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class Weather:
    code: str  # CN | CS | HRN, as in IDDA scenario codes
    name: str  # CARLA weather preset
    sun_elevation_deg: float  # sun height above the horizon
    sun_azimuth_deg: float  # sun direction, degrees from +x towards +y
    light_color: tuple[float, float, float]  # linear RGB of the sun light
    light_intensity: float  # directional light intensity (pyrender units)
    ambient: float  # ambient light share (0..1)
    sky_zenith: RGB  # sky colour straight up
    sky_horizon: RGB  # sky colour at the horizon
    cloudiness: float  # 0..1
    rain: float  # 0..1, rain streak intensity
    wetness: float  # 0..1, darkening and specular sheen of the road
    puddles: float  # 0..1, share of road covered by reflective puddles
    fog: float  # 0..1, contrast loss per 1000 m
    grading: tuple[float, float, float]  # per-channel colour grading gain
    marker: str  # matplotlib marker of the weather in plots


WEATHERS: tuple[Weather, ...] = (
    # Calibrated to CARLA 0.9.6's presets (the version IDDA used); the mapping
    # (CARLA value -> ours) is in docs/assumptions.md, "Weathers".
    Weather("CN", "ClearNoon", 65.0, 40.0, (1.0, 0.98, 0.94), 4.0, 0.45,
            (38, 98, 190), (160, 200, 235), 0.1, 0.0, 0.0, 0.0, 0.02, (1.0, 1.0, 1.0), "o"),
    Weather("CS", "ClearSunset", 15.0, 200.0, (1.0, 0.86, 0.72), 3.6, 0.50,
            (78, 104, 170), (240, 182, 148), 0.15, 0.0, 0.0, 0.0, 0.04, (1.03, 0.99, 0.95), "s"),
    Weather("HRN", "HardRainNoon", 75.0, 40.0, (0.88, 0.90, 0.94), 2.8, 1.00,
            (128, 133, 140), (170, 173, 178), 0.90, 0.6, 0.6, 0.2, 0.08, (0.96, 0.98, 1.0), "^"),
)


# --------------------------------------------------------------------------
# Viewpoints
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class Viewpoint:
    code: str  # A | M | J | V | B, as in IDDA scenario codes
    vehicle: str  # ego vehicle the camera is mounted on
    camera_height_m: float  # camera height above the road
    hood_fraction: float  # share of the image covered by the hood (0 = none)
    hood_color: RGB  # hood paint colour
    hood_curvature: float  # bulge of the hood's top edge, in image heights
    hood_drop_m: float  # hood surface below the camera
    ego_size_m: tuple[float, float]  # the ego vehicle's footprint (length, width), kept clear of crossing pedestrians
    ego_speed_mps: tuple[float, float]  # the ego's speed range off the freeway (uniform draw per episode)

    @property
    def hood_visible(self) -> bool:
        return self.hood_fraction > 0.0


VIEWPOINTS: tuple[Viewpoint, ...] = (
    Viewpoint("A", "Audi TT", 1.20, 0.1399, (196, 24, 28), 0.10, 0.45, (4.8, 2.0), (10.0, 14.0)),
    Viewpoint("M", "Ford Mustang", 1.35, 0.1250, (28, 52, 120), 0.07, 0.50, (4.8, 2.0), (10.0, 14.0)),
    Viewpoint("J", "Jeep Wrangler", 1.80, 0.1108, (70, 82, 58), 0.02, 0.60, (4.8, 2.0), (9.0, 13.0)),
    Viewpoint("V", "Volkswagen T2", 2.10, 0.0, (210, 200, 170), 0.0, 0.0, (4.8, 2.0), (8.0, 12.0)),
    Viewpoint("B", "Bus", 2.50, 0.0, (230, 180, 20), 0.0, 0.0, (11.0, 2.55), (8.0, 11.0)),
)

AXIS_TABLES: dict[str, tuple] = dict(zip(AXES, (TOWNS, WEATHERS, VIEWPOINTS)))  # each axis's table, in AXES order
TOWN_BY_CODE = {t.code: t for t in TOWNS}
WEATHER_BY_CODE = {w.code: w for w in WEATHERS}
VIEWPOINT_BY_CODE = {v.code: v for v in VIEWPOINTS}


def town(code: str) -> Town:
    return lookup(TOWN_BY_CODE, code, "town")


def weather(code: str) -> Weather:
    return lookup(WEATHER_BY_CODE, code, "weather")


def viewpoint(code: str) -> Viewpoint:
    return lookup(VIEWPOINT_BY_CODE, code, "viewpoint")


# --------------------------------------------------------------------------
# Scenarios = town x weather x viewpoint
# --------------------------------------------------------------------------


def split_code(code: str) -> tuple[str, ...]:
    """``T01_CS_A`` -> ``("T01", "CS", "A")``, one part per axis; ValueError if malformed."""
    parts = code.split(CODE_SEPARATOR)
    if len(parts) != len(AXES) or not all(parts):
        raise ValueError(
            f"malformed scenario code {code!r}; expected TOWN_WEATHER_VIEWPOINT such as T01_CS_A"
        )
    return tuple(parts)


def format_code(*parts: str) -> str:
    """``("T01", "CS", "A")`` -> ``T01_CS_A``."""
    if len(parts) != len(AXES):
        raise ValueError(f"a scenario code has {len(AXES)} parts ({', '.join(AXES)}), got {parts!r}")
    return CODE_SEPARATOR.join(parts)


def code_axes(code: str) -> dict[str, str]:
    """``T01_CS_A`` -> ``{"town": "T01", "weather": "CS", "viewpoint": "A"}``."""
    return dict(zip(AXES, split_code(code)))

@dataclass(frozen=True)
class Scenario:
    town: Town
    weather: Weather
    viewpoint: Viewpoint

    @cached_property
    def code(self) -> str:
        return format_code(self.town.code, self.weather.code, self.viewpoint.code)

    @property
    def key(self) -> tuple[int, int, int]:
        """Stable numeric identity (table positions), used to derive seeds."""
        return (
            TOWNS.index(self.town),
            WEATHERS.index(self.weather),
            VIEWPOINTS.index(self.viewpoint),
        )

    def __str__(self) -> str:
        return self.code


ALL_SCENARIOS: tuple[Scenario, ...] = tuple(
    Scenario(t, w, v) for t in TOWNS for w in WEATHERS for v in VIEWPOINTS
)
SCENARIO_BY_CODE = {s.code: s for s in ALL_SCENARIOS}


def scenario(code: str) -> Scenario:
    """Parse a scenario code such as ``T01_CS_A``."""
    t, w, v = split_code(code)
    return Scenario(town(t), weather(w), viewpoint(v))


def scenarios(codes: Iterable[str]) -> list[Scenario]:
    return [scenario(c) for c in codes]
