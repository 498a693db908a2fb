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

from manifests.layout import LAYOUT_KEY, LAYOUTS
from manifests.schema import RUN_FILE

CHECKSUM_KEY = "checksum"
# config key -> accepted types; a record whose config lacks one, or has another type, is damaged
CONFIG_TYPES: dict[str, tuple[type, ...]] = {
    "domains": (str,),
    "scale": (float, int, type(None)),
    "frames_per_scenario": (int, type(None)),
    "width": (int,),
    "height": (int,),
    "seed": (int,),
    "world": (str,),
    "outputs": (list,),  # absent in roots from before --outputs: the six seed outputs
    "rgb_format": (str,),  # absent in roots from before --rgb-format: png
    "catalog": (dict,),  # the user domain entries in force (docs/catalog.md); absent: the built-in catalog only
    "frame_interval_s": (float, int),  # absent in roots from before --frame-interval: 3.0
    "pairing": (int,),  # 1: episode seeds leave the weather out (roots.episode_spec); absent in roots from before: 0
    "rules": (int,),  # 1: the rules of roots.episode_spec (splits per scene, ...); absent in roots from before: 0
    "rig": (str,),  # the sensor rig (domains.rigs); absent in roots from before rigs: front
}
# keys older records (and built-in runs, for the catalog) lack
OPTIONAL_CONFIG = ("world", "outputs", "rgb_format", "catalog", "frame_interval_s", "pairing", "rules", "rig")


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


def check_record(record, where: str) -> dict:
    """``record`` if it has the shape of a run record; RunRecordError naming ``where`` otherwise."""
    if not isinstance(record, dict) or not isinstance(record.get("config"), dict):
        raise RunRecordError(f"{where} is not a run record (expected an object with a 'config' object)")
    config = record["config"]
    for key, types in CONFIG_TYPES.items():
        if key not in config and type(None) not in types and key not in OPTIONAL_CONFIG:
            raise RunRecordError(f"{where} is damaged: its config lacks {key!r}")
        value = config.get(key)
        if key in config and (not isinstance(value, types) or isinstance(value, bool)):
            raise RunRecordError(f"{where} is damaged: config {key!r} is {value!r}")
    unknown = sorted(set(config) - set(CONFIG_TYPES))
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


def read_record(storage) -> dict | None:
    """The root's run record, None if there is none; RunRecordError if it is damaged."""
    where = storage.join(RUN_FILE)
    if storage.is_local and os.path.lexists(storage.path(RUN_FILE)) and not os.path.isfile(storage.path(RUN_FILE)):
        raise RunRecordError(f"{where} is not a regular file")
    if not storage.exists(RUN_FILE):
        return None
    try:
        record = json.loads(storage.read_bytes(RUN_FILE))
    except (ValueError, UnicodeDecodeError) as exc:
        raise RunRecordError(f"{where} is not valid JSON: {exc}") from None
    return check_record(record, where)
