"""Small real roots for tests: episodes rendered by the worker function, as produce's workers do."""

from __future__ import annotations

from pathlib import Path


def render_root(root: Path, config, compact: bool = False):
    """Prepare ``root`` for ``config`` (a RunConfig) and render every planned episode
    into it; ``compact`` also writes the indexes, as produce does at the end. Returns the Storage."""
    from dataclasses import replace

    from manifests.layout import record_layout
    from manifests.reader import compact as write_indexes
    from manifests.root import claim_root
    from pipeline.episode_job import run_episode
    from pipeline.planner import make_plan
    from pipeline.runmeta import prepare_root
    from storage import Storage

    storage = Storage.from_uri(str(root))
    storage.ensure_writable()
    claim_root(storage)  # as produce does: the root marker first
    layout = record_layout(prepare_root(storage, config))  # a new root's, or an old root's own
    for spec in make_plan(config.plan).episodes:
        run_episode(replace(spec, layout=layout), storage, world=config.world)
    if compact:
        write_indexes(storage)
    return storage
