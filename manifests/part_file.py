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
        return pq.read_table(arrow_reader(data), schema=schema, page_checksum_verification=True)
    except Exception as exc:  # pyarrow raises several types for a damaged file
        raise ManifestError(f"manifest file {storage.join(rel)} is unreadable: {exc}") from exc
