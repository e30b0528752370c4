"""Command intake: the command subscriptions and the latest valid command of each group (wheels
or cmd_vel, arm). The one module of the node that uses rclpy's internals.

Commands are not callbacks: the stepping thread takes the waiting messages itself when a
segment starts (`CommandIntake.held`), latest first, so a flood costs the middleware (whose
keep-last history drops the surplus), not the executor. Invalid messages (wrong length, NaN,
Inf) are rejected with a throttled warning naming the topic as remapped; the last valid command
stays. A command older than the command timeout (simulated time) falls to zero once, with one
warning, until the next one.
"""
from __future__ import annotations

import contextlib
import math
import threading
from typing import Callable

import numpy as np
from rclpy.callback_groups import CallbackGroup
from rclpy.guard_condition import GuardCondition
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from std_msgs.msg import Float64MultiArray

from ..ros.messages import command_values
from ..ros.topics import (
    ARM_TOPIC,
    CMD_VEL_TOPIC,
    COMMAND_QOS_DEPTH,
    WHEEL_TOPIC,
    command_qos,
    relative,
)
from ..runtime.timeline import NS, CommandSlot
from ..scene.arm_controller import MODES
from .throttle import Throttle

MAX_TAKEN = 4 * COMMAND_QOS_DEPTH   # messages one drain takes from a command topic, at most
# The symbols of an arm topic's values, per joint pair (revolute, prismatic), for messages.
ARM_LABELS = {mode.topic: mode.symbols for mode in MODES.values() if mode.array}


def command_problem(values, expected: int, labels: str) -> tuple[str, str] | None:
    """(kind, explanation) of why `values` is not a valid command of `expected` numbers, or
    None when it is one. `kind` ("length", "NaN", "Inf", "NaN and Inf") keys the throttling."""
    if len(values) != expected:
        return "length", f"expected {expected} values ({labels}), got {len(values)}"
    bad = [(i, v) for i, v in enumerate(values) if not math.isfinite(v)]
    if bad:
        kind = " and ".join(sorted({"NaN" if math.isnan(v) else "Inf" for _, v in bad},
                                   reverse=True))
        where = ", ".join(f"[{i}] = {v}" for i, v in bad)
        return kind, f"contains {kind} ({where})"
    return None


class _TakenByTheSteppingThread(CallbackGroup):
    """Subscriptions the executor neither waits on nor runs: the stepping thread takes their
    messages itself."""

    def can_execute(self, entity) -> bool:
        return False

    def beginning_execution(self, entity) -> bool:
        return False

    def ending_execution(self, entity) -> None:
        pass


class CommandInput:
    """One command topic: its subscription and its slot (`timeline.CommandSlot`)."""

    def __init__(self, node, topic: str, kind, size: int, labels: str, what: str, group,
                 times_out: bool = True):
        self.topic, self.labels, self.what = topic, labels, what
        self.times_out = times_out   # falls to zero after the command timeout
        self.slot = CommandSlot(size)
        self.subscription = node.create_subscription(kind, relative(topic), lambda _: None,
                                                     command_qos(), callback_group=group)
        self.name = self.subscription.topic_name   # as remapped, for messages

    def take(self, since_ns: int) -> list:
        """The messages waiting that arrived at or after ``since_ns`` (wall clock, ns), oldest
        first; at most MAX_TAKEN: a flood cannot hold us."""
        taken = []
        subscription = self.subscription
        with subscription.handle:
            for _ in range(MAX_TAKEN):
                message = subscription.handle.take_message(subscription.msg_type, False)
                if message is None:
                    break
                if message[1]["received_timestamp"] >= since_ns:
                    taken.append(message[0])
        return taken

    def commanded(self) -> bool:
        """Someone publishes on this topic."""
        return self.subscription.get_publisher_count() > 0


class CommandIntake:
    """The base input (wheel torques, or cmd_vel in velocity mode) and the arm input of a node
    (``arm_topic``: the effort topic, an arm controller's array topic, or None when the arm
    takes trajectories only). ``warn`` throttles the warnings about bad messages;
    ``log_warning`` says the timeouts (an arm controller's set-points do not time out)."""

    def __init__(self, node, velocity_mode: bool, stamped: bool, arm_size: int,
                 timeout: float, throttle: Throttle, log_warning: Callable[[str], None],
                 arm_topic: str | None = ARM_TOPIC):
        taken = _TakenByTheSteppingThread()
        if velocity_mode:
            from geometry_msgs.msg import Twist, TwistStamped
            base = CommandInput(node, CMD_VEL_TOPIC, TwistStamped if stamped else Twist, 2,
                                "v, omega", "base velocity", taken)
        else:
            base = CommandInput(node, WHEEL_TOPIC, Float64MultiArray, 2, "tau_R, tau_L",
                                "wheel", taken)
        symbols = ARM_LABELS.get(arm_topic, ("tau", "F"))
        arm_labels = ", ".join(f"{symbols[0]}_{i}, {symbols[1]}_{i}"
                               for i in range(1, arm_size // 2 + 1)) or "none"
        self.inputs = (base,)
        if arm_topic is not None:
            self.inputs += (CommandInput(node, arm_topic, Float64MultiArray, arm_size, arm_labels,
                                         "arm", taken, times_out=arm_topic == ARM_TOPIC),)
        self._stamped = stamped
        self.timeout_ns = round(timeout * NS)
        self._throttle, self._log_warning = throttle, log_warning
        self._lock = threading.Lock()   # the slots: the stepping thread and ~/reset
        # Wall time (ns, the middleware's reception clock) of the latest ~/reset: commands
        # received before it are dropped.
        self._since_ns = 0
        # Wakes the stepping thread from `wait` (lockstep).
        self._guard = GuardCondition(None, None, context=node.context)
        self._context = node.context

    def set_timeout(self, seconds: float) -> None:
        self.timeout_ns = round(seconds * NS)

    def drain(self, now_ns: int) -> None:
        """Take the waiting messages; the latest valid one of each topic becomes its slot's
        command, received at ``now_ns`` (the current segment start)."""
        for command in self.inputs:
            latest = None
            for message in reversed(command.take(self._since_ns)):
                stamped = self._stamped and command.topic == CMD_VEL_TOPIC
                values = command_values(command.topic, message.twist if stamped else message)
                problem = command_problem(values, command.slot.size, command.labels)
                if problem is None:
                    latest = values if latest is None else latest
                    continue
                kind, text = problem
                self._throttle.warn((command.topic, kind),
                                    f"{command.name}: {text}; keeping the last valid command")
            if latest is not None:
                with self._lock:
                    command.slot.receive(latest, now_ns)

    def held(self, segment_start_ns: int) -> tuple[np.ndarray, np.ndarray]:
        """The base command (wheel torques, or [v, ω]) and the arm's (efforts, or an arm
        controller's set-points; None without an arm input) to hold from ``segment_start_ns``
        on, after the timeout (a stale cmd_vel is zero speed)."""
        self.drain(segment_start_ns)
        held = []
        with self._lock:
            for command in self.inputs:
                timeout_ns = self.timeout_ns if command.times_out else 0
                values, timed_out = command.slot.held(segment_start_ns, timeout_ns)
                held.append(values)
                if timed_out:
                    self._log_warning(
                        f"{command.name}: no command for {self.timeout_ns / NS:g} s of "
                        f"simulated time (command_timeout); {command.what} "
                        f"{'command' if command.topic == CMD_VEL_TOPIC else 'efforts'} set to "
                        f"zero until commands resume")
        return held[0], held[1] if len(held) > 1 else None

    def arm_received(self) -> int:
        """Valid arm commands taken so far (an arm controller applies each new one once)."""
        with self._lock:
            return self.inputs[1].slot.seq if len(self.inputs) > 1 else 0

    def forget(self, now_wall_ns: int) -> None:
        """~/reset asked for (executor thread): the held commands go, and those still waiting
        in the subscriptions, received before ``now_wall_ns``, are dropped when taken."""
        with self._lock:
            for command in self.inputs:
                command.slot.clear()
            self._since_ns = now_wall_ns

    def restart(self) -> None:
        """At the new t = 0: commands that arrived since the reset count as received then."""
        with self._lock:
            for command in self.inputs:
                if command.slot.received_ns is not None:
                    command.slot.received_ns = 0

    # --- lockstep -------------------------------------------------------------------------
    def mark_published(self) -> None:
        """A state goes out: a command received after this counts as a reply to it."""
        with self._lock:
            for command in self.inputs:
                command.slot.seq_published = command.slot.seq

    def replies(self) -> list[bool]:
        """Per input: a valid command came since the latest state went out."""
        with self._lock:
            return [command.slot.seq != command.slot.seq_published for command in self.inputs]

    def commanded(self) -> list[bool]:
        return [command.commanded() for command in self.inputs]

    def wait(self, timeout: float) -> None:
        """Until a command subscription has a message, `wake` is called, or ``timeout`` s."""
        subscriptions = [command.subscription for command in self.inputs]
        with contextlib.ExitStack() as stack:
            for entity in (*subscriptions, self._guard):
                stack.enter_context(entity.handle)
            wait_set = _rclpy.WaitSet(len(subscriptions), 1, 0, 0, 0, 0, self._context.handle)
            wait_set.clear_entities()
            for subscription in subscriptions:
                wait_set.add_subscription(subscription.handle)
            wait_set.add_guard_condition(self._guard.handle)
            wait_set.wait(max(1, round(timeout * NS)))

    def wake(self) -> None:
        self._guard.trigger()
