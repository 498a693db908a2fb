"""Expand a domain selection into shards (one per scenario) of episodes.

At full scale the 105 scenarios hold exactly the paper's 1,006,800 frames.
Frames are shared out between towns in proportion to their drivable road
length (the same for every weather and viewpoint of a town), and each shard is
split into episodes of 60-80 frames (3-4 simulated minutes at one frame every
3 s): 60 in the smallest town, 80 in the largest.

A plan holds episodes, never frames, so it stays small at any scale.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field


from domains.catalog import TOWN_BY_CODE, TOWNS, WEATHERS, VIEWPOINTS, Town, catalog_for, using
from outputs.encoding import check_rgb_format
from outputs.table import DEFAULT_OUTPUTS, check_outputs
from domains.rigs import DEFAULT_RIG, rig_named
from domains.selection import parse_selection
from roots.episode_spec import (
    FRAME_PERIOD_S,
    PAIRED,
    UNPAIRED,
    EpisodeSpec,
    check_frame_interval,
    check_pairing,
    check_rules,
    episode_seed,
)
from manifests.schema import NEW_RULES, OLD_RULES

PAPER_TOTAL_FRAMES = 1_006_800
EPISODE_FRAMES = (60, 80)  # 3-4 simulated minutes
MIN_SIZE, MAX_SIZE = 32, 8192  # accepted image width / height in pixels

# Upper bound on --frames-per-scenario: 100 times the paper's largest scenario
# (T01 at full scale). A plan holds one small record per episode, so this
# keeps a typo such as 10**10 from exhausting memory; real runs are far below.
MAX_SCALE_FACTOR = 100

def _largest_remainder(total: int, weights: list[float]) -> list[int]:
    exact = [total * w / sum(weights) for w in weights]
    counts = [math.floor(x) for x in exact]
    by_remainder = sorted(range(len(weights)), key=lambda i: exact[i] - counts[i], reverse=True)
    for i in by_remainder[: total - sum(counts)]:
        counts[i] += 1
    return counts


def full_scale_frames(town: Town) -> int:
    """Frames per scenario of ``town`` at full scale (paper total, by road length).

    A town of the paper's (with its road length) gets its share of the paper's
    total; any other town the same frames per km of road."""
    per_town_column = PAPER_TOTAL_FRAMES // (len(WEATHERS) * len(VIEWPOINTS))
    counts = _largest_remainder(per_town_column, [t.road_km for t in TOWNS])
    builtin = TOWN_BY_CODE.get(town.code)
    if builtin is not None and builtin.road_km == town.road_km:
        return counts[TOWNS.index(builtin)]
    return max(1, round(per_town_column * town.road_km / sum(t.road_km for t in TOWNS)))


def max_frames_per_scenario() -> int:
    """The largest --frames-per-scenario accepted (see MAX_SCALE_FACTOR)."""
    return MAX_SCALE_FACTOR * max(full_scale_frames(t) for t in TOWNS)


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


# What a recorded config (run.json, a plan file) that lacks a key meant when it was written.
RECORDED_DEFAULTS = {"pairing": UNPAIRED, "rules": OLD_RULES, "rig": DEFAULT_RIG}


@dataclass(frozen=True)
class PlanConfig:
    """What the user asked for; validated before any work starts."""

    domains: str = "all"
    scale: float | None = None
    frames_per_scenario: int | None = None
    width: int = 1920
    height: int = 1080
    seed: int = 0
    outputs: tuple[str, ...] = DEFAULT_OUTPUTS  # what every frame writes (outputs.table)
    rgb_format: str = "png"  # the rgb output's file format: png (lossless) or jpg (IDDA's released format)
    catalog: str = ""  # user domain entries in force (Catalog.layer_json; a dict when read back from JSON)
    frame_interval_s: float = FRAME_PERIOD_S  # simulated seconds between frames (3 s: the paper's sparse sampling)
    # roots.episode_spec.PAIRED (new roots): episode seeds leave the weather out; UNPAIRED is what a config
    # recorded before pairing means (run.json or a plan file without the key: RECORDED_DEFAULTS)
    pairing: int = PAIRED
    # manifests.schema.NEW_RULES (new roots): splits per scene, ...; OLD_RULES is what a config recorded
    # before them means (RECORDED_DEFAULTS)
    rules: int = NEW_RULES
    rig: str = DEFAULT_RIG  # the sensor rig every frame is seen by (domains.rigs: a built-in rig's name)

    def __post_init__(self) -> None:
        object.__setattr__(self, "outputs", tuple(self.outputs))  # a list when read back from JSON
        if isinstance(self.catalog, dict):
            object.__setattr__(self, "catalog", json.dumps(self.catalog, separators=(",", ":")) if self.catalog else "")

    def validate(self) -> None:
        rig_named(self.rig)
        if self.scale is not None and self.frames_per_scenario is not None:
            raise ValueError("give either --scale or --frames-per-scenario, not both")
        if self.scale is not None and not (0.0 < self.scale <= 1.0):
            raise ValueError(f"scale must be in (0, 1], got {self.scale}")
        if self.frames_per_scenario is not None and self.frames_per_scenario < 1:
            raise ValueError(
                f"frames per scenario must be at least 1, got {self.frames_per_scenario}"
            )
        if self.frames_per_scenario is not None and self.frames_per_scenario > max_frames_per_scenario():
            raise ValueError(
                f"frames per scenario must be at most {max_frames_per_scenario():,} "
                f"({MAX_SCALE_FACTOR} times the paper's largest scenario), got {self.frames_per_scenario:,}"
            )
        for name, value in (("width", self.width), ("height", self.height)):
            if not (MIN_SIZE <= value <= MAX_SIZE):
                raise ValueError(
                    f"{name} must be between {MIN_SIZE} and {MAX_SIZE} pixels, got {value}"
                )
        if self.seed < 0:
            raise ValueError(f"seed must be a non-negative integer, got {self.seed}")
        with using(catalog_for(self.catalog)):
            parse_selection(self.domains)
        if check_outputs(self.outputs) != self.outputs:
            raise ValueError(f"outputs must be listed once each in table order, got {', '.join(self.outputs)}")
        check_rgb_format(self.rgb_format)
        check_frame_interval(self.frame_interval_s)
        check_pairing(self.pairing)
        check_rules(self.rules)

    def to_dict(self) -> dict:
        """As JSON holds it (run.json, plan files); the catalog only where user entries are in force."""
        out = {**asdict(self), "outputs": list(self.outputs)}
        del out["catalog"]
        return out | ({"catalog": json.loads(self.catalog)} if self.catalog else {})


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
