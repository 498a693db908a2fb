import numpy as np
import pytest

from domains import catalog
from domains.catalog import ALL_SCENARIOS, LABELS, PALETTE, TOWNS, VIEWPOINTS, WEATHERS
from domains.fog import contrast_at


def test_class_ids_are_unique_and_dense():
    ids = [label.id for label in LABELS]
    assert ids == list(range(24))
    assert len({label.name for label in LABELS}) == 24


# The paper's classes (Fig. "pixeldistr", shared/REFERENCE.md): id, name, RGB.
# Written out here, not derived from the catalog, so a swapped colour or id fails.
REFERENCE_CLASSES = [
    (0, "unlabeled", (0, 0, 0)), (1, "building", (70, 70, 70)), (2, "fence", (190, 153, 153)),
    (3, "other", (72, 0, 90)), (4, "pedestrian", (220, 20, 60)), (5, "pole", (153, 153, 153)),
    (6, "road line", (157, 234, 50)), (7, "road", (128, 64, 128)), (8, "sidewalk", (244, 35, 232)),
    (9, "vegetation", (107, 142, 35)), (10, "vehicle", (0, 0, 142)), (11, "wall", (102, 102, 156)),
    (12, "traffic sign", (220, 220, 0)), (13, "traffic light", (250, 170, 30)), (14, "guard rail", (180, 165, 180)),
    (15, "dynamic", (111, 74, 0)), (16, "bicycle", (119, 11, 32)), (17, "motorcycle", (0, 0, 230)),
    (18, "rider", (255, 0, 0)), (19, "terrain", (152, 251, 152)), (20, "sky", (70, 130, 180)),
    (21, "railway", (230, 150, 140)), (22, "ground", (81, 0, 81)), (23, "static", (0, 0, 0)),
]


def test_palette_equals_table():
    for label in LABELS:
        assert tuple(PALETTE[label.id]) == label.color
    assert PALETTE.dtype == np.uint8 and PALETTE.shape == (24, 3)


def test_every_class_id_name_and_colour_is_the_papers():
    """Issue 21.13a: road and sidewalk colours swapped passed a palette test that compared the table with itself."""
    assert [(label.id, label.name, tuple(label.color)) for label in LABELS] == REFERENCE_CLASSES
    assert [tuple(int(v) for v in PALETTE[i]) for i, _, _ in REFERENCE_CLASSES] == [c for _, _, c in REFERENCE_CLASSES]
    assert [catalog.class_id(name) for _, name, _ in REFERENCE_CLASSES] == list(range(24))


def test_sixteen_evaluated_classes():
    evaluated = {label.name for label in LABELS if label.evaluated}
    assert len(evaluated) == 16
    assert evaluated.isdisjoint(
        {"unlabeled", "other", "road line", "guard rail", "dynamic", "railway", "ground", "static"}
    )


# Cityscapes label ids and trainIds of the 19 training classes
# (cityscapesScripts helpers/labels.py).
CITYSCAPES = {
    "road": (7, 0), "sidewalk": (8, 1), "building": (11, 2), "wall": (12, 3), "fence": (13, 4),
    "pole": (17, 5), "traffic light": (19, 6), "traffic sign": (20, 7), "vegetation": (21, 8),
    "terrain": (22, 9), "sky": (23, 10), "pedestrian": (24, 11), "rider": (25, 12),
    "vehicle": (26, 13), "motorcycle": (32, 17), "bicycle": (33, 18),
}
# Cityscapes ids with ignoreInEval=True.
CITYSCAPES_IGNORED = {0, 1, 2, 3, 4, 5, 6, 9, 10, 14, 15, 16, 18, 29, 30}


def test_train_id_map_matches_cityscapes():
    for label in LABELS:
        if label.evaluated:
            assert (label.cityscapes_id, label.train_id) == CITYSCAPES[label.name]
        else:
            assert label.train_id == 255
            assert label.cityscapes_id in CITYSCAPES_IGNORED
    assert catalog.TRAIN_ID_LUT[7] == 0 and catalog.TRAIN_ID_LUT[200] == 255


def test_axis_codes_unique_and_scenario_codes():
    for table in (TOWNS, WEATHERS, VIEWPOINTS):
        codes = [row.code for row in table]
        assert len(codes) == len(set(codes))
    assert len(catalog.ALL_SCENARIOS) == 105
    assert catalog.scenario("T01_CS_A").code == "T01_CS_A"
    assert catalog.town("T01").road_km == 2.9 and catalog.town("T02").road_km == 1.4


def test_viewpoints_match_paper():
    heights = [v.camera_height_m for v in VIEWPOINTS]
    assert min(heights) == 1.2 and max(heights) == 2.5
    for v in VIEWPOINTS:
        if v.code in "AMJ":
            assert 0.1108 <= v.hood_fraction <= 0.1399
        else:
            assert not v.hood_visible


@pytest.mark.parametrize("bad", ["T08_CN_A", "T01_XX_A", "T01_CN_Z", "T01CNA"])
def test_bad_scenario_codes_name_valid_values(bad):
    with pytest.raises(ValueError, match="valid|expected"):
        catalog.scenario(bad)


def test_unknown_class_name():
    with pytest.raises(ValueError, match="valid classes: unlabeled, building"):
        catalog.class_id("cat")


def test_weathers_follow_carla_096():
    """CARLA 0.9.6's presets (docs/assumptions.md, "Weathers"): no fog parameter, so our haze stays light
    (HardRainNoon keeps at least 98% contrast at 200 m and its town colours); rain only in HardRainNoon;
    the ambient share is a share."""
    by = {w.code: w for w in WEATHERS}
    for w in WEATHERS:
        assert 0.0 <= w.ambient <= 1.0 and w.visibility_m > 1000.0
        assert contrast_at(w.visibility_m, 200) >= 0.98
    assert by["HRN"].rain > 0 and by["CN"].rain == by["CS"].rain == 0
    assert by["HRN"].cloudiness > by["CS"].cloudiness >= by["CN"].cloudiness
    assert by["CS"].sun_elevation_deg == 15.0  # the same in every CARLA release


def test_the_scenario_code_is_parsed_and_formatted_in_one_place():
    from domains.catalog import AXES, code_axes, format_code, split_code
    from manifests.schema import PARTITION_KEYS, part_path

    assert AXES == PARTITION_KEYS == ("town", "weather", "viewpoint")
    for s in ALL_SCENARIOS:
        assert format_code(*split_code(s.code)) == s.code
        assert code_axes(s.code) == {"town": s.town.code, "weather": s.weather.code, "viewpoint": s.viewpoint.code}
    assert part_path("T07_HRN_B", 3) == "manifest/town=T07/weather=HRN/viewpoint=B/T07_HRN_B_e0003.parquet"
    for bad in ("T01_CS", "T01__A", "T01_CS_A_X", ""):
        with pytest.raises(ValueError, match="malformed scenario code"):
            split_code(bad)
