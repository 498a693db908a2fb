"""Done / pending per scenario for an output root, with a time estimate."""

from __future__ import annotations

import json
from dataclasses import dataclass, field

from manifests.reader import episode_frames, part_files, rows_read
from roots.contract import require_root
from roots.run_file import REPAIR_HINT
from manifests.schema import STATS_DIR
from pipeline.planner import make_plan
from pipeline.provenance import read_run, recorded_config
from storage import StorageError


@dataclass
class ScenarioStatus:
    scenario: str
    episodes_done: int
    episodes_total: int
    frames_done: int
    frames_total: int


@dataclass
class RootStatus:
    uri: str
    config: dict
    scenarios: list[ScenarioStatus] = field(default_factory=list)
    frames_per_s: float | None = None  # rate of the last produce run
    extra_episodes: int = 0  # done episodes outside the recorded plan (from --extend history)
    misnamed: list[str] = field(default_factory=list)  # parts whose names say other rows than they hold

    @property
    def frames_done(self) -> int:
        return sum(s.frames_done for s in self.scenarios)

    @property
    def frames_total(self) -> int:
        return sum(s.frames_total for s in self.scenarios)

    @property
    def eta_s(self) -> float | None:
        if not self.frames_per_s:
            return None
        return (self.frames_total - self.frames_done) / self.frames_per_s


def root_status(storage) -> RootStatus:
    require_root(storage)
    record = read_run(storage)
    if record is None:
        raise ValueError(f"{storage.uri} has no run.json, so its plan is unknown; {REPAIR_HINT}")
    config = recorded_config(record)
    plan = make_plan(config.plan)
    held = episode_frames(storage)  # frames each part's name says it holds: done only if all the plan asks
    status = RootStatus(uri=storage.uri, config=record["config"])
    _check_names(storage, plan, held, status)
    planned = set()
    for code, episodes in plan.by_scenario().items():
        have = [min(held.get((e.scenario, e.episode), 0) // len(e.sensors), e.frames) for e in episodes]  # rows / sensors
        planned.update((e.scenario, e.episode) for e in episodes)
        status.scenarios.append(
            ScenarioStatus(
                scenario=code,
                episodes_done=sum(n == e.frames for n, e in zip(have, episodes)),
                episodes_total=len(episodes),
                frames_done=sum(have),
                frames_total=sum(e.frames for e in episodes),
            )
        )
    status.extra_episodes = len(set(held) - planned)
    if storage.exists(f"{STATS_DIR}/driver.json"):
        try:
            rate = json.loads(storage.read_bytes(f"{STATS_DIR}/driver.json")).get("frames_per_s")
            status.frames_per_s = float(rate) if isinstance(rate, (int, float)) and rate > 0 else None
        except (ValueError, AttributeError, OSError, StorageError):  # a damaged or odd driver.json: no rate
            status.frames_per_s = None
    return status


def _check_names(storage, plan, held: dict[tuple[str, int], int], status: RootStatus) -> None:
    """A part whose name says more rows than the plan asks cannot be one this run wrote
    (a root never shrinks): its footer is read, ``held`` takes the rows it really
    holds, and ``status.misnamed`` names it. Only such parts are read."""
    frames = {(e.scenario, e.episode): e.frames for e in plan.episodes}
    over = sorted(key for key, rows in held.items() if key in frames and rows > frames[key])
    paths = part_files(storage) if over else {}
    for key in over:
        rel = paths[key[0]][key[1]]
        rows = rows_read(storage, rel) or 0
        if rows != held[key]:
            status.misnamed.append(f"{rel} (its name says {held[key]} rows, it holds {rows})")
            held[key] = rows


def format_duration(seconds: float) -> str:
    seconds = int(round(seconds))
    days, rem = divmod(seconds, 86400)
    hours, rem = divmod(rem, 3600)
    minutes, secs = divmod(rem, 60)
    if days:
        return f"{days}d {hours}h {minutes}m"
    if hours:
        return f"{hours}h {minutes}m"
    return f"{minutes}m {secs}s"
