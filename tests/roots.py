"""Small real roots for tests: episodes rendered by the worker function, as produce's workers do."""

from __future__ import annotations

from pathlib import Path


def render_root(root: Path, config, compact: bool = False):
    """Prepare ``root`` for ``config`` (a RunConfig) and render every planned episode
    into it (``pipeline.episode_job.render_plan``); ``compact`` also writes the
    indexes, as produce does at the end. Returns the Storage."""
    from manifests.reader import compact as write_indexes
    from pipeline.episode_job import render_plan
    from storage import Storage

    storage = Storage.from_uri(str(root))
    render_plan(storage, config)
    if compact:
        write_indexes(storage)
    return storage
