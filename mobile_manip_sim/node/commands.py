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
    JOINT_COMMANDS_TOPIC,
    WHEEL_TOPIC,
    command_qos,
    relative,
)
from ..runtime.timeline import NS, CommandSlot
from ..scene import schema
from ..scene.arm_controller import MODES
from ..scene.limits import EFFORT, SPEED
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
        return take(self.subscription, since_ns)

    def commanded(self) -> bool:
        """Someone publishes on this topic."""
        return self.subscription.get_publisher_count() > 0


def take(subscription, since_ns: int) -> list:
    """The messages waiting on ``subscription`` that arrived at or after ``since_ns`` (wall
    clock, ns), oldest first; at most MAX_TAKEN: a flood cannot hold us."""
    taken = []
    with subscription.handle:
        for _ in range(MAX_TAKEN):
            message = subscription.handle.take_message(subscription.msg_type, False)
            if message is None:
                break
            if message[1]["received_timestamp"] >= since_ns:
                taken.append(message[0])
    return taken


class JointCommands:
    """ros2_control's topic-based hardware interface (joint_state_topic_hardware_interface):
    sensor_msgs/JointState commands by joint name on one topic. Each joint takes the field of its
    command interface — the wheels velocity (base_command velocity) or effort, the arm's joints
    the arm controller's (position, velocity or effort) — as that interface fills it: a field
    as long as ``name`` is by name; a shorter one holds, in ``name`` order, the values of the
    named joints whose interface it is. A joint a message does not name, or whose value is NaN
    (ros2_control's "no command": a command interface never written, or one a controller
    released), keeps its last command; ±inf refuses the message.
    The wheels' values become the base command (wheel torques, or v = r(ω_R + ω_L)/2,
    ω = r(ω_R − ω_L)/(2b)), the arm's the arm command: the same slots the array topics fill."""

    FIELDS = ("position", "velocity", "effort")
    BOUNDS = {"velocity": SPEED, "effort": EFFORT}   # the scene's, as on the arm's commands

    def __init__(self, node, group, names, velocity_mode: bool, arm_interface: str,
                 wheel_radius: float, half_track: float, arm_initial):
        self.topic, self.what, self.times_out = JOINT_COMMANDS_TOPIC, "joint", False
        self.names = list(names)
        self.interfaces = {name: ("velocity" if velocity_mode else "effort") if j < 2
                           else arm_interface for j, name in enumerate(self.names)}
        self._velocity_mode, self._r, self._b = velocity_mode, wheel_radius, half_track
        self._arm_initial = np.array(arm_initial, dtype=float)
        self.values = np.zeros(len(self.names))   # the last command of each joint
        self.restart()
        from sensor_msgs.msg import JointState
        self.subscription = node.create_subscription(JointState, relative(self.topic),
                                                     lambda _: None, command_qos(),
                                                     callback_group=group)
        self.name = self.subscription.topic_name

    def take(self, since_ns: int) -> list:
        return take(self.subscription, since_ns)

    def commanded(self) -> bool:
        return self.subscription.get_publisher_count() > 0

    def restart(self) -> None:
        """~/reset: the wheels' commands zero, the arm's its initial ones."""
        self.values[:2] = 0.0
        self.values[2:] = self._arm_initial

    def read(self, message) -> tuple[np.ndarray | None, str | None]:
        """(every joint's command after ``message``, None), or (None, why it is refused)."""
        names = list(message.name)
        unknown = [name for name in names if name not in self.interfaces]
        if unknown:   # a peer's name, cut: a 10⁶-character one was echoed whole
            return None, (f"unknown joint {schema.short(unknown[0])} (the node's joints: "
                          f"{', '.join(self.names)})")
        if len(set(names)) != len(names):
            return None, "a joint is named twice"
        values = self.values.copy()
        for field in self.FIELDS:
            given = list(getattr(message, field))
            if not given:
                continue
            if len(given) == len(names):
                pairs = zip(names, given, strict=True)
            else:
                mine = [name for name in names if self.interfaces[name] == field]
                if len(given) != len(mine):
                    return None, (f"{field} has {len(given)} values for {len(names)} names "
                                  f"({len(mine)} of them take {field} commands)")
                pairs = zip(mine, given, strict=True)
            for name, value in pairs:
                if self.interfaces[name] != field or math.isnan(value):
                    continue
                if not math.isfinite(value):
                    return None, f"{field} of {name} is {value}"
                bound = self.BOUNDS.get(field)
                if bound is not None and abs(value) > bound:   # 1e308 rad/s would overflow v
                    return None, f"{field} of {name} is {value:g}: must be within ±{bound:g}"
                values[self.names.index(name)] = value
        return values, None

    def base(self, values) -> list[float]:
        """The base slot's command from the wheels' values."""
        right, left = float(values[0]), float(values[1])
        if not self._velocity_mode:
            return [right, left]
        return [0.5 * self._r * (right + left), 0.5 * self._r * (right - left) / self._b]


class CommandIntake:
    """The base input (wheel torques, or cmd_vel in velocity mode) and the arm input of a node
    (``arm_topic``: the effort topic, an arm controller's array topic, or None when the arm
    takes trajectories only). ``warn`` throttles the warnings about bad messages;
    ``log_warning`` says the timeouts (an arm controller's set-points do not time out)."""

    def __init__(self, node, velocity_mode: bool, stamped: bool, arm_size: int,
                 timeout: float, throttle: Throttle, log_warning: Callable[[str], None],
                 arm_topic: str | None = ARM_TOPIC, joint_commands: dict | None = None):
        """``joint_commands``: the keyword arguments of `JointCommands` but the node's and the
        group's, to take ros2_control's joint commands too (then no command times out: that
        interface sends a command only when it changes); None: not."""
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
        self.joints = None
        if joint_commands is not None:
            for command in self.inputs:
                command.times_out = False
            self.joints = JointCommands(node, taken, velocity_mode=velocity_mode,
                                        **joint_commands)
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
        if self.joints is not None:
            self._drain_joints(now_ns)

    def _drain_joints(self, now_ns: int) -> None:
        """The latest valid joint command fills the base slot and the arm's (if any)."""
        joints = self.joints
        for message in reversed(joints.take(self._since_ns)):
            values, problem = joints.read(message)
            if problem is not None:
                self._throttle.warn((joints.topic, "bad"),
                                    f"{joints.name}: {problem}; keeping the last valid command")
                continue
            joints.values = values
            with self._lock:
                self.inputs[0].slot.receive(joints.base(values), now_ns)
                if len(self.inputs) > 1:
                    self.inputs[1].slot.receive(values[2:], now_ns)
            return

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
            if self.joints is not None:
                self.joints.restart()
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

    def topic_names(self) -> list[str]:
        """The command topics, as remapped."""
        return [command.name for command in self.inputs] + \
            ([self.joints.name] if self.joints is not None else [])

    def commanded(self) -> list[bool]:
        """Per input: someone publishes on it (ros2_control's joint commands count for both)."""
        joints = self.joints is not None and self.joints.commanded()
        return [command.commanded() or joints for command in self.inputs]

    def wait(self, timeout: float) -> None:
        """Until a command subscription has a message, `wake` is called, or ``timeout`` s."""
        subscriptions = [command.subscription for command in self.inputs]
        if self.joints is not None:
            subscriptions.append(self.joints.subscription)
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
