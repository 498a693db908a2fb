"""A run's settings as the pipeline takes them: what defines the dataset in a root (``RunConfig``:
the plan's config and the world) and how one ``idda produce`` runs it (``ProduceConfig``)."""

from __future__ import annotations

from dataclasses import dataclass

from pipeline.planner import PlanConfig
from render_workers.worlds.registry import check_world
from roots.lease import TTL_S


@dataclass(frozen=True)
class RunConfig:
    """What defines the dataset in one output root."""

    plan: PlanConfig
    world: str = "procedural"

    def to_dict(self) -> dict:
        return {**self.plan.to_dict(), "world": self.world}


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
