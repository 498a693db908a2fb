"""``<root>/run.json``, the run's record: read, shape-checked and checksummed.

The record carries a ``checksum`` of its own canonical JSON (without that
field), so verify notices a flipped byte anywhere in it. Records written
before the checksum existed are accepted without one. ``pipeline.provenance``
decides what goes into a record; this module only reads and writes it.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from typing import Mapping

from manifests.layout import LAYOUT_KEY, LAYOUTS
from manifests.schema import RUN_FILE

CHECKSUM_KEY = "checksum"


@dataclass(frozen=True)
class ConfigShape:
    """What a record's config may hold: key -> accepted JSON types (``None`` among them: the key may be
    left out), and the keys older records may lack. The run's settings declare it
    (``pipeline.settings.CONFIG_SHAPE``, read from their fields); the readers here take it from their
    callers, since this floor does not import the pipeline."""

    types: Mapping[str, tuple[type, ...]]
    optional: tuple[str, ...] = ()


REPAIR_HINT = "`idda produce --repair` with the run's options rewrites it"  # said with every RunRecordError


class RunRecordError(ValueError):
    """run.json is unreadable, of the wrong shape, or fails its checksum."""


def _digest(record: dict) -> str:
    body = {k: v for k, v in record.items() if k != CHECKSUM_KEY}
    return hashlib.sha256(json.dumps(body, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def record_bytes(record: dict) -> bytes:
    """The file content for ``record``, with its checksum."""
    sealed = {**{k: v for k, v in record.items() if k != CHECKSUM_KEY}, CHECKSUM_KEY: _digest(record)}
    return (json.dumps(sealed, indent=2, sort_keys=True) + "\n").encode()


def check_record(record, where: str, shape: ConfigShape | None = None) -> dict:
    """``record`` if it has the shape of a run record, its config that of ``shape`` (None: any keys,
    for readers of the record's other parts); RunRecordError naming ``where`` otherwise."""
    if not isinstance(record, dict) or not isinstance(record.get("config"), dict):
        raise RunRecordError(f"{where} is not a run record (expected an object with a 'config' object)")
    config = record["config"]
    for key, types in (shape.types if shape is not None else {}).items():
        if key not in config and type(None) not in types and key not in shape.optional:
            raise RunRecordError(f"{where} is damaged: its config lacks {key!r}")
        value = config.get(key)
        if key in config and (not isinstance(value, types) or isinstance(value, bool)):
            raise RunRecordError(f"{where} is damaged: config {key!r} is {value!r}")
    unknown = sorted(set(config) - set(shape.types)) if shape is not None else []
    if unknown:
        raise RunRecordError(f"{where} is damaged: unknown config keys {', '.join(unknown)}")
    history = record.get("history", [])
    if not isinstance(history, list) or not all(isinstance(h, dict) for h in history):
        raise RunRecordError(f"{where} is damaged: 'history' must be a list of configs")
    layout = record.get(LAYOUT_KEY, LAYOUTS[0])  # absent in roots from before layouts: flat
    if isinstance(layout, bool) or layout not in LAYOUTS:
        raise RunRecordError(f"{where} is damaged: unknown file layout {layout!r}")
    if CHECKSUM_KEY in record and record[CHECKSUM_KEY] != _digest(record):
        raise RunRecordError(f"{where} is damaged: its checksum does not match its content")
    return record


def read_record(storage, shape: ConfigShape | None = None) -> dict | None:
    """The root's run record, None if there is none; RunRecordError if it is damaged (its config
    checked against ``shape``, ``check_record``)."""
    where = storage.join(RUN_FILE)
    if storage.is_local and os.path.lexists(storage.path(RUN_FILE)) and not os.path.isfile(storage.path(RUN_FILE)):
        raise RunRecordError(f"{where} is not a regular file")
    if not storage.exists(RUN_FILE):
        return None
    try:
        record = json.loads(storage.read_bytes(RUN_FILE))
    except (ValueError, UnicodeDecodeError) as exc:
        raise RunRecordError(f"{where} is not valid JSON: {exc}") from None
    return check_record(record, where, shape)
