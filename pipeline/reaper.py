"""Make a local Ray cluster die with its driver, however the driver dies.

Ray ties its GCS and raylet to the driver that started them
(PR_SET_PDEATHSIG), and ``RAY_enable_pipe_based_agent_to_parent_health_check``
makes its agents notice the raylet's death at once; but an agent then spends
up to 60 s (a timeout fixed in Ray) trying to report that death to the dead
GCS, and a worker may keep writing for a moment. SIGKILL cannot be caught,
so this small watcher runs beside the driver in its own session: it records
the driver's Ray descendants while the cluster runs and, if the driver's pipe
closes without a "stop" line (the driver died), kills those still alive.
After a clean ``ray.shutdown`` ("stop"), the same agents would still linger
for up to that minute, so it gives them ``GRACE_S`` to go and then kills
what is left, and returns once they are gone: nothing of the run outlives
the command. Every write is atomic, so what a killed worker leaves behind is
a temp file that the next run removes. Linux only (/proc); elsewhere nothing
is started.
"""

from __future__ import annotations

import os
import select
import shutil
import signal
import subprocess
import sys
import time

POLL_S = 0.5
STOP = b"stop\n"
REMOVE = b"remove "  # + a folder's path and a newline: removed when the watcher ends
GRACE_S = 1.0  # after a clean shutdown, how long Ray's processes get to exit by themselves
GONE_S = 5.0  # how long to wait for killed processes to disappear


def _proc_table() -> dict[int, tuple[int, str]]:
    """{pid: (parent pid, start time)} of every process."""
    table = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as f:
                    fields = f.read().rsplit(")", 1)[1].split()
                table[int(entry)] = (int(fields[1]), fields[19])
            except (OSError, IndexError, ValueError):
                continue
    return table


def _is_ray(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            return b"ray" in f.read()
    except OSError:
        return False


def descendants(pid: int, table: dict[int, tuple[int, str]]) -> dict[int, str]:
    """{pid: start time} of every process below ``pid``."""
    found, frontier = {}, {pid}
    while frontier:
        children = {p for p, (parent, _) in table.items() if parent in frontier and p not in found}
        found.update((p, table[p][1]) for p in children)
        frontier = children
    return found


def _alive(seen: dict[int, str]) -> dict[int, str]:
    """The processes of ``seen`` still running (same pid and start time, not a zombie)."""
    table = _proc_table()
    alive = {}
    for pid, start in seen.items():
        if pid in table and table[pid][1] == start:
            try:
                with open(f"/proc/{pid}/stat") as f:
                    state = f.read().rsplit(")", 1)[1].split()[0]
            except (OSError, IndexError):
                continue
            if state != "Z":
                alive[pid] = start
    return alive


def _wait_gone(seen: dict[int, str], seconds: float) -> dict[int, str]:
    """Wait up to ``seconds`` for ``seen`` to exit; returns those still alive."""
    deadline = time.monotonic() + seconds
    alive = _alive(seen)
    while alive and time.monotonic() < deadline:
        time.sleep(0.05)
        alive = _alive(alive)
    return alive


def _kill(seen: dict[int, str]) -> None:
    for pid in _alive(seen):  # the same processes, not reused pids
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass


def watch(driver: int) -> None:
    """Record ``driver``'s Ray descendants until stdin says stop or closes; on close, kill
    them; on stop, kill those that do not exit within GRACE_S. Either way, remove the folders
    the driver named in ``remove <path>`` lines (its scratch folders: progress counts)."""
    seen: dict[int, str] = {}
    folders: list[str] = []
    stdin = sys.stdin.buffer
    while True:
        table = _proc_table()
        seen.update((p, start) for p, start in descendants(driver, table).items() if p not in seen and _is_ray(p))
        ready, _, _ = select.select([stdin], [], [], POLL_S)
        if ready:
            line = stdin.readline()
            if line == STOP:
                _kill(_wait_gone(seen, GRACE_S))
                break
            if line.startswith(REMOVE):
                folders.append(os.fsdecode(line[len(REMOVE):].rstrip(b"\n")))
                continue
            if line:
                continue
            _kill(seen)  # EOF without "stop": the driver is gone
            break
    _wait_gone(seen, GONE_S)
    for folder in folders:  # after the workers that wrote there are gone
        shutil.rmtree(folder, ignore_errors=True)


class Reaper:
    """The watcher process of one driver; ``stop()`` when the cluster was shut down cleanly."""

    def __init__(self) -> None:
        self._proc = None
        if os.path.isdir("/proc") and sys.platform.startswith("linux"):
            self._proc = subprocess.Popen(
                [sys.executable, "-m", "pipeline.reaper", str(os.getpid())],
                stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                start_new_session=True,  # a kill of the driver's process group spares it
                env={**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)},
            )

    def remove_on_exit(self, folder: str) -> None:
        """Have the watcher remove ``folder`` when it ends, however the driver ends."""
        if self._proc is None:
            return
        try:
            self._proc.stdin.write(REMOVE + os.fsencode(folder) + b"\n")
            self._proc.stdin.flush()
        except OSError:  # the watcher is gone: the driver's own cleanup is all there is
            pass

    def stop(self) -> None:
        if self._proc is None:
            return
        try:
            self._proc.stdin.write(STOP)
            self._proc.stdin.close()
        except OSError:
            pass
        try:
            self._proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()
        self._proc = None


if __name__ == "__main__":
    watch(int(sys.argv[1]))
