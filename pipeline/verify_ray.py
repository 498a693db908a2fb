"""Verify on Ray: ``roots.verify.check_unit`` as one task per scenario.

The driver plans the units (a listing of the parts, never their rows) and
gathers each unit's small result; the workers list, read and hash. At most
twice the cluster's CPUs in tasks are in flight. Like ``produce``: an address
(or ``RAY_ADDRESS``) attaches to a cluster, otherwise a private local cluster
is started for the call and stopped after it. A root too small to pay for
starting Ray is checked in this process.
"""

from __future__ import annotations

import logging
import os
from collections import deque
from typing import Callable, Iterator

from pipeline.cluster import _import_ray, attach, shutdown
from roots.verify import check_unit, plain_runner

log = logging.getLogger(__name__)

# Below this many parts in scope (and with no cluster to attach to), starting a
# local Ray cluster (seconds) costs more than it saves: verify in this process.
RAY_MIN_PARTS = 256


def choose_runner(address: str | None = None, workers: int | None = None, use_ray: bool | None = None) -> Callable[..., Iterator]:
    """The runner for ``roots.verify.verify``: ``use_ray`` True forces Ray,
    False this process; None (auto) uses Ray with an address, an initialised
    Ray, or at least RAY_MIN_PARTS parts in scope."""
    address = address or os.environ.get("RAY_ADDRESS") or None

    def run(storage, units, config, threads, on_files):
        parts = sum(len(unit.parts) for unit in units)
        wanted = use_ray
        if wanted is None:
            wanted = bool(address) or _ray_initialized() or parts >= RAY_MIN_PARTS
        if not wanted or not units:
            yield from plain_runner(storage, units, config, threads, on_files)
        else:
            yield from ray_units(storage, units, config, threads, address, workers)

    return run


def _ray_initialized() -> bool:
    import sys

    ray = sys.modules.get("ray")  # never import Ray just to ask
    return ray is not None and ray.is_initialized()


def ray_units(storage, units: list, config: dict | None, threads: int, address: str | None,
              workers: int | None) -> Iterator:
    """Run ``check_unit`` for each unit as a Ray task; yields results as they finish."""
    ray = _import_ray()
    started = not ray.is_initialized()
    reaper = None
    try:
        if started:
            attach(ray, address, workers)
            if not address:  # our own local cluster: it dies with this process
                from pipeline.reaper import Reaper

                reaper = Reaper()
        slots = max(1, int(ray.cluster_resources().get("CPU", 1)))
        task = ray.remote(check_unit).options(num_cpus=1, max_retries=3, retry_exceptions=True)
        storage_ref, config_ref = ray.put(storage), ray.put(config)
        # the biggest scenarios first: the last task to finish is a short one
        queue = deque(sorted(units, key=lambda u: -len(u.parts)))
        in_flight: dict = {}
        while queue or in_flight:
            while queue and len(in_flight) < 2 * slots:
                unit = queue.popleft()
                in_flight[task.remote(storage_ref, unit, config_ref, threads)] = unit
            ready, _ = ray.wait(list(in_flight), num_returns=1)
            for ref in ready:
                in_flight.pop(ref)
                yield ray.get(ref)
    finally:
        if started and ray.is_initialized():
            shutdown(ray)
        if reaper is not None:
            reaper.stop()
