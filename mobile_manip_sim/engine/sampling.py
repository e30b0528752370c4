"""The sampled controllers: the wheel-speed loop and the arm controller updated at a control rate,
as ros2_control's controller manager runs its controllers at its ``update_rate`` and the hardware
holds each command until the next update (docs/controllers.md, "The control rate").

An update is a discrete map applied at the update instants t_m = m T (T = 1/rate, m = 0, 1, …),
outside the right-hand side, which only reads what the update left (`system.held`):

    τ_m = sat(law(s(t_m)))            the controllers' outputs at the instant, held until t_{m+1}
    z_{m+1} = z_m + T ż(s(t_m))       each integral by one forward-Euler step of its rate

where law and ż are the continuous controllers' own (`system.wheel_speed_loop`,
`arm_control.arm_efforts`): each output computed with the integral as it stands, then the
integral advanced by T times the error, or not at all while the output is saturated in the
error's direction — control_toolbox's ``Pid::compute_command`` with its conditional integration
(i_term += dt · i_gain · error after the command). Between updates the right-hand side is smooth
(the held efforts are constants), and an update is a step boundary as a command change is: the
fixed-step core ends a step there, the adaptive solves restart there (`stepping.advance`,
`adaptive_stepping.advance`).

The count of updates applied so far is the clock's (`stepping.CLOCK_UPDATES`); the next one is
due at CLOCK_UPDATES / rate, while a controller drives (`next_update`). A call that ends at an
update instant leaves that update to the next call, which applies it first: a command given
between the calls, at the instant, is taken at that update (ros2_control reads its commands in
the update), and the state a call ends with is the one the update reads. A rate of 0 keeps the
continuous controllers: no update, no hold.
"""
import math

from ..dynamics import indices, kernels
from ..dynamics.jit import jit, jit_inline
from ..scene.coordinates import OMEGA, V
from . import layout
from .arm_control import ARM_ON
from .events import holding_margin
from .stops import any_resting, release
from .system import WHEEL_VELOCITY_MODE, arm_law, wheel_speed_loop


@jit_inline
def next_update(system, updates):
    """The instant (s) of the next update after `updates` of them; +inf when continuous, or when
    no controller drives (the arm in effort mode, the wheels under torque commands): a run
    without controllers is not cut at update instants."""
    if system.rate > 0.0 and (system.arm[ARM_ON] != 0.0
                              or system.control[WHEEL_VELOCITY_MODE] != 0.0):
        # m / rate, as a user's k / rate: an instant a target names is the update's exactly
        return updates / system.rate
    return math.inf


@jit
def update_controllers(system, s, rates):
    """The update at the current instant (module doc): the outputs into system.held (and the
    arm's into arm_ref, as an evaluation leaves them), the integrals of s advanced by T times
    their rates; `rates` (the size of s) is scratch."""
    nq, nu = layout.sizes(system)
    period, held, Q = 1.0 / system.rate, system.held, system.Q
    for k in range(nu):   # the base's forces acting now: the arm's computed torque reads them
        Q[k] = system.Q_cmd[k]
    if system.control[WHEEL_VELOCITY_MODE] != 0.0:
        base = system.model.base
        r, b = base.wheel_radius, base.half_track
        i_e = layout.controller(nq, nu)
        held[0], held[1], rates[i_e], rates[i_e + 1] = wheel_speed_loop(system.control, r, b, s,
                                                                        nq, nu, False)
        s[i_e] += period * rates[i_e]
        s[i_e + 1] += period * rates[i_e + 1]
        Q[V] = (held[0] + held[1]) / r
        Q[OMEGA] = b * (held[0] - held[1]) / r
    if system.arm[ARM_ON] != 0.0:
        kernels.frames(system.model, s[:nq], system.ws)
        arm_law(system, s, rates)
        i_z = layout.arm_integrals(nq, nu)
        for j in range(indices.arm_width(nu)):
            held[indices.arm_u(j)] = Q[indices.arm_u(j)]
            s[i_z + j] += period * rates[i_z + j]


@jit
def update_at_instant(system, stops, scr, s):
    """`update_controllers`, then, as at a command change, the resting rods that the new
    efforts pull off their stops freed at this very instant (`stops.release`). True when the
    stops' contact solve failed (stops.failed says so)."""
    update_controllers(system, s, scr.trial)
    if any_resting(stops) and holding_margin(system, s, stops.resting, scr.stages[3],
                                             scr.forces) < 0.0:
        release(system, stops, s, scr.impact, scr.stages[3], scr.forces, False)
    return stops.failed[0] != 0
