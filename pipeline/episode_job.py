"""One episode, start to finish: render, encode, write frames, then the part.

A plain function (no Ray), so tests and the plain-loop benchmark call it
directly. The order is what makes runs resumable: frame files first, the
episode's manifest part last; a killed episode leaves no part and is simply
rendered again (same spec, same bytes).
"""

from __future__ import annotations

import errno
import json
import logging
import os
import signal
import socket
import time
from typing import Callable

from outputs.deflaters import deflating_with
from outputs.table import OUTPUTS, encode_outputs, file_bytes
from manifests.layout import frame_path, output_dir
from manifests.schema import frame_id, part_path, part_stem, stats_path
from manifests.schema import NEW_RULES
from pipeline.planner import make_plan
from pipeline.provenance import for_root, prepare_root
from render_workers.render.episode import render_episode
from roots.contract import claim_root
from roots.episode_spec import EpisodeResult, EpisodeSpec  # noqa: F401 (EpisodeResult: public here too)
from manifests.writer import frame_row, write_part
from roots.lease import LeaseLost, check_fence
from storage.errors import storage_error

log = logging.getLogger(__name__)

# Test hooks, unset in normal runs:
# "kill-after:<frames>:<marker path>" makes the worker process die abruptly
# (os._exit) after writing that many frames, once per marker file, so the test
# suite can kill a real worker mid-episode; "enospc-after:<frames>" makes the
# next write fail as a full disk does (the StorageError storage raises for ENOSPC);
# "stop-before-commit:<marker path>" makes the worker stop itself (SIGSTOP) just
# before it commits its part, once per marker (which it writes its pid into), so
# a test can stop a real worker past its lease's expiry and wake it up later.
FAULT_ENV = "IDDA_FAULT_INJECT"


def _once(marker: str) -> int | None:
    """A file descriptor for a new ``marker``, or None where it exists (the hook fired already)."""
    try:
        return os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
    except FileExistsError:
        return None


def _stop_before_commit() -> None:
    spec = os.environ.get(FAULT_ENV, "")
    if spec.startswith("stop-before-commit:") and (fd := _once(spec.split(":", 1)[1])) is not None:
        os.write(fd, f"{os.getpid()}\n".encode())
        os.close(fd)
        os.kill(os.getpid(), signal.SIGSTOP)


def _enospc_after() -> int | None:
    spec = os.environ.get(FAULT_ENV, "")
    return int(spec.split(":")[1]) if spec.startswith("enospc-after:") else None


def _fault_after() -> int | None:
    spec = os.environ.get(FAULT_ENV, "")
    if not spec.startswith("kill-after:"):
        return None
    _, count, marker = spec.split(":", 2)
    fd = _once(marker)
    if fd is None:
        return None
    os.close(fd)
    return int(count)


def frame_outputs(spec: EpisodeSpec, frame) -> dict:
    """The spec's outputs of a rendered frame (a LiDAR's: its own), encoded from its named buffers."""
    return encode_outputs(frame.buffers, spec.sensor_outputs(frame.sensor), old_rules=spec.rules < NEW_RULES)


def frame_files(spec: EpisodeSpec, frame) -> dict[str, bytes]:
    """The file bytes of each of the spec's outputs of a frame, in table order."""
    return {name: file_bytes(name, content, spec.rgb_format) for name, content in frame_outputs(spec, frame).items()}


# Frame files are fenced: the producer's lease is checked before a frame file is
# written whenever this long (monotonic clock: it runs on while a process is
# stopped) has passed since the last check, so a worker stopped past its lease
# (a hung node given up) writes at most the one file it was writing on waking.
FENCE_EVERY_S = 1.0


class FrameFence:
    """The producer's lease (``roots.lease.Fence``, None: unfenced), checked
    before frame files are written at most once per ``every_s``, and on
    ``check(force=True)``; LeaseLost once the lease is gone or its generation moved."""

    def __init__(self, storage, fence, every_s: float = FENCE_EVERY_S) -> None:
        self._storage, self._fence, self._every_s = storage, fence, every_s
        self._checked = float("-inf")

    def check(self, force: bool = False) -> None:
        if self._fence is None:
            return
        now = time.monotonic()
        if force or now - self._checked >= self._every_s:
            check_fence(self._storage, self._fence)
            self._checked = time.monotonic()


def store_frame(spec: EpisodeSpec, frame, storage, fence: FrameFence | None = None) -> dict:
    """Encode one frame's outputs, write their files (each after ``fence.check()``); return its manifest row."""
    with deflating_with(spec.png_deflater):  # the root's deflater (an older root keeps its own)
        files = frame_files(spec, frame)
    for name, data in files.items():
        fid = frame_id(spec.episode, frame.index)
        if fence is not None:
            fence.check()
        # each file fsynced, its folder once before the part (sync_frame_dirs): the part is the commit point
        storage.write_bytes(frame_path(spec.scenario, name, fid, spec.rgb_format, spec.layout, frame.sensor), data,
                            durable=False)
    return frame_row(spec, frame, files)


def sync_frame_dirs(storage, spec: EpisodeSpec) -> None:
    """fsync the episode's frame folders: their files' names are on disk before its part names them."""
    storage.sync_dirs(output_dir(spec.scenario, name, spec.episode, spec.layout, sensor)
                      for sensor in spec.sensors for name in spec.sensor_outputs(sensor))


def run_episode(spec: EpisodeSpec, storage, world: str = "procedural",
                on_frame: Callable[[int], None] | None = None, fence=None) -> EpisodeResult:
    """Render ``spec`` into ``storage`` and mark it done; returns timings.

    ``on_frame(n)``, if given, is called after each frame's files are written
    with the number of frames written so far (the driver's progress).
    ``fence`` (``roots.lease.Fence``): the producer's lease, checked before
    frame files are written (``FrameFence``: at most once per FENCE_EVERY_S),
    before the stats, and just before and just after the part is written;
    LeaseLost, and nothing more written, if the lease was taken over or
    released meanwhile (a repair may have deleted this episode's frames, or
    the driver gave this task up and finished)."""
    spec.check_outputs()  # the writer's fields (outputs, rgb format, layout): the renderer checks the rest
    start = time.perf_counter()
    for sensor in spec.sensors:  # temp files of an earlier, killed attempt at this episode
        for output in OUTPUTS:
            storage.remove_stale_temp(output_dir(spec.scenario, output, spec.episode, spec.layout, sensor),
                                      f"{spec.episode:04d}_")
    part_dir = part_path(spec.scenario, spec.episode).rpartition("/")[0]
    storage.remove_stale_temp(part_dir, part_stem(spec.scenario, spec.episode))  # under any of its names
    rows: list[dict] = []
    kill_after, full_after = _fault_after(), _enospc_after()
    frame_fence = FrameFence(storage, fence)

    def sink(frame) -> None:
        if full_after is not None and len(rows) >= full_after:
            raise storage_error("write", storage.join(spec.scenario), OSError(errno.ENOSPC, "No space left on device"))
        rows.append(store_frame(spec, frame, storage, frame_fence))
        if on_frame is not None and len(rows) % len(spec.sensors) == 0:  # a frame: every sensor of the rig
            on_frame(len(rows) // len(spec.sensors))
        if kill_after is not None and len(rows) >= kill_after:
            os._exit(17)

    # The process keeps one renderer alive across episodes (render_workers.render.episode).
    info = render_episode(spec.drawing, sink, world=world)  # the renderer takes only what it draws
    if len(rows) != spec.frames * len(spec.sensors):  # one row per sensor frame
        raise RuntimeError(f"{spec.key}: rendered {len(rows)} sensor frames, expected {spec.frames * len(spec.sensors)}")
    seconds = time.perf_counter() - start
    result = EpisodeResult(spec.scenario, spec.episode, spec.frames, seconds, socket.gethostname(), os.getpid())
    stats = {"frames": spec.frames, "seconds": round(seconds, 3), "node": result.node, "stages": info.timings}
    frame_fence.check(force=True)
    storage.write_bytes(stats_path(spec.scenario, spec.episode), json.dumps(stats).encode())
    sync_frame_dirs(storage, spec)
    _stop_before_commit()
    commit_part(storage, spec, rows, fence)
    log.debug("%s done: %d frames in %.1f s", spec.key, len(rows), seconds)
    return result


def commit_part(storage, spec: EpisodeSpec, rows: list[dict], fence=None) -> None:
    """Write the episode's part, the "done" marker, unless the producer's lease was lost.

    The second check closes the window between the first and the write: a
    part written after a takeover is deleted again (the episode stays pending;
    whoever renders it next writes the same bytes). A ``pipeline.ray_task.GatedFence`` first
    waits for the driver's checks of the root, which run beside the first episodes of a resume
    (asked by its method: ray_task imports this module, not the other way)."""
    wait_for_checks = getattr(fence, "wait_for_checks", None)
    if wait_for_checks is not None:
        wait_for_checks()
    check_fence(storage, fence)
    rel = write_part(storage, spec.scenario, spec.episode, rows)  # last: the "done" marker
    try:
        check_fence(storage, fence)
    except LeaseLost:
        storage.delete(rel)
        raise


def render_plan(storage, config, extend: bool = False) -> None:
    """Claim ``storage`` as a root, prepare it for ``config`` (a RunConfig) and
    render every planned episode into it here, one after another, with no Ray:
    the same files produce's workers write (tests, reports). ``extend``: as --extend."""
    storage.ensure_writable()
    claim_root(storage)  # as produce does: the root marker first
    record = prepare_root(storage, config, extend=extend)
    for spec in for_root(make_plan(config.plan).episodes, record):  # a new root's layout, or an old root's own
        run_episode(spec, storage, world=config.world)
