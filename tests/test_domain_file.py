"""Issue 25.1: the domain file. The paper's catalog is data (domains/catalog.toml),
loaded into the same rows, bit for bit; user files derive, override and append
entries; bad files give one line naming file, entry and key."""

from __future__ import annotations

import hashlib
import tomllib
from dataclasses import astuple
from pathlib import Path

import pytest
from typer.testing import CliRunner

from domains import catalog
from domains.catalog import ALL_SCENARIOS, BUILTIN, TOWNS, VIEWPOINTS, WEATHERS, scenario, using
from domains.catalog_file import CatalogError, catalog_from_text, catalog_toml, with_file
from domains.selection import parse_selection
from domains.fog import visibility_of_share
from manifests.schema import OLD_RULES
from roots.episode_spec import PAIRED, UNPAIRED, episode_seed, town_seed
from pipeline.cli import app
from pipeline.planner import make_plan
from pipeline.settings import PlanConfig

runner = CliRunner()

# The values domains/catalog.py held as Python tables before they moved to catalog.toml.
# Written out here, not derived, so a change on either side fails.
TOWNS_REF = (
    ('T01', 'Town01', 2.9, 'european old town', 1, 80.0, (6.0, 14.0), 0.7, 0.45, 0.7, False, True, False, False, False),
    ('T02', 'Town02', 1.4, 'european village', 1, 60.0, (5.0, 11.0), 0.75, 0.4, 0.7, False, True, False, False, False),
    ('T03', 'Town03', 4.1, 'modern downtown', 2, 90.0, (12.0, 45.0), 0.85, 0.25, 0.9, True, True, True, True, True),
    ('T04', 'Town04', 6.0, 'mountain town', 2, 110.0, (7.0, 16.0), 0.6, 0.5, 0.8, False, True, True, False, True),
    ('T05', 'Town05', 3.9, 'glass city', 2, 90.0, (18.0, 60.0), 0.85, 0.25, 0.9, False, True, True, True, True),
    ('T06', 'Town06', 5.2, 'suburban industrial', 2, 120.0, (5.0, 12.0), 0.65, 0.4, 0.8, False, True, False, True, True),
    ('T07', 'Town07', 11.0, 'farmland', 1, 150.0, (4.0, 9.0), 0.15, 0.8, 0.15, False, True, False, False, False),
)
# Parameters added with dense streets (street_density, issue 34): their defaults, which the paper's towns keep.
NEW_TOWN_DEFAULTS = (0.0,)
# Parameters added with camera geometry (hfov_deg, issue 34): the paper's 90 degrees.
NEW_VIEWPOINT_DEFAULTS = (90.0,)
# Parameters added with fog, night, snow and shifts (snowfall, snow_cover, street_lights, car_lights,
# shift_from, shift_to, easing), structured domain randomization (randomize), a real camera's look
# (camera), the surface and light levers (textures, foliage, occlusion), looks drawn per frame
# (frame_looks) and reflections on vehicles: their defaults, which the paper's three weathers keep.
NEW_WEATHER_DEFAULTS = (0.0, 0.0, 0.0, 0.0, "", "", "linear", 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
_V = visibility_of_share  # fog, a share per km in those tables, is the visibility of that share (issue 32)
WEATHERS_REF = (
    ('CN', 'ClearNoon', 65.0, 40.0, (1.0, 0.98, 0.94), 4.0, 0.45, (38, 98, 190), (160, 200, 235), 0.1, 0.0, 0.0, 0.0,
     _V(0.02), (1.0, 1.0, 1.0), 'o', *NEW_WEATHER_DEFAULTS),
    ('CS', 'ClearSunset', 15.0, 200.0, (1.0, 0.86, 0.72), 3.6, 0.5, (78, 104, 170), (240, 182, 148), 0.15, 0.0, 0.0,
     0.0, _V(0.04), (1.03, 0.99, 0.95), 's', *NEW_WEATHER_DEFAULTS),
    ('HRN', 'HardRainNoon', 75.0, 40.0, (0.88, 0.9, 0.94), 2.8, 1.0, (128, 133, 140), (170, 173, 178), 0.9, 0.6, 0.6,
     0.2, _V(0.08), (0.96, 0.98, 1.0), '^', *NEW_WEATHER_DEFAULTS),
)
VIEWPOINTS_REF = (
    ('A', 'Audi TT', 1.2, 0.1399, (196, 24, 28), 0.1, 0.45, (4.8, 2.0), (10.0, 14.0)),
    ('M', 'Ford Mustang', 1.35, 0.125, (28, 52, 120), 0.07, 0.5, (4.8, 2.0), (10.0, 14.0)),
    ('J', 'Jeep Wrangler', 1.8, 0.1108, (70, 82, 58), 0.02, 0.6, (4.8, 2.0), (9.0, 13.0)),
    ('V', 'Volkswagen T2', 2.1, 0.0, (210, 200, 170), 0.0, 0.0, (4.8, 2.0), (8.0, 12.0)),
    ('B', 'Bus', 2.5, 0.0, (230, 180, 20), 0.0, 0.0, (11.0, 2.55), (8.0, 11.0)),
)
# sha256 of make_plan's episodes (scenario, episode, seed, frames, split) for `all` at full scale (seed 0)
# and at 130 frames per scenario (seed 7), and of the town seeds; computed with the Python tables.
# Unpaired and of the old rules, as roots made before pairing keep (a paired plan leaves the weather out of
# the seeds, and NEW_RULES draw splits per scene).
PLAN_DIGEST = "da7ebfe1539a68dd"

FOG = """
[[weather]]
code = "FG1"
like = "CN"
name = "FoggyNoon"
sun_elevation_deg = 35.0
visibility_m = 3000.0
"""


def _typed(rows):
    """Each value with its type, so 1 and 1.0 (or True and 1) differ."""
    return [[(type(v).__name__, tuple((type(x).__name__, x) for x in v) if isinstance(v, tuple) else v)
             for v in astuple(row)] for row in rows]


def _typed_ref(ref):
    return [[(type(v).__name__, tuple((type(x).__name__, x) for x in v) if isinstance(v, tuple) else v) for v in row]
            for row in ref]


def test_builtin_file_gives_the_python_tables_bit_for_bit():
    assert _typed(TOWNS) == _typed_ref(tuple(row + NEW_TOWN_DEFAULTS for row in TOWNS_REF))
    assert _typed(WEATHERS) == _typed_ref(WEATHERS_REF)
    assert _typed(VIEWPOINTS) == _typed_ref(tuple(row + NEW_VIEWPOINT_DEFAULTS for row in VIEWPOINTS_REF))
    assert len(ALL_SCENARIOS) == 105 and catalog.weather("HRN") is WEATHERS[2]


def test_plan_and_seeds_are_those_of_the_python_tables():
    digest = hashlib.sha256()
    for cfg in (PlanConfig(domains="all", scale=1.0, seed=0, pairing=UNPAIRED, rules=OLD_RULES),
                PlanConfig(domains="all", frames_per_scenario=130, seed=7, pairing=UNPAIRED, rules=OLD_RULES)):
        for e in make_plan(cfg).episodes:
            digest.update(repr((e.scenario, e.episode, e.seed, e.frames, e.split)).encode())
    digest.update(repr([town_seed(3, t) for t in TOWNS]).encode())
    assert digest.hexdigest()[:16] == PLAN_DIGEST


def test_the_package_ships_the_file():
    pyproject = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml").read_text())
    assert "*.toml" in pyproject["tool"]["setuptools"]["package-data"]["domains"]
    assert (Path(catalog.__file__).parent / catalog.BUILTIN_FILE).is_file()


def test_like_derives_and_user_entries_come_after_the_builtin_ones():
    cat = with_file(BUILTIN, FOG + '[[viewpoint]]\ncode = "A"\ncamera_height_m = 1.3\n', "fog.toml")
    fg = cat.by_code("weather")["FG1"]
    cn = BUILTIN.by_code("weather")["CN"]
    assert (fg.sun_elevation_deg, fg.visibility_m, fg.name) == (35.0, 3000.0, "FoggyNoon")
    assert (fg.sky_zenith, fg.light_intensity, fg.marker) == (cn.sky_zenith, cn.light_intensity, cn.marker)
    assert [w.code for w in cat.weathers] == ["CN", "CS", "HRN", "FG", "NT", "SN", "CNtoNT", "CNtoFG", "CNtoHRN", "FG1"]
    assert cat.by_code("viewpoint")["A"].camera_height_m == 1.3 and cat.place("viewpoint", "A") == 0
    assert cat.by_code("viewpoint")["A"].vehicle == "Audi TT"  # an override keeps what it does not give
    assert [(axis, [r.code for r in rows]) for axis, rows in cat.layer] == [("weather", ["FG1"]), ("viewpoint", ["A"])]
    with using(cat):
        assert scenario("T01_FG1_A").key == (0, 3, 0)
        assert len(parse_selection("all")) == 105 and len(parse_selection("catalog")) == 7 * 10 * 5
        assert [s.code for s in parse_selection("weathers=fg1 towns=T02 viewpoints=B")] == ["T02_FG1_B"]
        builtin_seeds = [episode_seed(5, s, 1) for s in ALL_SCENARIOS]
    assert builtin_seeds == [episode_seed(5, s, 1) for s in ALL_SCENARIOS]  # user entries move no built-in seed
    with pytest.raises(ValueError, match="unknown weather 'FG1'"):
        catalog.weather("FG1")  # out of the block, the built-in catalog is in force again


BAD = {
    "unknown key": ('[[weather]]\ncode = "FG1"\nlike = "CN"\nfogg = 0.5\n', "weather 'FG1': key 'fogg': unknown key"),
    "out of range": ('[[weather]]\ncode = "FG1"\nlike = "CN"\nvisibility_m = 0.5\n',
                     "weather 'FG1': key 'visibility_m': 0.5 is out of range [1.0, inf]"),
    "wrong type": ('[[town]]\ncode = "T09"\nlike = "T01"\nlanes = 1.5\n', "town 'T09': key 'lanes': expected a whole number"),
    "unknown like": ('[[weather]]\ncode = "FG1"\nlike = "XX"\n', "weather 'FG1': key 'like': unknown weather 'XX'"),
    "duplicate code": ('[[viewpoint]]\ncode = "Z"\nlike = "A"\n[[viewpoint]]\ncode = "Z"\nlike = "B"\n',
                       "viewpoint 'Z': key 'code': duplicate code 'Z'"),
    "separator": ('[[weather]]\ncode = "FG_1"\nlike = "CN"\n', "weather #1: key 'code': 'FG_1' is not a code"),
    "missing": ('[[weather]]\ncode = "FG1"\nvisibility_m = 500.0\n', "weather 'FG1': key 'name': missing"),
    "min above max": ('[[town]]\ncode = "T09"\nlike = "T01"\nbuilding_height_m = [20.0, 10.0]\n',
                      "town 'T09': key 'building_height_m': the first value (min) exceeds the second"),
    "table": ('[[weathers]]\ncode = "FG1"\n', "key 'weathers': unknown table"),
    "field of view": ('[[viewpoint]]\ncode = "A2"\nlike = "A"\nhfov_deg = 170.0\n',
                      "viewpoint 'A2': key 'hfov_deg': 170.0 is out of range [10.0, 150.0]"),
    "randomize": ('[[weather]]\ncode = "CNW"\nlike = "CN"\nrandomize = 2.5\n',
                  "weather 'CNW': key 'randomize': 2.5 is out of range [0.0, 2.0]"),
}


@pytest.mark.parametrize("case", BAD)
def test_bad_files_raise_one_error_naming_file_entry_and_key(case, tmp_path):
    text, message = BAD[case]
    with pytest.raises(CatalogError) as info:
        with_file(BUILTIN, text, "my.toml")
    assert str(info.value).startswith("my.toml: ") and message in str(info.value), str(info.value)
    path = tmp_path / "bad.toml"
    path.write_text(text)
    result = runner.invoke(app, ["plan", "--catalog", str(path), "--domains", "catalog", "--frames-per-scenario", "2"])
    lines = result.output.strip().splitlines()
    assert result.exit_code == 2 and len(lines) == 1 and lines[0].startswith(f"error: {path}: "), result.output


def test_an_unknown_style_is_one_error_line(tmp_path):
    path = tmp_path / "town.toml"
    path.write_text('[[town]]\ncode = "T09"\nlike = "T01"\nstyle = "moon base"\n')
    result = runner.invoke(app, ["plan", "--catalog", str(path)])
    assert result.exit_code == 2 and "town 'T09': key 'style': unknown style 'moon base'" in result.output


def test_show_round_trips_the_builtin_catalog(tmp_path):
    result = runner.invoke(app, ["catalog", "show"])
    assert result.exit_code == 0, result.output
    assert result.output == catalog_toml(BUILTIN) and catalog_from_text(result.output, "shown") == BUILTIN
    assert "# sun height above the horizon; deg; range -90.0 to 90.0\nsun_elevation_deg = 65.0" in result.output
    path = tmp_path / "fog.toml"
    path.write_text(FOG)
    shown = runner.invoke(app, ["catalog", "show", "--catalog", str(path)]).output
    assert catalog_from_text(shown, "shown").weathers == with_file(BUILTIN, FOG, "fog.toml").weathers


def test_plan_takes_a_catalog(tmp_path):
    path = tmp_path / "fog.toml"
    path.write_text(FOG)
    result = runner.invoke(app, ["plan", "--catalog", str(path), "--domains", "weathers=FG1 towns=T01",
                                 "--frames-per-scenario", "2", "--out", str(tmp_path / "plan.parquet")])
    assert result.exit_code == 0 and "T01_FG1_B" in result.output and "T01_CN_A" not in result.output, result.output
    from pipeline.plan_file import read_plan

    plan = read_plan(tmp_path / "plan.parquet")  # the plan file carries the entries: read back without the file
    assert plan.scenarios()[0] == "T01_FG1_A" and '"visibility_m":3000.0' in plan.config.catalog
    result = runner.invoke(app, ["plan", "--domains", "weathers=FG1"])
    assert result.exit_code == 2 and "unknown weather 'FG1'" in result.output


TOWN = '[[town]]\ncode = "T09"\nlike = "T01"\nroad_km = 5.8\nbuilding_height_m = [20.0, 30.0]\n'


def test_a_user_town_is_planned_and_built_under_its_own_cache_key(tmp_path, monkeypatch):
    from pipeline.planner import episode_target
    from pipeline.settings import full_scale_frames
    from render_workers.render.episode import cached_world
    from render_workers.worlds import worldcache

    cat = with_file(BUILTIN, TOWN + '[[town]]\ncode = "T02"\nblock_m = 70.0\n', "towns.toml")
    t09, t02 = cat.by_code("town")["T09"], cat.by_code("town")["T02"]
    assert full_scale_frames(t09) == round(1_006_800 // 15 * 5.8 / sum(t.road_km for t in TOWNS))
    assert full_scale_frames(t02) == full_scale_frames(TOWNS[1])  # same road length: the paper's share
    assert 60 <= episode_target(t09) <= 80
    assert catalog.town_variant(TOWNS[1]) == "" and catalog.town_variant(t02) not in ("", catalog.town_variant(t09))
    monkeypatch.setenv(worldcache.CACHE_ENV, str(tmp_path))
    with using(cat):
        plan = make_plan(PlanConfig(domains="towns=T09,T02 weathers=CN viewpoints=A", frames_per_scenario=2,
                                    catalog=cat.layer_json()))
        assert [e.scenario for e in plan.episodes] == ["T02_CN_A", "T09_CN_A"]
        assert plan.episodes[0].seed == episode_seed(0, scenario("T02_CN_A"), 0, PAIRED)  # T02's place kept
        world = cached_world("test", "T09", town_seed(0, t09), catalog.town_variant(t09))
        plain = cached_world("test", "T01", town_seed(0, TOWNS[0]))
    assert world is not plain and plan.episodes[1].catalog == cat.layer_json() != ""
    assert sorted(p.name.split("_")[1] for p in tmp_path.glob("*.pickle")) == ["T01", f"T09-{catalog.town_variant(t09)}"]


def test_preview_renders_a_user_weather(tmp_path):
    path = tmp_path / "fog.toml"
    path.write_text(FOG)
    result = runner.invoke(app, ["preview", "--out", str(tmp_path / "p"), "--domains", "T01_FG1_A", "--width", "64",
                                 "--height", "36", "--world", "test", "--catalog", str(path)])
    assert result.exit_code == 0 and (tmp_path / "p" / "preview_FG1.png").stat().st_size > 100, result.output


def test_the_realism_recipe_in_the_docs_loads_and_plans_the_measured_run(tmp_path):
    """docs/realism.toml, issue 34's best recipe, stays a valid domain file as the catalog grows: two
    weathers with every kept lever, the seven towns dense, and the measured run's 28 scenarios; the
    built-in entries stay as designed."""
    path = Path(__file__).resolve().parents[1] / "docs" / "realism.toml"
    recipe = with_file(BUILTIN, path.read_text(), str(path))
    weathers = {w.code: w for w in recipe.weathers}
    for code, like in (("CNR", "CN"), ("CSR", "CS")):
        w = weathers[code]
        assert (w.randomize, w.camera, w.foliage, w.occlusion, w.frame_looks, w.reflections) == (1.8, 1, 1, 1, 1, 1)
        assert w.sun_elevation_deg == weathers[like].sun_elevation_deg
    assert {t.code: t.street_density for t in recipe.towns if t.street_density} == {f"T0{i}": 1.0 for i in range(1, 8)}
    assert recipe.weathers[: len(BUILTIN.weathers)] == BUILTIN.weathers
    domains = "towns=T01-T07 weathers=CNR,CSR viewpoints=A,V"
    result = runner.invoke(app, ["plan", "--catalog", str(path), "--domains", domains, "--frames-per-scenario", "20",
                                 "--out", str(tmp_path / "plan.parquet")])
    assert result.exit_code == 0, result.output
    from pipeline.plan_file import read_plan

    plan = read_plan(tmp_path / "plan.parquet")
    assert len(plan.scenarios()) == 28 and plan.total_frames == 560
