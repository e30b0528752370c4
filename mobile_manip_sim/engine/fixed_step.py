"""Fixed-step integrators, compiled, and the loop that runs them between events.

All three advance ``s = (q, u, W)`` by one step of length h (s):

- ``euler``: explicit Euler, order 1: s⁺ = s + h f(s).
- ``semi_implicit_euler``: symplectic Euler, order 1: u⁺ = u + h u̇(q, u), then
  q⁺ = q + h q̇(q, u⁺) (the constraints evaluated with the new velocities), W⁺ = W + h Ẇ.
- ``rk4``: the classic Runge–Kutta method, order 4 (Butcher tableau c = 0, ½, ½, 1;
  b = 1/6, 1/3, 1/3, 1/6).

`run` takes whole steps until it is told to stop, a rod crosses an end stop inside a step
(located later by `stops.py`), a resting rod is pulled off its stop, or the state stops being
finite; it returns how many steps it completed and why it stopped.
"""
import math

from ..dynamics import kernels
from ..dynamics.jit import jit
from . import layout
from .stops import crossing_in_step, release_wanted
from .system import derivative

EULER, SEMI_IMPLICIT_EULER, RK4 = 0, 1, 2
METHOD_IDS = {"euler": EULER, "semi_implicit_euler": SEMI_IMPLICIT_EULER, "rk4": RK4}
ORDER = {"euler": 1, "semi_implicit_euler": 1, "rk4": 4}

# why `run` returned
DONE, CROSSING, RELEASE, NOT_FINITE = 0, 1, 2, 3


@jit
def step(method, system, s, h, out, stages):
    """One step of length h from s into out; ``stages`` is (4, len(s)) scratch."""
    k1, k2, k3, k4 = stages[0], stages[1], stages[2], stages[3]
    derivative(system, s, k1)
    if method == EULER:
        for i in range(s.shape[0]):
            out[i] = s[i] + h * k1[i]
    elif method == SEMI_IMPLICIT_EULER:
        nq, nu = layout.sizes(system)
        for i in range(nq, s.shape[0]):
            out[i] = s[i] + h * k1[i]
        kernels.configuration_rate(system.model, s[:nq], out[nq:nq + nu], k2[:nq])
        for i in range(nq):
            out[i] = s[i] + h * k2[i]
    else:
        for i in range(s.shape[0]):
            out[i] = s[i] + 0.5 * h * k1[i]
        derivative(system, out, k2)
        for i in range(s.shape[0]):
            out[i] = s[i] + 0.5 * h * k2[i]
        derivative(system, out, k3)
        for i in range(s.shape[0]):
            out[i] = s[i] + h * k3[i]
        derivative(system, out, k4)
        for i in range(s.shape[0]):
            out[i] = s[i] + h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])


@jit
def _finite(s):
    for i in range(s.shape[0]):
        if not math.isfinite(s[i]):
            return False
    return True


@jit
def run(method, system, s, h, n_steps, stops, out, stages, forces):
    """Up to n_steps steps of h, in place on s. Returns (steps completed, reason).

    ``stops`` = (watched, resting, stroke): watched[k] is true for rods whose end stops are
    checked, resting[k] is −1/+1 for a rod held at its lower/upper stop (0 otherwise),
    stroke (n, 2). On CROSSING and RELEASE (a resting rod is pulled off its stop during the step),
    s is left at the start of the offending step, for the engine to locate the event in it.
    """
    watched, resting, stroke = stops
    any_resting = False
    for k in range(resting.shape[0]):
        if resting[k] != 0:
            any_resting = True
    for i in range(n_steps):
        step(method, system, s, h, out, stages)
        if not _finite(out):
            return i, NOT_FINITE
        if watched.shape[0] > 0 and crossing_in_step(s, out, h, system, watched, stroke, stages[0], stages[1]):
            return i, CROSSING
        if any_resting and release_wanted(system, out, resting, stages[1], forces):
            return i, RELEASE
        for j in range(s.shape[0]):
            s[j] = out[j]
    return n_steps, DONE
