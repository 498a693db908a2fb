"""The job spec: a small frozen description of one episode to render.

Workers take a spec and return a small result; they never take live objects.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from domains.catalog import Scenario, Town, active, code_axes
from domains.rigs import rig_from_json
from outputs.deflaters import DEFAULT_DEFLATER
from outputs.encoding import check_rgb_format
from manifests.layout import NEW_ROOT_LAYOUT, check_layout
from manifests.schema import NEW_RULES, RULES
from outputs.table import DEFAULT_OUTPUTS, LIDAR_OUTPUTS, check_outputs, output

FRAME_PERIOD_S = 3.0  # the default frame interval: one frame every 3 s of simulated time (the paper's)
MAX_FRAME_INTERVAL_S = 60.0
_EPISODE_STREAM = 2  # rng stream ids keep seeds of different uses apart
_TOWN_STREAM = 3
_PAIRED_STREAM = 5
# Pairing (docs/weathers.md, "Paired scenes"): in a paired root an episode's seed (traffic, spawn
# point, motion) comes from the run seed, town, viewpoint and episode, not the weather, so the same
# episode under every weather is the same scene and its labels match pixel for pixel. New roots are
# paired (run.json's config records "pairing": 1); a root made before, without the key, keeps the
# old per-weather seeds (UNPAIRED) for its life.
UNPAIRED, PAIRED = 0, 1
PAIRINGS = (UNPAIRED, PAIRED)


def check_frame_interval(seconds: float) -> float:
    """ValueError unless ``seconds`` is a usable frame interval: (0, MAX_FRAME_INTERVAL_S]."""
    if not (isinstance(seconds, (int, float)) and 0.0 < seconds <= MAX_FRAME_INTERVAL_S):
        raise ValueError(f"frame interval must be in (0, {MAX_FRAME_INTERVAL_S:g}] seconds, got {seconds!r}")
    return float(seconds)


def town_seed(run_seed: int, town: Town) -> int:
    """Seed of a town's static world: shared by all its weathers and viewpoints."""
    rng = np.random.default_rng([run_seed, _TOWN_STREAM, active().place("town", town.code)])
    return int(rng.integers(0, 2**63 - 1))


def episode_seed(run_seed: int, scenario: Scenario, episode: int, pairing: int = UNPAIRED) -> int:
    """Seed of one episode (traffic, spawn point); independent of the selection. ``pairing``:
    PAIRED leaves the weather out (the same scene under every weather), UNPAIRED (roots made
    before pairing) keeps it in."""
    if pairing == PAIRED:
        cat = active()
        key = [cat.place("town", scenario.town.code), cat.place("viewpoint", scenario.viewpoint.code)]
        rng = np.random.default_rng([run_seed, _PAIRED_STREAM, *key, episode])
    else:
        rng = np.random.default_rng([run_seed, _EPISODE_STREAM, *scenario.key, episode])
    return int(rng.integers(0, 2**63 - 1))


def check_pairing(pairing) -> int:
    if isinstance(pairing, bool) or pairing not in PAIRINGS:
        raise ValueError(f"unknown pairing {pairing!r} (known: {', '.join(map(str, PAIRINGS))})")
    return pairing


def check_rules(rules) -> int:
    if isinstance(rules, bool) or rules not in RULES:
        raise ValueError(f"unknown rules {rules!r} (known: {', '.join(map(str, RULES))})")
    return rules


@dataclass(frozen=True)
class DrawSpec:
    """What the renderer draws an episode from (``EpisodeSpec.drawing``): the scene, its seeds, size and
    timing, and the named buffers to make. How the frames are encoded and where they go is the writer's."""

    scenario: str  # scenario code, e.g. T01_CS_A
    episode: int  # episode index within the scenario (names the episode in messages)
    seed: int  # episode seed (traffic, spawn point, pedestrians, sky, post effects)
    frames: int  # frames to render, one every frame_interval_s
    width: int
    height: int
    run_seed: int  # the run's seed; the town's world derives from it
    buffers: frozenset[str]  # the renderer's named buffers to make (the outputs' sources: outputs.table)
    catalog: str = ""  # the run's user domain entries (domains.rows.Catalog.layer_json); "" = built-in only
    frame_interval_s: float = FRAME_PERIOD_S  # simulated seconds between frames (--frame-interval)
    rules: int = NEW_RULES  # the root's rules: OLD_RULES draws a weather shift's ramp as roots made before them
    rig: str = ""  # the run's sensor rig as JSON (domains.rigs.Rig.as_json); "" = the default rig, front

    def frame_time(self, index: int) -> float:
        """Simulated time of frame ``index`` in seconds (frame 0 at 0)."""
        return index * self.frame_interval_s

    @property
    def key(self) -> str:
        """Unique name of the episode within a run."""
        return episode_key(self.scenario, self.episode)


@dataclass(frozen=True)
class EpisodeResult:
    """What a worker reports back: small, never image data. Defined here, beside the job, not with the
    worker's code (pipeline.episode_job): the driver unpickles it in ray.get, and a class whose module
    the driver has not imported yet is imported right there (the renderer, a second or more), inside
    Ray's deserialization, which turns a Ctrl-C or SIGTERM arriving then into a failed result: the stop
    was lost and the run went on (tests/test_signals.py)."""

    scenario: str
    episode: int
    frames: int
    seconds: float
    node: str
    pid: int


def episode_key(scenario: str, episode: int) -> str:
    """An episode's name within a run: ``T01_CS_A/e0003``."""
    return f"{scenario}/e{episode:04d}"


@dataclass(frozen=True)
class EpisodeSpec:
    """A small, serialisable job: everything a worker needs to render an episode (``drawing``: what the
    renderer takes of it) and write its files (outputs, rgb format, layout, PNG deflater, split)."""

    scenario: str  # scenario code, e.g. T01_CS_A
    episode: int  # episode index within the scenario
    seed: int  # episode seed (traffic, spawn point, pedestrians)
    frames: int  # frames to render, one every frame_interval_s
    width: int
    height: int
    split: str  # train | val | test
    run_seed: int  # the run's seed; the town's world derives from it
    outputs: tuple[str, ...] = DEFAULT_OUTPUTS  # which outputs to write (outputs.table)
    rgb_format: str = "png"  # the rgb output's file format (outputs.encoding.RGB_FORMATS)
    layout: int = NEW_ROOT_LAYOUT  # where the frame files go: the root's layout (manifests.layout)
    catalog: str = ""  # the run's user domain entries (domains.rows.Catalog.layer_json); "" = built-in only
    frame_interval_s: float = FRAME_PERIOD_S  # simulated seconds between frames (--frame-interval)
    png_deflater: str = DEFAULT_DEFLATER  # the root's PNG deflater (outputs.deflaters): an older root keeps its own
    rules: int = NEW_RULES  # the root's rules (OLD_RULES in roots made before them: run.json without "rules")
    rig: str = ""  # the run's sensor rig as JSON (domains.rigs.Rig.as_json); "" = the default rig, front

    @property
    def sensors(self) -> tuple[str, ...]:
        """The names of the rig's sensors, in the order each frame renders them; ("",) for the default rig."""
        rig = rig_from_json(self.rig)
        return ("",) if rig.is_default else tuple(s.name for s in rig.sensors)

    def sensor_outputs(self, sensor: str) -> tuple[str, ...]:
        """The outputs ``sensor`` writes: the spec's for a camera, the LiDAR's own files for a lidar."""
        rig = rig_from_json(self.rig)
        kind = "camera" if rig.is_default else next(s.kind for s in rig.sensors if s.name == sensor)
        return LIDAR_OUTPUTS if kind == "lidar" else self.outputs

    @property
    def drawing(self) -> DrawSpec:
        """What the renderer takes of this job: nothing of how its frames are encoded or filed."""
        return DrawSpec(scenario=self.scenario, episode=self.episode, seed=self.seed, frames=self.frames,
                        width=self.width, height=self.height, run_seed=self.run_seed, buffers=self.buffers,
                        catalog=self.catalog, frame_interval_s=self.frame_interval_s, rules=self.rules,
                        rig=self.rig)

    @property
    def town(self) -> str:
        return code_axes(self.scenario)["town"]

    @property
    def weather(self) -> str:
        return code_axes(self.scenario)["weather"]

    @property
    def viewpoint(self) -> str:
        return code_axes(self.scenario)["viewpoint"]

    @property
    def buffers(self) -> frozenset[str]:
        """The renderer's named buffers this spec's outputs are encoded from (each output row names one)."""
        return frozenset(output(name).source for name in self.outputs)

    def check_outputs(self) -> None:
        """ValueError for an unknown output, rgb format or layout, or a frame interval out of range."""
        check_outputs(self.outputs)
        check_rgb_format(self.rgb_format)
        check_layout(self.layout)
        check_frame_interval(self.frame_interval_s)
        check_rules(self.rules)
        rig = rig_from_json(self.rig)
        if not rig.is_default and self.layout != NEW_ROOT_LAYOUT:
            raise ValueError(f"rig {rig.name!r} needs the episode-folder layout; this root is flat (make a new root)")

    @property
    def key(self) -> str:
        """Unique name of the episode within a run."""
        return episode_key(self.scenario, self.episode)
