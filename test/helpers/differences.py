"""Central differences for the Jacobian tests: Richardson-extrapolated (error O(h⁴)), and the best
agreement over a sweep of steps (truncation shrinks with the step, round-off grows)."""
import numpy as np

STEPS = (1e-2, 3e-3, 1e-3, 3e-4)


def central_differences(function, x, h):
    """∂function/∂x at x by Richardson-extrapolated central differences of step h."""
    def plain(step):
        columns = []
        for j in range(x.size):
            e = np.zeros(x.size)
            e[j] = step
            columns.append((function(x + e) - function(x - e)) / (2.0 * step))
        return np.array(columns).T
    return (4.0 * plain(h / 2.0) - plain(h)) / 3.0


def best_agreement(function, x, exact, steps=STEPS) -> float:
    """The smallest difference from `exact` over the sweep of steps, relative to its size."""
    error = min(np.abs(central_differences(function, x, h) - exact).max() for h in steps)
    return error / max(1.0, np.abs(exact).max())
