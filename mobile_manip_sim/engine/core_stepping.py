"""The engine compiled ahead of time: the C++ core's `Stepper` (core/include/mms/
stepping.hpp for the fixed-step methods, adaptive_stepping.hpp for rk45, dop853 and the steps
SciPy's radau and bdf hand in) on a simulation's own arrays — its system record
(`system.SystemData`), its stops and their impact log (`stops.StopsData`) and its step scratch
(`stepping.StepScratch`) — so that everything a run is stays where Python reads it between calls
(but for an adaptive run's step in hand).

It runs euler, semi-implicit Euler, rk4, rk45 and dop853 in effort mode, under wheel-speed
commands and with the arm driven by its controller (every mode and feed-forward, model error
included; core/include/mms/arm_control.hpp), the controllers continuous or sampled
(stepping.hpp), events, impacts, rests, releases, the Zeno guard and the crawl limits included;
for SciPy's radau and bdf it takes each step SciPy makes into its step in hand and does all the
rest (`scipy_steps.py`).
"""
from __future__ import annotations

import numpy as np

from ..core import Stepper


def compiled_stepper(dynamics, method: str, system, stops, scratch, solve=None) -> Stepper:
    """The compiled stepper of a simulation's records (`Dynamics.core` its robot); `solve` the
    adaptive methods' (`adaptive_stepping.Solve`: its tolerances and its crawl count)."""
    rtol, atol = (solve.tolerance if solve is not None else (0.0, 0.0))
    watch = solve.watch if solve is not None else np.zeros(3)
    data = system.data
    law = stops.law
    stepper = Stepper(dynamics.core, method, float(data.gravity), data.damping, data.free,
                      data.Q_cmd, data.control, data.counters, data.holding, stops.watched,
                      stops.resting, stops.stroke, stops.permanent, int(law.kind),
                      float(law.restitution), float(law.rest_speed), stops.log, stops.log_q,
                      stops.log_u, stops.log_free, stops.count, stops.run, stops.failed,
                      scratch.out, scratch.trial, scratch.stages, scratch.forces, scratch.samples,
                      scratch.crossed, float(rtol), float(atol), watch, float(data.rate), data.held)
    if system.arm_on:
        drive_arm(stepper, data)
    return stepper


def drive_arm(stepper: Stepper, data) -> None:
    """The arm controller's arrays of the system record `data` (`system.SystemData`) into the
    stepper: at its making, and again when the record's reference arrays were replaced."""
    stepper.drive_arm(data.arm, data.arm_gains, data.arm_limits, data.ref_starts, data.ref_coeffs,
                      data.arm_ref, data.ff_masses)
