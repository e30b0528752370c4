"""Compiled loops that call one dynamics evaluation `count` times, for timing without the
Python-to-compiled call in the measurement (the per-call cost from Python is measured apart).

Each loop evaluates at the same (q, u): the work per evaluation does not depend on the values.
"""
from __future__ import annotations

import time

import numpy as np

from ..dynamics import articulated, kernels
from ..dynamics.jit import jit
from ..engine import system


@jit
def inverse_dynamics_recursive(model, q, u, ud, g, ws, Q, count):
    """frames + one Gibbs–Appell pass: Q = M u̇ + h, O(n)."""
    for _ in range(count):
        kernels.frames(model, q, ws)
        kernels.gibbs_appell(model, q, u, ud, g, ws, Q)


@jit
def inverse_dynamics_by_columns(model, q, u, ud, g, ws, Q, M, zeros, unit, column, count):
    """The non-recursive baseline: Q = M u̇ + h with M assembled column by column (n_u passes)."""
    nu = Q.shape[0]
    for _ in range(count):
        kernels.frames(model, q, ws)
        kernels.mass_matrix_by_columns(model, q, ws, zeros, unit, column, M)
        kernels.gibbs_appell(model, q, u, zeros, g, ws, Q)
        for i in range(nu):
            s = Q[i]
            for j in range(nu):
                s += M[i, j] * ud[j]
            Q[i] = s


@jit
def forward_dynamics_articulated(model, q, u, Q, g, free, ws, ud, count):
    """frames + the articulated-body recursion, O(n)."""
    for _ in range(count):
        kernels.frames(model, q, ws)
        articulated.articulated_forward_dynamics(model, q, u, Q, g, free, ws, ud)


@jit
def forward_dynamics_cholesky(model, q, u, Q, g, free, ws, ud, h, rhs, M, L, zeros, unit,
                              column, by_columns, count):
    """frames + h by one pass + M + Cholesky (O(n³)); M by composite rigid bodies (O(n²)), or,
    with ``by_columns``, the non-recursive baseline: n_u inverse-dynamics passes."""
    nu = Q.shape[0]
    for _ in range(count):
        kernels.frames(model, q, ws)
        kernels.gibbs_appell(model, q, u, zeros, g, ws, h)
        for i in range(nu):
            rhs[i] = Q[i] - h[i]
        if by_columns:
            kernels.mass_matrix_by_columns(model, q, ws, zeros, unit, column, M)
        else:
            kernels.mass_matrix(model, q, ws, zeros, unit, column, M)
        kernels.cholesky_solve(M, rhs, free, nu, L, ud)


@jit
def engine_derivative(system_tuple, s, ds, count):
    """The engine's right-hand side (`engine.system.derivative`), as the integrators call it."""
    for _ in range(count):
        system.derivative(system_tuple, s, ds)


def per_call(function, *args, target: float = 0.05, repeats: int = 7) -> float:
    """CPU seconds per evaluation of ``function(*args, count)``: best of `repeats` batches,
    each batch sized to take about `target` s."""
    function(*args, 3)  # compile or load, and warm the caches
    count = 16
    while True:
        start = time.thread_time()
        function(*args, count)
        elapsed = time.thread_time() - start
        if elapsed > target / 4 or count > 1 << 24:
            break
        count *= 4
    count = max(1, int(count * target / max(elapsed, 1e-9)))
    best = np.inf
    for _ in range(repeats):
        start = time.thread_time()
        function(*args, count)
        best = min(best, (time.thread_time() - start) / count)
    return float(best)


def per_python_call(function, *args, target: float = 0.05, repeats: int = 7) -> float:
    """CPU seconds per call of ``function(*args)`` from Python: best of `repeats` batches."""
    function(*args)
    count = 64
    while True:
        start = time.thread_time()
        for _ in range(count):
            function(*args)
        elapsed = time.thread_time() - start
        if elapsed > target / 4:
            break
        count *= 4
    count = max(1, int(count * target / max(elapsed, 1e-9)))
    best = np.inf
    for _ in range(repeats):
        start = time.thread_time()
        for _ in range(count):
            function(*args)
        best = min(best, (time.thread_time() - start) / count)
    return float(best)
