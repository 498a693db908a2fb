"""Leases on an output root: who is writing into it, and who may delete from it.

Two kinds of lease file, both JSON ``{"owner", "host", "pid", "purpose", "expires"}``
under ``<root>/_lease/``:

* ``producer-<owner>.json``: one per running ``idda produce``. Producers
  only add files that are identical whoever writes them, so any number may
  run side by side.
* ``exclusive.json``: held by a destructive operation (repair, which deletes
  files, and compaction, which replaces indexes). Only one holder at a time;
  repair also refuses while any other producer's lease is live, so it never
  deletes a running producer's in-progress frames.

A lease expires ``ttl_s`` after its last refresh (a holder refreshes it from a
background thread), so a killed holder blocks nobody for longer than that.
Expiry times are wall-clock seconds: machines sharing a root need clocks
within a few seconds of each other.

Exclusive creation: a local root uses an atomic hard link; on S3 (no
conditional write through pyarrow) the holder writes its lease, waits
``S3_SETTLE_S`` and reads it back: of concurrent writers only the last PUT
reads itself back, so at most one wins (S3 reads are strongly consistent).
"""

from __future__ import annotations

import json
import os
import socket
import threading
import time
import uuid
from dataclasses import dataclass, field

LEASE_DIR = "_lease"
EXCLUSIVE = f"{LEASE_DIR}/exclusive.json"
PRODUCER_PREFIX = f"{LEASE_DIR}/producer-"
TTL_S = 120.0  # a lease not refreshed for this long is dead
S3_SETTLE_S = 2.0


class LeaseError(Exception):
    """The root is locked by another operation."""


def new_owner() -> str:
    return f"{socket.gethostname()}-{os.getpid()}-{uuid.uuid4().hex[:8]}"


def _body(owner: str, purpose: str, ttl_s: float) -> bytes:
    info = {"owner": owner, "host": socket.gethostname(), "pid": os.getpid(), "purpose": purpose,
            "expires": time.time() + ttl_s}
    return json.dumps(info, sort_keys=True).encode()


def read_lease(storage, rel: str) -> dict | None:
    """A lease file's content; None if it is gone or unreadable (a torn lease is dead)."""
    try:
        info = json.loads(storage.read_bytes(rel))
        return info if isinstance(info, dict) and isinstance(info.get("expires"), (int, float)) else None
    except (FileNotFoundError, ValueError, OSError):
        return None


def is_live(info: dict | None) -> bool:
    return info is not None and info["expires"] > time.time()


def describe(info: dict) -> str:
    left = max(0, int(info["expires"] - time.time()))
    return f"{info.get('purpose', '?')} by {info.get('owner', '?')} (lease expires in {left} s unless renewed)"


@dataclass
class Lease:
    """A held lease; refresh it while working, release it when done (or use ``with``)."""

    storage: object
    rel: str
    owner: str
    purpose: str
    ttl_s: float = TTL_S
    _stop: threading.Event = field(default_factory=threading.Event, repr=False)
    _thread: threading.Thread | None = field(default=None, repr=False)

    def refresh(self) -> None:
        self.storage.write_bytes(self.rel, _body(self.owner, self.purpose, self.ttl_s))

    def keep_alive(self) -> Lease:
        """Refresh from a daemon thread every quarter of the TTL until released."""
        def loop() -> None:
            while not self._stop.wait(self.ttl_s / 4):
                try:
                    self.refresh()
                except Exception:  # a failed refresh: the next one may succeed; expiry is the backstop
                    pass

        self._thread = threading.Thread(target=loop, name=f"lease-{self.purpose}", daemon=True)
        self._thread.start()
        return self

    def release(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        info = read_lease(self.storage, self.rel)
        if info is not None and info.get("owner") == self.owner:
            self.storage.delete(self.rel)

    def __enter__(self) -> Lease:
        return self

    def __exit__(self, *exc) -> None:
        self.release()


def _create(storage, rel: str, owner: str, purpose: str, ttl_s: float) -> bool:
    body = _body(owner, purpose, ttl_s)
    if storage.is_local:
        return storage.create_exclusive(rel, body)
    if storage.exists(rel):
        return False
    storage.write_bytes(rel, body)
    time.sleep(S3_SETTLE_S)
    info = read_lease(storage, rel)
    return info is not None and info.get("owner") == owner


def acquire_exclusive(storage, purpose: str, owner: str | None = None, wait_s: float = 0.0,
                      ttl_s: float = TTL_S, poll_s: float = 0.5) -> Lease:
    """Take the root's exclusive lease for ``purpose``; wait up to ``wait_s``
    for a live holder, else LeaseError in one line. A dead lease is taken over."""
    owner = owner or new_owner()
    deadline = time.monotonic() + wait_s
    while True:
        if _create(storage, EXCLUSIVE, owner, purpose, ttl_s):
            return Lease(storage, EXCLUSIVE, owner, purpose, ttl_s).keep_alive()
        info = read_lease(storage, EXCLUSIVE)
        if not is_live(info):
            storage.delete(EXCLUSIVE)  # its holder died (or the file is torn): take it over
            continue
        if time.monotonic() >= deadline:
            raise LeaseError(f"{storage.uri} is locked: {describe(info)}; try again when it is done")
        time.sleep(poll_s)


def exclusive_holder(storage) -> dict | None:
    """The live exclusive lease, if any."""
    info = read_lease(storage, EXCLUSIVE)
    return info if is_live(info) else None


def register_producer(storage, owner: str | None = None, ttl_s: float = TTL_S) -> Lease:
    """Announce a running producer (kept alive until released)."""
    owner = owner or new_owner()
    lease = Lease(storage, f"{PRODUCER_PREFIX}{owner}.json", owner, "produce", ttl_s)
    lease.refresh()
    return lease.keep_alive()


def live_producers(storage, except_owner: str | None = None) -> list[dict]:
    """Live producer leases other than ``except_owner``'s; dead ones are removed."""
    found = []
    for rel in storage.list_files(PRODUCER_PREFIX):
        info = read_lease(storage, rel)
        if info is not None and info.get("owner") == except_owner:
            continue
        if is_live(info):
            found.append(info)
        else:
            storage.delete(rel)
    return found
