"""The one registry of integration methods: name → kind, order, who steps it, bench sweep.

Scene validation, the engine, the node's parameter description, the bench and the
tests all read this table; nothing else lists the methods. (It sits below the engine so that
the scene layer may use it: it imports nothing of the package.)
"""
from __future__ import annotations

from dataclasses import dataclass

FIXED, ADAPTIVE = "fixed step", "adaptive"
COMPILED_STEPPERS = ("stepping", "runge_kutta")   # compiled cores; "scipy:<class>" is SciPy's


@dataclass(frozen=True)
class Method:
    name: str
    kind: str                 # FIXED (takes dt) or ADAPTIVE (takes rtol, atol)
    order: int                # of the propagated solution (bdf: the highest it reaches)
    stepper: str              # who steps it (STEPPERS): "stepping" (compiled fixed-step core),
                              # "runge_kutta" (compiled Dormand–Prince), "scipy:<class>" (SciPy)
    sweep: tuple              # the bench's work–precision sweep of dt (s) or rtol
    summary: str

    @property
    def fixed_step(self) -> bool:
        return self.kind == FIXED

    @property
    def compiled(self) -> bool:
        """Stepped by one of our compiled cores (not by a SciPy solver from Python)."""
        return self.stepper in COMPILED_STEPPERS


METHODS = {m.name: m for m in (
    Method("euler", FIXED, 1, "stepping", (1e-3, 3e-4, 1e-4, 3e-5, 1e-5), "explicit Euler"),
    Method("semi_implicit_euler", FIXED, 1, "stepping", (1e-3, 3e-4, 1e-4, 3e-5, 1e-5),
           "symplectic Euler: u first, then q with the new u"),
    Method("rk4", FIXED, 4, "stepping", (1e-2, 3e-3, 1e-3, 3e-4, 1e-4), "classic Runge–Kutta"),
    Method("rk45", ADAPTIVE, 5, "runge_kutta", (1e-3, 1e-5, 1e-7, 1e-9, 1e-11),
           "Dormand–Prince 5(4), dense output of order 4"),
    Method("dop853", ADAPTIVE, 8, "runge_kutta", (1e-3, 1e-5, 1e-7, 1e-9, 1e-11),
           "Dormand–Prince 8(5,3), dense output of order 7"),
    Method("radau", ADAPTIVE, 5, "scipy:Radau", (1e-3, 1e-5, 1e-7, 1e-9), "implicit Radau IIA"),
    Method("bdf", ADAPTIVE, 5, "scipy:BDF", (1e-3, 1e-5, 1e-7, 1e-9), "implicit BDF, orders 1–5"),
)}
NAMES = tuple(METHODS)
FIXED_STEP_NAMES = tuple(name for name, m in METHODS.items() if m.fixed_step)
ADAPTIVE_NAMES = tuple(name for name, m in METHODS.items() if not m.fixed_step)
# One id space for the compiled cores, which take a method as a compile-time integer: a method's
# id is its place in this registry (euler 0 … dop853 4).
IDS = {name: i for i, name in enumerate(NAMES)}
