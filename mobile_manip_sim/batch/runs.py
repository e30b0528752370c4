"""`Batch`: N runs of one robot, stepped together — the lanes of the fixed-step methods in one
compiled call spread over the cores (the C++ core's `LaneSet`), each lane bit for bit its own
`simulate` run.

    from mobile_manip_sim.batch import Batch
    batch = Batch(scene, [{"robot.arm.links[0].mass_per_length": m} for m in masses])
    rows = batch.sample(times)        # (N, samples, state + 1): (s, T + V) of each lane
    batch.status[i]                   # LaneStatus: ok, error, t, impacts, energy_error, …

Every lane is a `Simulation` of its own scene (the scene with the lane's overrides, parsed as
`simulate --set` parses them), so parameters, initial states, efforts, controller and integrator
settings may all differ between lanes; only the number of links must be the same. Commands go to
one lane (`set_efforts`, or any command of `lane(i)`) between calls.

Lanes of rk4, semi-implicit Euler and Euler run in the compiled call, their plain grid steps
`core.build_info()["lane_width"]` lanes at a time in vector registers (core/include/mms/lanes.hpp;
`vector=False`: each lane alone, the same bits). Lanes of the adaptive methods (rk45,
dop853, radau, bdf) and lanes whose arm a controller drives are not compiled lanes: each is
stepped by its own `Simulation` from Python, sample by sample — the same numbers, without the
batch's speed (`LaneStatus.compiled` says which). A lane that fails (a bad override, a
non-finite command or state, chatter, its time limit) is failed alone, with its one-line reason;
the others go on.
"""
from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass

import numpy as np

from ..core import LaneSet
from ..engine.simulation import Simulation
from ..engine.status import BUDGET
from ..scene.errors import UserError
from ..scene.loading import Scene
from ..scene.methods import METHODS
from . import lane_logs
from .build import build_lanes

BLOCK_SECONDS = 0.25   # wall s aimed at per compiled call: progress, limits and Ctrl-C between


class TimeLimit(Exception):
    """A lane ran past its share of wall time (`Batch(time_limit=…)`)."""


def error_line(error: BaseException) -> str:
    """The line a failed run reports: a user error or time limit as it is, the state gone
    non-finite (`SimulationError`) with its type's name, anything else (a bug) likewise, its
    first line only."""
    if isinstance(error, (UserError, TimeLimit)):
        return str(error)
    if isinstance(error, RuntimeError):
        return f"{type(error).__name__}: {error}"
    return f"{type(error).__name__}: {error}".splitlines()[0]


@dataclass
class LaneStatus:
    ok: bool                 # False once the lane has failed (it is then stepped no more)
    error: str | None        # the one-line reason of a failed lane
    t: float                 # s: where the lane is (where it stopped, if failed)
    impacts: int             # impacts so far (`Simulation.impacts`)
    energy_error: float      # J: `Simulation.energy_error()` now (nan if it never started)
    compiled: bool           # stepped in the compiled lanes, or by its own Simulation


class Batch:
    def __init__(self, scene: Scene | dict, overrides: list[dict] | None = None, *,
                 threads: int | None = None, time_limit: float | None = None, check=None,
                 vector: bool = True):
        """`scene`: a `Scene` or a scene document; `overrides`: one {key path: value} per lane
        (default: one lane, the scene itself). `threads`: threads of the compiled calls (default:
        one per core). `time_limit`: wall s per lane (its share of each call's wall time,
        call wall × threads / lanes in the call); past it the lane is failed at its next sample.
        `check(scene)`: a further check of each lane's scene (a raise fails the lane with it).
        Lanes that differ only in numbers are copies of one template (`build.py`). `vector`:
        lanes' plain steps together in vector lanes; False: each lane alone (the same bits
        either way)."""
        document = scene.document if isinstance(scene, Scene) else scene
        overrides = [{}] if overrides is None else list(overrides)
        scenes, sims = build_lanes(document, overrides, check,
                                   scene if isinstance(scene, Scene) else None)
        self._start(scenes, sims, threads, time_limit, vector)

    @classmethod
    def of_scenes(cls, scenes: list, *, threads: int | None = None,
                  time_limit: float | None = None, vector: bool = True) -> Batch:
        """A batch of these scenes, one lane each (an exception in place of a scene: that lane
        is failed from the start with it as its reason)."""
        batch = cls.__new__(cls)
        scenes, sims = list(scenes), []
        for i, scene in enumerate(scenes):
            try:
                sims.append(None if isinstance(scene, BaseException) else Simulation(scene))
            except Exception as error:
                scenes[i] = error
                sims.append(None)
        batch._start(scenes, sims, threads, time_limit, vector)
        return batch

    def _start(self, scenes: list, sims: list, threads: int | None,
               time_limit: float | None, vector: bool = True) -> None:
        self.size = len(scenes)
        self.vector = bool(vector)
        # grid steps of each lane taken in vector blocks and alone (`core.LaneSet`)
        self.paths = np.zeros((self.size, 2), dtype=np.int64)
        self.threads = threads
        self.time_limit = time_limit
        self.sims: list[Simulation | None] = list(sims)
        self.errors: list[str | None] = [None] * self.size
        self.wall = np.zeros(self.size)   # each lane's share of wall time (s)
        self.sample_t = np.zeros((self.size, 0))   # each lane's own t at the last samples
        self.compiled_cpu = 0.0   # CPU s (all threads of the process) during the compiled calls
        self.python_cpu = 0.0     # CPU s of the stepping thread outside the compiled calls
        self._caller_in_calls = 0.0   # … and inside them
        links = None
        for i, scene in enumerate(scenes):
            if isinstance(scene, BaseException):
                self.errors[i], self.sims[i] = error_line(scene), None
                continue
            if links is None:
                links = scene.robot.n_links
            if scene.robot.n_links != links:
                self.errors[i] = str(UserError("robot.arm.links", "the lanes of a batch have one "
                                                                  "number of links"))
                self.sims[i] = None
        self.compiled = self._compiled()
        self._records = None
        self._logs = None         # each compiled lane's own impact log (`lanes.impact_logs`)
        self.block = 1            # samples in the next compiled call (grown to BLOCK_SECONDS)

    # --- per lane ---------------------------------------------------------------------------
    def lane(self, i: int) -> Simulation | None:
        """Lane i's own `Simulation` (None if it failed before it started): read it, or command
        it between calls (the batch picks up the records a command replaces)."""
        return self.sims[i]

    @property
    def lane_steps(self) -> tuple[int, int]:
        """Grid steps the compiled lanes began so far in vector blocks (a lane leaving its block
        at an event counted there), and alone (the wheel-speed loop, a lane ready without
        company)."""
        return int(self.paths[:, 0].sum()), int(self.paths[:, 1].sum())

    @property
    def ok(self) -> np.ndarray:
        return np.array([error is None for error in self.errors], dtype=bool)

    @property
    def status(self) -> list[LaneStatus]:
        return [self._status(i) for i in range(self.size)]

    def _status(self, i: int) -> LaneStatus:
        sim = self.sims[i]
        if sim is None:
            return LaneStatus(False, self.errors[i], 0.0, 0, math.nan, False)
        return LaneStatus(self.errors[i] is None, self.errors[i], sim.t, len(sim.impacts),
                          sim.energy_error(), bool(self.compiled[i]))

    def fail(self, i: int, error: BaseException | str) -> None:
        """Lane i is failed with this reason: it is stepped no more."""
        if self.errors[i] is None:
            self.errors[i] = error if isinstance(error, str) else error_line(error)

    def set_efforts(self, wheels=None, joints=None, lanes=None) -> None:
        """`Simulation.set_efforts` on each lane in `lanes` (default: all that are ok); `wheels`
        and `joints` are one command for all of them or one row per lane. A lane that refuses its
        command (non-finite, wrong length, overflowing) is failed alone, with the reason."""
        chosen = np.flatnonzero(self.ok) if lanes is None else np.asarray(lanes, dtype=int)
        for row, i in enumerate(chosen):
            if self.errors[i] is not None:
                continue
            try:
                self.sims[i].set_efforts(_row(wheels, row, len(chosen)),
                                         _row(joints, row, len(chosen)))
            except Exception as error:
                self.fail(i, error)

    # --- stepping ---------------------------------------------------------------------------
    def advance_to(self, t_end: float) -> None:
        """Every lane that is ok to exactly t_end (s)."""
        self._run(np.array([float(t_end)]), None, None)
        self.collect()

    def sample(self, times, progress=None, collect: bool = True) -> np.ndarray:
        """Every lane through the increasing sample times (s): an (N, samples, state + 1) array
        whose [i, k] is lane i's (s, T + V) at times[k], as `Simulation.sample` gives it (nan
        after a lane failed). `progress`: a `runtime.progress.Progress` counting samples.
        `collect=False` leaves the impacts in the lanes' own logs until `collect()` (another
        thread may then read them while this one steps another batch)."""
        times = np.ascontiguousarray(times, dtype=float).reshape(-1)
        size = self._state_size()
        rows = np.full((self.size, times.size, size + 1), np.nan)
        self.sample_t = np.full((self.size, times.size), np.nan)
        self._run(times, rows, progress)
        if collect:
            self.collect()
        return rows

    def collect(self) -> None:
        """Each lane's impacts moved from its own log into its `impacts` (`Simulation`'s)."""
        logs = self._logs
        if logs is None:
            return
        for i in np.flatnonzero(logs.count):
            self.sims[i]._collect_impacts(lane_logs.lane_log(logs, i))

    def _state_size(self) -> int:
        return next((sim.s.size for sim in self.sims if sim is not None), 0)

    def _compiled(self) -> np.ndarray:
        """The lanes the compiled call runs: those of a fixed-step method whose controllers
        are not sampled now (the compiled lanes take no controller updates) and whose arm no
        controller drives (the vector blocks have no arm controller)."""
        return np.array([sim is not None and METHODS[sim.settings.method].fixed_step
                         and not sim.controllers_sampled and not sim.arm_controller.active
                         for sim in self.sims], dtype=bool)

    def _run(self, times: np.ndarray, rows, progress) -> None:
        self.compiled = self._compiled()   # a command may have started a sampled controller
        start, in_calls = time.thread_time(), self._caller_in_calls
        for i in np.flatnonzero(self.ok & ~self.compiled):
            self._scalar_lane(i, times, rows)
        lanes = np.flatnonzero(self.ok & self.compiled)
        if lanes.size:
            self._compiled_lanes(lanes, times, rows, progress)
        self.python_cpu += (time.thread_time() - start) - (self._caller_in_calls - in_calls)

    def _scalar_lane(self, i: int, times: np.ndarray, rows) -> None:
        """A lane the compiled call does not run, stepped by its own Simulation as `simulate`
        steps it: advance_to, sample after sample."""
        sim = self.sims[i]
        start = time.perf_counter()
        try:
            for k, t in enumerate(times):
                sim.advance_to(t)
                if rows is not None:
                    rows[i, k, :-1], rows[i, k, -1] = sim.s, sim.total_energy()
                    self.sample_t[i, k] = sim.t
                self.wall[i] += time.perf_counter() - start
                start = time.perf_counter()
                self._check_time_limit(i)
        except Exception as error:
            self.fail(i, error)

    def _check_time_limit(self, i: int) -> None:
        if self.time_limit is not None and self.wall[i] > self.time_limit:
            raise TimeLimit(f"time_limit: stopped after {self.time_limit:g} s wall at "
                            f"t = {self.sims[i].t:.6g} s")

    def prepare(self) -> None:
        """Build the compiled call's lane set now rather than at the first call (a sweep builds
        it in its own thread while the last batch steps)."""
        if (self.ok & self.compiled).any():
            self._lists()

    def _lists(self):
        """The compiled call's lane set (the compiled lanes' steppers), rebuilt when a lane's
        records were replaced (a command that grew them, a reset)."""
        chosen = np.flatnonzero(self.compiled)
        sims = [self.sims[i] for i in chosen]
        key = [(sim.system.data, sim.s, sim.stops, sim._scratch, sim._clock, sim._stepper)
               for sim in sims]
        if self._records is None or len(key) != len(self._records[0]) or any(
                any(a is not b for a, b in zip(old, new, strict=True))
                for old, new in zip(self._records[0], key, strict=True)):
            lane_of = np.full(self.size, -1, dtype=np.int64)
            lane_of[chosen] = np.arange(len(sims))
            self._records = (key, lane_of, LaneSet([sim._stepper for sim in sims],
                                                   [sim.s for sim in sims],
                                                   [sim._clock for sim in sims]))
        return self._records[1], self._records[2]

    def _compiled_lanes(self, lanes: np.ndarray, times: np.ndarray, rows, progress) -> None:
        lane_of, lane_set = self._lists()
        first_sim = self.sims[lanes[0]]
        budget = first_sim._step_budget
        threads = min(self.threads or 1 << 30, len(os.sched_getaffinity(0)))
        code = np.zeros(self.size, dtype=np.int64)
        failure = np.zeros(self.size, dtype=np.int64)
        next_sample = np.zeros(self.size, dtype=np.int64)
        if self._logs is None:
            self._logs = lane_logs.impact_logs(self.size, first_sim.nq, first_sim.nu)
        logs = self._logs
        write = rows is not None
        out = rows if write else lane_logs.empty_rows(self.size, self._state_size())
        out_t = self.sample_t if write else np.zeros((self.size, 1))
        block, first = self.block, 0
        while first < times.size:
            last = _call_end(first, block, times.size)
            pending = lanes[[self.errors[i] is None for i in lanes]]
            next_sample[pending] = first
            block_start = started = time.perf_counter()
            while pending.size:
                cpu, own = time.process_time(), time.thread_time()
                lane_set.advance(pending, lane_of[pending], times, last, out, out_t, write,
                                 budget, code, next_sample, failure, *logs, self.paths,
                                 self.vector, threads)
                self.compiled_cpu += time.process_time() - cpu
                self._caller_in_calls += time.thread_time() - own
                now = time.perf_counter()
                self.wall[pending] += (now - started) * threads / max(pending.size, threads)
                started = now
                pending = self._after_call(pending, code, failure, next_sample, last, logs)
            if progress is not None:
                progress.update(last, f", {int((~self.ok).sum())} failed")
            block = _next_block(block, last - first, time.perf_counter() - block_start)
            first = last
        self.block = block

    def _after_call(self, pending, code, failure, next_sample, last, logs) -> np.ndarray:
        """After a compiled call: a paused or failed lane's impacts read from its own log (and
        the stops' log, as Python does after every call of a run; the others' stay in their logs
        until `collect`), failed lanes told why, time limits checked; returns the lanes that
        still have samples to reach in this block."""
        busy = pending[code[pending] != lane_logs.LANE_DONE]
        for i in busy:
            sim = self.sims[i]
            if logs.count[i]:
                sim._collect_impacts(lane_logs.lane_log(logs, i))
            if code[i] == lane_logs.LANE_DONE:
                continue
            try:
                if code[i] == lane_logs.LANE_FAILED:
                    sim._after_compiled(int(failure[i]))   # raises the run's own error
                    raise RuntimeError(f"the stepping ended with status {int(failure[i])}")
                sim._after_compiled(BUDGET)                 # paused: its log read, as after a call
            except Exception as error:
                self.fail(i, error)
        if self.time_limit is not None:
            for i in pending:
                if self.errors[i] is None:
                    try:
                        self._check_time_limit(i)
                    except TimeLimit as error:
                        self.fail(i, error)
        again = pending[(code[pending] == lane_logs.LANE_PAUSED) & (next_sample[pending] < last)]
        return again[[self.errors[i] is None for i in again]].astype(np.int64)


def overlapped(items: list, build, step):
    """(item, build(item), step(built)) for each item, in order, with item k stepped in a helper
    thread while item k + 1 is built, and item k - 1's results are used by the caller (between
    two of its `next`), in this thread: the compiled calls of a step release the GIL, so a
    sweep's Python work (building lanes, reading their figures) runs beside them on the cores."""
    if len(items) < 2:
        for item in items:
            built = build(item)
            yield item, built, step(built)
        return
    from concurrent.futures import ThreadPoolExecutor
    with ThreadPoolExecutor(1, thread_name_prefix="batch-steps") as helper:
        built = build(items[0])
        stepping = helper.submit(step, built)
        for k, item in enumerate(items):
            following = build(items[k + 1]) if k + 1 < len(items) else None
            stepped = stepping.result()
            done = built
            if following is not None:
                stepping, built = helper.submit(step, following), following
            yield item, done, stepped


def _row(values, row: int, lanes: int):
    """One lane's command out of one shared command or one row per lane."""
    if values is None:
        return None
    array = np.asarray(values, dtype=float) if not isinstance(values, np.ndarray) else values
    return array[row] if array.ndim == 2 and array.shape[0] == lanes else values


def _call_end(first: int, block: int, samples: int) -> int:
    """The end of the next call's samples: `block` of them from `first`, or all that are left
    when fewer than half a block would remain after it (one call of up to 1.5 blocks rather
    than a short one after it: each call ends on its slowest thread)."""
    last = first + block
    return samples if samples - last < (block + 1) // 2 else last


def _next_block(block: int, done: int, spent: float) -> int:
    """Samples for the next compiled call: doubled while a call takes under BLOCK_SECONDS."""
    if spent < BLOCK_SECONDS / 2 and done >= block:
        return 2 * block
    if spent > 2 * BLOCK_SECONDS:
        return max(1, block // 2)
    return block
