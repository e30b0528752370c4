"""`SteppingLoop`: the node's stepping thread, with one explicit `State`. No ROS: it is given
callables to restart, compute, publish and record, and a `Pacer`, so it is tested on a fake
clock (test_stepping_loop.py).

For each k the loop computes segment k → k + 1 (outside its lock: services answer during a long
segment), waits until the pacer says state k + 1 is due, then publishes it (under its lock: once
~/pause or ~/reset has answered, nothing more of the old time line goes out). Computing before
waiting keeps the compute time out of the publication jitter. A segment computed across a pause
is published after the resume; one computed across a reset is dropped.

Nothing ends the loop but `stop`: an exception in a segment (or anywhere in a turn) is one line
and the FAILED state until ~/reset. A segment whose engine has made no progress — neither its
time nor its count of accepted steps, which compiled code advances as it goes, has moved — for
WATCHDOG_SECONDS of wall time is reported once (`watch`); a ~/reset then abandons it: the engine
is replaced (``replace()``) and a new stepping thread goes on from t = 0, while the old one, stuck
inside code that no Python can interrupt, is left to end with the process. When it returns it
never reaches the new engine: ``compute`` holds the engine it began with and raises `Abandoned`
once it finds it replaced (the shell's generation check), and the loop drops what it computed.
"""
from __future__ import annotations

import enum
import threading
from typing import Callable

from ..runtime.pacing import Pacer
from ..runtime.timeline import Grid, format_ns
from ..scene.errors import SimulationError, UserError

PEER_POLL = 0.01    # s: lockstep's start-up checks for peers this often
MAX_WAIT = 3600.0   # s: the longest single wait (then the loop looks again)
WATCHDOG_SECONDS = 10.0   # s of wall time without engine progress before a segment is reported


class Abandoned(Exception):
    """Raised in a stepping thread whose segment was abandoned: the thread ends quietly. The
    ``compute`` callable raises it too, when it finds its engine replaced."""




class State(enum.Enum):
    RUNNING = "running"       # computing and publishing, paced
    PAUSED = "paused"         # time stands still
    STEPPING = "stepping"     # paused, with ~/step calls whose states are not out yet
    FAILED = "failed"         # a segment failed: nothing is computed until ~/reset
    RESETTING = "resetting"   # ~/reset called: the next state out is t = 0
    STOPPING = "stopping"     # shutting down: nothing more goes out


def describe(error: BaseException) -> str:
    """One line naming an exception: its message (our errors say what and where), or its type
    when it says nothing by itself."""
    text = " ".join(str(error).split())
    ours = isinstance(error, (SimulationError, UserError))
    return text if ours and text else f"{type(error).__name__}: {text}".rstrip(": ")


class SteppingLoop:
    """The stepping state machine. Given:
    - ``restart()``: engine and commands back to t = 0; returns the messages of state 0;
    - ``compute(k, start_ns)``: advance over segment k → k + 1 (starting at ``start_ns``);
      returns the messages of state k + 1; any exception fails the segment;
    - ``publish(k, messages)``: send state k (state 0 goes out with the robot description);
    - ``record()``: after a turn, outside the lock: record what was published;
    - ``failed(text)``: log the one line of a failure; ``warn(key, text)``: a throttled warning;
    - ``lockstep``: a `lockstep.Lockstep` in synchronous mode; ``wake()`` interrupts its wait;
    - ``alive()``: False once the ROS context is down (a publication then fails: no error);
    - ``progress()``: (the engine's time (s), its count of accepted steps), which the watchdog
      watches: a segment is stuck when neither moves, slow is not stuck; ``replace()``: a new
      engine for the one a stuck segment holds; ``report(text)``: the watchdog's warning.
    The services call `pause`, `step`, `reset`, `set_real_time_factor` and `stop` from another
    thread, a timer calls `watch`; `run` is the stepping thread."""

    def __init__(self, grid: Grid, pacer: Pacer, *, restart: Callable, compute: Callable,
                 publish: Callable, record: Callable[[], None], failed: Callable[[str], None],
                 warn: Callable[[tuple, str], bool], lockstep=None,
                 wake: Callable[[], None] = lambda: None, alive: Callable[[], bool] = lambda: True,
                 progress: Callable[[], tuple] = lambda: (0.0, 0),
                 replace: Callable[[], None] = lambda: None,
                 report: Callable[[str], None] | None = None,
                 wait: Callable[[float | None], object] | None = None):
        self.grid, self.pacer = grid, pacer
        self._restart, self._compute, self._publish = restart, compute, publish
        self._record, self._failed, self._warn = record, failed, warn
        self.lockstep, self._wake, self._alive = lockstep, wake, alive
        self._progress, self._replace, self._report = progress, replace, report or failed
        self.cv = threading.Condition()   # guards everything below and every publication
        self._wait = wait or self.cv.wait   # under cv: until notified or timeout s
        self.state = State.RUNNING
        # The ~/pause switch (true from pause(true) to pause(false)): what a reset returns to,
        # PAUSED or RUNNING, also when it comes while FAILED or RESETTING.
        self.pause_requested = False
        self.k = 0                  # index of the latest published state
        self.now_ns = 0             # its stamp: simulated time at the start of the open segment
        self.pending = None         # (k + 1, messages): computed, waiting for its wall time
        self.steps = 0              # STEPPING: ~/step calls whose states are not out yet
        self.failure: str | None = None   # FAILED: when and why
        self.time_line = 0          # resets so far: a ~/step answers for its own time line
        self.thread = 0             # the stepping thread in charge (one more per abandon)
        # The segment being computed: [thread, start ns, engine time, wall time it was last
        # seen to move, reported yet], or None.
        self.computing: list | None = None

    # --- the stepping thread ---------------------------------------------------------------
    def run(self) -> None:
        """The thread's body: the first state, then turns until stopped. Nothing that goes
        wrong in a turn ends it: the loop fails (one line) and waits for ~/reset."""
        try:
            started = self.begin()
        except Abandoned:
            return
        except Exception as error:
            started = self._crashed(error)
        if started:
            self._turns()

    def _turns(self) -> None:
        while True:
            try:
                if not self.turn():
                    return
                self._record()
            except Abandoned:
                return
            except Exception as error:
                if not self._crashed(error):
                    return

    def _crashed(self, error: Exception) -> bool:
        """An exception outside a segment (a publication, the recorder): FAILED, said in one
        line; False when it only means shutting down."""
        if self.state is State.STOPPING or not self._alive():
            return False
        self._fail(self.now_ns, error)
        return True

    def begin(self) -> bool:
        """The first state (in lockstep once a peer listens and one commands), then the first
        segment, before pacing starts. False when stopped before it began."""
        if self.lockstep is not None:
            with self.cv:   # graph changes do not notify: poll, woken early by stop()
                while self.state is not State.STOPPING and not self.lockstep.ready():
                    self.lockstep.waiting(self._report)
                    self.cv.wait(PEER_POLL)
        with self.cv:
            if self.state is State.STOPPING:
                return False
            self._go_out(0, self._restart())
        self._record()
        if self.lockstep is None:
            computed = self._segment()
            with self.cv:
                if self.state is not State.RESETTING:
                    self.pending = computed
                self.pacer.reanchor(self.now_ns)
        return True

    def turn(self) -> bool:
        """One step of the state machine; False once stopping."""
        with self.cv:
            if self.state is State.STOPPING:
                return False
            if self.state is State.RESETTING:
                self._reset_now()
                return True
            if self.state in (State.PAUSED, State.FAILED):
                self._wait(None)
                return True
            pending = self.pending
        if pending is None:
            if self.lockstep is not None:
                self.lockstep.await_replies(self.now_ns, self._interrupted)
                with self.cv:
                    if self.state in (State.STOPPING, State.RESETTING, State.PAUSED):
                        return True
            computed = self._segment()   # outside the lock
            with self.cv:
                if self.state is not State.RESETTING:
                    self.pending = computed
            return True
        with self.cv:
            if self.state not in (State.RUNNING, State.STEPPING):
                return True
            k, messages = pending
            if (self.state is State.STEPPING and getattr(self.pacer, "follows", False)
                    and self.pacer.delay(self.grid.stamp(k)) > 0):
                # a node following another's /clock steps no further than that clock
                self._wait(self.pacer.delay(self.grid.stamp(k)))
                return True
            if self.state is State.STEPPING:   # a ~/step: publish now, no pacing
                self._go_out(k, messages)
                self.pending = None
                self.steps -= 1
                if self.steps == 0:
                    self.state = State.PAUSED
                self.cv.notify_all()
                return True
            stamp = self.grid.stamp(k)
            delay = self.pacer.delay(stamp)
            if delay > 0:
                self._wait(min(delay, MAX_WAIT))   # woken early by pause, reset, parameters
                return True
            self._report_lag(stamp, -delay)
            self._go_out(k, messages)
            self.pending = None
        return True

    def _interrupted(self) -> bool:
        with self.cv:
            return self.state is not State.RUNNING

    def _reset_now(self) -> None:
        """Under cv: state 0 of a new time line goes out."""
        messages = self._restart()
        self.k, self.now_ns, self.pending, self.steps, self.failure = 0, 0, None, 0, None
        self.time_line += 1
        self.pacer.reanchor(0)
        self._go_out(0, messages)
        self.state = State.PAUSED if self.pause_requested else State.RUNNING
        self.cv.notify_all()

    def _go_out(self, k: int, messages) -> None:
        """Under cv: publish state k; it is then the latest."""
        if self.lockstep is not None:
            self.lockstep.publishing(self.now_ns)
        self._publish(k, messages)
        self.k, self.now_ns = k, self.grid.stamp(k)

    def _segment(self):
        """Compute segment k → k + 1: (k + 1, messages), or None when it failed. Abandoned
        when a reset gave up on it meanwhile."""
        with self.cv:
            k, start_ns, thread = self.k, self.now_ns, self.thread
            self.computing = [thread, start_ns, self._progress(), self.pacer.clock(), False]
        try:
            result = k + 1, self._compute(k, start_ns)
        except Abandoned:
            raise
        except Exception as error:
            result = error
        with self.cv:
            if thread != self.thread:
                raise Abandoned
            self.computing = None
        if isinstance(result, Exception):
            self._fail(start_ns, result)
            return None
        return result

    def watch(self) -> None:
        """The watchdog (a timer calls it about once a second): a segment whose engine time has
        not moved for WATCHDOG_SECONDS is reported once; while a reset waits for it, it is
        abandoned."""
        with self.cv:
            computing = self.computing
            if computing is None:
                return
            thread, start_ns, seen, since, reported = computing
            now, progress = self.pacer.clock(), self._progress()
            if progress != seen:
                self.computing = [thread, start_ns, progress, now, reported]
                return
            stuck = now - since
            if stuck < WATCHDOG_SECONDS:
                return
            if not reported:
                computing[4] = True
                self._report(f"watchdog: the segment after t = {format_ns(start_ns)} s has made "
                             f"no progress for {stuck:.0f} s (engine at t = {progress[0]:.9g} s); "
                             f"~/reset abandons it")
            if self.state is not State.RESETTING:
                return
            # Give up on the stuck thread: a new engine and a new stepping thread take over.
            self.thread += 1
            self.computing = None
            self._replace()
            threading.Thread(target=self._turns, name="stepping", daemon=True).start()
        self._report(f"watchdog: abandoned the segment after t = {format_ns(start_ns)} s; a new "
                     f"engine starts from t = 0 (the stuck one keeps a core busy until the node "
                     f"exits)")

    def _fail(self, start_ns: int, error: Exception) -> None:
        cause = describe(error)
        with self.cv:
            if self.state in (State.RESETTING, State.STOPPING) or not self._alive():
                return   # the segment is dropped anyway; a context gone is the node stopping
            self.state = State.FAILED
            self.failure = f"t = {format_ns(start_ns)} s: {cause}"
            self.cv.notify_all()
        self._failed(f"simulation failed in the segment after t = {format_ns(start_ns)} s: "
                     f"{cause}; paused, call ~/reset to start again")

    def _report_lag(self, stamp: int, late: float) -> None:
        """Publishing `late` s behind the wall clock: beyond the pacer's tolerance, warn
        (throttled, with the measured real-time factor); the pacer paces on from here."""
        measured = self.pacer.late(stamp, late)
        if measured is None:
            return
        since = format_ns(self.pacer.window[1])
        if self._warn(("lag",), f"cannot keep up with real_time_factor "
                                f"{self.pacer.real_time_factor:g}: {late:.3f} s behind the wall "
                                f"clock, measured real-time factor {measured:.2f} since {since} "
                                f"s; simulated time runs slower"):
            self.pacer.restart_window()

    def notify(self) -> None:
        """Something the pacer waits for happened (a /clock heard): look again now."""
        with self.cv:
            self.cv.notify_all()

    def _changed(self) -> None:
        """Under cv: the state changed; wake the stepping thread wherever it waits."""
        self.cv.notify_all()
        self._wake()

    # --- the services (executor thread) ----------------------------------------------------
    def pause(self, on: bool) -> tuple[bool, str]:
        """~/pause: (success, message)."""
        with self.cv:
            now = format_ns(self.now_ns)
            was_paused = self.pause_requested
            if on:
                self.pause_requested = True
                if self.state is State.RUNNING:
                    self.state = State.PAUSED
                result = True, f"{'already ' if was_paused else ''}paused at t = {now} s"
            elif self.state is State.FAILED:
                result = False, (f"cannot resume: the simulation failed ({self.failure}); call "
                                 f"~/reset")
            else:
                self.pause_requested = False
                if self.state in (State.PAUSED, State.STEPPING):
                    self.state, self.steps = State.RUNNING, 0
                    self.pacer.reanchor(self.now_ns)
                result = True, f"{'resumed' if was_paused else 'running'} at t = {now} s"
            self._changed()
        return result

    def step(self, timeout: float) -> tuple[bool, str]:
        """~/step while paused: the next state, one period on, is published; then answers."""
        with self.cv:
            self.cv.wait_for(lambda: self.state is not State.RESETTING, timeout)
            if self.state not in (State.PAUSED, State.STEPPING):
                if self.state is State.FAILED:
                    return False, (f"cannot step: the simulation failed ({self.failure}); call "
                                   f"~/reset")
                if self.state is State.RUNNING:
                    return False, "not paused: call ~/pause (true) first, then ~/step"
                return False, f"step not completed (t = {format_ns(self.now_ns)} s)"
            self.steps += 1
            self.state = State.STEPPING
            target, time_line = self.k + self.steps, self.time_line
            self._changed()
            self.cv.wait_for(lambda: self.k >= target or self.state is not State.STEPPING,
                             timeout)
            if self.k >= target and self.time_line == time_line:
                return True, f"stepped to t = {format_ns(self.now_ns)} s"
            return False, f"step not completed (t = {format_ns(self.now_ns)} s)"

    def reset(self) -> None:
        """~/reset: from here on nothing of the old time line is published."""
        with self.cv:
            if self.state is not State.STOPPING:
                self.state = State.RESETTING
            self._changed()

    def set_real_time_factor(self, factor: float) -> None:
        with self.cv:
            self.pacer.set_real_time_factor(factor, self.now_ns)
            self.cv.notify_all()

    def stop(self) -> None:
        """Nothing is published after this returns."""
        with self.cv:
            self.state = State.STOPPING
            self._changed()
