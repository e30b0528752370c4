"""Compile the kernels with numba when it is installed and not disabled.

``MOBILE_MANIP_SIM_NO_JIT=1`` (or numba's own ``NUMBA_DISABLE_JIT=1``) runs the very same source
as plain Python: the tests compare both paths. Compiled code is cached on disk, so only the first
run of a new install pays the compile time.
"""
import os

ENABLED = os.environ.get("MOBILE_MANIP_SIM_NO_JIT", "") in ("", "0")

try:
    if not ENABLED:
        raise ImportError
    import numba
except ImportError:  # pure-Python path
    ENABLED = False

    def jit(function):
        return function
else:
    def jit(function):
        return numba.njit(cache=True, fastmath=False, nogil=True)(function)
