"""Output roots (local directory or s3://bucket/prefix): URIs, atomic writes, checksums.

A leaf package: it imports only the standard library and pyarrow.
"""

from storage.checksum import sha256_bytes
from storage.errors import StorageError
from storage.fs import Storage

__all__ = ["Storage", "StorageError", "sha256_bytes"]
