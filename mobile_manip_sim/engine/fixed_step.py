"""Fixed-step integrators, compiled, and the loop that runs them between events.

All three advance ``s = (q, u, e, W)`` (`layout.py`) by one step of length h (s):

- ``euler``: explicit Euler, order 1: s⁺ = s + h f(s).
- ``semi_implicit_euler``: symplectic Euler, order 1: u⁺ = u + h u̇(q, u), then
  q⁺ = q + h q̇(q, u⁺) (the constraints evaluated with the new velocities), W⁺ = W + h Ẇ.
- ``rk4``: the classic Runge–Kutta method, order 4 (Butcher tableau c = 0, ½, ½, 1;
  b = 1/6, 1/3, 1/3, 1/6).

`stepping.py` runs them, with the events in between.
"""
from ..dynamics import kernels
from ..dynamics.jit import jit, jit_inline
from ..scene.methods import IDS
from . import layout
from .system import derivative, derivative_inline

EULER, SEMI_IMPLICIT_EULER, RK4 = IDS["euler"], IDS["semi_implicit_euler"], IDS["rk4"]


@jit_inline
def step(method, system, s, h, out, stages, k1_ready=False):
    """One step of length h from s into out; ``stages`` is (4, len(s)) scratch. With
    ``k1_ready`` stages[0] already holds f(s) (computed by the caller at this very state)."""
    if method == RK4:
        # int(): one compiled `rk4_step` for every caller (a literal False would be another)
        rk4_step(system, s, h, out, stages, int(k1_ready))
        return
    k1, k2 = stages[0], stages[1]
    if not k1_ready:
        derivative(system, s, k1)
    if method == EULER:
        for i in range(s.shape[0]):
            out[i] = s[i] + h * k1[i]
    else:   # SEMI_IMPLICIT_EULER
        nq, nu = layout.sizes(system)
        for i in range(nq, s.shape[0]):
            out[i] = s[i] + h * k1[i]
        kernels.configuration_rate(system.model, s[:nq], out[nq:nq + nu], k2[:nq])
        for i in range(nq):
            out[i] = s[i] + h * k2[i]


@jit
def rk4_step(system, s, h, out, stages, first_stage):
    """`step` of rk4, its stages from ``first_stage`` (1: stages[0] holds f(s) already).

    One compiled call per step, the right-hand side inlined once in the loop over the stages:
    a call to `system.derivative` is handed every array descriptor of the system's record one
    word at a time (some 330 words for the paper robot), which each stage would pay. (The
    one-stage methods call `derivative` as before: their step in one call was slower.)"""
    k1, k2, k3, k4 = stages[0], stages[1], stages[2], stages[3]
    for stage in range(first_stage, 4):
        x = s
        if stage > 0:   # s + c h k_(stage−1), c = ½, ½, 1
            c = h if stage == 3 else 0.5 * h
            previous = stages[stage - 1]
            for i in range(s.shape[0]):
                out[i] = s[i] + c * previous[i]
            x = out
        derivative_inline(system, x, stages[stage])
    for i in range(s.shape[0]):
        out[i] = s[i] + h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
