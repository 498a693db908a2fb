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

Fencing: ``_lease/generation.json`` holds the root's lease generation. A
producer records it in its lease when it registers and every episode's part
commit re-checks it (``check_fence``), before and after writing the part.
A repair (through ``live_producers``) bumps the generation before it removes
dead producers' leases, so a producer that was stopped past its lease's
expiry and wakes up afterwards can no longer mark an episode done: its commit
fails with LeaseLost, and its refresh thread does not bring the lease back.
A new producer removes dead producers' lease files when it registers, without
a bump (their holders fail their next fence check: the file is gone). Verify
only looks (``live_producers(take_over=False)``): it never changes the root.

A lease of a process on this same host (same host name and pid namespace)
whose pid no longer exists is dead at once, whatever its expiry: the next
run takes it over and says so in a warning.

Exclusive creation: a local root uses an atomic hard link; on S3 (no
conditional write through pyarrow) the holder writes its lease, waits
``S3_SETTLE_S`` and reads it back: of concurrent writers only the last PUT
reads itself back, so at most one wins (S3 reads are strongly consistent).
"""

from __future__ import annotations

import json
import logging
import os
import socket
import threading
import time
import uuid
from dataclasses import dataclass, field

from storage import StorageError

LEASE_DIR = "_lease"
EXCLUSIVE = f"{LEASE_DIR}/exclusive.json"
PRODUCER_PREFIX = f"{LEASE_DIR}/producer-"
GENERATION = f"{LEASE_DIR}/generation.json"
TTL_S = 120.0  # a lease not refreshed for this long is dead
TTL_ENV = "IDDA_LEASE_TTL_S"  # read by the CLI (tests shorten it)
S3_SETTLE_S = 2.0

log = logging.getLogger(__name__)


class LeaseError(Exception):
    """The root is locked by another operation."""


class LeaseLost(StorageError):
    """This producer's lease was taken over (or its generation bumped): it may not commit."""

    def __init__(self, message: str) -> None:
        super().__init__(message, cause="lease lost", fatal=True)


def ttl_from_env(environ=os.environ) -> float:
    """The lease TTL: ``IDDA_LEASE_TTL_S`` if set (ValueError if it is not a positive number), else TTL_S."""
    raw = environ.get(TTL_ENV)
    if raw is None:
        return TTL_S
    try:
        ttl = float(raw)
    except ValueError:
        ttl = -1.0
    if not ttl > 0:
        raise ValueError(f"{TTL_ENV} must be a positive number of seconds, got {raw!r}")
    return ttl


def new_owner() -> str:
    return f"{socket.gethostname()}-{os.getpid()}-{uuid.uuid4().hex[:8]}"


def _pid_namespace() -> str | None:
    try:
        return os.readlink("/proc/self/ns/pid")
    except OSError:
        return None


def _body(owner: str, purpose: str, ttl_s: float, generation: int | None = None) -> bytes:
    info = {"owner": owner, "host": socket.gethostname(), "pid": os.getpid(), "pidns": _pid_namespace(),
            "purpose": purpose, "expires": time.time() + ttl_s}
    if generation is not None:
        info["generation"] = generation
    return json.dumps(info, sort_keys=True).encode()


def read_generation(storage) -> int:
    """The root's lease generation (0 before the first takeover)."""
    try:
        value = json.loads(storage.read_bytes(GENERATION)).get("generation", 0)
    except FileNotFoundError:
        return 0
    except (ValueError, AttributeError):  # torn or odd: nobody can match it, so every fence fails
        return -1
    return int(value) if isinstance(value, int) else -1


def bump_generation(storage) -> int:
    """Invalidate every producer fence taken so far; call under the exclusive lease."""
    generation = max(read_generation(storage), 0) + 1
    storage.write_bytes(GENERATION, json.dumps({"generation": generation}).encode())
    return generation


@dataclass(frozen=True)
class Fence:
    """What a producer's part commit checks (small and picklable: it travels to workers)."""

    rel: str  # the producer's lease file
    owner: str
    generation: int


def check_fence(storage, fence: Fence | None) -> None:
    """LeaseLost unless ``fence``'s lease still exists, is ours, and the root's
    generation is unchanged (``None``: no fencing, e.g. a plain-loop benchmark)."""
    if fence is None:
        return
    info = read_lease(storage, fence.rel)
    if info is None or info.get("owner") != fence.owner:
        raise LeaseLost(f"lost the lease on {storage.uri}: it was taken over (this producer was stopped or "
                        "cut off past its expiry); nothing more is committed, run again to resume")
    generation = read_generation(storage)
    if generation != fence.generation:
        raise LeaseLost(f"lost the lease on {storage.uri}: a repair or takeover ran meanwhile (lease generation "
                        f"{fence.generation} -> {generation}); nothing more is committed, run again to resume")


def _process_gone(info: dict) -> bool:
    """True if the lease's holder ran on this host (same name and pid namespace) and its pid is gone."""
    if info.get("host") != socket.gethostname() or info.get("pidns") != _pid_namespace() or info.get("pidns") is None:
        return False
    pid = info.get("pid")
    if not isinstance(pid, int) or pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except PermissionError:  # exists, another user's
        return False
    return False


def read_lease(storage, rel: str) -> dict | None:
    """A lease file's content; None if it is gone or unreadable (a torn lease is dead)."""
    try:
        info = json.loads(storage.read_bytes(rel))
        return info if isinstance(info, dict) and isinstance(info.get("expires"), (int, float)) else None
    except (FileNotFoundError, ValueError, OSError):
        return None


def is_live(info: dict | None) -> bool:
    """A lease not yet expired whose holder is not known to be gone."""
    return info is not None and info["expires"] > time.time() and not _process_gone(info)


def _say_taken_over(storage, info: dict | None) -> None:
    if info is not None and info["expires"] > time.time():  # live by its expiry: its process is gone
        log.warning("took over the lease of %s on %s: its process %s on this host is gone",
                    describe(info).split(" (")[0], storage.uri, info.get("pid"))


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
    generation: int | None = None  # producer leases: the root's generation when registered
    lost: bool = False  # set once the lease is found taken over; it is never refreshed again
    _stop: threading.Event = field(default_factory=threading.Event, repr=False)
    _thread: threading.Thread | None = field(default=None, repr=False)

    @property
    def fence(self) -> Fence | None:
        return None if self.generation is None else Fence(self.rel, self.owner, self.generation)

    def refresh(self) -> None:
        """Extend the lease; a fenced lease that was taken over is marked lost instead, never revived."""
        if self.lost:
            return
        if self.generation is not None:
            try:
                check_fence(self.storage, self.fence)
            except LeaseLost as exc:
                log.warning("%s", exc)
                self.lost = True
                self._stop.set()
                return
        self.storage.write_bytes(self.rel, _body(self.owner, self.purpose, self.ttl_s, self.generation))

    def keep_alive(self) -> Lease:
        """Refresh from a daemon thread every quarter of the TTL until released."""
        def loop() -> None:
            while not self._stop.wait(self.ttl_s / 4):
                try:
                    self.refresh()
                except Exception:  # a failed refresh: the next one may succeed; the fence is the backstop
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
            _say_taken_over(storage, info)
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
    """Announce a running producer (kept alive until released), fenced by the root's generation.

    Dead producers' lease files (a killed driver's) are removed first, without
    a generation bump: a holder that was only stopped finds its lease file gone
    at its next fence check and commits nothing more, and producers add only
    files identical whoever writes them, so no other fence is needed here."""
    owner = owner or new_owner()
    remove_dead_producers(storage)
    lease = Lease(storage, f"{PRODUCER_PREFIX}{owner}.json", owner, "produce", ttl_s, generation=read_generation(storage))
    storage.write_bytes(lease.rel, _body(owner, "produce", ttl_s, lease.generation))
    return lease.keep_alive()


def _producer_leases(storage, except_owner: str | None) -> tuple[list[tuple[str, dict]], list[tuple[str, dict | None]]]:
    """(live, dead) producer leases other than ``except_owner``'s, as (path, content)."""
    found, dead = [], []
    for rel in storage.list_files(PRODUCER_PREFIX):
        info = read_lease(storage, rel)
        if info is not None and info.get("owner") == except_owner:
            continue
        (found if is_live(info) else dead).append((rel, info))
    return found, dead


def remove_dead_producers(storage) -> int:
    """Remove the lease files of dead producers (expired, or their process gone from
    this host); the generation is left as it is. Returns how many were removed."""
    _, dead = _producer_leases(storage, None)
    for rel, info in dead:
        _say_taken_over(storage, info)
        storage.delete(rel)
    return len(dead)


def live_producers(storage, except_owner: str | None = None, take_over: bool = True) -> list[dict]:
    """Live producer leases other than ``except_owner``'s.

    ``take_over=False`` only looks: nothing in the root changes (verify).
    With ``take_over`` (a repair, under the exclusive lease) dead ones are
    taken over: their files are removed (their holders can no longer commit).
    Where no other producer is live (so the caller goes on to delete files)
    the root's generation is bumped first, which also fences a holder that
    refreshed its lease at the very moment it was judged dead, or whose lease
    file someone else removed."""
    found, dead = _producer_leases(storage, except_owner)
    if not take_over:
        return [info for _, info in found]
    if not found:
        bump_generation(storage)
    for rel, info in dead:
        _say_taken_over(storage, info)
        storage.delete(rel)
    return [info for _, info in found]
