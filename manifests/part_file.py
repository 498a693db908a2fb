"""Reading one manifest file (a part or an index) whole, and the errors of a damaged manifest.

Below the writer, the reader and the layout, which all read part files; nothing here writes.
"""

from __future__ import annotations

import pyarrow as pa
import pyarrow.parquet as pq

from storage.buffers import arrow_reader


class ManifestError(Exception):
    """A manifest part is missing, unreadable or inconsistent."""

    exit_code = 2  # what the CLI exits with


class MisfiledParts(ManifestError):
    """Parts whose rows belong to another scenario or episode: damaged data."""

    exit_code = 1


def read_part_file(storage, rel: str, schema: pa.Schema | None = None, data: bytes | None = None) -> pa.Table:
    """Read a whole manifest file (a part or an index; ``data`` if already read),
    page checksums verified; ManifestError naming the file if it is damaged."""
    try:
        data = storage.read_bytes(rel) if data is None else data
    except FileNotFoundError:
        raise
    except Exception as exc:  # a directory, a FIFO, an I/O error
        raise ManifestError(f"manifest file {storage.join(rel)} is unreadable: {exc}") from exc
    try:
        return _read_table(data, schema)
    except Exception as exc:  # pyarrow raises several types for a damaged file
        raise ManifestError(f"manifest file {storage.join(rel)} is unreadable: {exc}") from exc


def _read_table(data: bytes, schema: pa.Schema | None) -> pa.Table:
    """What ``pq.read_table(data, schema=schema)`` gives (columns cast to ``schema``, those the file lacks
    null, others dropped), without ``pyarrow.dataset``: pq.read_table imports it, and it imports pandas,
    a quarter of a second of the first read in every process (the driver's last index fold among them)."""
    file = pq.ParquetFile(arrow_reader(data), page_checksum_verification=True)
    if schema is None:
        return file.read()
    have = set(file.schema_arrow.names)
    table = file.read(columns=[name for name in schema.names if name in have])
    columns = [table.column(field.name) if field.name in have else pa.nulls(len(table), field.type) for field in schema]
    return pa.Table.from_arrays(columns, schema=schema)  # which casts each column to its field's type
