"""The constants of the events inside a step — a rod reaching an end stop, a resting rod pulled
off its stop — and of the Zeno guard, as the compiled core uses them (core/include/mms/events.hpp,
stops.hpp; their semantics in docs/model.md, "Resting, leaving, and no Zeno"):

- a crossing is bracketed between N_SAMPLES instants of the step (plus the turning points of each
  rod's cubic Hermite path), then located by the Illinois method on the integrator's own step
  (fixed-step methods) or the step's dense output (adaptive ones); a pull likewise;
- rods that reach their stops within SIMULTANEOUS (s) of each other take part in one impact;
- an impact is evidence of an accumulation point when the last ZENO_RUN intervals and arrival
  speeds at its stop shrank and the predicted tail fits in ZENO_TAIL (s), or the interval itself
  does; the rod is then held only if the hold removes at most ZENO_SHARE of the run's kinetic
  energy beyond the law's loss. Each rod and stop keeps its own record of RUN_FIELDS numbers
  (`stops.StopsData.run`).
"""
from ..core import vocabulary

N_SAMPLES = vocabulary["N_SAMPLES"]
SIMULTANEOUS = vocabulary["SIMULTANEOUS"]   # s: stops reached this close together are one impact
ZENO_TAIL = vocabulary["ZENO_TAIL"]     # s: a run whose remaining tail is shorter is evidence
ZENO_RUN = vocabulary["ZENO_RUN"]       # shrinking intervals (and speeds) in a row that make a run
ZENO_SHARE = vocabulary["ZENO_SHARE"]   # a hold removes at most this share of its run's T (J / J)
RUN_FIELDS = vocabulary["RUN_FIELDS"]   # numbers per rod and stop of the Zeno guard's record
