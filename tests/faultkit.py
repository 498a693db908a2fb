"""Fault injection for tests: run a real ``idda`` command in a subprocess and
hurt it at a chosen point, or hurt the world around it.

* :func:`start` runs ``python -m pipeline.cli <args>`` in its own session. With
  ``pause_at="module:function:n"`` the child stops on the n-th call of that
  function (before it runs), writes :attr:`Child.paused` and waits until
  :meth:`Child.release`: so a fault lands at the same point on every run,
  never "whenever a poll happened to see it".
* At that point: :meth:`Child.kill` (SIGKILL to the command and every process
  it started, e.g. its local Ray cluster), :meth:`Child.signal` (SIGTERM,
  SIGINT, SIGHUP: to the command alone, as a terminal or scheduler does),
  :meth:`Child.stop` / :meth:`Child.cont` (SIGSTOP / SIGCONT).
* In the render workers: ``IDDA_FAULT_INJECT=stop-before-commit:<marker>``
  stops a worker (SIGSTOP) just before it commits its part; :func:`stopped_worker`
  waits for it and gives its pid.
* :func:`full_disk`: a small tmpfs mounted for the test (root only); None
  where mounting is not allowed, and :data:`ENOSPC_ENV` is the fallback
  (``IDDA_FAULT_INJECT=enospc-after:N``, the workers' own fault hook).
* :func:`symlink_swap` replaces a folder by a symlink to another; :func:`swap`
  exchanges two files.
* :func:`s3_outage`: stop the moto server of ``tests/s3_server.py`` (the
  network to S3 is gone for every process using it).
* :func:`listing`: the file count and checksum listing of a tree (symlinks as
  their link text, never followed), to show that a refusal changed nothing.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib
import os
import shutil
import signal
import subprocess
import sys
import time
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

REPO = Path(__file__).resolve().parents[1]
PAUSE_ENV = "IDDA_TEST_PAUSE"  # "module:function:n:flag dir", read by the child only
ENOSPC_ENV = {"IDDA_FAULT_INJECT": "enospc-after:0"}  # the workers' hook: the first frame write fails as a full disk
WAIT_S = 240.0


def listing(root: Path, skip: tuple[str, ...] = ()) -> dict[str, str]:
    """Relative path -> sha256 of the bytes (files), "-> target" (symlinks, not followed) or "dir".

    ``skip``: top-level folders left out, never walked into (``_lease``, whose
    writers come and go with temp files that may vanish between listing and reading)."""
    out = {}
    root = Path(root)
    if not root.exists():
        return out
    for folder, dirs, files in os.walk(root, followlinks=False):
        if Path(folder) == root:
            dirs[:] = [d for d in dirs if d not in skip]
        for name in sorted(dirs + files):
            path = Path(folder) / name
            rel = path.relative_to(root).as_posix()
            if path.is_symlink():
                out[rel] = "-> " + os.readlink(path)
            elif path.is_dir():
                out[rel] = "dir"
            else:
                out[rel] = hashlib.sha256(path.read_bytes()).hexdigest()
    return dict(sorted(out.items()))


def descendants(pid: int) -> list[int]:
    """Every process below ``pid`` (Ray's GCS, raylet and workers start their own sessions)."""
    parents = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as f:
                    parents[int(entry)] = int(f.read().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
    found, frontier = [], [pid]
    while frontier:
        children = [c for c, parent in parents.items() if parent in frontier]
        found += children
        frontier = children
    return found


@dataclass
class Result:
    returncode: int
    stdout: str
    stderr: str

    def error_line(self) -> str:
        """The one ``error:`` line of a refusal (stderr holds nothing else)."""
        lines = [line for line in self.stderr.strip().splitlines() if line.strip()]
        assert len(lines) == 1 and lines[0].startswith("error: "), self.stderr[-3000:]
        assert "Traceback" not in self.stderr + self.stdout
        return lines[0]


class Child:
    """A running ``idda`` command (see :func:`start`)."""

    def __init__(self, args: list[str], env: dict[str, str], pause_at: str | None) -> None:
        self.flags = Path(env.get("IDDA_TEST_FLAGS", "/nonexistent"))
        self.proc = subprocess.Popen(
            [sys.executable, "-c", "from tests.faultkit import _child; _child()", *args],
            env=env, cwd=str(REPO), start_new_session=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )
        self.pause_at = pause_at

    @property
    def paused(self) -> Path:
        return self.flags / "paused"

    def wait_paused(self, timeout: float = WAIT_S) -> None:
        """Block until the child sits at its pause point (AssertionError if it ended first)."""
        deadline = time.time() + timeout
        while not self.paused.exists():
            if self.proc.poll() is not None:
                out, err = self.proc.communicate()
                raise AssertionError(f"the command ended before {self.pause_at}: rc {self.proc.returncode}\n{err[-3000:]}")
            if time.time() > deadline:
                self.kill()
                raise AssertionError(f"the command never reached {self.pause_at}")
            time.sleep(0.02)

    def release(self) -> None:
        (self.flags / "release").touch()

    def signal(self, sig: int) -> None:
        self.proc.send_signal(sig)

    def stop(self) -> None:
        self.proc.send_signal(signal.SIGSTOP)

    def cont(self) -> None:
        self.proc.send_signal(signal.SIGCONT)

    def kill(self) -> None:
        """SIGKILL the command and everything it started, at once."""
        for pid in [self.proc.pid, *descendants(self.proc.pid)]:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        self.proc.wait()

    def finish(self, timeout: float = WAIT_S) -> Result:
        try:
            out, err = self.proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.kill()
            raise
        return Result(self.proc.returncode, out, err)


def start(args: list[str], flags: Path, pause_at: str | None = None, env: dict[str, str] | None = None) -> Child:
    """Run ``idda <args>`` in a subprocess; ``pause_at`` "module:function:n" pauses it there (see the module doc).

    ``flags`` is an empty folder for the pause handshake."""
    flags.mkdir(parents=True, exist_ok=True)
    environ = {**os.environ, "PYTHONPATH": str(REPO), "IDDA_TEST_FLAGS": str(flags), **(env or {})}
    environ.pop(PAUSE_ENV, None)
    if pause_at is not None:
        environ[PAUSE_ENV] = pause_at
    return Child(args, environ, pause_at)


def stopped_worker(marker: Path, child: Child, timeout: float = WAIT_S) -> int:
    """The pid of the worker that the ``stop-before-commit:<marker>`` hook
    stopped, once it is stopped (AssertionError if the command ended first)."""
    deadline = time.time() + timeout
    while time.time() < deadline:
        if child.proc.poll() is not None:
            raise AssertionError(f"the command ended before a worker stopped: rc {child.proc.returncode}")
        text = marker.read_text() if marker.exists() else ""
        if text.endswith("\n"):
            pid = int(text)
            with open(f"/proc/{pid}/stat") as f:
                if f.read().rsplit(")", 1)[1].split()[0] == "T":
                    return pid
        time.sleep(0.05)
    child.kill()
    raise AssertionError("no worker stopped before its commit")


def run(args: list[str], flags: Path, env: dict[str, str] | None = None) -> Result:
    """Run ``idda <args>`` to the end, no fault."""
    return start(args, flags, env=env).finish()


def _child() -> None:
    """The child's entry point: install the pause point, then run the CLI with the rest of argv.

    SIGINT is handled as a terminal's foreground job gets it (Python's KeyboardInterrupt): a shell that
    runs the suite in the background (`make test &`, no job control) starts it with SIGINT ignored,
    every child inherits that, and a test's Ctrl-C did nothing (the command ran on, or stayed paused)."""
    signal.signal(signal.SIGINT, signal.default_int_handler)
    spec = os.environ.get(PAUSE_ENV)
    if spec:
        module_name, name, nth = spec.split(":")
        flags = Path(os.environ["IDDA_TEST_FLAGS"])
        module = importlib.import_module(module_name)
        original = getattr(module, name)
        calls = [0]

        def paused(*args, **kwargs):
            calls[0] += 1
            if calls[0] == int(nth):
                (flags / "paused").touch()
                while not (flags / "release").exists():
                    time.sleep(0.01)
            return original(*args, **kwargs)

        setattr(module, name, paused)
    from pipeline.cli import main

    sys.argv = ["idda", *sys.argv[1:]]
    main()


@contextlib.contextmanager
def full_disk(base: Path, size_kb: int = 256) -> Iterator[Path | None]:
    """A ``size_kb`` tmpfs mounted at a new folder under ``base`` (None when mounting is not allowed)."""
    mount = base / f"small-disk-{uuid.uuid4().hex[:8]}"
    mount.mkdir(parents=True)
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size_kb}k", "tmpfs", str(mount)],
                          capture_output=True) if shutil.which("mount") else None
    if done is None or done.returncode != 0:
        mount.rmdir()
        yield None
        return
    try:
        yield mount
    finally:
        subprocess.run(["umount", "-l", str(mount)], capture_output=True)


def fill(path: Path) -> int:
    """Fill the file system of ``path`` until a write fails; returns the bytes written."""
    written = 0
    fd = os.open(path / f".filler-{uuid.uuid4().hex[:8]}", os.O_CREAT | os.O_WRONLY)
    try:
        with contextlib.suppress(OSError):
            while True:
                written += os.write(fd, b"\0" * 4096)
    finally:
        os.close(fd)
    return written


def symlink_swap(folder: Path, target: Path) -> Path:
    """Replace ``folder`` by a symlink to ``target``; returns where the real folder was moved."""
    aside = folder.with_name(f".{folder.name}.aside-{uuid.uuid4().hex[:8]}")
    os.rename(folder, aside)
    folder.symlink_to(target, target_is_directory=True)
    return aside


def swap(a: Path, b: Path) -> None:
    """Exchange the contents of two files (each replaced by a rename)."""
    tmp = a.with_name(f".{a.name}.swap")
    os.rename(a, tmp)
    os.rename(b, a)
    os.rename(tmp, b)


def s3_outage(server) -> None:
    """The network to S3 is gone: stop the moto server (tests/s3_server.py) for good."""
    server.moto.stop()
