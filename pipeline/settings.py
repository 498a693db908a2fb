"""A run's settings, in one place: what the user asks for (``PlanConfig``), what defines the dataset in a
root (``RunConfig``: the plan's config and the world) and how one ``idda produce`` runs it (``ProduceConfig``).

Each setting a root records (run.json's ``config``, a plan file's metadata) is one field declared with
``setting()``, which says what run.json may hold for it, whether it defines what a frame looks like, and
what a record written before it existed means. ``CONFIG_TYPES``, ``OPTIONAL_CONFIG``, ``FRAME_DEFINING``
and ``RECORDED_DEFAULTS`` are read from those fields, so a new setting is one field plus its use.
"""

from __future__ import annotations

import copy
import json
import math
from dataclasses import MISSING, asdict, dataclass, field, fields

from domains.catalog import TOWN_BY_CODE, TOWNS, VIEWPOINTS, WEATHERS, Town, catalog_for, using
from domains.rigs import DEFAULT_RIG, rig_named
from domains.selection import parse_selection
from manifests.schema import NEW_RULES, OLD_RULES
from outputs.encoding import check_rgb_format
from outputs.table import DEFAULT_OUTPUTS, SEED_OUTPUTS, check_outputs
from render_workers.worlds.registry import DEFAULT_WORLD, check_world
from roots.episode_spec import FRAME_PERIOD_S, PAIRED, UNPAIRED, check_frame_interval, check_pairing, check_rules
from roots.lease import TTL_S
from roots.run_file import ConfigShape

PAPER_TOTAL_FRAMES = 1_006_800
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
    """Frames per scenario of ``town`` at full scale (--scale 1: the paper's total, by road length).

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


# A recorded setting's field metadata (setting()).
_JSON, _FRAMES, _OPTIONAL, _ABSENT = "json", "frame_defining", "optional", "absent"


def setting(default, json_types: tuple[type, ...], *, frame_defining: bool = False, optional: bool = False,
            absent=MISSING):
    """A field of a setting that run.json records.

    ``json_types``: what its config may hold for it (any other type marks the record damaged; ``None``
    among them: the key may be left out). ``frame_defining``: changing it would make new frames unlike
    the ones in a root, so no run into a root may. ``absent``: what a record without the key means (a
    root from before the setting), filled in when a record is read; ``optional`` alone: a record may
    lack the key, and nothing is filled in."""
    return field(default=default, metadata={_JSON: json_types, _FRAMES: frame_defining,
                                            _OPTIONAL: optional or absent is not MISSING, _ABSENT: absent})


@dataclass(frozen=True)
class PlanConfig:
    """What the user asked for; validated before any work starts."""

    domains: str = setting("all", (str,))
    scale: float | None = setting(None, (float, int, type(None)))
    frames_per_scenario: int | None = setting(None, (int, type(None)))
    width: int = setting(1920, (int,), frame_defining=True)
    height: int = setting(1080, (int,), frame_defining=True)
    seed: int = setting(0, (int,), frame_defining=True)
    # what every frame writes (outputs.table); roots from before --outputs hold the six seed outputs
    outputs: tuple[str, ...] = setting(DEFAULT_OUTPUTS, (list,), frame_defining=True, absent=list(SEED_OUTPUTS))
    # the rgb output's file format: png (lossless) or jpg (IDDA's released format); before --rgb-format: png
    rgb_format: str = setting("png", (str,), frame_defining=True, absent="png")
    # user domain entries in force (Catalog.layer_json; a dict in JSON, docs/catalog.md); absent: built-in only
    catalog: str = setting("", (dict,), optional=True)
    # simulated seconds between frames (3 s: the paper's sparse sampling); before --frame-interval: 3 s
    frame_interval_s: float = setting(FRAME_PERIOD_S, (float, int), frame_defining=True, absent=FRAME_PERIOD_S)
    # roots.episode_spec.PAIRED (new roots): episode seeds leave the weather out; UNPAIRED is what a config
    # recorded before pairing means
    pairing: int = setting(PAIRED, (int,), frame_defining=True, absent=UNPAIRED)
    # manifests.schema.NEW_RULES (new roots): splits per scene, ...; OLD_RULES is what a config recorded
    # before them means
    rules: int = setting(NEW_RULES, (int,), frame_defining=True, absent=OLD_RULES)
    # the sensor rig every frame is seen by (domains.rigs): a built-in rig's name, or a domain file's declared
    # rig as JSON; roots from before rigs: front
    rig: str = setting(DEFAULT_RIG, (str,), frame_defining=True, absent=DEFAULT_RIG)

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
class RunConfig:
    """What defines the dataset in one output root."""

    plan: PlanConfig
    # the world builder (render_workers.worlds.registry); roots from before --world may lack it
    world: str = setting(DEFAULT_WORLD, (str,), frame_defining=True, optional=True)

    def to_dict(self) -> dict:
        return {**self.plan.to_dict(), "world": self.world}


# The recorded settings: run.json's config keys, in the order of the fields.
RECORDED = tuple(f for f in fields(PlanConfig) + fields(RunConfig) if _JSON in f.metadata)
CONFIG_TYPES: dict[str, tuple[type, ...]] = {f.name: f.metadata[_JSON] for f in RECORDED}
OPTIONAL_CONFIG = tuple(f.name for f in RECORDED if f.metadata[_OPTIONAL])  # keys older records may lack
FRAME_DEFINING = tuple(f.name for f in RECORDED if f.metadata[_FRAMES])  # fixed for a root's life
# What a recorded config (run.json, a plan file) that lacks a key meant when it was written.
RECORDED_DEFAULTS = {f.name: f.metadata[_ABSENT] for f in RECORDED if f.metadata[_ABSENT] is not MISSING}
CONFIG_SHAPE = ConfigShape(CONFIG_TYPES, OPTIONAL_CONFIG)  # what roots.run_file checks a record's config by


def recorded(config: dict) -> dict:
    """A recorded config as today's settings read it: a key a record from before its setting lacks
    holds what it meant then (RECORDED_DEFAULTS)."""
    return {**copy.deepcopy(RECORDED_DEFAULTS), **config}


@dataclass(frozen=True)
class ProduceConfig:
    run: RunConfig
    out: str  # output root: local path or s3:// URI
    address: str | None = None  # Ray cluster; None: RAY_ADDRESS, else a local cluster
    workers: int | None = None  # CPUs of the local cluster (default: all cores)
    cpus_per_task: float = 1.0
    gpus_per_task: float = 0.0  # e.g. 0.25 to pack four renderers on one GPU
    max_retries: int = 3  # per episode, for worker/node death and renderer errors
    max_in_flight: int | None = None  # default: twice the cluster's task slots
    progress_interval_s: float = 1.0  # least time between two progress reports of one task
    extend: bool = False
    repair: bool = False
    lease_ttl_s: float = TTL_S  # the producer lease's time to live (the CLI reads IDDA_LEASE_TTL_S)
    index_every_s: float = 180.0  # fold finished parts into their scenarios' indexes this often

    def validate(self) -> None:
        self.run.plan.validate()
        check_world(self.run.world)  # here, not in each of the Ray tasks
        if self.workers is not None and self.workers < 1:
            raise ValueError(f"workers must be at least 1, got {self.workers}")
        if self.cpus_per_task <= 0:
            raise ValueError(f"cpus per task must be positive, got {self.cpus_per_task}")
        if not 0 <= self.gpus_per_task <= 1:
            raise ValueError(f"gpus per task must be in [0, 1], got {self.gpus_per_task}")
        if self.max_retries < 0:
            raise ValueError(f"max retries must be >= 0, got {self.max_retries}")
        if self.max_in_flight is not None and self.max_in_flight < 1:
            raise ValueError(f"max in flight must be at least 1, got {self.max_in_flight}")
        if not self.lease_ttl_s > 0 or not self.index_every_s > 0:
            raise ValueError(f"lease ttl and index interval must be positive, got {self.lease_ttl_s}, {self.index_every_s}")
        if self.progress_interval_s < 0:
            raise ValueError(f"progress interval must be >= 0 s, got {self.progress_interval_s}")
