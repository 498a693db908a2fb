"""Expand a domain selection into shards (one per scenario) of episodes.

At full scale the 105 scenarios hold exactly the paper's 1,006,800 frames.
Frames are shared out between towns in proportion to their drivable road
length (the same for every weather and viewpoint of a town), and each shard is
split into episodes of 60-80 frames (3-4 simulated minutes at one frame every
3 s): 60 in the smallest town, 80 in the largest.

A plan holds episodes, never frames, so it stays small at any scale.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from domains.catalog import TOWNS, Town, catalog_for, using
from domains.rigs import rig_named
from domains.selection import parse_selection
from manifests.schema import NEW_RULES
from pipeline.settings import PlanConfig, full_scale_frames
from roots.episode_spec import EpisodeSpec, episode_seed

EPISODE_FRAMES = (60, 80)  # 3-4 simulated minutes


def episode_target(town: Town) -> int:
    """Target episode length: 60 frames in the shortest town, 80 in the longest."""
    lo, hi = EPISODE_FRAMES
    lengths = [t.road_km for t in TOWNS]
    share = (town.road_km - min(lengths)) / (max(lengths) - min(lengths))
    return round(lo + min(1.0, max(0.0, share)) * (hi - lo))


def split_episodes(frames: int, target: int) -> list[int]:
    """Split ``frames`` into near-equal episodes close to ``target``, none above 80."""
    n = max(1, round(frames / target), math.ceil(frames / EPISODE_FRAMES[1]))
    base, extra = divmod(frames, n)
    return [base + (1 if i < extra else 0) for i in range(n)]


@dataclass(frozen=True)
class Plan:
    config: PlanConfig
    episodes: tuple[EpisodeSpec, ...] = field(repr=False)

    @property
    def total_frames(self) -> int:
        return sum(e.frames for e in self.episodes)

    def scenarios(self) -> list[str]:
        return list(dict.fromkeys(e.scenario for e in self.episodes))

    def by_scenario(self) -> dict[str, list[EpisodeSpec]]:
        out: dict[str, list[EpisodeSpec]] = {}
        for e in self.episodes:
            out.setdefault(e.scenario, []).append(e)
        return out


def scenario_frames(config: PlanConfig, town: Town) -> int:
    if config.frames_per_scenario is not None:
        return config.frames_per_scenario
    full = full_scale_frames(town)
    if config.scale is None:
        return full
    return max(1, round(config.scale * full))


# The split rule (docs/layout.md, "Splits"). Episode ``e`` of the scenario at
# place ``r`` (0-based, table order) in the run's selection takes
# SPLIT_PATTERN[(2 * e + r) % 20]. Places 0-2 are train, val, test, so any run
# of three or more episodes has all three splits: three scenarios fill them
# with their first episodes, one scenario with its first three (places 0, 2, 4)
# and two scenarios with any third episode (places 2 and 3 are both test). Each
# scenario steps through every other place, and each half of the pattern holds
# 8 train, 1 val and 1 test, so every scenario tends to 80/10/10 % (the shares
# of SPLIT_SHARES). An episode's split depends only on (e, r): adding frames or
# episodes to a run never changes the split of an episode it had.
#
# That is the rule of roots made before rules (OLD_RULES). A root of NEW_RULES draws the split per
# scene (town, viewpoint, episode): r is the scene's place among the root's scenes (scene_places:
# the (town, viewpoint) pairs of its selections in table order, a later --extend's new pairs after
# the earlier ones), never the weather's, so every weather of a scene has the same split, a paired
# root never puts one scene on both sides, and extending a root to other domains never moves a scene.
SPLIT_PATTERN = ("train", "val", "test", "test", "val") + ("train",) * 15


def episode_split(place: int, episode: int) -> str:
    """The split of episode ``episode`` of the scenario (or scene) at ``place``."""
    return SPLIT_PATTERN[(2 * episode + place) % len(SPLIT_PATTERN)]


def scene_places(selections) -> dict[tuple[str, str], int]:
    """(town, viewpoint) -> the scene's place in the split rule of NEW_RULES roots: the scenes of
    ``selections`` (a root's selections in the order it was asked for them: run.json's history, then
    this run's) in order of first appearance, each selection's in table order."""
    places: dict[tuple[str, str], int] = {}
    for selection in selections:
        for s in parse_selection(selection):
            places.setdefault((s.town.code, s.viewpoint.code), len(places))
    return places


def scene_split(places: dict[tuple[str, str], int], scenario, episode: int) -> str:
    """The split of ``episode`` of ``scenario`` (a Scenario) under NEW_RULES, ``places`` from scene_places."""
    return episode_split(places[scenario.town.code, scenario.viewpoint.code], episode)


def make_plan(config: PlanConfig) -> Plan:
    """Build the plan; raises ValueError for any invalid config."""
    config.validate()
    with using(catalog_for(config.catalog)):
        return _plan(config)


def _plan(config: PlanConfig) -> Plan:
    episodes: list[EpisodeSpec] = []
    scenes = scene_places([config.domains]) if config.rules >= NEW_RULES else None  # a new root's
    rig = rig_named(config.rig)
    for place, scenario in enumerate(parse_selection(config.domains)):
        lengths = split_episodes(scenario_frames(config, scenario.town), episode_target(scenario.town))
        for index, frames in enumerate(lengths):
            episodes.append(
                EpisodeSpec(
                    scenario=scenario.code,
                    episode=index,
                    seed=episode_seed(config.seed, scenario, index, config.pairing),
                    frames=frames,
                    width=config.width,
                    height=config.height,
                    split=episode_split(place, index) if scenes is None else scene_split(scenes, scenario, index),
                    run_seed=config.seed,
                    outputs=config.outputs,
                    rgb_format=config.rgb_format,
                    catalog=config.catalog,
                    frame_interval_s=float(config.frame_interval_s),
                    rules=config.rules,
                    rig="" if rig.is_default else rig.as_json(),
                )
            )
    return Plan(config=config, episodes=tuple(episodes))
