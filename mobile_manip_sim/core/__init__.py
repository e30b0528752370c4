"""The compiled core: the Gibbs–Appell dynamics as C++ templates generic in their scalar type
(``double`` for a run, vector lanes for many runs, dual numbers for exact derivatives), built
ahead of time with the package (`CMakeLists.txt`, driven by setup.py) and bound with nanobind.

    from mobile_manip_sim.core import compiled_dynamics
    core = compiled_dynamics(model)                 # a scene's RobotModel
    ud = core.forward_dynamics(q, u, Q, g, moving)  # moving: 1.0 free, 0.0 locked, per u
    s_next = core.step("rk4", s, h, Q_cmd, damping, moving, g)   # s = (q, u, e, W)
    value, d_dx, d_dtau = core.jacobians("rk4", s, h, Q_cmd, B, damping, moving, g)

`Stepper` is the engine of one simulation, events and impacts included, on the
simulation's own arrays (`engine/core_stepping.py` builds it); `LaneSet` advances the steppers
of a batch's fixed-step lanes together, over threads, their plain steps in vector blocks
(`batch/runs.py`). The sources are in
``include/mms/`` (the kernels) and ``src/bindings.cpp``; `build_info` says how
this copy was compiled (flags, vector width); `vocabulary` names the indices, sizes and
constants of the arrays the engine hands the core (their one owner is the C++ source).
"""
from __future__ import annotations

import numpy as np

try:
    from ._core import (
        BaseParameters,
        Dynamics,
        LaneSet,
        Stepper,
        WheelLoop,
        arm_reference,
        build_info,
        multiply_add,
        solve_contacts,
        time_multiply_add,
        vocabulary,
        zeno_guard,
    )
except ImportError as error:  # the extension was never built (or built for another Python)
    raise ImportError(
        "mobile_manip_sim's compiled core is not built: run `pip install -e .` (or "
        "`colcon build`), which needs a C++20 compiler (g++ ≥ 10), CMake ≥ 3.18 and nanobind "
        f"({error})") from error

__all__ = ["BaseParameters", "Dynamics", "LaneSet", "Stepper", "WheelLoop", "arm_reference",
           "build_info",
           "compiled_dynamics", "multiply_add", "solve_contacts", "time_multiply_add", "vocabulary",
           "zeno_guard"]


def compiled_dynamics(robot, tip_mass: float = 0.0, wheel_inertia: bool = True) -> Dynamics:
    """The compiled dynamics of a `scene.model.RobotModel`; ``wheel_inertia=False`` zeroes I_w,
    ``tip_mass`` (kg) is a point payload at the distal end of the last rod."""
    b = robot.base
    base = BaseParameters()
    base.mass, base.yaw_inertia, base.com_offset = b.mass, b.yaw_inertia, b.com_offset
    base.wheel_radius, base.half_track = b.wheel_radius, b.half_track
    base.wheel_inertia = b.wheel_inertia if wheel_inertia else 0.0
    n = robot.n_links

    def array(values, shape):
        return np.ascontiguousarray(np.asarray(values, dtype=float).reshape(shape))

    return Dynamics(base, array(robot.mount, (3,)), array(robot.joint_rotation, (n, 3, 3)),
                    array(robot.length, (n,)), array(robot.mass_per_length, (n,)),
                    array(robot.inertia_per_length, (n, 3, 3)), float(tip_mass))
