"""Issue 32: fog is a physical quantity, meteorological visibility in metres (domains.fog), recorded
as float64; a shift thickens it evenly; the weathers declared before render as they did, and roots
made before rules keep recording and blending the old share per km."""

from __future__ import annotations

import math

import numpy as np
import pytest

from domains.catalog import BUILTIN, weather
from domains.catalog_file import CatalogError, current_layer, with_file, with_layer_json
from domains.fog import blend_share, contrast_at, share_of_visibility, visibility_of_share
from domains.ramps import weather_at
from render_workers.render import postfx
from tests.test_postfx import H, W, context

# The fog shares per km the built-in weathers had before (CN, CS, HRN, FG, NT, SN).
SHARES_BEFORE = {"CN": 0.02, "CS": 0.04, "HRN": 0.08, "FG": 0.99999, "NT": 0.03, "SN": 0.2}


def _old_coefficient(share: float) -> np.float32:
    """The renderer's fog exponent per metre before (render_workers.render.postfx.fog)."""
    return np.float32(math.log(1.0 - min(share, 1.0 - 1e-12)) / 1000.0)


def test_declared_weathers_render_and_record_as_before():
    """Each built-in weather's visibility gives the renderer the float32 exponent its share gave, and
    a root made before rules records the float32 share it did, also along CNtoFG and CNtoHRN at
    every episode length up to 80 frames (the old linear blend of the share)."""
    for code, share in SHARES_BEFORE.items():
        v = weather(code).visibility_m
        assert np.float32(-math.log(20) / v) == _old_coefficient(share) or np.float32(-(math.log(20) / v)) == \
            _old_coefficient(share), code
        assert np.float32(share_of_visibility(v)) == np.float32(share), code
    for shift, (a, b) in {"CNtoFG": ("CN", "FG"), "CNtoHRN": ("CN", "HRN")}.items():
        for frames in range(2, 81):
            for i in range(frames):
                s = i / (frames - 1)
                old = SHARES_BEFORE[a] + (SHARES_BEFORE[b] - SHARES_BEFORE[a]) * s
                v = weather_at(weather(shift), i, frames, weather, old_rules=True).visibility_m
                assert np.float32(-math.log(20) / v if not math.isinf(v) else 0.0) == _old_coefficient(old)
                assert np.float32(share_of_visibility(v)) == np.float32(old)
    assert weather("FG").visibility_m == pytest.approx(260.2, abs=0.01)  # 5 % contrast left at 260 m


def _far_contrast(w) -> float:
    """Contrast left by the fog of ``w`` on a black and white pattern 120 m away (a building)."""
    ctx = context("CN")
    ctx = type(ctx)(**{**ctx.__dict__, "depth": np.full((H, W), 120.0, np.float32), "weather": w})
    img = np.zeros((H, W, 3), np.float32)
    img[:, ::2] = 1.0
    out = postfx.fog(img, ctx)
    return float(out[:, ::2].mean() - out[:, 1::2].mean())


def test_a_shift_to_fog_thickens_evenly():
    """Far contrast along CNtoFG's 12 frames falls at every frame without a jump: no step is 2.5 times
    the mean (measured: 0.998, 0.957, 0.914, ..., 0.499, 0.398, 0.251); the old rule, a linear share,
    lost two thirds of it at the last frame (0.998, 0.986, ..., 0.813, 0.748, 0.251)."""
    new = [_far_contrast(weather_at(weather("CNtoFG"), i, 12, weather)) for i in range(12)]
    steps = np.diff(new)
    assert new[0] > 0.99 and new[-1] == pytest.approx(contrast_at(weather("FG").visibility_m, 120), abs=2e-3)
    assert (steps < 0).all() and steps.min() > 2.5 * steps.mean(), [round(c, 3) for c in new]
    old = [_far_contrast(weather_at(weather("CNtoFG"), i, 12, weather, old_rules=True)) for i in range(12)]
    assert old[-2] - old[-1] > 0.6 * (old[0] - old[-1])  # the old rule's jump (kept for old roots)
    # the ends are the fixed weathers', exactly
    assert weather_at(weather("CNtoFG"), 0, 12, weather).visibility_m == weather("CN").visibility_m
    assert weather_at(weather("CNtoFG"), 11, 12, weather).visibility_m == weather("FG").visibility_m


def test_domain_files_declare_visibility_and_old_records_still_load():
    cat = with_file(BUILTIN, '[[weather]]\ncode = "HF"\nlike = "FG"\nvisibility_m = 130.0\n', "hf.toml")
    assert cat.by_code("weather")["HF"].visibility_m == 130.0
    clear = with_file(BUILTIN, '[[weather]]\ncode = "AIR"\nlike = "CN"\nvisibility_m = inf\n', "air.toml")
    assert math.isinf(clear.by_code("weather")["AIR"].visibility_m)
    with pytest.raises(CatalogError, match=r"key 'fog': fog is declared as visibility_m now .* fog = 0.6 per km "
                                           r"is visibility_m = 3269"):
        with_file(BUILTIN, '[[weather]]\ncode = "FG1"\nlike = "CN"\nfog = 0.6\n', "fog.toml")
    with pytest.raises(CatalogError, match="key 'visibility_m': 0.5 is out of range"):
        with_file(BUILTIN, '[[weather]]\ncode = "FG1"\nlike = "CN"\nvisibility_m = 0.5\n', "fog.toml")
    # a run.json of a root made before records its weathers' fog as a share: read as a visibility
    recorded = {"weather": [{**{k: v for k, v in _row("FG").items() if k != "visibility_m"}, "code": "HF",
                             "fog": 0.9999999999}]}
    hf = with_layer_json(BUILTIN, __import__("json").dumps(recorded)).by_code("weather")["HF"]
    assert hf.visibility_m == visibility_of_share(0.9999999999) == pytest.approx(130.1, abs=0.1)
    assert current_layer(recorded)["weather"][0]["visibility_m"] == hf.visibility_m
    assert math.isinf(visibility_of_share(0.0)) and share_of_visibility(math.inf) == 0.0
    assert blend_share(weather("CN").visibility_m, weather("FG").visibility_m, 1.0) == pytest.approx(260.2, abs=0.01)


def _row(code: str) -> dict:
    from domains.rows import row_dict

    return row_dict(weather(code))


def test_the_docs_condition_examples_select_what_they_say():
    """docs/weathers.md: --max-condition visibility_m=1000 gives every FG frame and CNtoFG's last 5 of 12
    (each with less than two thirds of its contrast left at 120 m); --min-condition precipitation=0.5 HRN, SN and
    CNtoHRN's last 2 of 12."""
    import pyarrow as pa

    from manifests import query as q
    from manifests.synthetic import episode_table
    from pipeline.planner import make_plan
    from pipeline.settings import PlanConfig

    plan = make_plan(PlanConfig(domains="towns=T01 weathers=CN,FG,CNtoFG,HRN,SN,CNtoHRN,NT viewpoints=A",
                                frames_per_scenario=12, width=64, height=36))
    table = pa.concat_tables([episode_table(spec) for spec in plan.episodes])
    table = table.append_column("weather", pa.array([s.split("_")[1] for s in table.column("scenario").to_pylist()]))
    for column in ("town", "viewpoint"):
        table = table.append_column(column, pa.array([{"town": "T01", "viewpoint": "A"}[column]] * len(table)))

    def chosen(**bounds) -> dict:
        got = q.filter_frames(table, q.Query(domains="catalog", **bounds)).to_pylist()
        return {w: sorted(r["frame"] for r in got if r["weather"] == w) for w in {r["weather"] for r in got}}

    foggy = chosen(max_condition=(("visibility_m", 1000.0),))
    assert foggy == {"FG": list(range(12)), "CNtoFG": list(range(7, 12))}
    assert all(contrast_at(weather_at(weather("CNtoFG"), i, 12, weather).visibility_m, 120) < 2 / 3 for i in range(7, 12))
    assert chosen(min_condition=(("precipitation", 0.5),)) == {"HRN": list(range(12)), "SN": list(range(12)),
                                                               "CNtoHRN": [10, 11]}
