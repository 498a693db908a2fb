"""SHA-256 of bytes and of streams read in fixed-size chunks."""

from __future__ import annotations

import hashlib
from typing import BinaryIO

CHUNK = 1 << 20  # 1 MiB


def sha256_bytes(data: bytes) -> str:
    """Hex SHA-256 of ``data``."""
    return hashlib.sha256(data).hexdigest()


def sha256_stream(stream: BinaryIO, chunk: int = CHUNK) -> str:
    """Hex SHA-256 of everything left in ``stream``, read ``chunk`` bytes at a time."""
    digest = hashlib.sha256()
    while block := stream.read(chunk):
        digest.update(block)
    return digest.hexdigest()
