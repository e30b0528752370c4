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
from ..dynamics.jit import jit_inline
from ..scene.methods import IDS
from . import layout
from .system import derivative

EULER, SEMI_IMPLICIT_EULER, RK4 = IDS["euler"], IDS["semi_implicit_euler"], IDS["rk4"]


@jit_inline
def step(method, system, s, h, out, stages, k1_ready=False):
    """One step of length h from s into out; ``stages`` is (4, len(s)) scratch. With
    ``k1_ready`` stages[0] already holds f(s) (computed by the caller at this very state)."""
    k1, k2, k3, k4 = stages[0], stages[1], stages[2], stages[3]
    if not k1_ready:
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
