"""Repair: drop exactly what verify finds broken so the run renders it again,
under the root's exclusive lease, after checking the config, the rows and
symbolic links (nothing is deleted when any check refuses)."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

from manifests.reader import episode_parts
from manifests.schema import index_path, part_path
from pipeline.cluster import cluster_address
from pipeline.runmeta import RunConfigError, prepare_root

if TYPE_CHECKING:
    from pipeline.driver import ProduceConfig

log = logging.getLogger(__name__)


def _repair(storage, config: ProduceConfig, plan, owner: str) -> list[str]:
    """Drop what verify finds broken so the run rebuilds it: the parts of
    episodes with bad files or a bad part (they re-render), stray frame files
    (our naming only) and damaged indexes (compaction rewrites them). A damaged
    run.json is rewritten by ``prepare_root``.

    Everything is checked before anything is deleted, and only the plan's
    scenarios are verified. A symbolic link anywhere in them, or a part whose
    rows belong to another run (seed, resolution), refuses the whole repair:
    RootError or RunConfigError, and nothing deleted."""
    from manifests.root import RootError
    from manifests.verify import Scope, verify
    from pipeline.runmeta import check_before_repair

    check_before_repair(storage, config.run, extend=config.extend)
    scope = Scope(scenarios=frozenset(plan.scenarios()))
    report = verify(storage, scope=scope, config=config.run.to_dict(), runner=verify_runner(config),
                    except_owner=owner)  # our own lease: no other producer is live (checked)
    links = [p for p in report.problems if p.kind == "link"]
    if links:
        raise RootError(
            f"{storage.join(links[0].path)} is a symbolic link; repair never follows a link out of the root "
            "and deletes nothing: replace the link with the files it points to, or remove it, and run again"
        )
    conflicts = [p for p in report.problems if p.conflict]
    if conflicts:
        raise RunConfigError(
            f"{storage.join(conflicts[0].path)} holds frames of another run ({conflicts[0].detail}; "
            f"{len(conflicts)} part(s) in all); repair deleted nothing: check --seed/--width/--height, "
            "or move such parts out of the root"
        )
    planned = {(e.scenario, e.episode) for e in plan.episodes}
    touched = []
    for scenario, episode in sorted(report.affected_episodes()):
        for rel in episode_parts(storage, scenario, episode) or [part_path(scenario, episode)]:
            storage.delete(rel)
        storage.delete(index_path(scenario))
        if (scenario, episode) not in planned:
            log.warning("%s_e%04d is damaged but not in the current plan; it stays pending", scenario, episode)
        touched.append(f"{scenario}/e{episode:04d}")
    for problem in report.problems:
        if problem.kind in ("extra", "bad-index"):
            storage.delete(problem.path)
            if problem.kind == "bad-index":
                touched.append(problem.path)
        elif problem.kind == "bad-run":
            touched.append(problem.path)
    return touched


def verify_runner(config: ProduceConfig):
    """Repair's verify: on Ray when produce would attach to a cluster or the
    scope is large, else in this process."""
    from pipeline.verify_ray import choose_runner

    return choose_runner(address=cluster_address(config.address), workers=config.workers)


def check_no_repair_running(storage) -> None:
    from manifests.lease import LeaseError, describe, exclusive_holder

    holder = exclusive_holder(storage)
    if holder is not None and holder.get("purpose") == "repair":
        raise LeaseError(f"{storage.uri} is being repaired ({describe(holder)}); run again when it is done")


def repair_alone(storage, config: ProduceConfig, plan, owner: str) -> list[str]:
    """Repair under the root's exclusive lease, refusing beside another live producer."""
    from manifests.lease import LeaseError, acquire_exclusive, describe, live_producers

    with acquire_exclusive(storage, "repair", owner=owner):
        others = live_producers(storage, except_owner=owner)
        if others:
            raise LeaseError(
                f"{storage.uri} is being written by another producer ({describe(others[0])}); repair when it has finished"
            )
        repaired = _repair(storage, config, plan, owner)
        prepare_root(storage, config.run, extend=config.extend, repair=True)
    return repaired
