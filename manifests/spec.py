"""The job spec: a small frozen description of one episode to render.

Workers take a spec and return a small result; they never take live objects.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class EpisodeSpec:
    """A small, serialisable job: everything a worker needs to render an episode."""

    scenario: str  # scenario code, e.g. T01_CS_A
    episode: int  # episode index within the scenario
    seed: int  # episode seed (traffic, spawn point, pedestrians)
    frames: int  # frames to render, one every FRAME_PERIOD_S
    width: int
    height: int
    split: str  # train | val | test
    run_seed: int  # the run's seed; the town's world derives from it

    @property
    def town(self) -> str:
        return self.scenario.split("_")[0]

    @property
    def weather(self) -> str:
        return self.scenario.split("_")[1]

    @property
    def viewpoint(self) -> str:
        return self.scenario.split("_")[2]

    @property
    def key(self) -> str:
        """Unique name of the episode within a run."""
        return f"{self.scenario}/e{self.episode:04d}"
