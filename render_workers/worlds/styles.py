"""How towns look: the world kit's surfaces and each town's style row, as data.

A town's catalog row (``domains.catalog.TOWNS``) names its style; everything
the world builder needs to dress it (materials, road dress, buildings, plants,
relief) is here, so the dataset's vocabulary in ``domains/`` carries no
render detail. Every name is checked against its table when a row is made.
"""

from __future__ import annotations

from dataclasses import dataclass

from domains.catalog import RGB, TOWNS, Town, lookup


# --------------------------------------------------------------------------
# Town styles: what a town is made of, as data
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class Surface:
    """A named material of the world kit: albedo and procedural variation."""

    name: str  # unique key, referenced by styles
    color: RGB  # base albedo (sRGB)
    noise: float  # 0..1, strength of the large-scale colour variation
    scale_m: float  # size of that variation
    look: str = "matte"  # renderer material (render_workers.worlds.scene.MATERIALS)
    texture: str = ""  # procedural texture (TEXTURE_NAMES) multiplied in; "" = none

    def __post_init__(self) -> None:
        if self.texture:
            lookup(dict.fromkeys(TEXTURE_NAMES), self.texture, "texture")


# render_workers.worlds.textures makes these; each is grey and multiplies a surface's colour
TEXTURE_NAMES = ("asphalt", "brick", "paving", "plaster", "concrete", "glass", "grass", "crop", "soil", "gravel",
                 "stalks")


SURFACES: tuple[Surface, ...] = (
    # road and roadside
    Surface("asphalt dark", (56, 57, 61), 0.16, 6.0, "road", texture="asphalt"),
    Surface("asphalt grey", (84, 84, 86), 0.14, 6.0, "road", texture="asphalt"),
    Surface("asphalt blue-grey", (70, 74, 82), 0.12, 7.0, "road", texture="asphalt"),
    Surface("asphalt freeway", (80, 80, 84), 0.15, 8.0, "road", texture="asphalt"),
    Surface("chip seal", (146, 134, 110), 0.22, 3.0, "road", texture="gravel"),
    Surface("marking white", (226, 226, 220), 0.06, 2.0),
    Surface("marking yellow", (214, 178, 58), 0.06, 2.0),
    Surface("kerb granite", (176, 174, 168), 0.08, 1.0),
    Surface("kerb concrete", (198, 196, 190), 0.06, 1.0),
    Surface("paving grey", (150, 146, 140), 0.10, 1.3, texture="paving"),
    Surface("paving red", (162, 118, 104), 0.10, 1.3, texture="paving"),
    Surface("paving buff", (190, 176, 146), 0.10, 1.3, texture="paving"),
    Surface("concrete slabs", (172, 172, 170), 0.08, 2.0, texture="concrete"),
    Surface("gravel", (146, 136, 118), 0.20, 1.5, texture="gravel"),
    Surface("dirt", (118, 94, 64), 0.22, 2.5, texture="soil"),
    Surface("farm track", (150, 122, 84), 0.24, 2.0, texture="gravel"),
    # ground and vegetation
    Surface("lawn", (72, 112, 44), 0.25, 3.0, texture="grass"),
    Surface("meadow", (104, 124, 56), 0.28, 8.0, texture="grass"),
    Surface("dry grass", (140, 136, 80), 0.25, 6.0, texture="grass"),
    Surface("leaf litter", (128, 92, 58), 0.3, 3.0, texture="grass"),  # verges under fallen leaves
    Surface("alpine grass", (78, 106, 58), 0.25, 10.0, texture="grass"),
    Surface("rock", (118, 114, 108), 0.25, 12.0, texture="soil"),
    Surface("snow", (232, 236, 242), 0.05, 10.0),
    Surface("soil", (104, 78, 54), 0.18, 5.0, texture="soil"),
    Surface("wheat", (212, 176, 72), 0.16, 6.0, texture="crop"),
    Surface("young crop", (110, 142, 52), 0.18, 6.0, texture="crop"),
    Surface("hay meadow", (170, 146, 62), 0.25, 8.0, texture="grass"),
    Surface("maize", (136, 142, 60), 0.18, 5.0, texture="stalks"),
    Surface("ripe maize", (196, 166, 80), 0.18, 5.0, texture="stalks"),
    Surface("dry maize", (168, 136, 78), 0.20, 5.0, texture="stalks"),
    Surface("canopy green", (58, 96, 38), 0.25, 1.2),
    Surface("canopy light", (96, 128, 46), 0.25, 1.2),
    Surface("canopy dark", (34, 62, 36), 0.22, 1.2),
    Surface("canopy autumn", (150, 116, 44), 0.25, 1.2),
    Surface("canopy olive", (88, 96, 42), 0.25, 1.2),
    Surface("hedge", (44, 84, 34), 0.30, 0.7),
    Surface("hedge russet", (126, 84, 52), 0.35, 0.7),  # hawthorn and bramble in late autumn
    Surface("canopy rust", (156, 88, 40), 0.28, 1.2),
    Surface("canopy straw", (176, 150, 70), 0.25, 1.2),
    Surface("canopy bare", (118, 100, 90), 0.3, 1.0),  # leafless crowns of late autumn: bare twigs
    Surface("stubble", (196, 170, 112), 0.20, 4.0, texture="crop"),
    Surface("bark", (84, 64, 44), 0.20, 0.5),
    Surface("birch bark", (206, 204, 196), 0.15, 0.5),
    Surface("bark grey", (148, 144, 134), 0.18, 0.5),  # the smooth pale bark of poplars, ash and beech
    # facades and roofs
    Surface("brick red", (152, 74, 54), 0.10, 4.0, texture="brick"),
    Surface("brick brown", (118, 70, 54), 0.10, 4.0, texture="brick"),
    Surface("plaster cream", (214, 200, 166), 0.08, 4.0, texture="plaster"),
    Surface("plaster ochre", (206, 160, 96), 0.08, 4.0, texture="plaster"),
    Surface("plaster pink", (206, 164, 150), 0.08, 4.0, texture="plaster"),
    Surface("plaster white", (226, 224, 214), 0.06, 4.0, texture="plaster"),
    Surface("concrete light", (188, 184, 176), 0.08, 4.0, texture="concrete"),
    Surface("concrete dark", (118, 118, 116), 0.08, 4.0, texture="concrete"),
    Surface("glass blue", (64, 96, 130), 0.10, 6.0, "glass", texture="glass"),
    Surface("glass teal", (58, 104, 104), 0.10, 6.0, "glass", texture="glass"),
    Surface("glass bronze", (110, 92, 70), 0.10, 6.0, "glass", texture="glass"),
    Surface("siding grey", (150, 154, 156), 0.06, 3.0, "metal"),
    Surface("siding blue", (70, 98, 136), 0.06, 3.0, "metal"),
    Surface("siding beige", (196, 184, 156), 0.06, 3.0),
    Surface("timber dark", (92, 62, 40), 0.12, 2.0),
    Surface("barn red", (150, 46, 36), 0.12, 3.0),
    Surface("stone wall", (150, 142, 128), 0.18, 1.5, texture="gravel"),
    Surface("roof terracotta", (156, 72, 48), 0.10, 2.0, texture="brick"),
    Surface("roof slate", (70, 72, 80), 0.08, 2.0),
    Surface("roof flat", (110, 108, 104), 0.10, 4.0, texture="concrete"),
    Surface("roof metal", (128, 132, 136), 0.06, 3.0, "metal"),
    Surface("roof green metal", (70, 96, 80), 0.06, 3.0, "metal"),
    Surface("silo metal", (182, 184, 182), 0.06, 2.0, "metal"),
)
SURFACE_BY_NAME = {s.name: s for s in SURFACES}


def surface(name: str) -> Surface:
    return lookup(SURFACE_BY_NAME, name, "surface")


ROAD_EDGES = ("kerb", "gravel", "dirt")  # kerb = raised sidewalks; the others are verges
MARKINGS = ("full", "centre", "none")  # centre + lane + edge lines / centre line only / none
ARCHITECTURES = ("european", "modern", "alpine", "suburban", "farm")  # render_workers.worlds.buildings kits
TREE_SPECIES = ("broadleaf", "conifer", "poplar", "birch", "bush")  # render_workers.worlds.builder meshes
FIELD_BOUNDS = ("hedge", "fence", "wall")  # what may line a countryside block (render_workers.worlds.countryside)


@dataclass(frozen=True)
class Furniture:
    """The street furniture of a town: what its poles, signal heads, sign plates,
    fences and walls are made of (the same shapes everywhere, so that the city
    shift is also one of looks: steel and enamel in town, timber and stone out of it)."""

    name: str  # unique key, referenced by styles
    pole: RGB  # lamp posts, sign and signal poles, mast arms
    pole_look: str  # renderer material of the poles
    signal: RGB  # traffic light housings
    signs: tuple[RGB, ...]  # sign plate faces, one drawn per sign
    fences: tuple[RGB, ...]  # field and garden fences, one drawn per piece
    walls: tuple[RGB, ...]  # garden and yard walls, one drawn per piece

    def __post_init__(self) -> None:
        if not (self.signs and self.fences and self.walls):
            raise ValueError(f"furniture {self.name!r}: signs, fences and walls must not be empty")


FURNITURES: tuple[Furniture, ...] = (
    Furniture("steel and enamel", (112, 114, 118), "metal", (38, 38, 40),
              ((190, 30, 30), (30, 70, 170), (235, 235, 235), (230, 190, 30)),
              ((92, 96, 100), (120, 92, 62), (70, 84, 70), (150, 150, 150)),
              ((160, 152, 140), (140, 128, 116), (176, 170, 160), (120, 100, 84))),
    Furniture("anthracite", (54, 58, 64), "metal", (26, 26, 28),
              ((190, 30, 30), (30, 70, 170), (235, 235, 235), (30, 70, 170)),
              ((60, 64, 70), (84, 88, 94), (40, 42, 46), (120, 124, 130)),
              ((128, 128, 126), (96, 96, 96), (150, 150, 146), (78, 80, 82))),
    Furniture("galvanised", (166, 170, 168), "metal", (84, 88, 84),
              ((190, 30, 30), (30, 70, 170), (235, 235, 235), (230, 190, 30)),
              ((170, 172, 170), (150, 152, 150), (120, 124, 120), (190, 190, 186)),
              ((176, 176, 170), (160, 158, 150), (190, 188, 180), (140, 138, 132))),
    Furniture("forest green", (52, 82, 64), "metal", (40, 60, 46),
              ((190, 30, 30), (30, 70, 170), (235, 235, 235), (230, 190, 30)),
              ((104, 78, 52), (86, 64, 44), (52, 82, 64), (120, 92, 62)),
              ((150, 142, 128), (120, 112, 100), (170, 164, 152), (104, 96, 86))),
    # country roads: creosoted timber poles, yellow signal heads, yellow and green plates,
    # weathered split-rail fences and dry-stone walls
    Furniture("timber and stone", (74, 56, 40), "matte", (196, 160, 32),
              ((236, 186, 30), (34, 110, 64), (244, 238, 214), (236, 186, 30)),
              ((136, 118, 92), (112, 94, 70), (156, 144, 122), (98, 82, 62)),
              ((152, 140, 118), (128, 116, 98), (172, 158, 132), (108, 98, 84))),
)
FURNITURE_BY_NAME = {f.name: f for f in FURNITURES}


def _plural(noun: str) -> str:
    if noun.endswith("s"):
        return noun
    return noun[:-1] + "ies" if noun.endswith("y") else noun + "s"


@dataclass(frozen=True)
class Style:
    """How a town looks: its material palette, road dress, buildings, plants and relief.

    The world builder reads only this row (and the town's topology), never the
    town's code. Every name is checked against its table when the row is made.
    """

    name: str  # unique, shown in reports
    asphalt: str  # road surface
    asphalt_wear: float  # 0..1: share of cracks and patches on the road
    kerb: str  # kerb stones (kerb edges only)
    paving: tuple[str, ...]  # sidewalk pavings, one picked per block
    road_edge: str  # one of ROAD_EDGES
    verge: str  # surface of verges, planting strips and shoulders
    lane_w_m: float  # lane width
    markings: str  # one of MARKINGS
    marked_share: float  # share of street segments that carry markings
    marking: str  # paint surface of the centre line
    architecture: str  # one of ARCHITECTURES
    facades: tuple[str, ...]  # facade surfaces
    roofs: tuple[str, ...]  # roof surfaces
    trees: tuple[tuple[str, float], ...]  # (species, weight) of roadside and garden trees
    canopies: tuple[str, ...]  # canopy surfaces
    ground: str  # open ground: gardens, parks, outskirts
    crops: tuple[str, ...]  # field surfaces of low crops, labelled terrain (empty: no crop fields)
    relief_m: float  # height of the hills around the town (0 = flat)
    mountains_m: float  # height of the mountain backdrop (0 = none)
    tall_crops: tuple[str, ...] = ()  # field surfaces of tall crops (maize), labelled vegetation
    tall_crop_share: float = 0.0  # share of the fields sown with tall crops
    # (boundary, share) of countryside block edges: hedgerows, fences, dry-stone walls; the rest stay open
    field_bounds: tuple[tuple[str, float], ...] = (("hedge", 0.3), ("fence", 0.25), ("wall", 0.15))
    furniture: str = "steel and enamel"  # one of FURNITURES: poles, signals, signs, fences, walls
    hedge: str = "hedge"  # surface of hedgerows and bushes
    conifer: str = "canopy dark"  # canopy surface of conifers
    bark: str = "bark"  # surface of tree trunks (birches keep their own)
    track: str = ""  # surface of unpaved farm tracks (with a crown of the verge's grass); "" = every street paved
    track_share: float = 0.0  # share of the street segments (off bridges) that are such tracks

    def __post_init__(self) -> None:
        lookup(FURNITURE_BY_NAME, self.furniture, "furniture")
        for name in (self.asphalt, self.kerb, self.verge, self.marking, self.ground, self.hedge, self.conifer,
                     self.bark, *((self.track,) if self.track else ()),
                     *self.paving, *self.facades, *self.roofs, *self.canopies, *self.crops, *self.tall_crops):
            surface(name)
        for value, valid, what in ((self.road_edge, ROAD_EDGES, "road edge"),
                                   (self.markings, MARKINGS, "marking scheme"),
                                   (self.architecture, ARCHITECTURES, "architecture"),
                                   *((sp, TREE_SPECIES, "tree species") for sp, _ in self.trees),
                                   *((b, FIELD_BOUNDS, "field boundary") for b, _ in self.field_bounds)):
            lookup(dict.fromkeys(valid), value, what, _plural(what))
        shares = [share for _, share in self.field_bounds]
        if any(share < 0 for share in shares) or sum(shares) > 1.0 + 1e-9:
            raise ValueError(f"style {self.name!r}: field_bounds shares must be >= 0 and sum to at most 1")
        if not 0.0 <= self.tall_crop_share <= 1.0 or (self.tall_crop_share > 0) != bool(self.tall_crops):
            raise ValueError(f"style {self.name!r}: tall_crop_share must be in [0, 1], and above 0 exactly when "
                             "there are tall crops")
        if not 0.0 <= self.track_share <= 1.0 or (self.track_share > 0) != bool(self.track):
            raise ValueError(f"style {self.name!r}: track_share must be in [0, 1], and above 0 exactly when "
                             "there is a track surface")
        if not (self.paving and self.facades and self.roofs and self.trees and self.canopies):
            raise ValueError(f"style {self.name!r}: paving, facades, roofs, trees and canopies must not be empty")

    @property
    def props(self) -> Furniture:
        """The style's street furniture row."""
        return FURNITURE_BY_NAME[self.furniture]

    @property
    def sidewalks(self) -> bool:
        """Raised sidewalks behind kerbs (else verges level with the road)."""
        return self.road_edge == "kerb"


STYLES: tuple[Style, ...] = (
    Style("european old town", "asphalt dark", 0.35, "kerb granite", ("paving grey", "paving red"), "kerb", "lawn",
          3.5, "centre", 1.0, "marking white", "european",
          ("brick red", "brick brown", "plaster cream", "plaster ochre", "plaster pink"),
          ("roof terracotta", "roof slate"), (("broadleaf", 0.8), ("conifer", 0.2)),
          ("canopy green", "canopy light"), "lawn", (), 8.0, 0.0),
    Style("european village", "asphalt grey", 0.45, "kerb granite", ("paving buff", "paving grey"), "kerb", "lawn",
          3.3, "centre", 1.0, "marking white", "european",
          ("plaster white", "plaster cream", "brick red", "plaster pink"),
          ("roof terracotta",), (("broadleaf", 0.6), ("birch", 0.4)),
          ("canopy light", "canopy green"), "lawn", (), 12.0, 0.0),
    Style("modern downtown", "asphalt blue-grey", 0.1, "kerb concrete", ("concrete slabs",), "kerb", "lawn",
          3.5, "full", 1.0, "marking yellow", "modern",
          ("glass blue", "concrete light", "glass teal", "concrete dark"),
          ("roof flat",), (("broadleaf", 0.7), ("poplar", 0.3)),
          ("canopy green",), "lawn", (), 0.0, 0.0, furniture="anthracite"),
    Style("mountain town", "asphalt grey", 0.3, "kerb granite", ("paving grey",), "kerb", "alpine grass",
          3.5, "full", 1.0, "marking white", "alpine",
          ("plaster white", "plaster cream", "timber dark", "stone wall"),
          ("roof slate", "roof green metal"), (("conifer", 0.85), ("broadleaf", 0.15)),
          ("canopy dark",), "alpine grass", (), 25.0, 160.0, furniture="forest green"),
    Style("glass city", "asphalt dark", 0.05, "kerb concrete", ("concrete slabs", "paving grey"), "kerb", "lawn",
          3.5, "full", 1.0, "marking yellow", "modern",
          ("glass teal", "glass bronze", "concrete dark", "glass blue"),
          ("roof flat",), (("poplar", 0.5), ("broadleaf", 0.5)),
          ("canopy dark", "canopy green"), "lawn", (), 0.0, 0.0, furniture="anthracite"),
    Style("suburban industrial", "asphalt freeway", 0.2, "kerb concrete", ("concrete slabs",), "kerb", "dry grass",
          3.7, "full", 1.0, "marking yellow", "suburban",
          ("siding beige", "siding grey", "siding blue", "brick brown", "plaster white"),
          ("roof metal", "roof slate", "roof flat"), (("broadleaf", 0.5), ("bush", 0.3), ("conifer", 0.2)),
          ("canopy light", "canopy autumn"), "dry grass", (), 4.0, 0.0, furniture="galvanised"),
    Style("farmland", "chip seal", 0.8, "kerb granite", ("paving grey",), "dirt", "leaf litter",
          3.0, "none", 0.3, "marking white", "farm",
          ("barn red", "plaster white", "stone wall", "timber dark"),
          ("roof metal", "roof terracotta"), (("poplar", 0.4), ("broadleaf", 0.4), ("bush", 0.2)),
          ("canopy autumn", "canopy rust", "canopy straw", "canopy bare"), "hay meadow", ("wheat", "stubble", "soil"),
          30.0, 0.0, ("ripe maize", "dry maize"), 0.9, (("hedge", 0.7), ("fence", 0.1), ("wall", 0.1)),
          furniture="timber and stone", hedge="hedge russet", conifer="canopy olive", bark="bark grey",
          track="farm track", track_share=0.6),
)
STYLE_BY_NAME = {s.name: s for s in STYLES}


def style(name: str) -> Style:
    return lookup(STYLE_BY_NAME, name, "style")


def look(town: Town) -> Style:
    """The town's style row."""
    return style(town.style)


def is_urban(town: Town) -> bool:
    """Streets with kerbs and sidewalks (else a countryside of verges and fields)."""
    return look(town).sidewalks


for _town in TOWNS:
    style(_town.style)  # every town names a known style
del _town
