"""What runs inside Ray's worker processes: the episode task and the progress counters
(the actor of a cluster, the count files of a run on the driver's own machine).

Kept apart from ``pipeline.driver`` because Ray ships a remote function or
actor class by reference, so a worker imports the module that defines it. The
driver imports the manifest reader and the planner, the progress actor none of
that: defined in the driver, the actor was ready 0.9 s later, on cores the
first frames need (defined here, 0.1 s). Ray is imported only inside a task,
where it is already loaded.
"""

from __future__ import annotations

import logging
import os
import time
from dataclasses import dataclass
from urllib.parse import quote

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Fatal:
    """A worker's error that retrying cannot fix (full disk, read-only root)."""

    message: str


class FileCounts:
    """The frame counts of the episodes of a Ray cluster on the driver's own machine (the one
    ``produce`` starts for itself): one small file per running episode in ``folder``, replaced whole
    at each report (a reader never sees half a count), read by the driver (``pipeline.driver``).

    No actor, so no process of its own. On 2 cores the progress actor's process took ~1 CPU-s of a
    run's start, and, as it took one of the two workers Ray prestarts, the second episode waited
    ~0.5 s for a worker started for it (docs/bench_render.md, sixth round). A cluster of several
    machines keeps the actor (``FrameCounter``): its tasks share no folder with the driver."""

    def __init__(self, folder: str) -> None:
        self.folder = folder

    def _path(self, key: str) -> str:
        return os.path.join(self.folder, quote(key, safe=""))

    def write(self, key: str, n: int) -> None:
        # Not storage.atomic.atomic_write: that fsyncs (a count a second needs no durability) and
        # makes the folder again, where a folder the driver removed must stay gone.
        path = self._path(key)
        part = f"{path}.{os.getpid()}.part"
        with open(part, "w") as f:
            f.write(str(n))
        os.replace(part, path)

    def read(self, keys) -> dict[str, int]:
        """The counts of those of ``keys`` that have one (an episode not started yet has none)."""
        counts = {}
        for key in keys:
            try:
                with open(self._path(key)) as f:
                    counts[key] = int(f.read())
            except (OSError, ValueError):  # not started yet, or the run's folder is gone
                continue
        return counts

    def forget(self, key: str) -> None:
        try:
            os.unlink(self._path(key))
        except OSError:
            pass


class FrameReporter:
    """An episode's ``on_frame``: sends its frame count, and the Ray node it runs
    on (``node``), to the progress actor, batched and back-pressured; or, given a
    ``FileCounts``, writes the count to its file at most once per ``interval_s``.

    At most one call is in flight (a new count waits until the actor acked
    the last one; counts are cumulative, so a skipped one is carried by the
    next) and at most one call per ``interval_s``. So a task never queues
    more than one message, however fast it writes frames, and the actor gets
    at most one call per second per task. Progress is best effort: a dead or
    restarting actor costs the display some updates, never the episode."""

    def __init__(self, counter, key: str, interval_s: float, node: str | None = None) -> None:
        self._counter, self._key, self._interval, self._node = counter, key, interval_s, node
        self._pending = None
        self._last = float("-inf")

    def __call__(self, n: int) -> None:
        now = time.monotonic()
        if now - self._last < self._interval:
            return
        if isinstance(self._counter, FileCounts):
            try:
                self._counter.write(self._key, n)
            except OSError as exc:  # best effort, as below: never the episode's failure
                log.debug("progress of %s not written: %s", self._key, exc)
                return
            self._last = now
            return
        if self._pending is not None and not self._acked():
            return
        try:
            self._pending = self._counter.frame.remote(self._key, n, self._node)
        except Exception as exc:  # the actor is gone for good: no more progress from this task
            log.debug("progress report of %s dropped: %s", self._key, exc)
            return
        self._last = now

    def _acked(self) -> bool:
        import ray

        ready, _ = ray.wait([self._pending], timeout=0)
        if not ready:
            return False
        try:
            ray.get(ready[0])  # consumed, so Ray does not log an unhandled error of a dead actor
        except Exception as exc:
            log.debug("progress report of %s lost: %s", self._key, exc)
        self._pending = None
        return True


def episode_task(spec, storage, world, counter=None, lp_threads=None, progress_interval_s=1.0, episode_fn=None,
                 fence=None, cv_threads=None):
    """Render one episode in a Ray worker (with ``episode_fn``, default ``run_episode``); a ``Fatal`` in
    place of errors retrying cannot help (a full disk, or the producer's lease lost: ``fence``).
    ``lp_threads``, ``cv_threads``: llvmpipe's and OpenCV's threads in this worker (None: as they are)."""
    from pipeline.episode_job import run_episode  # deferred: the progress actor imports this module, not the renderer
    from storage import StorageError  # deferred: (as above)

    if lp_threads is not None:  # read when this worker's GL context is made (its first episode)
        os.environ.setdefault("LP_NUM_THREADS", lp_threads)
    if cv_threads is not None:  # OpenCV's pool, process-wide: this and later episodes of this worker
        import cv2

        cv2.setNumThreads(cv_threads)
    on_frame = None
    if counter is not None:
        import ray

        on_frame = FrameReporter(counter, spec.key, progress_interval_s, ray.get_runtime_context().get_node_id())
        on_frame(0)  # at once: the driver learns which node runs this episode (it gives up a hung node's)
    try:
        return (episode_fn or run_episode)(spec, storage, world=world, on_frame=on_frame, fence=fence)
    except StorageError as exc:
        if exc.fatal:  # returned, not raised: Ray would retry it
            return Fatal(str(exc))
        raise


class FrameCounter:
    """Ray actor the render tasks report their frame counts to.

    Keeps the highest count per running episode (a retried episode is not
    counted twice) and the node each one last reported from. ``counts`` answers as soon as a count moves (or after
    ``timeout``) with the counts of the episodes the driver still waits for,
    and forgets the others, so its memory is bounded by the tasks in flight,
    not by the plan. Holds nothing the run needs: if it dies, Ray restarts it
    empty and the running tasks fill it again with their next report."""

    def __init__(self) -> None:
        import asyncio

        self._done: dict[str, int] = {}
        self._nodes: dict[str, str] = {}
        self._version = 0
        self._moved = asyncio.Event()

    async def frame(self, key: str, n: int, node: str | None = None) -> None:
        moved = False
        if node is not None and self._nodes.get(key) != node:
            self._nodes[key] = node
            moved = True
        if n > self._done.get(key, 0):
            self._done[key] = n
            moved = True
        if moved:
            self._version += 1
            self._moved.set()

    async def counts(self, keys: list[str], seen: int, timeout: float) -> tuple[int, dict[str, int], dict[str, str]]:
        """(version, frame counts, nodes) of ``keys``, once the version moves past ``seen`` or after ``timeout``."""
        import asyncio

        wanted = set(keys)
        self._done = {k: n for k, n in self._done.items() if k in wanted}
        self._nodes = {k: node for k, node in self._nodes.items() if k in wanted}
        if self._version == seen:
            self._moved.clear()
            try:
                await asyncio.wait_for(self._moved.wait(), timeout)
            except asyncio.TimeoutError:
                pass
        return self._version, dict(self._done), dict(self._nodes)


class ChecksGate:
    """Ray actor that holds back the part commits of the first episodes of a resume while the
    driver still checks the root's parts (their footers: misfiled parts, seeds, resolutions),
    so a root the checks refuse gets no part from this run. ``wait`` answers once ``open`` was
    called: True if the checks passed. Its answer is one object every waiting task reads, and
    outlives the actor once given."""

    def __init__(self) -> None:
        import asyncio

        self._opened = asyncio.Event()
        self._passed = False

    async def wait(self) -> bool:
        await self._opened.wait()
        return self._passed

    async def open(self, passed: bool) -> None:
        self._passed = passed
        self._opened.set()


@dataclass(frozen=True)
class GatedFence:
    """The producer's lease, as ``roots.lease.Fence`` (its fields, so ``check_fence`` takes it;
    not a subclass, which would load the storage code into the progress actor), and in ``gate``
    the answer of ``ChecksGate.wait`` (an ObjectRef): a part is committed only once the
    driver's checks of the root passed (``pipeline.episode_job.commit_part``)."""

    rel: str
    owner: str
    generation: int
    gate: object

    @classmethod
    def of(cls, fence, gate) -> "GatedFence":
        return cls(fence.rel, fence.owner, fence.generation, gate)

    def wait_for_checks(self) -> None:
        """Block until the driver's checks of the root are done; a fatal StorageError if they
        refused it (nothing is committed: the driver says why)."""
        import ray

        from storage import StorageError

        if not ray.get(self.gate):
            raise StorageError("the root's checks refused it; nothing committed", fatal=True)
