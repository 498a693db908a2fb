"""Built worlds on disk, so a worker process loads a town instead of building it.

A procedural town takes 1.4-1.7 s to build at start-up and 0.01-0.07 s to load
(7-11 MB pickled). :func:`load_or_build` wraps a world's ``build_world`` from
outside: the builders know nothing about it.

An entry is keyed by the world's name, the town code, the town seed and
:func:`code_digest`, a digest of every module the builders could read
(``render_workers/worlds/*.py``, ``domains/*.py`` and the built-in catalog ``domains/catalog.toml``) and of the Python, numpy and
trimesh versions. Any edit to that code makes new keys, so a stale world is
never loaded. Entries unused for ``KEEP_DAYS`` days are deleted when a new one
is written (not every other digest: two checkouts sharing the cache would
keep deleting each other's worlds).

Size bound: ``$IDDA_WORLD_CACHE_MAX`` (bytes, or with a K/M/G suffix, powers
of 1024; default ``2G``). After writing an entry, the least recently used
entries (loading one marks it used) are deleted until the cache fits, never
the entry just written. Deleting is safe beside other processes: a reader
that has an entry open keeps reading it (POSIX unlink), one that comes later
rebuilds it; an entry being written is a temp file, which only the cleanup
of writers killed long ago (``STALE_TEMP_S``) may delete.

Where: ``$IDDA_WORLD_CACHE``, else ``$XDG_CACHE_HOME/idda/worlds``, else
``~/.cache/idda/worlds``; ``IDDA_WORLD_CACHE=off`` turns the cache off. Writes
go to a temp file renamed into place, so concurrent workers never read half a
file; an entry that cannot be read is rebuilt and rewritten. Entries are
pickles: the cache directory must be as trusted as the code itself.
"""

from __future__ import annotations

import hashlib
import logging
import os
import pickle
import platform
import tempfile
import time
from functools import cache
from pathlib import Path
from typing import Callable, TypeVar

log = logging.getLogger(__name__)

CACHE_ENV = "IDDA_WORLD_CACHE"
MAX_ENV = "IDDA_WORLD_CACHE_MAX"
DEFAULT_MAX_BYTES = 2 * 1024**3
STALE_TEMP_S = 3600  # a temp file this old is a killed writer's, not one still writing
_UNITS = {"": 1, "B": 1, "K": 1024, "M": 1024**2, "G": 1024**3, "T": 1024**4}
_PACKAGES = ("render_workers/worlds", "domains")  # the code a world can depend on (worlds/ imports no GL, and only domains/ of ours)
KEEP_DAYS = 14  # an entry not loaded for this long is dropped
W = TypeVar("W")


def cache_dir() -> Path | None:
    """The cache directory, or None when the cache is turned off."""
    chosen = os.environ.get(CACHE_ENV)
    if chosen:
        return None if chosen.lower() in ("off", "0", "none") else Path(chosen)
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "idda" / "worlds"


def max_bytes() -> int:
    """The cache's size bound, from ``$IDDA_WORLD_CACHE_MAX`` (a malformed value warns and means the default)."""
    text = os.environ.get(MAX_ENV, "").strip()
    if not text:
        return DEFAULT_MAX_BYTES
    number, unit = text.upper().rstrip("IB") or "0", ""
    if number[-1:] in _UNITS:
        number, unit = number[:-1], number[-1]
    try:
        value = float(number) * _UNITS[unit]
    except ValueError:
        value = -1.0
    if value < 0:
        log.warning("%s=%r is not a size (bytes, or a number with K, M or G, e.g. 2G); using %d bytes",
                    MAX_ENV, text, DEFAULT_MAX_BYTES)
        return DEFAULT_MAX_BYTES
    return int(value)


@cache
def code_digest() -> str:
    """sha256 (16 hex digits) of the world-building code and the library versions pickles depend on."""
    import numpy
    import trimesh

    root = Path(__file__).resolve().parents[2]
    digest = hashlib.sha256(f"{platform.python_version()} numpy {numpy.__version__} trimesh {trimesh.__version__}".encode())
    for package in _PACKAGES:
        for path in sorted([*(root / package).glob("*.py"), *(root / package).glob("*.toml")]):  # the built-in catalog
            digest.update(path.name.encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()[:16]


def entry_path(directory: Path, world: str, town_code: str, seed: int, variant: str = "") -> Path:
    town = f"{town_code}-{variant}" if variant else town_code  # variant: a domain file's town of that code
    return directory / f"{world}_{town}_{seed}_{code_digest()}.pickle"


def _read(path: Path):
    try:
        with open(path, "rb") as f:
            value = pickle.load(f)
        os.utime(path)  # recently used: kept by the pruning in _write
        return value
    except FileNotFoundError:
        return None
    except Exception as exc:  # noqa: BLE001 - a truncated or foreign pickle raises many types
        log.warning("world cache entry %s is unreadable (%s); rebuilding it", path, exc)
        return None


def _write(path: Path, value) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
        try:
            with os.fdopen(fd, "wb") as f:
                pickle.dump(value, f, protocol=pickle.HIGHEST_PROTOCOL)
            os.replace(tmp, path)
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)
        prune(path.parent, keep=path)
    except OSError as exc:  # a cache that cannot be written costs a rebuild next time, nothing else
        log.warning("world cache entry %s not written (%s)", path, exc)


def _stat(entry: Path):
    try:
        return entry.stat()
    except FileNotFoundError:  # deleted by another process meanwhile
        return None


def prune(directory: Path, keep: Path | None = None, limit: int | None = None) -> list[Path]:
    """Delete entries unused for KEEP_DAYS, then the least recently used ones
    until the entries fit ``limit`` bytes (default :func:`max_bytes`), never
    ``keep``; and temp files of writers killed more than STALE_TEMP_S ago.
    Returns the deleted entries."""
    limit = max_bytes() if limit is None else limit
    now = time.time()
    for temp in directory.glob("*.pickle*.tmp"):
        st = _stat(temp)
        if st is not None and st.st_mtime < now - STALE_TEMP_S:
            temp.unlink(missing_ok=True)
    entries = []
    for entry in directory.glob("*.pickle"):
        st = _stat(entry)
        if st is not None:
            entries.append((st.st_mtime_ns, entry.name, entry, st.st_size))
    entries.sort()  # least recently used first
    total = sum(size for *_, size in entries)
    deleted = []
    for mtime_ns, _, entry, size in entries:
        if entry == keep:
            continue
        if mtime_ns / 1e9 < now - KEEP_DAYS * 86400 or total > limit:
            entry.unlink(missing_ok=True)
            total -= size
            deleted.append(entry)
    if deleted:
        log.info("world cache %s: deleted %d least recently used entries (bound %d bytes, %s)",
                 directory, len(deleted), limit, MAX_ENV)
    return deleted


def load_or_build(world: str, town_code: str, seed: int, build: Callable[[str, int], W], variant: str = "") -> W:
    """``build(town_code, seed)``, from the disk cache when an entry for this code (and variant:
    ``domains.catalog.town_variant``) exists."""
    directory = cache_dir()
    if directory is None:
        return build(town_code, seed)
    path = entry_path(directory, world, town_code, seed, variant)
    value = _read(path)
    if value is None:
        value = build(town_code, seed)
        _write(path, value)
    return value
