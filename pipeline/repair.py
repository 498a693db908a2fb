"""Repair: drop exactly what verify finds broken so the run renders it again,
under the root's exclusive lease, after checking the config, the rows and
symbolic links (nothing is deleted when any check refuses)."""

from __future__ import annotations

import logging

from manifests.layout import NEW_ROOT_LAYOUT, frame_path, held_layout, record_layout
from manifests.reader import episode_parts
from manifests.schema import frame_id, index_path, part_path, part_stem
from pipeline.cluster import cluster_address
from pipeline.provenance import RunConfigError, check_before_repair, prepare_root
from pipeline.settings import CONFIG_SHAPE, ProduceConfig
from pipeline import verify_ray  # by module: a test stands in for choose_runner
from roots.contract import RootError
from roots.episode_spec import episode_key
from roots.lease import LeaseError, acquire_exclusive, describe, exclusive_holder, live_producers
from roots.run_file import RunRecordError, read_record
from roots.verify import Scope, verify

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
    check_before_repair(storage, config.run, extend=config.extend)
    scope = Scope(scenarios=frozenset(plan.scenarios()))
    report = verify(storage, scope=scope, config=config.run.to_dict(), runner=verify_runner(config),
                    except_owner=owner, shape=CONFIG_SHAPE)  # our own lease: no other producer is live (checked)
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
    refuse_in_the_way(storage, [e for e in plan.episodes if (e.scenario, e.episode) in report.affected_episodes()],
                      _root_layout(storage), "repair deleted nothing")
    touched = []
    for scenario, episode in sorted(report.affected_episodes()):
        for rel in episode_parts(storage, scenario, episode) or [part_path(scenario, episode)]:
            storage.delete(rel)
        storage.delete(index_path(scenario))
        if (scenario, episode) not in planned:
            log.warning("%s is damaged but not in the current plan; it stays pending", part_stem(scenario, episode))
        touched.append(episode_key(scenario, episode))
    for problem in report.problems:
        if problem.kind in ("extra", "bad-index"):
            storage.delete(problem.path)
            if problem.kind == "bad-index":
                touched.append(problem.path)
        elif problem.kind == "bad-run":
            touched.append(problem.path)
    return touched


def episode_files(spec, layout: int) -> list[str]:
    """Every file rendering ``spec`` writes into a root of ``layout``: its frame files, then its part."""
    fids = [frame_id(spec.episode, i) for i in range(spec.frames)]
    return [frame_path(spec.scenario, name, fid, spec.rgb_format, layout) for name in spec.outputs for fid in fids] + [
        part_path(spec.scenario, spec.episode, spec.frames)]


def refuse_in_the_way(storage, specs, layout: int, nothing_done: str, parts_only: bool = False) -> None:
    """RootError in one line naming the first thing (a folder, a link, a special file) that
    stands where rendering ``specs`` would write a file (``parts_only``: only their parts).
    Nothing of it is ever deleted: it may be a user's."""
    for spec in specs:
        # parts_only: the part's path alone, not the frames' hundreds first (a resume with
        # 12,000 episodes pending spent over two minutes building paths it never looked at)
        for rel in [part_path(spec.scenario, spec.episode, spec.frames)] if parts_only else episode_files(spec, layout):
            blocker = storage.in_the_way(rel)
            if blocker is not None:
                where, what = blocker
                target = "a file" if where == rel else storage.join(rel)
                raise RootError(f"{storage.join(where)} is {what}, where {spec.key} writes {target}; "
                                f"{nothing_done}: move it out of the root and run again")


def _root_layout(storage) -> int:
    """The root's file layout: run.json's, else that of the frames its parts list."""
    try:
        record = read_record(storage, CONFIG_SHAPE)
    except RunRecordError:
        record = None
    return record_layout(record) if record else held_layout(storage) or NEW_ROOT_LAYOUT


def verify_runner(config: ProduceConfig):
    """Repair's verify: on Ray when produce would attach to a cluster or the
    scope is large, else in this process."""
    return verify_ray.choose_runner(address=cluster_address(config.address), workers=config.workers)


def check_no_repair_running(storage) -> None:
    holder = exclusive_holder(storage)
    if holder is not None and holder.get("purpose") == "repair":
        raise LeaseError(f"{storage.uri} is being repaired ({describe(holder)}); run again when it is done")


def repair_alone(storage, config: ProduceConfig, plan, owner: str) -> list[str]:
    """Repair under the root's exclusive lease, refusing beside another live producer."""
    with acquire_exclusive(storage, "repair", owner=owner):
        others = live_producers(storage, except_owner=owner)
        if others:
            raise LeaseError(
                f"{storage.uri} is being written by another producer ({describe(others[0])}); repair when it has finished"
            )
        repaired = _repair(storage, config, plan, owner)
        prepare_root(storage, config.run, extend=config.extend, repair=True)
    return repaired
