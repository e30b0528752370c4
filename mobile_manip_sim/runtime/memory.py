"""Give back memory a long-running process no longer uses: the compiler's pages once the
compiled kernels are loaded, and large buffers once they are freed.

numba brings LLVM (llvmlite's ``libllvmlite.so``, some 150 MB of machine code) into every
process that runs a kernel, and touches a large part of it twice: its static initialisers run
at ``import numba`` (LLVM registers every pass and option), and reading the cached kernels goes
through LLVM's object loader. After that a run that compiles nothing never executes LLVM again,
yet the pages stay mapped: 35-110 MB of the node's resident memory, depending on how the kernel
maps file pages (measured 69 MB of the node's 200 MB on Linux 6.18, bench/NODE.md).

`release_compiler_pages` unmaps them (``madvise(MADV_DONTNEED)``); `CompilerPages` does it
again whenever numba has loaded or compiled something since (a kernel first called on the
first impact reads some 12 MB of LLVM back). Only mappings that hold no
private (copy-on-write) page are touched: text and read-only data that are byte for byte the
file's, so an unmapped page that is needed again — a kernel compiled or loaded later — is read
back from the page cache (a minor fault), never lost. Elsewhere (no ``/proc/self/smaps``, no
libc ``madvise``, numba off) it does nothing.

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
import sys
from contextlib import contextmanager

COMPILER_LIBRARY = "libllvmlite"
MADV_DONTNEED = 4
M_MMAP_THRESHOLD = -3          # mallopt's parameter (glibc malloc.h)
MMAP_THRESHOLD = 128 * 1024    # bytes: glibc's own default, kept fixed from now on


def _clean_mappings(library: str):
    """(start, end, resident bytes) of each mapping of `library` that is private, not writable
    and holds no copy-on-write page, read from /proc/self/smaps."""
    found = []
    mapping = None
    with open("/proc/self/smaps") as smaps:   # streamed: a few hundred mappings
        for line in smaps:
            head, _, rest = line.partition(" ")
            if "-" in head and not head.endswith(":"):   # "start-end perms offset dev inode path"
                mapping = None
                fields = rest.split()
                perms, path = fields[0], fields[4] if len(fields) > 4 else ""
                if library in path and "w" not in perms and perms.endswith("p"):
                    start, end = (int(address, 16) for address in head.split("-"))
                    mapping = {"start": start, "end": end, "rss": 0}
                    found.append(mapping)
            elif mapping is not None and head == "Rss:":
                mapping["rss"] = int(rest.split()[0]) * 1024
            elif mapping is not None and head == "Anonymous:" and int(rest.split()[0]):
                found.remove(mapping)   # a relocated page: dropping it would lose the relocation
                mapping = None
    return [(m["start"], m["end"], m["rss"]) for m in found]


def release_compiler_pages(library: str = COMPILER_LIBRARY) -> int:
    """Unmap the resident clean pages of `library` (LLVM's); the bytes released (0 where
    nothing can be)."""
    try:
        mappings = _clean_mappings(library)
        libc = ctypes.CDLL(ctypes.util.find_library("c"), use_errno=True)
        madvise = libc.madvise
    except (OSError, AttributeError):
        return 0
    madvise.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int]
    released = 0
    for start, end, resident in mappings:
        if resident and madvise(start, end - start, MADV_DONTNEED) == 0:
            released += resident
    return released


class CompilerPages:
    """`release_if_used` after a stretch of work (the node: after each segment) releases LLVM's
    pages if numba has held its compiler lock — which it takes to load a cached kernel as to
    compile one — since the last release; the first call always releases. Costs a flag test
    when nothing was loaded. Without numba in the process it never releases anything."""

    def __init__(self):
        self.used = False
        event = sys.modules.get("numba.core.event")   # never imports numba (150 MB)
        if event is None:
            return
        self.used = True
        pages = self

        class Loaded(event.Listener):
            def on_start(self, _event):
                pass

            def on_end(self, _event):
                pages.used = True

        event.register("numba:compiler_lock", Loaded())

    def release_if_used(self) -> None:
        if self.used:
            self.used = False
            release_compiler_pages()


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
