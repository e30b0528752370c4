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
from .system import derivative_inline

EULER, SEMI_IMPLICIT_EULER, RK4 = IDS["euler"], IDS["semi_implicit_euler"], IDS["rk4"]


@jit_inline
def step(method, system, s, h, out, stages, k1_ready=False):
    """One step of length h from s into out; ``stages`` is (4, len(s)) scratch. With
    ``k1_ready`` stages[0] already holds f(s) (computed by the caller at this very state).
    A call (`called_step`): this step serves the events' trial steps, many call sites, which
    would each hold copies of the right-hand side inlined; the steps on the grid inline it
    (`inlined_step`)."""
    # int(): one compiled `called_step` for every caller (a literal False would be another)
    called_step(method, system, s, h, out, stages, int(k1_ready))


@jit
def called_step(method, system, s, h, out, stages, first_stage):
    """`inlined_step` in a call of its own (`step`)."""
    inlined_step(method, system, s, h, out, stages, first_stage)


@jit_inline
def inlined_step(method, system, s, h, out, stages, k1_ready):
    """`step` with the right-hand side inlined, for the steps on the grid (nearly all of a run:
    `stepping.grid_step`). A call hands the system record over word by word, some 330 words for
    the paper robot, every step: a 1 kHz rk4 run of the paper scene spent some 15 % of its time
    on it; rk4 evaluates its four stages through one copy (`rk4_stages`).

    It holds two copies of the right-hand side (rk4's stages, the one-stage methods'). An
    `overload` inlined into both keeps one set of variable names for both copies (numba caches
    its IR by signature), which numba's SSA pass can mix up: the right-hand side inlines none that
    defines a variable (the arm controller's stage is a call, `system.arm_stage`). The batch's
    groups call this step rather than inline it (`stepping.grid_step_calling`)."""
    if method == RK4:
        rk4_stages(system, s, h, out, stages, int(k1_ready))
        return
    if not k1_ready:
        derivative_inline(system, s, stages[0])
    one_stage(method, system, s, h, out, stages)


@jit_inline
def one_stage(method, system, s, h, out, stages):
    """Euler's or semi-implicit Euler's step from s into out, f(s) in stages[0]."""
    k1, k2 = stages[0], stages[1]
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


@jit_inline
def rk4_stages(system, s, h, out, stages, first_stage):
    """rk4's step, its stages from ``first_stage`` (1: stages[0] holds f(s) already), the
    right-hand side inlined once in the loop over the stages."""
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
