"""Issue 25.3: a weather may shift inside an episode (from, to, easing); frames are rendered
under their own weather and their condition columns carry it."""

from __future__ import annotations

import cv2
import pytest

from domains.catalog import BUILTIN, weather
from domains.catalog_file import CatalogError, catalog_toml, catalog_from_text, with_file, with_layer_json
from domains.fog import contrast_at
from domains.ramps import weather_at
from roots.episode_spec import EpisodeSpec
from manifests.synthetic import episode_rows
from render_workers.render import episode
from render_workers.render.renderer import Renderer


def test_shift_entries_blend_their_ends_by_the_easing():
    row = weather("CNtoNT")
    frames = [weather_at(row, i, 5, weather) for i in range(5)]
    assert frames[0].sun_elevation_deg == 65.0 and frames[-1].sun_elevation_deg == -25.0
    assert frames[-1].sky_zenith == weather("NT").sky_zenith and frames[-1].code == "CNtoNT"
    suns = [w.sun_elevation_deg for w in frames]
    assert all(a > b for a, b in zip(suns, suns[1:]))
    assert suns[1] > 65.0 - 90.0 / 4  # smoothstep starts slowly
    fog = [weather_at(weather("CNtoFG"), i, 3, weather).visibility_m for i in range(3)]
    # half way, the contrast left at FG's visibility is half way between CN's and FG's 5 % (tests/test_fog.py)
    assert fog[0] == weather("CN").visibility_m and fog[2] == weather("FG").visibility_m
    assert contrast_at(fog[1], fog[2]) == pytest.approx((contrast_at(fog[0], fog[2]) + 0.05) / 2)
    # the built-in file round-trips with its shifts written as from / to
    text = catalog_toml(BUILTIN)
    assert 'from = "CN"' in text and 'to = "NT"' in text and catalog_from_text(text, "shown") == BUILTIN


@pytest.mark.parametrize("entry, words", [
    ('from = "CN"\nto = "XX"\n', "key 'to': unknown weather 'XX'"),
    ('from = "CNtoNT"\nto = "NT"\n', "key 'from': 'CNtoNT' shifts itself"),
    ('from = "CN"\nto = "NT"\neasing = "bounce"\n', "key 'easing': unknown easing 'bounce'"),
    # issue 32: the key left out is named; one spelling, `from` / `to`, the fields' names refused
    ('from = "CN"\n', "key 'to': missing: a shift names the weather it starts in"),
    ('to = "NT"\n', "key 'from': missing"),
    ('from = "CN"\nto = "FG"\nshift_to = "NT"\n', "key 'shift_to': write it 'to' \\(a domain file's spelling\\)$"),
    ('shift_from = "CN"\nshift_to = "NT"\n', "key 'shift_from': write it 'from'"),
    ('from = "CN"\nto = "NT"\ntill = 3\n', "key 'till': unknown key; valid keys: like, code, .*, from, to, easing, randomize, camera, textures, foliage, occlusion, frame_looks, reflections$"),
])
def test_bad_shifts_give_one_line(entry, words):
    with pytest.raises(CatalogError, match=words):
        with_file(BUILTIN, f'[[weather]]\ncode = "S1"\nlike = "CN"\n{entry}', "s.toml")


def test_a_runs_record_keeps_the_fields_names():
    """run.json and job specs record a user shift by its fields' names (Catalog.layer_json), as roots
    made before this check hold it: it still loads, while a file must write from / to."""
    cat = with_file(BUILTIN, '[[weather]]\ncode = "S1"\nlike = "CN"\nfrom = "HRN"\nto = "SN"\n', "s.toml")
    layer = cat.layer_json()
    assert '"shift_from":"HRN"' in layer and '"shift_to":"SN"' in layer
    assert with_layer_json(BUILTIN, layer).by_code("weather")["S1"] == cat.by_code("weather")["S1"]


def test_a_user_shift_and_synthetic_rows_carry_each_frames_conditions():
    cat = with_file(BUILTIN, '[[weather]]\ncode = "S1"\nlike = "CN"\nfrom = "HRN"\nto = "SN"\n', "s.toml")
    assert cat.by_code("weather")["S1"].shift_to == "SN"
    rows = episode_rows(EpisodeSpec("T01_CNtoHRN_A", 0, 1, 3, 64, 36, "train", 0))
    assert [r["precipitation"] for r in rows] == pytest.approx([0.0, 0.3, 0.6])


def test_a_shifting_episode_moves_monotonically():
    got = []
    with Renderer() as renderer:
        spec = EpisodeSpec("T01_CNtoNT_A", 0, 3, 4, 160, 90, "train", 0, frame_interval_s=0.5)
        episode.render_episode(spec.drawing, got.append, world="test", renderer=renderer)
    suns = [f.conditions["sun_altitude_deg"] for f in got]
    luminance = [float(cv2.cvtColor(f.buffers["rgb"], cv2.COLOR_RGB2GRAY).mean()) for f in got]
    print("CNtoNT sun altitude", [round(s, 1) for s in suns], "mean luminance", [round(v, 1) for v in luminance])
    assert all(a > b for a, b in zip(suns, suns[1:])) and suns[0] == 65.0 and suns[-1] == -25.0
    assert all(a > b for a, b in zip(luminance, luminance[1:]))
    assert luminance[-1] < 0.4 * luminance[0]


def test_extending_a_shifting_episode_renders_it_again_whole_and_says_so(tmp_path):
    """Issue 32: a shift runs over its episode's length, so an --extend from 2 to 3 frames renders a
    CNtoNT episode again whole and its frame 1 changes (a fixed weather's frames stay byte for byte);
    produce's report names such episodes."""
    from dataclasses import replace

    from manifests.reader import read_manifest
    from pipeline.cli.progress import format_produce_report
    from pipeline.driver import ProduceReport, pending_episodes, reshifted_episodes
    from pipeline.planner import make_plan
    from pipeline.settings import PlanConfig, RunConfig
    from tests.roots import render_root

    small = RunConfig(plan=PlanConfig(domains="T01_CNtoNT_A,T01_CN_A", frames_per_scenario=2, width=32, height=32,
                                      outputs=("rgb",)), world="test")
    root = tmp_path / "root"
    render_root(root, small)
    before = {(r["scenario"], r["frame"]): (root / r["rgb_path"]).read_bytes() for r in read_manifest(str(root)).to_pylist()}
    longer = RunConfig(plan=replace(small.plan, frames_per_scenario=3), world="test")
    held = {("T01_CNtoNT_A", 0): 2, ("T01_CN_A", 0): 2}
    assert reshifted_episodes(pending_episodes(make_plan(longer.plan), held), held) == ["T01_CNtoNT_A/e0000"]
    render_root(root, longer, extend=True)
    after = {(r["scenario"], r["frame"]): (root / r["rgb_path"]).read_bytes() for r in read_manifest(str(root)).to_pylist()}
    assert after["T01_CN_A", 0] == before["T01_CN_A", 0] and after["T01_CN_A", 1] == before["T01_CN_A", 1]
    assert after["T01_CNtoNT_A", 0] == before["T01_CNtoNT_A", 0] and after["T01_CNtoNT_A", 1] != before["T01_CNtoNT_A", 1]
    text = format_produce_report(ProduceReport(str(root), 2, 6, 0, reshifted=["T01_CNtoNT_A/e0000"]))
    assert "1 episode of a shifting weather made longer (T01_CNtoNT_A/e0000) rendered again whole" in text
