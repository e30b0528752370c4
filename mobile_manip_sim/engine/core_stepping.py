"""The fixed-step engine compiled ahead of time: the C++ core's `Stepper` (core/include/mms/
stepping.hpp) on a simulation's own arrays — its system record (`system.SystemData`), its stops
and their impact log (`stops.StopsData`) and its step scratch (`stepping.StepScratch`) — so that
everything a run is stays where Python reads it between calls.

It runs the fixed-step methods in effort mode and under wheel-speed commands, events, impacts,
rests, releases and the Zeno guard included, and equals the numba kernels of `stepping.py` bit
for bit (test/core/test_core_stepping.py). A run whose arm is driven by a controller still takes
the numba kernels. ``MOBILE_MANIP_SIM_CORE=numba`` takes them for every run (the reference while
both exist).
"""
from __future__ import annotations

import os

from ..core import Stepper

CORE = os.environ.get("MOBILE_MANIP_SIM_CORE", "cpp")


def fixed_stepper(dynamics, method: str, system, stops, scratch) -> Stepper:
    """The compiled stepper of a simulation's records (`Dynamics.core` its robot)."""
    data = system.data
    law = stops.law
    return Stepper(dynamics.core, method, float(data.gravity), data.damping, data.free,
                   data.Q_cmd, data.control, data.counters, data.holding, stops.watched,
                   stops.resting, stops.stroke, stops.permanent, int(law.kind),
                   float(law.restitution), float(law.rest_speed), stops.log, stops.log_q,
                   stops.log_u, stops.log_free, stops.count, stops.run, stops.failed,
                   scratch.out, scratch.trial, scratch.stages, scratch.forces, scratch.samples,
                   scratch.crossed)
