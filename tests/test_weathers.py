"""Issue 25.2: the built-in weathers beyond the paper (FG, NT, SN) look like what they are,
their labels are the paper's weathers' labels, and each frame records its conditions."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from domains.catalog import ALL_SCENARIOS, BUILTIN, EXTRA_WEATHERS, class_id, weather
from domains.conditions import frame_conditions
from domains.catalog_file import with_file
from domains.selection import parse_selection
from roots.episode_spec import EpisodeSpec
from render_workers.render import episode
from render_workers.render.renderer import Renderer

W, H = 160, 90
GROUND = [class_id(name) for name in ("road", "sidewalk", "terrain")]
DENSER = """
[[weather]]
code = "FG2"
like = "FG"
visibility_m = 100.0
"""


@pytest.fixture(scope="module")
def frames():
    """Frame 1 of the same episode (same seed) under CN, FG, a denser FG, NT and SN, in the test world."""
    layer = with_file(BUILTIN, DENSER, "dense.toml").layer_json()
    out = {}
    with Renderer() as renderer:
        for code in ("CN", "FG", "FG2", "NT", "SN"):
            got = []
            spec = EpisodeSpec(f"T01_{code}_A", 0, 3, 2, W, H, "train", 0, catalog=layer)
            episode.render_episode(spec.drawing, got.append, world="test", renderer=renderer)
            out[code] = got[-1]
    return out


def _luminance(frame) -> np.ndarray:
    return cv2.cvtColor(frame.buffers["rgb"], cv2.COLOR_RGB2GRAY).astype(np.float64)


def _far_contrast(frame) -> float:
    """Standard deviation of luminance over surfaces 40 m or more away (not the sky)."""
    far = (frame.buffers["depth"] >= 40.0) & (frame.buffers["classes"] != class_id("sky"))
    assert far.sum() > 50
    return float(_luminance(frame)[far].std())


def test_the_paper_catalog_is_unchanged_and_catalog_selects_the_new_weathers():
    assert [w.code for w in BUILTIN.weathers[:6]] == ["CN", "CS", "HRN", "FG", "NT", "SN"]
    assert {"FG", "NT", "SN"} <= EXTRA_WEATHERS
    assert len(ALL_SCENARIOS) == 105 and len(parse_selection("all")) == 105
    assert {s.weather.code for s in parse_selection("catalog")} >= {"CN", "FG", "NT", "SN"}
    # an open axis or a '*' keeps meaning the paper's weathers; naming them selects the new ones
    assert {s.weather.code for s in parse_selection("towns=T01 viewpoints=A")} == {"CN", "CS", "HRN"}
    assert {s.weather.code for s in parse_selection("T01_*_A")} == {"CN", "CS", "HRN"}
    assert [s.code for s in parse_selection("T01_SN_A weathers=SN")] == ["T01_SN_A"]
    assert [s.code for s in parse_selection("towns=T01 weathers=FG,NT viewpoints=A")] == ["T01_FG_A", "T01_NT_A"]


def test_fog_lowers_far_contrast_with_density(frames):
    cn, fg, denser = (_far_contrast(frames[c]) for c in ("CN", "FG", "FG2"))
    print(f"far contrast (luminance std, depth >= 40 m): CN {cn:.1f}, FG {fg:.1f}, FG2 {denser:.1f}")
    assert denser < 0.8 * fg and fg < 0.6 * cn
    near = frames["FG"].buffers["depth"] < 8.0
    assert _luminance(frames["FG"])[near].std() > 2 * denser  # near things keep their contrast


def test_night_is_dark_except_where_lights_are(frames):
    noon, night = _luminance(frames["CN"]), _luminance(frames["NT"])
    bright = np.percentile(night, 99.5)
    print(f"mean luminance CN {noon.mean():.1f}, NT {night.mean():.1f}; NT 99.5th percentile {bright:.0f}")
    assert night.mean() < 0.4 * noon.mean()
    assert bright >= 150  # lamps, windows and car lights stay bright


def test_snow_whitens_the_ground(frames):
    ground = np.isin(frames["CN"].buffers["classes"], GROUND)
    assert ground.sum() > 100
    stats = {}
    for code in ("CN", "SN"):
        rgb = frames[code].buffers["rgb"][ground].astype(np.float64)
        stats[code] = (rgb.mean(), rgb.min(axis=1).mean())  # brightness; whiteness (the darkest channel)
    print(f"ground brightness / whiteness: CN {stats['CN'][0]:.1f} / {stats['CN'][1]:.1f}, "
          f"SN {stats['SN'][0]:.1f} / {stats['SN'][1]:.1f}")
    assert stats["SN"][0] > stats["CN"][0] + 12 and stats["SN"][1] > stats["CN"][1] + 12


def test_labels_are_the_same_under_every_weather_and_rows_carry_conditions(frames):
    reference = frames["CN"].buffers
    for code, frame in frames.items():
        for name in ("classes", "instance", "depth"):
            assert np.array_equal(frame.buffers[name], reference[name]), (code, name)
        if code != "FG2":
            assert frame.conditions == frame_conditions(weather(code))
    assert frames["SN"].conditions["snow_cover"] == 0.85 and frames["NT"].conditions["sun_altitude_deg"] < 0


ROAD = [class_id("road"), class_id("road line")]


def _ground_xy(frame) -> np.ndarray:
    """HxWx2 world (x, y) of each pixel's surface, from its depth and the frame's calibration."""
    K, cam_to_world = np.reshape(frame.K, (3, 3)), np.reshape(frame.cam_to_world, (4, 4))
    depth = frame.buffers["depth"].astype(np.float64)
    rows, cols = np.indices(depth.shape) + 0.5
    cam = np.stack([(cols - K[0, 2]) / K[0, 0] * depth, (rows - K[1, 2]) / K[1, 1] * depth, depth], axis=-1)
    return (cam @ cam_to_world[:3, :3].T + cam_to_world[:3, 3])[..., :2]


def _lane_offset(xy: np.ndarray, lanes) -> np.ndarray:
    """Distance of each point (..., 2) to the nearest lane centre line (closed polylines)."""
    best = np.full(xy.shape[:-1], np.inf)
    for lane in lanes:
        p = lane.points[:, :2]
        for a, b in zip(p, np.roll(p, -1, axis=0)):
            t = np.clip(((xy - a) @ (b - a)) / max((b - a) @ (b - a), 1e-12), 0.0, 1.0)
            best = np.minimum(best, np.linalg.norm(xy - (a + t[..., None] * (b - a)), axis=-1))
    return best


def test_snow_covers_the_road_but_for_darker_wheel_tracks(frames):
    """Issue 34.3: the road under snow is mostly white (luminance over 200), the lanes' wheel tracks (0.8 m either
    side of a lane's centre line) are grey slush, darker than the snow between them."""
    from domains.catalog import town as town_row
    from roots.episode_spec import town_seed

    frame = frames["SN"]
    lum = _luminance(frame)
    road = np.isin(frame.buffers["classes"], ROAD)
    lanes = episode.cached_world("test", "T01", town_seed(0, town_row("T01"))).lanes
    offset = _lane_offset(_ground_xy(frame), lanes)
    near = road & (frame.buffers["depth"] < 15.0)
    in_track, between = near & (np.abs(offset - 0.8) < 0.15), near & (offset < 0.3)
    bright, dark = np.mean(lum[road] > 200), np.mean(lum[road] < 150)
    print(f"SN road pixels above 200: {bright:.2f}, below 150: {dark:.2f}; near luminance in the wheel tracks "
          f"{lum[in_track].mean():.0f} ({in_track.sum()} px), between them {lum[between].mean():.0f} ({between.sum()} px)")
    assert road.sum() > 500 and in_track.sum() > 20 and between.sum() > 20
    assert bright > 0.35 and dark > 0.05
    assert lum[in_track].mean() < lum[between].mean() - 25

