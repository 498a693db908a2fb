"""The distributor: runs a plan's pending episodes on Ray.

This is the only module that imports Ray. One task per episode; worker
processes are reused, so each keeps its renderer alive between episodes.
In-flight tasks are bounded, so the driver's memory stays flat whatever the
plan size. Worker or node death and renderer exceptions are retried by Ray;
an episode that still fails is reported, never silently skipped.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import tempfile
import threading
import time
from collections import deque
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Callable

from domains.catalog import using, weather
from manifests.layout import record_layout
from manifests.reader import compact, episode_frames, refuse_misfiled, scan
from manifests.schema import STATS_DIR, named_rows
from pipeline.cluster import _import_ray, attach, cluster_address, shutdown, start_local_cluster  # noqa: F401 (re-exported)
from pipeline.cluster import _host_port
from pipeline.planner import make_plan
from pipeline.provenance import RunConfigError, check_rows, for_root, prepare_root, read_run, recorded_as_asked
from pipeline.ray_task import ChecksGate, Fatal, FileCounts, FrameCounter, GatedFence, episode_task
from pipeline.repair import check_no_repair_running, refuse_in_the_way, repair_alone
from pipeline.settings import ProduceConfig
from roots.contract import claim_root
from roots.lease import new_owner, register_producer
from storage import Storage, StorageError

log = logging.getLogger(__name__)

# Environment passed on to Ray workers (renderer platform, test hooks).
_FORWARDED_ENV = ("PYOPENGL_PLATFORM", "EGL_DEVICE_ID", "IDDA_FAULT_INJECT", "LP_NUM_THREADS", "IDDA_WORLD_CACHE")
# Mesa llvmpipe rasterises with one thread per core in every GL context. When
# the workers alone fill the cores, that is cores x cores threads on a large
# machine, so each worker's context then gets this many (unless LP_NUM_THREADS
# is set). None (0: the render thread rasterises): a worker already keeps two
# threads busy (drawing, and finishing the frame before), and with one pass per
# frame extra rasterising threads only add hand-offs (2 cores, 120 full-HD
# frames end to end, 5 rounds each alternating: median 3.00 frames/s and 0.627
# machine CPU-s per frame with 0, 2.85 and 0.644 with 2; a lone worker, as for
# the last episode of a run: 0.274 s per frame with 0, 0.30 with 2).
LP_THREADS_WHEN_FULL = "0"
# OpenCV's thread pool (the post effects, resizes, blurs) in each worker when the workers fill
# the cores, unless OPENCV_FOR_THREADS_NUM is set: its helper threads then only compete with the
# other workers (2 cores, 80 full-HD frames end to end, 5 rounds each alternating: median 3.14
# frames/s and 0.579 machine CPU-s per frame with 1, 2.96 and 0.612 with OpenCV's default of one per
# core). The frames' bytes do not depend on it (docs/contract.md).
CV_THREADS_WHEN_FULL = 1


@dataclass(frozen=True)
class Progress:
    """Sent to the progress callback when rendering starts, after each
    progress report of the workers (at most one per task per
    ``progress_interval_s``) and after each finished episode."""

    frames_done: int  # frames written so far (finished and running episodes)
    frames_total: int
    episodes_done: int
    episodes_total: int
    failed: int
    elapsed_s: float  # since produce() started

    @property
    def rate(self) -> float:
        """Frames per second over the whole run so far (0 before the first frame)."""
        return self.frames_done / self.elapsed_s if self.elapsed_s > 0 else 0.0

    @property
    def eta_s(self) -> float | None:
        """Seconds left at ``rate``; None before the first frame."""
        return (self.frames_total - self.frames_done) / self.rate if self.rate > 0 else None


@dataclass
class ProduceReport:
    out: str
    planned_episodes: int
    planned_frames: int
    skipped_episodes: int  # already done before this run
    rendered_frames: int = 0
    rendered_episodes: int = 0
    failed: list[tuple[str, str]] = field(default_factory=list)  # (episode key, error)
    repaired: list[str] = field(default_factory=list)
    reshifted: list[str] = field(default_factory=list)  # shifting episodes made longer: rendered again whole
    seconds: float = 0.0
    per_scenario: dict[str, dict] = field(default_factory=dict)  # frames, episodes, seconds
    workers: int = 0  # task slots when rendering started
    crashed: int = 0  # episodes whose worker died of a native fault on every try
    nodes_lost: int = 0  # cluster nodes that died or stopped answering meanwhile (their episodes ran elsewhere)

    @property
    def ok(self) -> bool:
        return not self.failed


class ProduceInterrupted(Exception):
    """The run was interrupted (Ctrl-C); ``report`` says what was done."""

    def __init__(self, report: ProduceReport) -> None:
        super().__init__(f"interrupted after {report.rendered_episodes} episode(s)")
        self.report = report


class HeadLost(Exception):
    """The Ray cluster's head stopped answering mid-run (its GCS port refuses
    connections for HEAD_GONE_S), so nothing more can be scheduled; ``report``
    says what was done. Finished episodes are committed: run again to resume."""

    def __init__(self, report: ProduceReport, address: str) -> None:
        super().__init__(f"the Ray head at {address} is gone")
        self.report, self.address = report, address


class StorageOutage(Exception):
    """The output root's storage failed an episode on every retry, so the run
    stopped; ``error`` is the StorageError, ``report`` says what was done."""

    def __init__(self, report: ProduceReport, error: Exception) -> None:
        super().__init__(str(error))
        self.report, self.error = report, error


def _address(config: ProduceConfig) -> str | None:
    return cluster_address(config.address)


def _connect(ray, config: ProduceConfig) -> None:
    """Start or attach to Ray, unless this process already has it.

    ``ray.init`` replaces the process's SIGTERM handler with one that exits at
    once; the caller's is put back (the CLI turns SIGTERM into an interrupt
    that releases the leases and shuts Ray down)."""
    import signal
    import threading

    if ray.is_initialized():
        return
    main = threading.current_thread() is threading.main_thread()
    keep = signal.getsignal(signal.SIGTERM) if main else None
    try:
        # a cluster this call starts runs only this run's tasks, which carry no runtime_env (_task_options)
        attach(ray, _address(config), config.workers, runtime_envs=False)
    finally:
        if main and keep is not None:
            signal.signal(signal.SIGTERM, keep)


PROGRESS_WAIT_S = 5.0  # longest the driver waits for a frame before it looks again


PROGRESS_ACTOR_OPTIONS = dict(num_cpus=0, max_restarts=-1, max_task_retries=0)
PROGRESS_RETRY_S = 1.0  # after a failed call to the progress actor, ask again this much later
FILE_POLL_S = 0.01  # the driver reads the count files of its own machine's run at most this often


def on_driver_node(ray) -> dict:
    """Actor options that place an actor on the driver's own node and nowhere else (no CPU): an actor
    the run cannot do without (``ChecksGate``: the tasks' part commits wait for its answer) is lost
    with the driver, never with a worker node."""
    from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

    node = ray.get_runtime_context().get_node_id()
    return dict(num_cpus=0, scheduling_strategy=NodeAffinitySchedulingStrategy(node_id=node, soft=False))


class RendererCrashes(Exception):
    """Render workers died of a native fault (not a Python error) on the first
    episodes of the run, none finished: retrying cannot help, the environment
    does not render (a GL driver setting, a library build). ``report`` says
    what was done."""

    def __init__(self, report: ProduceReport, crashed: int) -> None:
        settings = gl_settings()
        where = (f"GL-related settings in force: {', '.join(settings)}; unset them and run again (Mesa's llvmpipe "
                 "aborts under some of them)") if settings else (
                 "no GL-related variable is set; the workers' logs (`ray logs`, or /tmp/ray/session_latest/logs) "
                 "name the fault")
        super().__init__(f"render workers crashed (a native fault, not a Python error) on the first {crashed} "
                         f"episode(s), none finished, so the run stopped: retrying cannot help; {where}")
        self.report, self.crashed = report, crashed


# Variables that change what the GL driver runs; named when every worker crashes.
_GL_VARIABLES = ("LP_", "MESA_", "GALLIUM_", "EGL_", "LIBGL_", "__GLX_", "PYOPENGL_")
_GL_DEFAULTS = {"PYOPENGL_PLATFORM": "egl"}  # what compat chooses by itself: not a suspect


def gl_settings(environ=None) -> list[str]:
    """``NAME=value`` of the environment's GL driver settings, the platform default left out."""
    environ = os.environ if environ is None else environ
    return sorted(f"{k}={v}" for k, v in environ.items()
                  if k.startswith(_GL_VARIABLES) and _GL_DEFAULTS.get(k) != v)


# After this many crashed episodes with none finished, a run stops (RendererCrashes).
CRASHES_TO_STOP = 2


class _LiveFrames:
    """The driver's side of progress: frames of finished episodes (from their
    results) plus the best-effort counts of running ones (from the progress
    actor). Every actor call is guarded: if the actor dies, its node with it,
    the counts stall until Ray restarted it, and the run goes on."""

    def __init__(self, ray, counter) -> None:
        self._ray, self.counter = ray, counter
        self._version, self._counts, self._shown = 0, {}, 0
        self.watch, self._retry_at = None, 0.0
        self.nodes: dict[str, str] = {}  # episode key -> the Ray node id it last reported from
        self._asked: set[str] = set()

    def ask(self, keys: list[str]) -> None:
        """Start a long poll of the counts of ``keys`` unless one runs or the actor just failed."""
        if self.counter is None or self.watch is not None or time.monotonic() < self._retry_at:
            return
        self._asked = set(keys)
        try:
            self.watch = self.counter.counts.remote(keys, self._version, PROGRESS_WAIT_S)
        except Exception as exc:  # pragma: no cover - a handle whose actor is gone for good
            self._failed(exc)

    def wait_s(self) -> float | None:
        """How long the driver may block before it should ask again (None: as long as it likes)."""
        if self.counter is None or self.watch is not None:
            return None
        return max(0.0, self._retry_at - time.monotonic())

    def take(self) -> None:
        """Read the answer of the finished long poll."""
        watch, self.watch = self.watch, None
        try:
            self._version, self._counts, nodes = self._ray.get(watch)
            # kept across a restart of the actor (it comes back empty); finished episodes dropped
            self.nodes = {key: node for key, node in {**self.nodes, **nodes}.items() if key in self._asked}
        except Exception as exc:  # ActorDiedError, ActorUnavailableError, ...: best effort
            self._failed(exc)

    def _failed(self, exc: Exception) -> None:
        log.debug("progress actor unavailable (%s); counting finished episodes only for now", exc)
        self._version, self._counts = 0, {}
        self._retry_at = time.monotonic() + PROGRESS_RETRY_S

    def frames(self, finished: int, running) -> int:
        """Frames done: ``finished`` plus the counts of the ``running`` specs; never goes back."""
        live = sum(min(self._counts.get(spec.key, 0), spec.frames) for spec in running)
        self._shown = max(self._shown, finished + live)
        return self._shown

    def close(self) -> None:
        """Nothing of its own to remove (the actor goes with the cluster)."""


_COUNTS_PREFIX = "idda-progress-"  # + the driver's pid and "-": a run's count folder in the temp dir


def _remove_orphaned_counts() -> None:
    """Remove the count folders of drivers that are gone (killed with their watcher: a whole
    process tree killed at once leaves one behind). Best effort: a folder of a pid that is in
    use again stays until that process ends."""
    scratch = tempfile.gettempdir()
    try:
        names = os.listdir(scratch)
    except OSError:
        return
    for name in names:
        pid = name[len(_COUNTS_PREFIX):].partition("-")[0]
        if not (name.startswith(_COUNTS_PREFIX) and pid.isdigit()):
            continue
        try:
            os.kill(int(pid), 0)
        except ProcessLookupError:
            shutil.rmtree(os.path.join(scratch, name), ignore_errors=True)
        except (PermissionError, OverflowError):  # another user's live process, or no pid at all
            continue


class _FileFrames(_LiveFrames):
    """Progress of a run on a cluster this process started on its own machine: the tasks write
    their counts to files of a folder of its own (``FileCounts``), read here at most every
    ``interval_s`` (the tasks write at most that often; ``FILE_POLL_S`` at the least), when the
    display asks for frames. The files of episodes no longer running are removed; ``close``
    removes the folder (and the run's ``Reaper`` does, if the driver is killed)."""

    def __init__(self, ray, interval_s: float) -> None:
        _remove_orphaned_counts()
        super().__init__(ray, FileCounts(tempfile.mkdtemp(prefix=f"{_COUNTS_PREFIX}{os.getpid()}-")))
        self._every, self._due = max(interval_s, FILE_POLL_S), 0.0

    def ask(self, keys: list[str]) -> None:
        """Nothing to ask: the counts are read when shown."""

    def wait_s(self) -> float:
        return max(0.0, self._due - time.monotonic())

    def frames(self, finished: int, running) -> int:
        if time.monotonic() >= self._due:
            keys = {spec.key for spec in running}
            for key in set(self._counts) - keys:
                self.counter.forget(key)
            read = self.counter.read(keys)
            # the highest count per running episode: a retried one starts over from 0
            self._counts = {key: max(n, self._counts.get(key, 0)) for key, n in read.items()}
            self._due = time.monotonic() + self._every
        return super().frames(finished, running)

    def close(self) -> None:
        shutil.rmtree(self.counter.folder, ignore_errors=True)


NODE_POLL_S = 2.0  # on a cluster, the driver looks for nodes Ray marked dead this often
HEAD_GONE_S = 10.0  # the head's GCS port refusing connections this long: the head is gone (Ray waits 60 s, then aborts)
HEAD_POLL_S = 1.0  # a thread tries the head's GCS port this often
HEAD_STUCK_S = 5.0  # the head gone this long and the driver's loop has not said so: it is blocked inside Ray


class _NodeWatch:
    """The cluster's nodes as the driver last saw them (``ray.nodes()``, at most
    once per ``every_s``): ``lost()`` gives the nodes found dead since the last
    call, once each. Ray marks a node dead when it stops answering its health
    checks (a hung node: failure threshold x (period + timeout), about 65 s with
    Ray's defaults), minutes before a task running there fails.

    With a ``host:port`` address a thread tries the head's GCS port every HEAD_POLL_S:
    ``head_gone`` once it refused connections for HEAD_GONE_S. The driver's loop then
    stops (``HeadLost``), but a call into Ray can block on the dead head's raylet
    until Ray aborts the process at 60 s; so if the loop has not ``noticed()`` the
    loss HEAD_STUCK_S later, the thread calls ``on_stuck`` (the CLI says so and
    exits). ``close()`` stops the thread."""

    def __init__(self, ray, every_s: float = NODE_POLL_S, address: str | None = None,
                 on_stuck: Callable[[], None] | None = None) -> None:
        self._ray, self._every_s = ray, every_s
        self._next = time.monotonic() + every_s
        self._dead = {node["NodeID"] for node in self._nodes() if not node.get("Alive")}
        plain = address is not None and not address.startswith("ray://")  # a client server is no GCS
        self.address, self._head = address, (_host_port(address) if plain else None)
        self.silent = False  # the head's GCS port refused a connection at the last try
        self.head_gone = False  # ... and has refused them for HEAD_GONE_S
        self._noticed, self._closed = threading.Event(), threading.Event()
        self._on_stuck = on_stuck
        if self._head is not None:
            threading.Thread(target=self._watch_head, name="head-watch", daemon=True).start()

    def _watch_head(self) -> None:
        import socket

        silent_since = None
        while not self._closed.wait(HEAD_POLL_S):
            try:
                socket.create_connection(self._head, timeout=HEAD_POLL_S).close()
            except OSError:
                silent_since = silent_since or time.monotonic()
                self.silent = True
            else:
                silent_since, self.silent = None, False
                continue
            silent_s = time.monotonic() - silent_since
            self.head_gone = silent_s >= HEAD_GONE_S
            if silent_s >= HEAD_GONE_S + HEAD_STUCK_S and not self._noticed.is_set():
                if self._on_stuck is not None:
                    self._on_stuck()
                return

    def noticed(self) -> None:
        """The driver's loop has seen ``head_gone`` and stops: the thread need not act."""
        self._noticed.set()

    def close(self) -> None:
        self._closed.set()

    def _nodes(self) -> list[dict]:
        try:
            return self._ray.nodes()
        except Exception as exc:  # the GCS busy or gone: asked again next time
            log.debug("could not list the cluster's nodes: %s", exc)
            return []

    def lost(self) -> list[tuple[str, str]]:
        """(node id, address) of the nodes marked dead since the last call; [] between polls."""
        if time.monotonic() < self._next:
            return []
        self._next = time.monotonic() + self._every_s
        if self.silent:  # no GCS to ask (Ray's own calls would wait for it)
            return []
        found = [(node["NodeID"], node.get("NodeManagerAddress", "?")) for node in self._nodes()
                 if not node.get("Alive") and node["NodeID"] not in self._dead]
        self._dead.update(node_id for node_id, _ in found)
        return found


def _retry_lost_nodes(ray, watch: _NodeWatch, live: _LiveFrames, in_flight: dict, queue: deque,
                      report: ProduceReport, given_up: list) -> bool:
    """Give up the episodes of nodes found dead: cancel their tasks (forced: the node may
    only be stopped, and wake), cancel those not yet known to have started anywhere
    (not forced: one may have been meant for the lost node), run them all again first,
    and say so in one line per node. True if a node was lost."""
    if watch.head_gone:
        watch.noticed()
        raise HeadLost(report, watch.address)
    lost = watch.lost()
    if not lost:
        return False
    unknown = [ref for ref, spec in in_flight.items() if spec.key not in live.nodes]
    for i, (node_id, address) in enumerate(lost):
        on_node = [ref for ref, spec in in_flight.items() if live.nodes.get(spec.key) == node_id]
        retried = [(ref, True) for ref in on_node] + ([(ref, False) for ref in unknown] if i == 0 else [])
        for ref, force in retried:
            try:
                ray.cancel(ref, force=force)
            except Exception as exc:  # already finished, or its node unreachable: it is given up either way
                log.debug("cancelling a task of lost node %s: %s", address, exc)
            spec = in_flight.pop(ref)
            live.nodes.pop(spec.key, None)
            queue.appendleft(spec)
            given_up.append(ref)  # kept referenced: a dropped failed ref makes Ray log an "unhandled error"
        report.nodes_lost += 1
        log.warning("node %s lost: %s retried elsewhere", address,
                    f"{len(retried)} episode" + ("" if len(retried) == 1 else "s"))
    return True


def _task_options(config: ProduceConfig, slots: int, local: bool,
                  own_cluster: bool) -> tuple[dict, str | None, int | None]:
    """Ray options of the episode task, the llvmpipe threads each worker's GL context gets and the
    threads of each worker's OpenCV (None: as they are; ``local``: no cluster address;
    ``own_cluster``: a local cluster this run started)."""
    full = local and not config.gpus_per_task and slots * config.cpus_per_task >= (os.cpu_count() or 1)
    lp_threads = LP_THREADS_WHEN_FULL if full and "LP_NUM_THREADS" not in os.environ else None
    cv_threads = CV_THREADS_WHEN_FULL if full and "OPENCV_FOR_THREADS_NUM" not in os.environ else None
    options = dict(num_cpus=config.cpus_per_task, max_retries=config.max_retries, retry_exceptions=True)
    if config.gpus_per_task:
        options["num_gpus"] = config.gpus_per_task
    env = {k: os.environ[k] for k in _FORWARDED_ENV if k in os.environ}
    if env and not own_cluster:
        # Per task, so it also reaches workers of an existing cluster. A local
        # cluster this call started inherited our environment already, and a
        # runtime_env would make Ray start fresh workers instead of its
        # prestarted ones (a second or more of imports on each).
        options["runtime_env"] = {"env_vars": env}
    return options, lp_threads, cv_threads


def _collect(ray, ref, in_flight: dict, report: ProduceReport, max_retries: int) -> None:
    """One finished task into ``report``: its frames, or its failure. A storage
    error every retry hit means the storage is down (StorageOutage); a Fatal
    one (full disk, lease lost) stops the run; either cancels the rest."""
    spec = in_flight.pop(ref)
    try:
        result = ray.get(ref)
    except Exception as exc:  # RayTaskError, WorkerCrashedError, NodeDiedError...
        cause = getattr(exc, "cause", exc)
        if isinstance(cause, StorageError):  # every retry failed on storage: it is down, not the episode
            for other in in_flight:
                ray.cancel(other, force=True)
            raise StorageOutage(report, cause) from None
        message = str(exc).strip().splitlines()[-1] if str(exc).strip() else type(exc).__name__
        report.failed.append((spec.key, message))
        log.error("episode %s failed after %d retries: %s", spec.key, max_retries, message)
        if isinstance(exc, ray.exceptions.WorkerCrashedError):  # the process died: a native fault
            report.crashed += 1
        return
    if isinstance(result, Fatal):
        for other in in_flight:
            ray.cancel(other, force=True)
        raise StorageError(f"{result.message}; stopped the run (retrying cannot help)", fatal=True)
    report.rendered_frames += result.frames
    report.rendered_episodes += 1
    row = report.per_scenario.setdefault(spec.scenario, {"frames": 0, "episodes": 0, "seconds": 0.0})
    row["frames"] += result.frames
    row["episodes"] += 1
    row["seconds"] += result.seconds


# A resume with at least this many parts outside a current index (a root made before indexes, or
# whose _index/ was deleted: 14,355 at full scale) renders first the episodes the listing alone shows
# pending, and reads the parts' footers beside them (below this, their footers take under a second).
LATE_CHECK_PARTS = 2000
LATE_POLL_S = 0.5  # while those checks run, the driver looks whether they are done this often


class _LateChecks:
    """The checks of a resume that need every part's footer, run on a thread beside its first
    episodes: misfiled parts, the rows' seeds, resolutions and rgb formats (``check_rows``), and
    the rows each part holds. ``first``, the episodes rendered meanwhile, have no part at all, so
    the listing alone shows them pending and no frame of a done episode is written before the
    checks pass; their part commits wait for the checks (``pipeline.ray_task.ChecksGate``), so a
    root the checks refuse gets no part from this run."""

    def __init__(self, storage, state, config: ProduceConfig, plan, record: dict, first: list,
                 report: ProduceReport) -> None:
        self.storage, self.state, self.config, self.plan = storage, state, config, plan
        self.record, self.first, self.report = record, first, report
        self._more: list | None = None
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="root-checks", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def finished(self, timeout: float = 0.0) -> bool:
        """Whether the checks are done (waiting at most ``timeout``)."""
        self._thread.join(timeout)
        return not self._thread.is_alive()

    def result(self) -> list:
        """The further episodes to render (pending by the rows their parts hold: a part shorter
        than planned, or unreadable), in the root's layout; raises what a check refused."""
        if self._error is not None:
            raise self._error
        return self._more

    def _run(self) -> None:
        try:
            summaries = self.state.summaries(self.storage)  # O(parts): footers, or the indexes where current
            refuse_misfiled(self.storage, summaries)
            check_rows(self.storage, self.config.run, summaries)
            held = episode_frames(self.storage, summaries)
            todo = pending_episodes(self.plan, held)
            first = {spec.key for spec in self.first}
            more = for_root([spec for spec in todo if spec.key not in first], self.record)
            refuse_in_the_way(self.storage, more, record_layout(self.record), "nothing more rendered", parts_only=True)
            self.report.reshifted = reshifted_episodes(todo, held)
            self.report.skipped_episodes -= len(more)
            self._more = more
        except BaseException as exc:  # raised in the driver's loop, which stops the run
            self._error = exc


def _late_checks(config: ProduceConfig, plan, storage, state, report: ProduceReport,
                 fence) -> _LateChecks | None:
    """The checks to run beside the first episodes when that pays and is safe: a root with
    LATE_CHECK_PARTS parts or more outside a current index, each under a name that counts its
    rows, whose run.json records exactly this run (nothing to write before rendering), and
    with episodes that have no part yet. None: check everything first, as usual."""
    if config.repair or fence is None:
        return None
    unindexed = [rel for scenario, episodes in state.parts.items() if scenario not in state.current
                 for rel, _ in episodes.values()]
    if len(unindexed) < LATE_CHECK_PARTS or any(named_rows(rel) is None for rel in unindexed):
        return None
    record = recorded_as_asked(storage, config.run)
    if record is None:
        return None
    first = [spec for spec in plan.episodes if spec.episode not in state.parts.get(spec.scenario, {})]
    if not first:
        return None
    return _LateChecks(storage, state, config, plan, record, for_root(first, record), report)


def _render_on_ray(config: ProduceConfig, storage, todo: list, report: ProduceReport,
                   progress: Callable[[Progress], None] | None, start: float, episode_fn=None,
                   fence=None, late: _LateChecks | None = None,
                   on_head_lost: Callable[[HeadLost], None] | None = None) -> None:
    """Run one task per pending episode, at most ``limit`` in flight; fills ``report``.
    ``late``: the root's checks still to run (started here, once Ray is up); until they pass, the
    tasks' part commits wait (``ChecksGate``), and the episodes they find pending join the queue."""
    ray = _import_ray()
    started = not ray.is_initialized()
    reaper = watch = live = None
    try:
        _connect(ray, config)
        if started and not _address(config):  # our own local cluster: it dies with this process
            from pipeline.reaper import Reaper

            reaper = Reaper()
        slots = max(1, int(ray.cluster_resources().get("CPU", 1) // config.cpus_per_task))
        report.workers = slots
        limit = config.max_in_flight or 2 * slots
        local = not _address(config)
        options, lp_threads, cv_threads = _task_options(config, slots, local, own_cluster=started and local)
        task = ray.remote(episode_task).options(**options)
        storage_ref = ray.put(storage)
        if progress is not None and local and started:  # every task on this machine: no actor needed
            live = _FileFrames(ray, config.progress_interval_s)
            if reaper is not None:  # a driver killed outright leaves no folder behind either
                reaper.remove_on_exit(live.counter.folder)
        elif progress is not None or not local:  # on a cluster, it also tells which node runs each episode
            live = _LiveFrames(ray, ray.remote(FrameCounter).options(**PROGRESS_ACTOR_OPTIONS).remote())
        else:
            live = _LiveFrames(ray, None)
        counter = live.counter
        stuck = None if on_head_lost is None else (lambda: on_head_lost(HeadLost(report, _address(config))))
        watch = None if local else _NodeWatch(ray, address=_address(config), on_stuck=stuck)
        queue, in_flight, given_up = deque(todo), {}, []
        frames_total, episodes_total = sum(e.frames for e in todo), len(todo)
        if late is not None:
            gate = ray.remote(ChecksGate).options(**on_driver_node(ray)).remote()
            gated = GatedFence.of(fence, gate.wait.remote())
            late.start()

        def report_progress() -> None:
            if progress is not None:
                progress(
                    Progress(
                        frames_done=live.frames(report.rendered_frames, in_flight.values()),
                        frames_total=frames_total,
                        episodes_done=report.rendered_episodes,
                        episodes_total=episodes_total,
                        failed=len(report.failed),
                        elapsed_s=time.perf_counter() - start,
                    )
                )

        report_progress()  # at once: the display starts with the work, not after an episode
        while queue or in_flight or late is not None:
            if late is not None and late.finished():
                try:
                    more = late.result()
                except BaseException:
                    for other in in_flight:  # at the gate, or rendering towards it: nothing of theirs is committed
                        ray.cancel(other, force=True)
                    try:
                        gate.open.remote(False)  # and any that outlive their cancel commit nothing either
                    except Exception as exc:  # Ray going down: so are they
                        log.debug("could not close the checks' gate: %s", exc)
                    raise
                gate.open.remote(True)
                queue.extend(more)
                frames_total, episodes_total = frames_total + sum(e.frames for e in more), episodes_total + len(more)
                late = None
            while queue and len(in_flight) < limit:
                spec = queue.popleft()
                ref = task.remote(spec, storage_ref, config.run.world, counter, lp_threads,
                                  config.progress_interval_s, episode_fn, fence if late is None else gated,
                                  cv_threads)
                in_flight[ref] = spec
            if late is not None and not in_flight:  # the first episodes failed: wait for the checks
                late.finished(LATE_POLL_S)
                continue
            live.ask([spec.key for spec in in_flight.values()])
            watched = [live.watch] if live.watch is not None else []
            timeout = live.wait_s()
            if watch is not None:  # a hung node's tasks never finish: look at the nodes every NODE_POLL_S
                timeout = NODE_POLL_S if timeout is None else min(timeout, NODE_POLL_S)
            if late is not None:  # the checks' end opens the gate
                timeout = LATE_POLL_S if timeout is None else min(timeout, LATE_POLL_S)
            ready, _ = ray.wait(list(in_flight) + watched, num_returns=1, timeout=timeout)
            if live.watch is not None and live.watch in ready:
                ready = [ref for ref in ready if ref != live.watch]
                live.take()
            for ref in ready:
                _collect(ray, ref, in_flight, report, config.max_retries)
            if watch is not None and _retry_lost_nodes(ray, watch, live, in_flight, queue, report, given_up):
                # Ray hands a new task a worker lease it holds already (of the same scheduling class), even one
                # on the lost node whose task was just cancelled: the task then waits on a stopped process for
                # ever. A different resource shape (a few bytes of memory more) makes new tasks take new leases.
                task = ray.remote(episode_task).options(**options, memory=report.nodes_lost)
            if not ready:
                report_progress()
                continue
            if report.crashed and not report.rendered_episodes and (
                    report.crashed >= CRASHES_TO_STOP or not (queue or in_flight)):
                for other in in_flight:  # every episode so far died natively: the rest would too
                    ray.cancel(other, force=True)
                raise RendererCrashes(report, report.crashed)
            report_progress()
    finally:  # every path, errors and Ctrl-C included: a cluster we started goes down cleanly
        if watch is not None:
            watch.close()
        if live is not None:
            live.close()
        if started and ray.is_initialized():
            shutdown(ray)
        if reaper is not None:
            reaper.stop()


def pending_episodes(plan, frames: dict[tuple[str, int], int]) -> list:
    """Planned episodes whose part does not hold the frames the plan asks of
    them: absent, or shorter (an --extend to more frames renders the episode
    again; the same seed gives the same first frames, byte for byte).
    RunConfigError if a part holds more frames than planned (that would drop frames). A rig's part
    holds one row per sensor frame: ``frames`` counts rows, so its frames are rows / sensors."""
    todo = []
    for spec in plan.episodes:
        have = frames.get((spec.scenario, spec.episode))
        if have is not None and len(spec.sensors) > 1:
            have = have / len(spec.sensors)
        if have is not None and have > spec.frames:
            raise RunConfigError(
                f"{spec.scenario} episode {spec.episode} holds {have} frames, the plan asks for {spec.frames}; "
                "a root never shrinks: ask for at least as many frames, or use a new --out"
            )
        if have != spec.frames:
            todo.append(spec)
    return todo


def reshifted_episodes(todo, frames: dict[tuple[str, int], int]) -> list[str]:
    """The keys of the episodes in ``todo`` that hold frames already and whose weather shifts: an
    --extend renders them again whole, and as the shift runs over the episode's length
    (domains.ramps) their earlier frames change (docs/weathers.md)."""
    return [spec.key for spec in todo if frames.get((spec.scenario, spec.episode)) and weather(spec.weather).shift_from]


def _fold_indexes(storage, producer, state=None) -> None:
    """Fold finished parts into their scenarios' indexes (no lock needed: an
    index records the parts it was built from, see ``manifests.reader.compact``);
    left to the next fold or run if storage fails, or if this producer lost its lease.
    ``state``: the root's scan if nothing was written since (else one is made)."""
    if producer.lost:
        return
    try:
        compact(storage, state=state)
    except Exception as exc:  # the parts are the truth; an index is only a cache of them
        log.warning("indexes not updated this time (%s); readers use the parts meanwhile", exc)


@contextmanager
def _folding(storage, producer, every_s: float):
    """Fold indexes every ``every_s`` from a background thread while the run
    renders, so a killed run leaves them at most that stale."""
    stop = threading.Event()

    def loop() -> None:
        while not stop.wait(every_s):
            _fold_indexes(storage, producer)

    thread = threading.Thread(target=loop, name="index-fold", daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join()


def produce(config: ProduceConfig, progress: Callable[[Progress], None] | None = None,
            episode_fn: Callable | None = None, on_head_lost: Callable[[HeadLost], None] | None = None) -> ProduceReport:
    """Render every pending episode of the plan into ``config.out``.

    ``episode_fn(spec, storage, world=..., on_frame=...)`` renders one episode
    in a Ray task (default: ``pipeline.episode_job.run_episode``); the control
    plane benchmark swaps in a stand-in that writes no images. The run's user
    domain entries (``PlanConfig.catalog``) are in force meanwhile.

    ``on_head_lost(HeadLost)`` is called from another thread if the cluster's head is gone
    and this call stays blocked inside Ray (which aborts the process 60 s after its head
    went): the caller's chance to say what is committed and end the process first.
    Otherwise the loss is raised here, as ``HeadLost``."""
    with using(config.run.plan.catalog):
        config.validate()
        with _cluster_first(config):
            return _produce(config, progress, episode_fn, on_head_lost)


@contextmanager
def _cluster_first(config: ProduceConfig):
    """With a cluster address, attach before anything touches ``--out``, so a failed
    attach (a dead address, a refused token) writes nothing there; detach at the end.
    A private local cluster is started later, and only if there is something to render."""
    if not _address(config):
        yield
        return
    ray = _import_ray()
    if ray.is_initialized():
        yield
        return
    _connect(ray, config)
    try:
        yield
    except HeadLost:  # nothing to shut down: Ray's shutdown would wait for the GCS that is gone
        raise
    except BaseException:
        if ray.is_initialized():
            shutdown(ray)
        raise
    else:
        if ray.is_initialized():
            shutdown(ray)


def _checked_todo(storage, config: ProduceConfig, plan, state, report: ProduceReport) -> tuple[list, dict]:
    """The pending episodes in the root's layout, and the run record, once every check of the
    root passed: misfiled parts, run.json, the rows' seeds and resolutions (from the parts'
    summaries: footers, or the indexes where current)."""
    summaries = state.summaries(storage)  # O(parts): footers, or the indexes where current
    refuse_misfiled(storage, summaries)  # a swapped part is damage, never "done"
    held = episode_frames(storage, summaries)
    todo = pending_episodes(plan, held)
    report.reshifted = reshifted_episodes(todo, held)
    if not config.repair:
        record = prepare_root(storage, config.run, extend=config.extend, summaries=summaries)
    else:
        record = read_run(storage)  # repair_alone prepared it
    return for_root(todo, record), record  # the root's layout, PNG deflater and scenes' splits


def _produce(config: ProduceConfig, progress: Callable[[Progress], None] | None,
             episode_fn: Callable | None, on_head_lost: Callable[[HeadLost], None] | None = None) -> ProduceReport:
    plan = make_plan(config.run.plan)
    storage = Storage.from_uri(config.out)
    claim_root(storage)  # refuses a non-empty directory that is not ours; creates and marks the root

    report = ProduceReport(
        out=storage.uri,
        planned_episodes=len(plan.episodes),
        planned_frames=plan.total_frames,
        skipped_episodes=0,
    )
    owner = new_owner()
    if config.repair:  # before this run registers: the repair bumps the lease generation it then reads
        check_no_repair_running(storage)
        # refuses a shrink before repair deletes anything: from the rows the parts hold, never from their
        # names (a part renamed to say more rows than it holds is damage to repair, not frames to keep)
        pending_episodes(plan, episode_frames(storage, scan(storage).summaries(storage)))
        report.repaired = repair_alone(storage, config, plan, owner)
    producer = register_producer(storage, owner=owner, ttl_s=config.lease_ttl_s)
    try:
        check_no_repair_running(storage)
        state = scan(storage)
        # a big root without indexes: its footers are read beside the episodes the listing shows pending
        late = _late_checks(config, plan, storage, state, report, producer.fence)
        todo, record = (late.first, late.record) if late else _checked_todo(storage, config, plan, state, report)
        # a folder where a part goes fails every write of it: said before any rendering (frame files in the
        # way stop the run at their first write, in one line too)
        refuse_in_the_way(storage, todo, record_layout(record), "nothing rendered", parts_only=True)
        state = None if todo else state  # nothing to render: the final fold needs no second scan
        report.skipped_episodes = len(plan.episodes) - len(todo)
        start = time.perf_counter()
        try:
            if todo:
                with _folding(storage, producer, config.index_every_s):
                    _render_on_ray(config, storage, todo, report, progress, start, episode_fn, fence=producer.fence,
                                   late=late, on_head_lost=on_head_lost)
        except KeyboardInterrupt:
            raise ProduceInterrupted(report) from None
        _fold_indexes(storage, producer, state)  # also scenarios an earlier (killed) run finished
        report.seconds = time.perf_counter() - start
        if report.rendered_frames and report.seconds > 0:
            driver_stats = {
                "workers": report.workers,
                "frames_per_s": round(report.rendered_frames / report.seconds, 4),
            }
            storage.write_bytes(f"{STATS_DIR}/driver.json", json.dumps(driver_stats).encode())
    finally:
        try:
            producer.release()
        except StorageError as exc:  # the storage is down: the lease expires by itself
            log.info("lease %s not released (%s); it expires by itself", producer.rel, exc)
    return report
