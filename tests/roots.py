"""Small real roots for tests: episodes rendered by the worker function, as produce's workers do."""

from __future__ import annotations

from pathlib import Path


def render_root(root: Path, config, compact: bool = False, extend: bool = False):
    """Prepare ``root`` for ``config`` (a RunConfig) and render every planned episode
    into it (``pipeline.episode_job.render_plan``); ``compact`` also writes the
    indexes, as produce does at the end; ``extend`` as --extend. Returns the Storage."""
    from manifests.reader import compact as write_indexes
    from pipeline.episode_job import render_plan
    from storage import Storage

    storage = Storage.from_uri(str(root))
    render_plan(storage, config, extend=extend)
    if compact:
        write_indexes(storage)
    return storage


def part_of(root, scenario: str, episode: int) -> str:
    """The relative path of an episode's part as written (its name carries its row count)."""
    from manifests.reader import as_storage, episode_parts

    found = episode_parts(as_storage(root if hasattr(root, "list_files") else str(root)), scenario, episode)
    assert found, f"no part of {scenario} episode {episode} under {root}"
    return found[0]


def to_old_names(storage) -> int:
    """Rename every part of ``storage`` to the name parts had before names carried
    their row count (an old root); returns how many were renamed."""
    from manifests.reader import part_listing
    from manifests.schema import part_path

    renamed = 0
    for scenario, episodes in part_listing(storage).items():
        for episode, (rel, _) in episodes.items():
            old = part_path(scenario, episode)
            if rel != old:
                storage.write_bytes(old, storage.read_bytes(rel))
                storage.delete(rel)
                renamed += 1
    return renamed


def as_made_before(storage, key: str) -> None:
    """Drop the config ``key`` from ``storage``'s run.json (its config and history), as a root made
    before that key existed records it (e.g. "pairing", "rules")."""
    from roots.run_file import read_record, record_bytes
    from manifests.schema import RUN_FILE

    record = read_record(storage)
    for config in (record["config"], *record.get("history", [])):
        config.pop(key, None)
    storage.write_bytes(RUN_FILE, record_bytes(record))
