"""Compile the kernels with numba when it is installed and not disabled.

``MOBILE_MANIP_SIM_NO_JIT=1`` (or numba's own ``NUMBA_DISABLE_JIT=1``) runs the very same source
as plain Python: the tests compare both paths. Compiled code is cached on disk, so only the first
run of a new install pays the compile time.

`jit_inline` is for small helpers that numba should inline into their callers at the IR level.
All use ``error_model="numpy"``: a float division by zero gives inf/NaN (which the engine
reports) instead of raising, which leaves no exception paths in the hot loops.

`jit` and `jit_inline` compile without numba's reference counting (NRT): the kernels take
preallocated arrays and records of arrays and allocate nothing, and with NRT on every use of a
record (the system record holds some forty arrays) across a branch or a call increfs and decrefs
each of its arrays — atomic operations that cost more than the dynamics itself (1 µs of a 2.4 µs
right-hand side on the paper robot).
Scratch arrays come preallocated (workspaces, `stops.ImpactScratch`); numpy functions that
return a new array cannot be used in a kernel.

numba keys a cached function on its own source file only, yet a kernel called from another
module is compiled *into* its caller: after an edit of `kernels.py`, the cached
`engine.system.derivative` would keep running the old kernel. So the caches of the whole
package are dropped whenever a source that compiled code may depend on changes
(`_drop_stale_caches`).
"""
import hashlib
import os
import sys
from pathlib import Path

ENABLED = os.environ.get("MOBILE_MANIP_SIM_NO_JIT", "") in ("", "0")

try:
    if not ENABLED:
        raise ImportError
    import numba
except ImportError:  # pure-Python path
    ENABLED = False

    def jit(function):
        return function

    jit_inline = jit
else:
    def _njit(function, **options):
        """njit with an on-disk cache, or without one (one warning) where none can be written:
        a read-only install with a read-only HOME."""
        options = dict(fastmath=False, nogil=True, error_model="numpy", **options)
        try:
            return numba.njit(cache=True, **options)(function)
        except RuntimeError as error:  # numba: "cannot cache function …: no locator available"
            if "cannot cache" not in str(error):
                raise
            global _warned
            if not _warned:
                _warned = True
                import warnings
                warnings.warn("numba cannot cache compiled kernels here (read-only install and "
                              "HOME; set NUMBA_CACHE_DIR): compiling at every start", stacklevel=3)
            return numba.njit(cache=False, **options)(function)

    _warned = False

    def jit(function):
        return _njit(function, _nrt=False)

    def jit_inline(function):
        return _njit(function, _nrt=False, inline="always")


class Bound:
    """A compiled kernel called from Python, again and again, with arguments of types that never
    change (one simulation's own records and arrays; scalars passed as float or int as the
    kernel takes them). The first call goes through numba's dispatcher, which resolves the type
    of every argument — some 8 µs for the ~60 arrays of the engine's records, as long as ten
    1 kHz steps of the paper robot — and finds or compiles the machine code; later calls go
    straight to that code's entry point, which only unboxes the arguments (~1 µs).

    Bind per object whose arrays are passed (their types are then fixed); without numba it is
    the plain function."""

    def __init__(self, function):
        self.function = function
        self._entry = None

    def __call__(self, *args):
        if self._entry is not None:
            return self._entry(*args)
        result = self.function(*args)
        self._entry = self.function
        if ENABLED:
            overloads = self.function.overloads
            if len(overloads) == 1:   # the one this call used: no need to type the arguments
                self._entry = next(iter(overloads.values())).entry_point
            else:   # (None where the dispatcher converted an argument: keep calling it)
                found = overloads.get(tuple(numba.typeof(arg) for arg in args))
                if found is not None:
                    self._entry = found.entry_point
        return result


# Where compiled code may come from: the dynamics and the engine (below the adapters, they
# import nothing above them), the modules below them whose functions they compile
# (`coordinates.py`), and any other module that defines a kernel (`bench/loops.py`).
KERNEL_PACKAGES = ("dynamics", "engine", "coordinates.py")
PACKAGE = Path(__file__).resolve().parents[1]


def _drop_stale_caches(package: Path = PACKAGE) -> None:
    """Delete the package's numba cache files (``__pycache__/*.nbi, *.nbc``) when a source that
    compiled code may depend on changed: any module of dynamics/ or engine/ (kernels freeze the
    module constants they read, such as the method tables of runge_kutta.py, into their code),
    coordinates.py (its index functions are compiled into them) or one that defines a kernel. An
    edit of an adapter (node, CLI, plots) keeps the caches."""
    digest = hashlib.sha1(numba.__version__.encode())
    try:
        for path in sorted(package.rglob("*.py")):
            relative = path.relative_to(package)
            source = path.read_bytes()
            if relative.parts[0] in KERNEL_PACKAGES or b"@jit" in source:
                digest.update(str(relative).encode())
                digest.update(source)
        stamp = package / "__pycache__" / "numba-sources.sha1"
        if stamp.is_file() and stamp.read_text() == digest.hexdigest():
            return
        for cache in package.rglob("__pycache__"):
            for path in list(cache.glob("*.nbi")) + list(cache.glob("*.nbc")):
                path.unlink(missing_ok=True)
        stamp.parent.mkdir(exist_ok=True)
        stamp.write_text(digest.hexdigest())
    except OSError:  # a read-only install: its caches cannot go stale either
        pass


def _load_implementations_without_blas() -> None:
    """Load numba's library of implementations now, without scipy.linalg.

    The first compiled call of a process, even one read from the cache, makes numba import its
    implementations of Python and NumPy (`refresh` of the CPU target), and among them
    `numba.np.arraymath` imports scipy.linalg only to note whether np.dot has BLAS behind it:
    some 0.25 s of CPU, more than half of what loading the implementations costs, and 15 MB
    resident, in every run. No kernel here calls BLAS or LAPACK, so `scipy.linalg.cython_blas` is
    hidden while they load. In this process a numba function compiled later that calls np.dot or
    np.linalg still imports scipy.linalg itself, when it is compiled
    (`numba.np.linalg.ensure_blas`); only np.correlate and np.convolve take numba's own loop
    instead of BLAS."""
    from numba.core.compiler_lock import global_compiler_lock
    from numba.core.registry import cpu_target
    name = "scipy.linalg.cython_blas"
    hide = name not in sys.modules
    with global_compiler_lock:
        if hide:
            sys.modules[name] = None   # `import` of it raises ImportError, parents untouched
        try:
            cpu_target.target_context.refresh()
        except ImportError:   # a numba that needs it here: leave the loading to numba
            pass
        finally:
            if hide and name in sys.modules and sys.modules[name] is None:
                del sys.modules[name]


if ENABLED:
    _drop_stale_caches()
    _load_implementations_without_blas()
    # The four-lane number types (`vector.py`, `lane_arrays.py`), registered with numba in every
    # process before any kernel is typed: a kernel's cache index that also holds lane
    # specializations imports them when it is read, and overloads of math.sin & co. registered
    # halfway through typing a kernel make numba fail on it ("Cannot unify Function(cos) and
    # Function(cos)").
    from . import lane_arrays, vector  # noqa: E402, F401
