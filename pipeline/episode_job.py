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
from dataclasses import dataclass
from typing import Callable

from outputs.deflaters import deflating_with
from outputs.table import OUTPUTS, encode_outputs, file_bytes
from manifests.layout import frame_path, output_dir
from manifests.schema import STATS_DIR, frame_id, part_path, part_stem
from manifests.schema import NEW_RULES
from pipeline.planner import make_plan
from pipeline.provenance import for_root, prepare_root
from render_workers.render.episode import render_episode
from roots.contract import claim_root
from roots.episode_spec import EpisodeSpec
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


@dataclass(frozen=True)
class EpisodeResult:
    """What a worker reports back: small, never image data."""

    scenario: str
    episode: int
    frames: int
    seconds: float
    node: str
    pid: int


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
    """The spec's outputs of a rendered frame, encoded from its named buffers (arrays, or a table)."""
    return encode_outputs(frame.buffers, spec.outputs, old_rules=spec.rules < NEW_RULES)


def frame_files(spec: EpisodeSpec, frame) -> dict[str, bytes]:
    """The file bytes of each of the spec's outputs of a frame, in table order."""
    return {name: file_bytes(name, content, spec.rgb_format) for name, content in frame_outputs(spec, frame).items()}


def store_frame(spec: EpisodeSpec, frame, storage) -> dict:
    """Encode one frame's outputs, write their files; return its manifest row."""
    with deflating_with(spec.png_deflater):  # the root's deflater (an older root keeps its own)
        files = frame_files(spec, frame)
    for name, data in files.items():
        fid = frame_id(spec.episode, frame.index)
        storage.write_bytes(frame_path(spec.scenario, name, fid, spec.rgb_format, spec.layout), data)
    return frame_row(spec, frame, files)


def run_episode(spec: EpisodeSpec, storage, world: str = "procedural",
                on_frame: Callable[[int], None] | None = None, fence=None) -> EpisodeResult:
    """Render ``spec`` into ``storage`` and mark it done; returns timings.

    ``on_frame(n)``, if given, is called after each frame's files are written
    with the number of frames written so far (the driver's progress).
    ``fence`` (``roots.lease.Fence``): the producer's lease, checked just
    before and just after the part is written; LeaseLost, and no part, if the
    lease was taken over meanwhile (a repair may have deleted this episode's
    frames)."""
    start = time.perf_counter()
    for output in OUTPUTS:  # temp files of an earlier, killed attempt at this episode
        storage.remove_stale_temp(output_dir(spec.scenario, output, spec.episode, spec.layout), f"{spec.episode:04d}_")
    part_dir = part_path(spec.scenario, spec.episode).rpartition("/")[0]
    storage.remove_stale_temp(part_dir, part_stem(spec.scenario, spec.episode))  # under any of its names
    rows: list[dict] = []
    kill_after, full_after = _fault_after(), _enospc_after()

    def sink(frame) -> None:
        if full_after is not None and len(rows) >= full_after:
            raise storage_error("write", storage.join(spec.scenario), OSError(errno.ENOSPC, "No space left on device"))
        rows.append(store_frame(spec, frame, storage))
        if on_frame is not None:
            on_frame(len(rows))
        if kill_after is not None and len(rows) >= kill_after:
            os._exit(17)

    # The process keeps one renderer alive across episodes (render_workers.render.episode).
    info = render_episode(spec, sink, world=world)
    if len(rows) != spec.frames:
        raise RuntimeError(f"{spec.key}: rendered {len(rows)} frames, expected {spec.frames}")
    seconds = time.perf_counter() - start
    result = EpisodeResult(spec.scenario, spec.episode, len(rows), seconds, socket.gethostname(), os.getpid())
    stats = {"frames": len(rows), "seconds": round(seconds, 3), "node": result.node, "stages": info.timings}
    storage.write_bytes(f"{STATS_DIR}/{spec.scenario}_e{spec.episode:04d}.json", json.dumps(stats).encode())
    _stop_before_commit()
    commit_part(storage, spec, rows, fence)
    log.debug("%s done: %d frames in %.1f s", spec.key, len(rows), seconds)
    return result


def commit_part(storage, spec: EpisodeSpec, rows: list[dict], fence=None) -> None:
    """Write the episode's part, the "done" marker, unless the producer's lease was lost.

    The second check closes the window between the first and the write: a
    part written after a takeover is deleted again (the episode stays pending;
    whoever renders it next writes the same bytes)."""
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
