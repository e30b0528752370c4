"""3-vectors as tuples, so the compiled kernels allocate nothing in their inner loops.

Every function is compiled by numba when it is available (see `jit.py`) and is plain Python
otherwise; the arithmetic is the same either way.
"""
from .jit import jit


@jit
def add(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


@jit
def sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


@jit
def scale(s, a):
    return (s * a[0], s * a[1], s * a[2])


@jit
def axpy(s, a, b):
    """s·a + b."""
    return (s * a[0] + b[0], s * a[1] + b[1], s * a[2] + b[2])


@jit
def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@jit
def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@jit
def row(array, i):
    """Row i of an (n, 3) array as a tuple."""
    return (array[i, 0], array[i, 1], array[i, 2])


@jit
def put(array, i, a):
    """Store tuple a as row i of an (n, 3) array."""
    array[i, 0] = a[0]
    array[i, 1] = a[1]
    array[i, 2] = a[2]


@jit
def matvec(R, a):
    """R · a for a 3×3 array R."""
    return (R[0, 0] * a[0] + R[0, 1] * a[1] + R[0, 2] * a[2],
            R[1, 0] * a[0] + R[1, 1] * a[1] + R[1, 2] * a[2],
            R[2, 0] * a[0] + R[2, 1] * a[1] + R[2, 2] * a[2])


@jit
def tmatvec(R, a):
    """Rᵀ · a for a 3×3 array R."""
    return (R[0, 0] * a[0] + R[1, 0] * a[1] + R[2, 0] * a[2],
            R[0, 1] * a[0] + R[1, 1] * a[1] + R[2, 1] * a[2],
            R[0, 2] * a[0] + R[1, 2] * a[1] + R[2, 2] * a[2])
