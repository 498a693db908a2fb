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
    """Make this process's malloc keep freed blocks for reuse (once per process); whether it took the settings."""
    try:
        mallopt = ctypes.CDLL(None).mallopt  # the C library the process runs on
    except (OSError, AttributeError):  # no C library by that name, or one without mallopt
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return all([mallopt(param, value) == 1 for param, value in KEEP])  # a list: every setting is tried


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
