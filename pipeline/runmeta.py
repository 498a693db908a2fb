"""Provenance and config guard for an output root (``<root>/run.json``).

The file records the run config, package versions and the git revision. A
later run into the same root must ask for the same config, or pass --extend;
settings that decide what a frame looks like (seed, resolution, world) can
never change within one root, since frames would no longer match each other.
"""

from __future__ import annotations

import json
import platform
import subprocess
from dataclasses import asdict, dataclass
from importlib import metadata
from pathlib import Path

from manifests.schema import RUN_FILE
from pipeline.planner import PlanConfig

# Changing these would make new frames inconsistent with the ones on disk.
FRAME_DEFINING = ("seed", "width", "height", "world")
_PACKAGES = ("idda-pipeline", "numpy", "pyrender", "PyOpenGL", "trimesh", "ray", "pyarrow", "opencv-python-headless")


class RunConfigError(Exception):
    """The output root was produced with a different config."""


@dataclass(frozen=True)
class RunConfig:
    """What defines the dataset in one output root."""

    plan: PlanConfig
    world: str = "procedural"

    def to_dict(self) -> dict:
        return {**asdict(self.plan), "world": self.world}


def package_versions() -> dict[str, str]:
    versions = {"python": platform.python_version()}
    for name in _PACKAGES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = "not installed"
    return versions


def git_revision() -> str:
    here = Path(__file__).resolve().parent
    try:
        out = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=here, capture_output=True, text=True, timeout=10, check=True
        )
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"], cwd=here, capture_output=True, text=True, timeout=10
        )
        return out.stdout.strip() + ("-dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def read_run(storage) -> dict | None:
    if not storage.exists(RUN_FILE):
        return None
    try:
        return json.loads(storage.read_bytes(RUN_FILE))
    except ValueError as exc:
        raise RunConfigError(f"{storage.join(RUN_FILE)} is not valid JSON: {exc}") from None


def _differences(old: dict, new: dict) -> list[str]:
    return [f"{k} {old.get(k)!r} -> {new.get(k)!r}" for k in sorted(new) if old.get(k) != new.get(k)]


def prepare_root(storage, config: RunConfig, extend: bool = False) -> dict:
    """Record the run in ``run.json``, or check it matches the recorded one.

    Returns the record now in force. Raises RunConfigError on a mismatch.
    """
    new = config.to_dict()
    record = read_run(storage)
    if record is None:
        record = {
            "config": new,
            "history": [new],
            "versions": package_versions(),
            "git_revision": git_revision(),
        }
        body = (json.dumps(record, indent=2, sort_keys=True) + "\n").encode()
        if not storage.create_exclusive(RUN_FILE, body):
            return prepare_root(storage, config, extend)  # another driver was first
        return record
    old = record["config"]
    if old == new:
        return record
    diffs = _differences(old, new)
    fixed = [k for k in FRAME_DEFINING if old.get(k) != new.get(k)]
    if fixed:
        raise RunConfigError(
            f"{storage.uri} holds frames made with a different {', '.join(fixed)} ({'; '.join(diffs)}); "
            "frames would not match: use a new --out"
        )
    if not extend:
        raise RunConfigError(
            f"{storage.uri} was produced with another config ({'; '.join(diffs)}); "
            "pass --extend to add to it, or use a new --out"
        )
    record = {
        **record,
        "config": new,
        "history": record.get("history", [old]) + [new],
        "versions": package_versions(),
        "git_revision": git_revision(),
    }
    storage.write_bytes(RUN_FILE, (json.dumps(record, indent=2, sort_keys=True) + "\n").encode())
    return record


def recorded_config(record: dict) -> RunConfig:
    cfg = dict(record["config"])
    world = cfg.pop("world", "procedural")
    return RunConfig(plan=PlanConfig(**cfg), world=world)
