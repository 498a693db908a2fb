"""What runs inside Ray's worker processes: the episode task and the progress counter.

Kept apart from ``pipeline.driver`` because Ray ships a remote function or
actor class by reference, so a worker imports the module that defines it. The
driver imports the manifest reader and the planner, the progress actor none of
that: defined in the driver, the actor was ready 0.9 s later, on cores the
first frames need (defined here, 0.1 s). Nothing here imports Ray.
"""

from __future__ import annotations

import os
from dataclasses import dataclass


@dataclass(frozen=True)
class Fatal:
    """A worker's error that retrying cannot fix (full disk, read-only root)."""

    message: str


def episode_task(spec, storage, world, counter=None, lp_threads=None, fence=None):
    """Render one episode in a Ray worker; a ``Fatal`` in place of errors retrying cannot
    help (a full disk, or the producer's lease lost: ``fence``)."""
    from pipeline.episode_job import run_episode
    from storage import StorageError

    if lp_threads is not None:  # read when this worker's GL context is made (its first episode)
        os.environ.setdefault("LP_NUM_THREADS", lp_threads)
    on_frame = None
    if counter is not None:
        def on_frame(n: int) -> None:  # fire and forget: progress never slows rendering
            counter.frame.remote(spec.key, n)
    try:
        return run_episode(spec, storage, world=world, on_frame=on_frame, fence=fence)
    except StorageError as exc:
        if exc.fatal:  # returned, not raised: Ray would retry it
            return Fatal(str(exc))
        raise


class FrameCounter:
    """Ray actor the render tasks report each written frame to.

    Keeps the highest count per episode, so a retried episode is not counted
    twice; ``wait_total`` returns as soon as the total moves (or after
    ``timeout``), which lets the driver wake once per frame."""

    def __init__(self) -> None:
        import asyncio

        self._done: dict[str, int] = {}
        self._total = 0
        self._moved = asyncio.Event()

    async def frame(self, key: str, n: int) -> None:
        if n > self._done.get(key, 0):
            self._total += n - self._done.get(key, 0)
            self._done[key] = n
            self._moved.set()

    async def forget(self, key: str) -> None:
        self._total -= self._done.pop(key, 0)
        self._moved.set()

    async def wait_total(self, seen: int, timeout: float) -> int:
        import asyncio

        if self._total == seen:
            self._moved.clear()
            try:
                await asyncio.wait_for(self._moved.wait(), timeout)
            except asyncio.TimeoutError:
                pass
        return self._total
