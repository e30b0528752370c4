"""Timing loops: the compiled core's own (`core.Dynamics.time_*`, the loop in C++, without the
Python-to-compiled call in the measurement) and calls from Python. Both give CPU seconds of this
thread per call, best of several batches, each batch sized to take about `target` s.
"""
from __future__ import annotations

import time

import numpy as np


def per_call(timer, target: float = 0.05, repeats: int = 7) -> float:
    """CPU seconds per call of a compiled loop: ``timer(calls)`` runs the body `calls` times
    in C++ and answers the CPU seconds per call (as `core.Dynamics.time_forward_dynamics`)."""
    calls = 16
    while True:
        seconds = timer(calls)
        if seconds * calls > target / 4 or calls > 1 << 24:
            break
        calls *= 4
    calls = max(1, int(target / max(seconds, 1e-12)))
    return float(min(timer(calls) for _ in range(repeats)))


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
