"""Manifest parts: one Parquet file per episode, written last and atomically.

A part's existence is the episode's "done" marker, so it is written only
after every frame file it lists has been written.
"""

from __future__ import annotations

import io

import pyarrow as pa
import pyarrow.parquet as pq

import numpy as np

from domains.catalog import LABELS
from manifests.layout import frame_path
from domains.conditions import FOG_DENSITY, VISIBILITY
from domains.rigs import rig_from_json
from manifests.schema import (FIELD_SOURCE, OBJECT_FIELDS, OLD_PART_SCHEMA, PART_SCHEMA, RIG_FIELDS, RULE_PART_SCHEMA,
                              frame_id, frame_uid,
                              NEW_RULES, output_columns, part_path)
from outputs.table import OUTPUTS
from manifests.part_file import ManifestError
from storage import sha256_bytes
from storage.buffers import arrow_table


def frame_row(spec, frame, files: dict[str, bytes]) -> dict:
    """The manifest row of one rendered frame, column by column from PART_SCHEMA.

    ``spec`` is the episode's ``EpisodeSpec``; ``frame`` a rendered frame
    (``render_workers.worlds.scene.Frame``: the FIELD_SOURCE "frame" columns as
    attributes, the "condition" columns in ``conditions``, ``index``, ``class_counts`` per class id and ``object_counts``
    per object column); ``files`` the bytes written per output (outputs not
    asked for get null columns)."""
    fid = frame_id(spec.episode, frame.index)
    sensor = getattr(frame, "sensor", "")
    derived = {"frame_id": fid, "uid": frame_uid(spec.scenario, spec.episode, frame.index, sensor),
               "frame": frame.index, **frame.conditions}
    row = {}
    for name, source in FIELD_SOURCE.items():
        row[name] = (derived[name] if source in ("derived", "condition")
                     else getattr(spec if source == "spec" else frame, name))
    unknown = set(files) - set(OUTPUTS)
    if unknown:
        raise ManifestError(f"{spec.key} frame {frame.index}: unknown outputs {sorted(unknown)}")
    for name in OUTPUTS:
        data = files.get(name)
        path_col, bytes_col, sha_col = output_columns(name)
        row[path_col] = (None if data is None
                         else frame_path(spec.scenario, name, fid, spec.rgb_format, spec.layout, sensor))
        row[bytes_col] = None if data is None else len(data)
        row[sha_col] = None if data is None else sha256_bytes(data)
    if spec.rules < NEW_RULES:  # a root made before rules: its parts' columns, fog as its share per km
        del row[VISIBILITY.column]
    else:
        row[FOG_DENSITY.column] = None
    if spec.rig:  # a rig's part: the sensor column (LiDAR files are OUTPUTS above); else none of RIG_FIELDS
        row["sensor"] = sensor
        row["width"], row["height"] = rig_from_json(spec.rig).size_of(sensor, spec.width, spec.height)  # its own
    else:
        for name, _ in RIG_FIELDS:
            row.pop(name, None)
    if frame.class_counts is None:  # a LiDAR sweep: no pixels, no objects table
        for label in LABELS:
            row[label.column] = None
        for name, _ in OBJECT_FIELDS:
            row[name] = None
        return row
    counts = np.asarray(frame.class_counts, dtype=np.int64)
    if counts.shape != (len(LABELS),) or int(counts.sum()) != row["width"] * row["height"]:
        raise ManifestError(
            f"{spec.key} frame {frame.index}: class counts must be {len(LABELS)} values summing to "
            f"{row['width'] * row['height']}, got shape {counts.shape} sum {int(counts.sum())}"
        )
    for label in LABELS:
        row[label.column] = int(counts[label.id])
    for name, _ in OBJECT_FIELDS:
        row[name] = int(frame.object_counts[name])
    return row


def part_table(rows: list[dict]) -> pa.Table:
    """Build a part table from frame rows; every schema column must be present."""
    if not rows:
        raise ManifestError("an episode part needs at least one frame row")
    schema = (OLD_PART_SCHEMA if VISIBILITY.column not in rows[0]  # OLD_RULES: without visibility_m
              else PART_SCHEMA if "sensor" in rows[0] else RULE_PART_SCHEMA)  # a rig's part, or the default rig's
    missing = [name for name in schema.names if name not in rows[0]]
    if missing:
        raise ManifestError(f"frame row lacks manifest columns: {', '.join(missing)}")
    try:  # the table pa.table gives, without importing pandas in the worker (storage.buffers.arrow_table)
        return arrow_table({name: [row[name] for row in rows] for name in schema.names}, schema)
    except ValueError as exc:
        raise ManifestError(f"frame rows do not fit the manifest schema: {exc}") from None


def part_bytes(table: pa.Table, store_schema: bool = False) -> bytes:
    """Serialise deterministically: the same rows give the same bytes.

    Page checksums let readers (and verify) detect flipped bytes in the data.
    The Arrow schema is not stored (``store_schema``: as parts were written
    before): Parquet's own types read back as PART_SCHEMA, and decoding the
    stored one took half the time of reading a footer, which status and
    resume do for every part of a root without current indexes."""
    sink = io.BytesIO()
    pq.write_table(table, sink, compression="zstd", write_statistics=True, store_schema=store_schema,
                   write_page_checksum=True)
    return sink.getvalue()


def write_part(storage, scenario: str, episode: int, rows: list[dict] | pa.Table) -> str:
    """Write an episode's part (rows or a PART_SCHEMA table; OLD_PART_SCHEMA in a root made before rules)
    atomically; returns its path.

    Its name carries its row count (``schema.part_path``). Once it is written,
    the episode's part under the old name (an old root's episode rendered again)
    is removed: until then readers prefer the new name (``schema.newer_part``)."""
    table = rows if isinstance(rows, pa.Table) else part_table(rows)
    if table.schema not in (PART_SCHEMA, RULE_PART_SCHEMA, OLD_PART_SCHEMA):
        raise ManifestError(f"part for {scenario} episode {episode} does not have the manifest schema")
    rel = part_path(scenario, episode, len(table))
    storage.write_bytes(rel, part_bytes(table))
    storage.delete(part_path(scenario, episode))
    return rel
