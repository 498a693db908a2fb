"""Many local footers read at once: in worker processes, not threads.

Parsing a part's footer (89 columns' metadata) costs ~0.5 ms of CPU under
pyarrow's hold of the GIL, so threads add nothing on local disk (32 threads
were 2x slower than one, measured on 2,000 parts) while S3's latency is what
its threads hide. A scan of a whole root without indexes (14,355 parts at
full scale: an old root, or one whose ``_index/`` was deleted) reads them in
a few spawned processes instead: 9.7 s on one core, 5.8 s in two processes
on a 2-core machine (``benchmarks/bench_control_root.py``).

Each is a fresh interpreter (``python -c``) given its share in a file, not a
multiprocessing child: a fork would copy the driver's threads (the lease
refresher, pyarrow's pools) mid-state, and multiprocessing's spawn imports
the caller's main module again, which would run a user's script without a
``__main__`` guard a second time. A child that cannot start or fails leaves
the caller to read in this process.
"""

from __future__ import annotations

import logging
import os
import pickle
import subprocess
import sys
import tempfile
from typing import Callable

log = logging.getLogger(__name__)

MIN_PARTS_PER_PROCESS = 1500  # below this a process's start (~0.5 s: python and pyarrow) is not worth it
MAX_PROCESSES = 8
_CHILD = (
    "import pickle, sys\n"
    "with open(sys.argv[1], 'rb') as f:\n"
    "    path, uri, module, name, items = pickle.load(f)\n"
    "sys.path[:] = path\n"
    "from importlib import import_module\n"
    "from storage import Storage\n"
    "read, storage = getattr(import_module(module), name), Storage.from_uri(uri)\n"
    "pickle.dump([read(storage, rel, size) for rel, size in items], sys.stdout.buffer)\n"
)


def processes_for(storage, items: int) -> int:
    """How many processes should read ``items`` footers of ``storage``: 0 (read here) for
    remote storage, a single CPU or too few parts."""
    if not storage.is_local:
        return 0
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    n = min(cpus, MAX_PROCESSES, items // MIN_PARTS_PER_PROCESS)
    return n if n >= 2 else 0


def read_in_processes(storage, read: Callable, items: list[tuple[str, int]], processes: int) -> list | None:
    """``[read(storage, rel, size) for rel, size in items]`` in ``processes`` child processes,
    in order; ``read`` must be a module-level function. None if a child failed."""
    bounds = [len(items) * i // processes for i in range(processes + 1)]
    children = []
    try:
        with tempfile.TemporaryDirectory(prefix="idda-footers-") as tmp:
            for i, (a, b) in enumerate(zip(bounds, bounds[1:])):
                share = os.path.join(tmp, f"{i}.pickle")
                with open(share, "wb") as f:
                    pickle.dump((list(sys.path), storage.uri, read.__module__, read.__qualname__, items[a:b]), f)
                children.append(subprocess.Popen([sys.executable, "-c", _CHILD, share], stdin=subprocess.DEVNULL,
                                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE))
            done = []
            for child in children:
                out, err = child.communicate()
                if child.returncode != 0:
                    raise OSError(f"exit {child.returncode}: {err.decode(errors='replace').strip()[-300:]}")
                done.extend(pickle.loads(out))
        return done
    except (OSError, pickle.UnpicklingError, EOFError) as exc:
        log.info("footers read in this process: a reading process failed (%s)", exc)
        return None
    finally:
        for child in children:
            if child.poll() is None:
                child.kill()
                child.wait()
