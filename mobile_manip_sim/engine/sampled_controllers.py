"""The sampled controllers as `Simulation` drives them from Python (a mixin): the rate, whether
one drives now, the instant of the next update, its preview at a reset, the update between
SciPy's steps (the compiled stepper applies the others on the way, core/include/mms/
stepping.hpp), and where the updates resume when a controller starts driving.
"""
from __future__ import annotations

import math

from ..scene.errors import UserError
from ..scene.limits import CONTROL_RATE
from . import stepping


def checked_control_rate(rate) -> float:
    """The controllers' update rate (Hz), checked: a UserError naming controller.rate."""
    try:
        rate = float(rate)
    except (TypeError, ValueError):
        raise UserError("controller.rate", f"expected a number (Hz), got {rate!r}") from None
    if not CONTROL_RATE[0] <= rate <= CONTROL_RATE[1]:
        raise UserError("controller.rate", f"expected a number in [{CONTROL_RATE[0]:g}, "
                                           f"{CONTROL_RATE[1]:g}] Hz (0: continuous), got {rate}")
    return rate


class SampledControllers:
    def _preview_update(self) -> None:
        """At reset: the efforts the update at t = 0 holds, into system.held, so that what acts
        at t = 0 (the pressed rods' hold, the efforts read) is theirs; the update itself, its
        integrals' step included, is the first call's first act, after any command given at
        t = 0 (`stepping.advance`), as every update at the end of a call is."""
        self._sampled_update(self.s.copy())

    def _update_controllers(self) -> None:
        """The sampled controllers' update due now (core/include/mms/stepping.hpp
        `update_controllers`)."""
        self._clock[stepping.CLOCK_UPDATES] += 1.0
        failed = self._sampled_update(self.s)
        self._restart()
        if failed:
            self._contact_failed()

    @property
    def controllers_sampled(self) -> bool:
        """Sampled controllers drive now (the arm's, or the wheels' under cmd_vel)."""
        return self.sampled and (self.arm_controller.active or self.velocity_mode)

    @property
    def next_update(self) -> float:
        """The instant (s) of the sampled controllers' next update (stepping.hpp `next_update`);
        inf when continuous or when none drives."""
        return (self._clock[stepping.CLOCK_UPDATES] / self.system.data.rate
                if self.controllers_sampled else math.inf)

    def _resume_updates(self) -> None:
        """A sampled controller starts driving now with none driving before: its updates resume
        on the instants m T from the first at or after now (a command given at an update instant
        is taken at that update, the next call's first act, as with a controller that drives
        already: `stepping.advance`)."""
        if self.sampled and not self.controllers_sampled:
            self._clock[stepping.CLOCK_UPDATES] = math.ceil(self.t * self.control_rate - 1e-9)
