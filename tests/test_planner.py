from collections import Counter

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from domains.catalog import ALL_SCENARIOS, TOWNS
from domains.selection import parse_selection
from manifests.schema import NEW_RULES, OLD_RULES, RULES
from pipeline.planner import episode_target, make_plan, scene_places
from pipeline.settings import PAPER_TOTAL_FRAMES, PlanConfig, full_scale_frames


@pytest.fixture(scope="module")
def full_plan():
    return make_plan(PlanConfig())


def test_full_scale_matches_paper(full_plan):
    assert len(full_plan.scenarios()) == 105
    assert full_plan.total_frames == PAPER_TOTAL_FRAMES == 1_006_800


def test_episode_lengths_within_60_80(full_plan):
    lengths = {e.frames for e in full_plan.episodes}
    assert min(lengths) >= 60 and max(lengths) <= 80


def test_shards_monotone_in_town_length():
    by_length = sorted(TOWNS, key=lambda t: t.road_km)
    frames = [full_scale_frames(t) for t in by_length]
    targets = [episode_target(t) for t in by_length]
    assert frames == sorted(frames) and len(set(frames)) == len(frames)
    assert targets == sorted(targets)
    assert targets[0] == 60 and targets[-1] == 80


def test_paper_subsets_drawable(full_plan):
    per_scenario = {code: sum(e.frames for e in eps) for code, eps in full_plan.by_scenario().items()}
    worst = [s.code for s in parse_selection("towns=T07 weathers=HRN viewpoints=J,B")]
    assert sum(per_scenario[c] for c in worst) >= 40_128
    best = [s.code for s in parse_selection("towns=T01-T06 weathers=CN viewpoints=A,M")]
    assert len(best) == 12 and all(per_scenario[c] >= 2_496 for c in best)


def test_seeds_deterministic_distinct_and_independent_of_selection(full_plan):
    again = make_plan(PlanConfig())
    assert [e.seed for e in again.episodes] == [e.seed for e in full_plan.episodes]
    # paired (a new plan's default): one seed per town, viewpoint and episode, shared by its weathers
    scenes: dict = {}
    for e in full_plan.episodes:
        scenes.setdefault((e.town, e.viewpoint, e.episode), set()).add(e.seed)
    assert all(len(seeds) == 1 for seeds in scenes.values())
    assert len({e.seed for e in full_plan.episodes}) == len(scenes)
    sub = make_plan(PlanConfig(domains="T03_CS_M"))
    full_t03 = [e for e in full_plan.episodes if e.scenario == "T03_CS_M"]
    assert [e.seed for e in sub.episodes] == [e.seed for e in full_t03]
    other_seed = make_plan(PlanConfig(domains="T03_CS_M", seed=1))
    assert other_seed.episodes[0].seed != sub.episodes[0].seed


def test_seed_zero_is_a_real_seed():
    zero = make_plan(PlanConfig(domains="T01_CN_A", seed=0))
    one = make_plan(PlanConfig(domains="T01_CN_A", seed=1))
    assert zero.episodes[0].seed != one.episodes[0].seed


def test_splits_cover_train_val_test(full_plan):
    for code, eps in list(full_plan.by_scenario().items())[:5]:
        splits = [e.split for e in eps]
        assert set(splits) == {"train", "val", "test"}
        assert splits.count("train") > splits.count("val")


def _splits(plan) -> dict[tuple[str, int], str]:
    return {(e.scenario, e.episode): e.split for e in plan.episodes}


def test_make_produce_default_has_every_split():
    """make produce: 2 frames of each of the 105 scenarios, one episode each."""
    plan = make_plan(PlanConfig(domains="all", frames_per_scenario=2, width=480, height=270))
    counts = Counter(e.split for e in plan.episodes)
    assert len(plan.episodes) == 105 and counts == {"train": 81, "val": 12, "test": 12}


@settings(max_examples=60, deadline=None)
@given(
    codes=st.lists(st.sampled_from([s.code for s in ALL_SCENARIOS]), min_size=1, max_size=6, unique=True),
    frames=st.integers(1, 700),
    scaled=st.booleans(),
    rules=st.sampled_from(RULES),
)
def test_every_run_of_three_or_more_episodes_has_every_split(codes, frames, scaled, rules):
    """Of three or more episodes (OLD_RULES), or of three or more scenes' episodes (NEW_RULES: the
    weathers of one scene share its split)."""
    size = {"scale": frames / 20_000} if scaled else {"frames_per_scenario": frames}  # scale: towns differ
    plan = make_plan(PlanConfig(domains=",".join(codes), rules=rules, **size))
    units = {(e.scenario, e.episode) if rules == OLD_RULES else (e.town, e.viewpoint, e.episode) for e in plan.episodes}
    if len(units) >= 3:
        assert {e.split for e in plan.episodes} == {"train", "val", "test"}, _splits(plan)


@settings(max_examples=40, deadline=None)
@given(
    codes=st.lists(st.sampled_from([s.code for s in ALL_SCENARIOS]), min_size=1, max_size=4, unique=True),
    small=st.integers(1, 400),
    more=st.integers(0, 2000),
    rules=st.sampled_from(RULES),
)
def test_extending_a_run_never_changes_an_episode_split(codes, small, more, rules):
    domains = ",".join(codes)
    before = _splits(make_plan(PlanConfig(domains=domains, frames_per_scenario=small, rules=rules)))
    after = _splits(make_plan(PlanConfig(domains=domains, frames_per_scenario=small + more, rules=rules)))
    assert before.items() <= after.items()


def test_scenarios_tend_to_80_10_10():
    plan = make_plan(PlanConfig(domains="T01_CN_A,T01_CN_M", frames_per_scenario=16_000))
    for eps in plan.by_scenario().values():
        tens = len(eps) // 10 * 10  # every 10 episodes of a scenario: 8 train, 1 val, 1 test
        assert tens >= 200
        counts = Counter(e.split for e in eps[:tens])
        assert counts == {"train": tens * 8 // 10, "val": tens // 10, "test": tens // 10}


def test_scaled_and_fixed_size_plans():
    half = make_plan(PlanConfig(domains="T01_CN_A", scale=0.5))
    assert half.total_frames == round(0.5 * full_scale_frames(TOWNS[0]))
    fixed = make_plan(PlanConfig(domains="towns=T01,T07 weathers=CN viewpoints=A", frames_per_scenario=7))
    assert fixed.total_frames == 14 and len(fixed.episodes) == 2
    small = make_plan(PlanConfig(scale=0.001))
    assert len(small.scenarios()) == 105 and all(e.frames >= 1 for e in small.episodes)
    assert all(e.frames <= 80 for e in make_plan(PlanConfig(frames_per_scenario=200)).episodes)


def test_plan_holds_episodes_not_frames(full_plan):
    assert len(full_plan.episodes) < 20_000


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(scale=0.0), r"scale must be in \(0, 1\]"),
        (dict(scale=1.5), r"scale must be in \(0, 1\]"),
        (dict(width=0), "width must be between 32 and 8192"),
        (dict(height=-5), "height must be between 32 and 8192"),
        (dict(width=100_000), "width must be between"),
        (dict(frames_per_scenario=0), "at least 1"),
        (dict(scale=0.5, frames_per_scenario=3), "either"),
        (dict(domains="towns=T09"), "valid towns: T01, T02"),
        (dict(seed=-1), "non-negative"),
    ],
)
def test_bad_configs_raise_clear_errors(kwargs, message):
    with pytest.raises(ValueError, match=message):
        make_plan(PlanConfig(**kwargs))


def test_every_weather_of_a_scene_shares_its_split_and_old_rules_stay():
    """Issue 32: under NEW_RULES the split is drawn per scene (town, viewpoint, episode), so a paired
    root never has one scene on both sides of a split, whatever weathers it holds or adds later; a
    root of OLD_RULES keeps its splits per scenario place (the same scene was train, val and test)."""
    domains = "towns=T01,T02 weathers=CN,FG,NT,HRN viewpoints=A,M"
    new = make_plan(PlanConfig(domains=domains, frames_per_scenario=400))
    by_scene: dict = {}
    for e in new.episodes:
        by_scene.setdefault((e.town, e.viewpoint, e.episode), set()).add(e.split)
    assert all(len(splits) == 1 for splits in by_scene.values()) and len(by_scene) >= 4 * 5
    assert Counter(next(iter(s)) for s in by_scene.values()).keys() == {"train", "val", "test"}
    old = make_plan(PlanConfig(domains="T01_CN_A,T01_FG_A,T01_NT_A", frames_per_scenario=2, rules=OLD_RULES))
    assert [e.split for e in old.episodes] == ["train", "val", "test"]  # the old rule, unchanged
    assert PlanConfig().rules == NEW_RULES and PlanConfig().to_dict()["rules"] == 1
    # a root's later selections keep the places of the scenes it had (pipeline.provenance.for_root)
    first = scene_places(["T02_CN_M"])
    later = scene_places(["T02_CN_M", "towns=T01,T02 weathers=FG viewpoints=A,M"])
    assert later[("T02", "M")] == first[("T02", "M")] == 0 and set(later.values()) == {0, 1, 2, 3}


def test_make_produce_default_splits_under_both_rules():
    """105 one-episode scenarios: 35 scenes of 3 weathers give 27/4/4 scenes, the same 81/12/12 episodes."""
    for rules in RULES:
        plan = make_plan(PlanConfig(domains="all", frames_per_scenario=2, rules=rules))
        assert Counter(e.split for e in plan.episodes) == {"train": 81, "val": 12, "test": 12}
