"""Give back memory a long-running process no longer uses: large buffers once they are freed.

`return_large_buffers` keeps glibc's malloc from holding freed large buffers for good. By
default glibc raises its mmap threshold to the size of each large block freed, so that the next
ones of that size come from the heap of the thread that allocates them; a node that takes a
100,000-point trajectory (arrays of megabytes, read in the executor's threads) then kept 200 MB
after the first few and some 4 MB more with each later one. With the threshold fixed at its
default, every block above it is its own mapping, unmapped when freed, and the node's memory
stays bounded whatever it is sent (test_hostile_peers).

`collector_paused` holds Python's cycle collector off while a batch's lanes are made, stepped and
read: each of its passes walks every young object, and the lanes are thousands of them; none is in
a reference cycle (a lane's `Simulation` is freed by reference counting when dropped), so nothing
piles up meanwhile.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import gc
from contextlib import contextmanager

M_MMAP_THRESHOLD = -3          # mallopt's parameter (glibc malloc.h)
MMAP_THRESHOLD = 128 * 1024    # bytes: glibc's own default, kept fixed from now on


def return_large_buffers() -> bool:
    """Fix glibc's mmap threshold at MMAP_THRESHOLD (setting it turns off its growth), so every
    freed block above it goes back to the system at once. False where there is no glibc."""
    try:
        mallopt = ctypes.CDLL(ctypes.util.find_library("c")).mallopt
    except (OSError, AttributeError, TypeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    return mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD) == 1


@contextmanager
def collector_paused():
    """Python's cycle collector off for the block (on again after it, if it was on)."""
    collecting = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if collecting:
            gc.enable()
