"""Stroke end stops: the records the compiled core's impact law, rests and releases work on
(core/include/mms/stops.hpp; the semantics in docs/model.md, "Resting, leaving, and no Zeno").

- Impact: docs/model.md's unilateral impact law — one solve for every stop in contact at that
  instant: the rods reaching their stops within `events.SIMULTANEOUS` of each other (each with
  its restitution, 0 for one arriving slower than rebounds are kept) and those resting (e = 0),
  each stop only pushing — or the paper's `reflect` law; one row per rod hit goes to the stop log
  (`StopsData.log`), from which `Simulation` builds its `Impact` list (`impact_log.py`).
- Resting: a rod whose rebound would be slower than ``rest_speed`` stops dead at its stop (e = 0)
  and is held there (its l̇ degree of freedom is locked, not stiffly pushed back). At an
  accumulation point of impacts (the Zeno guard, `events.py`) every contact of the impact is held.
- Leaving: a resting rod leaves when its stop would have to pull to hold it — at an impact, at a
  command change, or at the instant located inside a step where its holding force changes sign;
  which rods leave together is decided by the same contact law at the level of accelerations,
  so freeing one never leaves another one pulled.
"""
from __future__ import annotations

from collections import namedtuple

import numpy as np

from ..core import vocabulary
from .events import RUN_FIELDS
from .impact_log import LOG_COLUMNS

IMPULSE, REFLECT = vocabulary["IMPULSE"], vocabulary["REFLECT"]
LAW_IDS = {"impulse": IMPULSE, "reflect": REFLECT}
# StopsData.failed[0]: why the stops failed the run (0: they did not)
CONTACT_SOLVE_FAILED = vocabulary["CONTACT_SOLVE_FAILED"]
LOG_ROOM = 64   # rows of the impact log per stop (see `make_stops`)

StopsData = namedtuple("StopsData", [
    "watched",    # (n,) bool: rod k's stops are checked for crossings (not while it rests)
    "resting",    # (n,) int64: −1 / +1 rod held at its lower / upper stop, 0 free
    "stroke",     # (n, 2) [min, max] of each l_k, m
    "permanent",  # (n_u,) bool: locked by the scene (locked joints, fixed base)
    "law",        # StopLaw: the impact law and its parameters
    "log",        # (capacity, LOG_COLUMNS) one row per impact
    "log_q",      # (capacity, n_q) configuration at each impact
    "log_u",      # (capacity, 2, n_u) u⁻ and u⁺ of each impact
    "log_free",   # (capacity, n_u) bool: the pseudo-velocities free at each impact
    "count",      # (1,) int64: rows of the log in use
    "run",        # (n, 2, events.RUN_FIELDS) the Zeno guard's record per rod and stop (0 lower,
                  # 1 upper) (`events.py`); cleared on reset
    "failed",     # (1,) int64: why the stops failed the run (CONTACT_SOLVE_FAILED), 0 while not
])

StopLaw = namedtuple("StopLaw", [
    "kind",         # IMPULSE (docs/model.md's unilateral law) or REFLECT (the paper's: l̇
                    # reversed alone)
    "restitution",  # e ∈ [0, 1]
    "rest_speed",   # m/s: a rod that would rebound slower than this stops dead and is held
])


def make_stops(model, stop_law, permanently_locked, resting) -> StopsData:
    """The stops of `model` under the scene's `StrokeLimits` (None: no stops, never watched);
    ``resting`` (n,) int64 is the system's own array (`system.SystemData.resting`)."""
    n, nq, nu = model.n_links, model.n_q, model.n_u
    # Half of it is room for one step's impacts: LOG_ROOM at each stop of every rod and
    # 4·LOG_ROOM more — far more than a run of impacts takes to reach its accumulation point
    # (`events.py`), so that the log-room exit (`status.CHATTER`) is a last resort.
    capacity = 4 * LOG_ROOM * (n + 2)
    permanent = np.zeros(nu, dtype=np.bool_)
    permanent[list(permanently_locked)] = True
    law = (StopLaw(LAW_IDS[stop_law.law], float(stop_law.restitution),
                   float(stop_law.rest_speed)) if stop_law else StopLaw(IMPULSE, 0.0, 0.0))
    return StopsData(np.zeros(n, dtype=np.bool_), resting,
                     np.array(model.stroke, dtype=float), permanent, law,
                     np.zeros((capacity, LOG_COLUMNS)), np.zeros((capacity, nq)),
                     np.zeros((capacity, 2, nu)), np.zeros((capacity, nu), dtype=np.bool_),
                     np.zeros(1, dtype=np.int64), np.zeros((n, 2, RUN_FIELDS)),
                     np.zeros(1, dtype=np.int64))
