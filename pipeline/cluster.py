"""Reaching Ray: attach to a cluster (checked first, with token authentication
only where the cluster uses it) or start this run's private local cluster.

Only ``pipeline`` imports Ray; this module does the attaching for ``produce``
and ``verify`` alike.
"""

from __future__ import annotations

import logging
import os
import shlex
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

log = logging.getLogger(__name__)


def cluster_address(address: str | None) -> str | None:
    """The cluster to attach to: ``address``, else RAY_ADDRESS; None means a private local cluster."""
    return address or os.environ.get("RAY_ADDRESS")


RAY_AUTH_MODE = "RAY_AUTH_MODE"
_RAY_TOKEN_LOGGER = "ray._private.authentication.authentication_token_setup"
_AUTH_HINT = (
    "put the head's token in ~/.ray/auth_token or RAY_AUTH_TOKEN on this machine (`ray get-auth-token` on the head prints it)"
)
ATTACH_TIMEOUT_S = 10.0  # to reach a cluster's address, and again for its GCS to answer


def ray_token_available(environ=os.environ) -> bool:
    """Whether this machine has a Ray auth token where Ray looks for one."""
    if environ.get("RAY_AUTH_TOKEN"):
        return True
    path = environ.get("RAY_AUTH_TOKEN_PATH") or Path.home() / ".ray" / "auth_token"
    try:
        return Path(path).is_file() and Path(path).stat().st_size > 0
    except OSError:
        return False


def _import_ray():
    try:
        import ray
    except ImportError as exc:  # pragma: no cover - ray is a dependency
        raise ImportError("Ray is not installed: run `make venv` or `pip install 'ray[default]'`") from exc
    return ray


def _host_port(address: str) -> tuple[str, int] | None:
    """(host, port) of a plain ``host:port`` GCS address or of a ``ray://host:port``
    client address; None for "auto" and the like."""
    if address.startswith("ray://"):
        address = address[len("ray://"):]
    host, sep, port = address.rpartition(":")
    if not sep or not port.isdigit() or "/" in host or not host:
        return None
    return host.strip("[]"), int(port)


# Asks a GCS, without a token, whether it is alive; prints "ok", "token" (it
# wants one) or the error. Where it wants one and argv[3] is "1", asks again
# with this machine's token: "token-ok", or "token-refused" (another token).
# A child process: Ray's client logs its retries to stderr from C++ threads and
# keeps trying for 40 s or more.
_PROBE = """
import os, sys
from ray._raylet import Config, GcsClient
from ray.exceptions import AuthenticationError
def first_line(exc):
    return (str(exc).strip().splitlines() or [type(exc).__name__])[0]
def alive():
    GcsClient(address=sys.argv[1]).check_alive([], timeout=float(sys.argv[2]))
try:
    alive()
    print("ok")
except AuthenticationError:
    if sys.argv[3] != "1":
        print("token")
    else:
        os.environ["RAY_AUTH_MODE"] = "token"
        Config.initialize("")
        try:
            alive()
            print("token-ok")
        except AuthenticationError:
            print("token-refused")
        except Exception as exc:
            print(first_line(exc))
except Exception as exc:
    print(first_line(exc))
"""


def _probe_gcs(address: str, with_token: bool = False) -> str:
    """"ok", "token" (the cluster uses token authentication), with ``with_token`` then
    "token-ok" or "token-refused" (this machine's token), or why the GCS at ``address``
    did not answer."""
    env = {k: v for k, v in os.environ.items() if k != RAY_AUTH_MODE}
    try:
        done = subprocess.run([sys.executable, "-c", _PROBE, address, str(ATTACH_TIMEOUT_S), "1" if with_token else "0"], env=env,
                              stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                              text=True, timeout=2 * ATTACH_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        return f"no answer in {2 * ATTACH_TIMEOUT_S:.0f} s"
    lines = done.stdout.strip().splitlines()
    return lines[-1] if lines else f"the probe exited with {done.returncode}"


def _unreachable(address: str, why: str) -> ConnectionError:
    return ConnectionError(f"no Ray cluster answers at {address} ({why}); "
                           "check the address (RAY_ADDRESS or --address) and that the cluster's head is running")


def check_cluster(address: str) -> bool:
    """Fail fast on a cluster address nobody answers at, and choose Ray's auth mode
    for it; True if token mode was switched on.

    A plain ``host:port`` is first reached over TCP (ATTACH_TIMEOUT_S), so a
    dead address is one line in seconds instead of Ray's minutes of retries.
    Then the GCS is asked, without a token, whether it is alive: it refuses
    only if the cluster uses token authentication, and only then does this
    driver switch to token mode (with a token at hand), after asking again
    with the token (a wrong one is refused in one line); a cluster without
    authentication is attached to as it is. A ``RAY_AUTH_MODE`` set by the
    user stands. A ``ray://`` client address is reached over TCP only.
    ConnectionError naming the address when it cannot work.
    """
    import socket

    target = _host_port(address)
    if target is None:
        return False
    try:
        socket.create_connection(target, timeout=ATTACH_TIMEOUT_S).close()
    except OSError as exc:
        raise _unreachable(address, exc.strerror or str(exc) or "timed out") from None
    if RAY_AUTH_MODE in os.environ or address.startswith("ray://"):  # a client server is no GCS to probe
        return False
    answer = _probe_gcs(address, with_token=ray_token_available())  # one child process, both questions
    if answer == "ok":
        return False
    if answer == "token":
        raise ConnectionError(f"the Ray cluster at {address} uses token authentication and this machine has no token; {_AUTH_HINT}")
    if answer == "token-refused":  # a wrong token: Ray alone retried for ~25 s, in 20 lines, naming another address
        raise ConnectionError(f"the Ray cluster at {address} refused this machine's token (another cluster's, or an old "
                              f"one); {_AUTH_HINT}")
    if answer != "token-ok":
        raise _unreachable(address, answer)
    from ray._raylet import Config

    os.environ[RAY_AUTH_MODE] = "token"
    Config.initialize("")  # Ray reads the mode into its config; read it again (as `ray start` does)
    return True


# Ray's own options that make a local cluster die with its driver: GCS and
# raylet already share the driver's fate (PR_SET_PDEATHSIG); with these the
# agents notice the raylet's death at once through a pipe (instead of after
# polling for up to a minute or two), and each worker runs in its own process
# group that the raylet kills with it. Workers run at the driver's priority:
# Ray's default (nice 15) is for shared machines, where its daemons must stay
# responsive; on a cluster that exists for this run, it only lets every daemon
# wake-up preempt rendering (the Ray overhead in docs/bench_produce.md). No task events: they
# feed Ray's dashboard and state API, which a private cluster without a dashboard never serves,
# and the driver's core worker flushed them at shutdown (`ray.shutdown()` 0.40 s with them, 0.15-0.17
# without; issue 35).
_LOCAL_CLUSTER_ENV = {
    "RAY_enable_pipe_based_agent_to_parent_health_check": "true",
    "RAY_process_group_cleanup_enabled": "true",
    "RAY_worker_niceness": "0",
    "RAY_task_events_report_interval_ms": "0",
}
_RAY_INIT_COMMON = dict(log_to_driver=False, logging_level=logging.WARNING)


_ANSI = __import__("re").compile(r"\x1b\[[0-9;]*[A-Za-z]")
_RAY_LINES = logging.getLogger("ray.cluster_messages")


def _quiet_cluster_messages(ray) -> None:
    """Keep the cluster's own messages (the raylet's "A worker died ...", printed by
    Ray's driver thread with colour codes) off a stream that is not a terminal: they
    go to the ``ray.cluster_messages`` logger at debug level, without colour codes, and
    idda says in its own words what happened (a lost node, a failed episode). On a
    terminal they are left as Ray prints them. Where Ray's printer is not found (another
    Ray version), nothing changes."""
    worker = getattr(getattr(ray, "_private", None), "worker", None)
    printer = getattr(worker, "print_to_stdstream", None)
    if printer is None or getattr(printer, "idda_quiet", False):
        return

    def print_to_stdstream(data, ignore_prefix: bool):
        stream = sys.stderr if data.get("is_err") else sys.stdout
        if getattr(stream, "isatty", lambda: False)():
            return printer(data, ignore_prefix)
        for line in data.get("lines", []):
            _RAY_LINES.debug("(%s) %s", data.get("pid"), _ANSI.sub("", str(line)))

    print_to_stdstream.idda_quiet = True
    worker.print_to_stdstream = print_to_stdstream


SHUTDOWN_LOG = "driver-shutdown.err"


def shutdown(ray) -> None:
    """``ray.shutdown()``, with whatever Ray's native code writes straight to this process's
    stderr meanwhile (file descriptor 2, past Python's ``sys.stderr``) put in SHUTDOWN_LOG in
    the session's logs dir instead: after a stop, the driver's core worker logs one ERROR line
    per task it can no longer report to its raylet ("Failed to push error to driver ..."),
    which the user can do nothing with, between idda's own last lines. Where the logs dir is
    unknown (another Ray version), those lines are dropped."""
    try:
        target = os.path.join(ray._private.worker._global_node.get_logs_dir_path(), SHUTDOWN_LOG)
    except AttributeError:  # not connected, or another Ray version
        target = os.devnull
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        try:
            fd = os.open(target, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
        except OSError:
            fd = os.open(os.devnull, os.O_WRONLY)
        os.dup2(fd, 2)
        os.close(fd)
        ray.shutdown()
    finally:
        sys.stderr.flush()
        os.dup2(saved, 2)
        os.close(saved)


def attach(ray, address: str | None, workers: int | None = None, runtime_envs: bool = True) -> None:
    """Attach to the cluster at ``address`` (one line if nothing answers there), or start a
    local one of ``workers`` CPUs (default all cores), unless this process already has Ray
    (``runtime_envs``: as :func:`start_local_cluster` takes it)."""
    if ray.is_initialized():
        return
    _quiet_cluster_messages(ray)
    if address:
        check_cluster(address)
        import warnings

        try:
            with warnings.catch_warnings():  # Ray Client's own warnings: the error below says it in one line
                warnings.simplefilter("ignore")
                ray.init(address=address, **_RAY_INIT_COMMON)
        except ConnectionError as exc:
            raise ConnectionError(f"could not attach to the Ray cluster at {address} ({exc})") from exc
    else:
        start_local_cluster(ray, workers, runtime_envs)


# What Ray 2.x says when a new node's raylet does not register with its GCS within a fixed 30 s (seen on a
# 2-core machine under load): a bare Exception, and a traceback at the CLI, without this.
_LOCAL_START_TIMEOUT = "timed out during startup"


def start_local_cluster(ray, cpus: int | None = None, runtime_envs: bool = True) -> None:
    """Start the private one-machine Ray cluster ``produce`` runs on when given no address
    (``cpus``: its CPU count, default all cores). Public so benchmarks start the same one.
    ``runtime_envs=False``: no task on it will carry a ``runtime_env`` (``produce``'s own
    cluster: its tasks inherit its environment), so its raylet gets a stand-in for its
    runtime-env agent too (see :func:`_agent_stand_in`); a task that did carry one would make
    that raylet exit."""
    # Ray's notice that it turned token authentication on is not something the user has to act on.
    logging.getLogger(_RAY_TOKEN_LOGGER).setLevel(logging.ERROR)
    for name, value in _LOCAL_CLUSTER_ENV.items():  # read by the raylet and agents it starts
        os.environ.setdefault(name, value)
    # address="local": a new instance even where `ray start` left a cluster
    # on this machine (ray.init() with no address would attach to it).
    try:
        with _lean_head(ray, runtime_envs):
            ray.init(address="local", num_cpus=cpus or os.cpu_count(), include_dashboard=False, **_RAY_INIT_COMMON)
    except Exception as exc:  # Ray raises a bare Exception when its raylet does not register in time
        if _LOCAL_START_TIMEOUT not in str(exc):
            raise
        raise ConnectionError("could not start the local Ray cluster: its raylet did not register within Ray's "
                              "30 s (a machine this busy starts it slowly); run the same command again") from None
    _stop_idle_daemons(ray)



@contextmanager
def _lean_head(ray, runtime_envs: bool = True) -> Iterator[None]:
    """While the private local cluster starts: a head of GCS and raylet, without the API server,
    the autoscaler monitor and the log monitor, with a stand-in for the dashboard agent (and for
    the runtime-env agent unless ``runtime_envs``), and ``ray.init`` back as soon as its raylet
    has registered.

    ``include_dashboard=False`` still starts the API server, a Python process that loads Ray's
    usage-stats module, and ``ray.init`` polls for its address before it returns; the monitors
    do nothing on a private one-node run whose driver does not print worker logs (see
    :func:`_stop_idle_daemons`). On 2 cores the three cost ~1.4 CPU-s of the start-up, and
    ``ray.init`` took ~0.7-1.5 s longer with them (docs/bench_render.md, fourth round). The
    agents (see :func:`_agent_stand_in`) and the node wait (see :func:`_registered_node`):
    its eleventh round. Reaches into Ray's node, parameter and
    services modules; where those are missing (another Ray version), the head starts as Ray
    starts it. Only a cluster this process starts for itself: attaching to a cluster leaves its
    head as its owner made it.
    """
    try:
        node_class, params_class = ray._private.node.Node, ray._private.parameter.RayParams
        services, utils = ray._private.services, ray._private.utils
        patches = [(node_class, "start_api_server", lambda self, **_: None)]
        params_init = params_class.__init__

        def lean_params(self, *args, **kwargs) -> None:
            params_init(self, *args, **kwargs)
            self.no_monitor, self.include_log_monitor = True, False

        patches.append((params_class, "__init__", lean_params))
        node_wait = _registered_node(ray._private.state.GlobalState, services._get_gcs_client_options,
                                     services.get_node)
        patches.append((services, "get_node", node_wait))
        if _pipe_health_check():
            agents = {flag: [getattr(ray._raylet, name) for name in names] for flag, names in _AGENTS.items()
                      if not runtime_envs or flag != _RUNTIME_ENV_AGENT}
            stand_in = _agent_stand_in(services.start_ray_process, ray._private.ray_constants.PROCESS_TYPE_RAYLET,
                                       ray._raylet.persist_port, agents)
            patches.append((services, "start_ray_process", stand_in))
            # what it answers only chose the real agent's mode (and imports aiohttp, ~0.3 CPU-s)
            patches.append((utils, "get_dashboard_dependency_error", lambda: None))
        saved = [(owner, name, getattr(owner, name)) for owner, name, _ in patches]
    except AttributeError:
        yield
        return
    for owner, name, value in patches:
        setattr(owner, name, value)
    try:
        yield
    finally:
        for owner, name, value in saved:
            setattr(owner, name, value)


_NODE_POLL_S = 0.02
_NODE_WAIT_S = 30.0  # Ray's own wait for a new raylet (raylet_start_wait_time_s)


def _registered_node(global_state, gcs_options, get_node):
    """Ray's ``services.get_node``, called once this node's raylet has registered with the GCS.

    ``ray.init`` asks for the new node's record 0.1 s after starting its raylet, and the GCS's
    accessor, finding none yet, sleeps a whole second before asking again: ~0.4-0.6 s of every
    start on 2 cores went by with the raylet up and nothing waiting on it but that sleep. The
    node table is read here every 20 ms instead (one GCS call each), up to Ray's own 30 s; then
    Ray's call, which finds the node at once.
    """

    def get_registered_node(gcs_address, node_id):
        state = global_state()
        state._initialize_global_state(gcs_options(gcs_address))
        try:
            deadline = time.monotonic() + _NODE_WAIT_S
            while time.monotonic() < deadline:
                try:
                    table = state.node_table()
                except Exception as exc:  # a GCS still starting: asked again, then Ray's call says what is wrong
                    log.debug("node table not read yet (%s)", exc)
                    table = []
                if any(node.get("NodeID") == node_id and node.get("Alive") for node in table):
                    break
                time.sleep(_NODE_POLL_S)
        finally:
            state.disconnect()
        return get_node(gcs_address, node_id)

    return get_registered_node


_RUNTIME_ENV_AGENT = "--runtime_env_agent_command="
# The raylet's argument for each agent a stand-in can take the place of -> the ports (the names of
# Ray's constants) that agent writes, which the raylet waits for before it registers.
_AGENTS = {
    "--dashboard_agent_command=": ("METRICS_AGENT_PORT_NAME", "METRICS_EXPORT_PORT_NAME",
                                   "DASHBOARD_AGENT_LISTEN_PORT_NAME"),
    _RUNTIME_ENV_AGENT: ("RUNTIME_ENV_AGENT_PORT_NAME",),
}
# The stand-in: blocks on the pipe its raylet holds as its stdin, and ends when the raylet does.
AGENT_STAND_IN = "import sys; sys.stdin.buffer.read()"


def _pipe_health_check() -> bool:
    return os.environ.get("RAY_enable_pipe_based_agent_to_parent_health_check", "").lower() in ("1", "true")


def _agent_stand_in(start_ray_process, raylet_type: str, persist_port, agents: dict):
    """Ray's ``services.start_ray_process``, starting the raylet with a stand-in for each of the
    ``agents`` (its argument's flag -> the ports that agent writes): a bare Python that reads the
    pipe the raylet holds as its stdin and ends when the raylet does (Ray's pipe-based health
    check, which the private cluster turns on), after the agent's ports are written as a minimal
    agent writes those it does not serve (-1).

    The dashboard agent serves metrics, logs, job submission and node reports to a dashboard; the
    private cluster ``produce`` starts for itself has no dashboard and scrapes no metrics. It
    imported for ~1 CPU-s (aiohttp, gRPC, OpenTelemetry, its seven modules) while the raylet waited
    ~0.5-0.8 s for its ports before registering, and both workers' imports of Ray competed with
    it. The runtime-env agent (~0.5 CPU-s of imports, and the raylet waited ~0.45 s for its port)
    serves only tasks that carry a ``runtime_env``, which ``produce``'s tasks on its own cluster
    never do; the raylet would exit at such a task's first worker.
    """

    def start(command, process_type, *args, **kwargs):
        if process_type == raylet_type:
            command = [_stand_in_argument(argument, persist_port, agents) for argument in command]
        return start_ray_process(command, process_type, *args, **kwargs)

    return start


def _stand_in_argument(argument: str, persist_port, agents: dict) -> str:
    """One argument of the raylet's command: the stand-in's command in place of one of the
    ``agents``' (whose ports are written first), any other as it is."""
    for flag, ports in agents.items():
        if argument.startswith(flag):
            break
    else:
        return argument
    options = dict(word[2:].split("=", 1) for word in shlex.split(argument[len(flag):])
                   if word.startswith("--") and "=" in word)
    if "session-dir" not in options or "node-id" not in options:
        return argument  # another Ray's agent: left as it is
    for port in ports:
        persist_port(options["session-dir"], options["node-id"], port, -1)
    return flag + subprocess.list2cmdline([sys.executable, "-I", "-S", "-c", AGENT_STAND_IN])


def _stop_idle_daemons(ray) -> None:
    """Kill the autoscaler and log monitors of the local cluster this process started, where
    :func:`_lean_head` could not keep them from starting (another Ray version).

    Neither does anything for a private one-node run with log_to_driver=False:
    one node has nothing to scale, and the log monitor publishes worker logs
    for drivers that print them.

    Both poll for as long as the cluster lives (about 0.01 CPU-s per second
    together, taken from render workers that fill the machine), and
    ``ray.shutdown`` stops the GCS first and then sends the monitor SIGTERM,
    which it answers by trying to report to that GCS, so shutdown waited its
    full second for it (1.0 of ~1.4 s). Reaches into Ray's node record; where that is missing (another
    Ray version), the daemons are left as they are.
    """
    try:
        constants, node = ray._private.ray_constants, ray._private.worker._global_node
        kinds = (constants.PROCESS_TYPE_MONITOR, constants.PROCESS_TYPE_LOG_MONITOR)
        processes = [info for kind in kinds for info in node.all_processes.get(kind, ())]
    except AttributeError:
        return
    for info in processes:
        info.process.kill()
    for info in processes:
        try:
            info.process.wait(timeout=1.0)
        except subprocess.TimeoutExpired:  # Ray's shutdown deals with it as before
            pass


# The progress actor: no CPU (it only counts), restarted empty wherever Ray
# can after its node dies (it holds nothing the run needs), and no retries of
# its calls (the next report carries the latest count anyway).
