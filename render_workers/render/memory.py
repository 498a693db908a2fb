"""A rendering process keeps the memory it frees: every frame allocates the same large buffers again.

A full-HD frame passes through a few dozen arrays of 8-25 MB (the GL reads, the post
effects' float images, the encoded outputs), on two threads. glibc's malloc gives such
blocks back to the kernel when they are freed (an ``mmap`` of their own, or the top of a
heap trimmed once more than twice the largest such block is free), and the next frame's
arrays of the same sizes take their pages again, zeroed by the kernel. With
:func:`keep_freed_memory` freed blocks stay in the process for the next frame. Measured with
``PF_FRAMES=24 python -m benchmarks.profile_frame`` (T01_CN_A, full HD, 3 alternating rounds):
~4,200 fewer page faults and ~0.035 s less system CPU per frame, process CPU 0.405 against
0.436 s per frame (medians); the peak resident memory did not grow (690 against 705 MB).

Only where malloc takes these settings (glibc's ``mallopt``); elsewhere nothing changes. Where
memory comes from does not change what is computed: the same frames' bytes with and without
(the small and full-HD produce digests of the issue 35 notes).

The same call turns off numpy's advice to back its large arrays with huge pages (``madvise``
``MADV_HUGEPAGE`` on every block of 4 MB or more): where the kernel defragments on such a fault
(transparent huge pages' ``defrag`` set to ``madvise``, a common default), the first touch of each
fresh 2 MB page compacts memory before it zeroes it. A rendering process touches ~700 MB for the
first time while it builds its world, loads an episode and draws the first frame: measured in
fresh processes (T03_CS_M at full HD, world built, 12 frames, 3 alternating rounds), the first
frame was stored after 2.08-2.19 CPU-s without the advice against 2.51-2.65 with it (system CPU
0.31-0.34 against 0.61-0.64), and the 12 frames took 5.02-5.07 against 5.44-5.55 CPU-s.
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import gc
from collections.abc import Iterator

# glibc's mallopt parameters (malloc.h) and the values set
M_TRIM_THRESHOLD, M_TOP_PAD, M_MMAP_THRESHOLD = -1, -2, -3
KEEP = (
    (M_MMAP_THRESHOLD, 32 << 20),  # blocks up to glibc's largest threshold (32 MB) come from the heaps ...
    (M_TRIM_THRESHOLD, (1 << 31) - 1),  # ... which are never trimmed ...
    (M_TOP_PAD, 256 << 20),  # ... and grow by 256 MB at a time
)


@functools.cache
def keep_freed_memory() -> bool:
    """Make this process's malloc keep freed blocks for reuse and numpy give no huge-page advice (once per
    process); whether malloc took the settings."""
    no_huge_page_advice()
    try:
        mallopt = ctypes.CDLL(None).mallopt  # the C library the process runs on
    except (OSError, AttributeError):  # no C library by that name, or one without mallopt
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return all([mallopt(param, value) == 1 for param, value in KEEP])  # a list: every setting is tried


def no_huge_page_advice() -> bool:
    """Stop numpy advising huge pages for the large arrays it allocates from now on (its switch, as the
    environment variable ``NUMPY_MADVISE_HUGEPAGE=0`` sets it at import); whether this numpy has the switch."""
    try:
        from numpy._core.multiarray import _set_madvise_hugepage
    except ImportError:  # numpy before 2.0 kept it in numpy.core
        try:
            from numpy.core.multiarray import _set_madvise_hugepage
        except ImportError:
            return False
    _set_madvise_hugepage(False)
    return True


@contextlib.contextmanager
def scene_frozen() -> Iterator[None]:
    """The objects alive on entry (a loaded episode: its world, traffic and pyrender scene, some
    200,000 of them) left out of Python's cyclic garbage collection until the block ends.

    A frame leaves little but arrays, yet enough allocations to start a collection of the oldest
    generation every few frames, which walked every object of the scene each time: ~100 ms per
    collection, ~6 ms per full-HD frame on average (T03_CS_M, 16 frames; none with the scene
    frozen). Freed by reference count as before; unfrozen at the end, so what the episode left in
    cycles is collected later, as it would have been. Where the process had frozen objects of its
    own already (``gc.freeze`` before forking workers, say), nothing is frozen or unfrozen here."""
    if gc.get_freeze_count():
        yield
        return
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()
