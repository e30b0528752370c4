"""Re-simulation: rebuild the `Simulation` from a bag alone (`bag_format.RecordedRun`: attachment
``scene.yaml``, metadata ``mobile_manip_sim``: integrator settings, rates, source, base command
mode and wheel-speed gains), run the source's time line (`timeline`: its grid of segments, its
start, the recorded commands — efforts and cmd_vel — held from their recorded simulated times,
and an arm controller's set-points and trajectories applied at theirs), and compare each recorded
/joint_states, /odom and (a node's bag) /imu with the messages the re-run gives at that stamp
(built by the same ``messages`` functions; the IMU with the bag's noise settings, whose sample k
noise depends on the seed and k only). Prints the largest difference per quantity; status 1 if
one exceeds the tolerance (0: bit for bit), else 0.
"""
from __future__ import annotations

import math

from mobile_manip_sim import __version__
from mobile_manip_sim.recording.bag_format import RecordedRun, decode, stamp_ns
from mobile_manip_sim.ros.imu import FIELDS, Imu
from mobile_manip_sim.ros.messages import (
    JOINT_STATES_TOPIC,
    NS,
    ODOM_TOPIC,
    joint_state,
    odometry,
    quaternion_yaw,
)
from mobile_manip_sim.ros.topics import IMU_TOPIC
from mobile_manip_sim.runtime.progress import Progress
from mobile_manip_sim.runtime.timeline import (
    apply_arm_command,
    apply_commands,
    start_node_time_line,
)
from mobile_manip_sim.scene.errors import SimulationError, StepLimitError, UserError


class Differences:
    """Largest |recorded − re-simulated| per quantity, and where it first exceeded tolerance."""

    def __init__(self, tolerance: float):
        self.tolerance = tolerance
        self.largest: dict[str, tuple[float, int]] = {}
        self.first_failure: tuple[int, str, float, float] | None = None

    def add(self, quantity: str, stamp: int, recorded: float, resimulated: float,
            angle: bool = False) -> None:
        if recorded == resimulated or (math.isnan(recorded) and math.isnan(resimulated)):
            difference = 0.0
        else:
            difference = abs(recorded - resimulated)
            if angle:
                difference = abs(math.remainder(recorded - resimulated, math.tau))
            if math.isnan(difference):
                difference = math.inf
        best = self.largest.get(quantity)
        if best is None or difference > best[0]:
            self.largest[quantity] = (difference, stamp)
        if difference > self.tolerance and self.first_failure is None:
            self.first_failure = (stamp, quantity, recorded, resimulated)

    def failed(self) -> list[str]:
        return [name for name, (difference, _) in self.largest.items()
                if difference > self.tolerance]


def start_run(run: RecordedRun):
    """The `Simulation` at the recorded source's t = 0."""
    from mobile_manip_sim.engine.simulation import Simulation

    # A node's arm controller is its parameters' (in its metadata); a headless run's is
    # its scene's `controller:` section.
    sim = Simulation(run.scene, run.settings,
                     arm_controller=run.arm_controller if run.source == "node" else None,
                     control_rate=run.control_rate)
    if run.gains is not None:
        sim.set_wheel_speed_gains(*run.gains)
    if run.source == "node":
        start_node_time_line(sim)
    return sim


def resimulate(bag, tolerance: float) -> int:
    run = RecordedRun(bag)
    run.check_robot()
    base_commands, arm_commands = run.commands()
    arm_events = run.arm_commands()   # an arm controller's, applied at their segment starts
    if run.metadata.get("version") != __version__:
        print(f"note: recorded by mobile_manip_sim {run.metadata.get('version')}, re-simulated "
              f"by {__version__}: bit-for-bit agreement is only expected from the same build")

    sim = start_run(run)
    if run.control_rate is None and (run.velocity or sim.arm_controller.active):
        print(f"note: the bag names no controller_rate (recorded before the controllers were "
              f"sampled, when they ran continuous): re-simulated at the scene's controller.rate, "
              f"{sim.control_rate:g} Hz; the states may differ")
    differences = Differences(tolerance)
    compared = {JOINT_STATES_TOPIC: 0, ODOM_TOPIC: 0}
    if IMU_TOPIC in bag.topics():
        compared[IMU_TOPIC] = 0
    imu = Imu(run.imu_noise)
    sim_stamp = None
    first_stamp = None
    begin, end = bag.time_span()
    progress = Progress("replay --resimulate", (end - begin) / NS, "s of the bag",
                        rate_unit="bag s per wall s")
    try:
        for message in bag.messages(list(compared)):
            recorded = decode(message)
            stamp = stamp_ns(recorded.header.stamp)
            if sim_stamp is None:
                if stamp != 0:
                    raise UserError(message.topic, f"the first state is at {stamp} ns, not at "
                                                   f"t = 0: cannot resimulate")
                sim_stamp = first_stamp = 0
            elif stamp < sim_stamp:
                raise UserError(message.topic, f"time goes back from {sim_stamp} to {stamp} ns")
            elif stamp > sim_stamp:
                for start, t_end in run.segments(sim_stamp, stamp):
                    # an arm controller takes references, not the efforts a headless bag
                    # of its scene recorded (zeros: `recording.headless`)
                    joints = None if sim.arm_controller.active else arm_commands.at(start)
                    apply_commands(sim, base_commands.at(start), joints, run.velocity)
                    for command in arm_events.get(start, ()):
                        apply_arm_command(sim, run.arm_controller.mode, command)
                    sim.advance_to(t_end)
                sim_stamp = stamp
            if message.topic == IMU_TOPIC:
                _compare_imu(imu, run, sim, stamp, recorded, differences)
            else:
                _compare(run, sim, stamp, message.topic, recorded, differences)
            compared[message.topic] += 1
            # once simulated up to it: said before, a bag of sparse samples was "100 %" from
            # its first second on while its one long segment was computed
            progress.update((message.log_time_ns - begin) / NS)
    except SimulationError as error:
        if isinstance(error, StepLimitError):   # settings and efforts: status 2
            raise
        print(f"replay: the re-simulation failed: {error}")
        return 1
    finally:
        progress.close()
    _report(run, bag, differences, compared, first_stamp, sim_stamp)
    return 1 if differences.failed() else 0


def _compare(run, sim, stamp: int, topic: str, recorded, differences: Differences) -> None:
    if topic == JOINT_STATES_TOPIC:
        run.check_joint_state(recorded)
        expected = joint_state(sim, stamp, run.names)
        for name, a, b in zip(run.names, recorded.position, expected.position, strict=True):
            differences.add(f"{name} position", stamp, a, b)
        for name, a, b in zip(run.names, recorded.velocity, expected.velocity, strict=True):
            differences.add(f"{name} velocity", stamp, a, b)
        if len(recorded.effort) != len(expected.effort):
            raise UserError(topic, f"{len(recorded.effort)} efforts at {stamp} ns, expected "
                                   f"{len(expected.effort)}")
        for name, a, b in zip(run.names, recorded.effort, expected.effort, strict=True):
            differences.add(f"{name} effort", stamp, a, b)
    else:
        expected = odometry(sim, stamp)
        pose, twist = recorded.pose.pose, recorded.twist.twist
        differences.add("x", stamp, pose.position.x, expected.pose.pose.position.x)
        differences.add("y", stamp, pose.position.y, expected.pose.pose.position.y)
        differences.add("yaw", stamp, quaternion_yaw(pose.orientation),
                        quaternion_yaw(expected.pose.pose.orientation), angle=True)
        differences.add("v", stamp, twist.linear.x, expected.twist.twist.linear.x)
        differences.add("omega", stamp, twist.angular.z, expected.twist.twist.angular.z)


def _compare_imu(imu: Imu, run, sim, stamp: int, recorded, differences: Differences) -> None:
    k = run.grid.index(stamp)
    if k is None:
        raise UserError(IMU_TOPIC, f"{stamp} ns is not a publication time of the bag's rate")
    expected = imu.read(sim, k)
    for field in FIELDS:
        vector = getattr(recorded, field)
        for axis, value in zip("xyz", getattr(expected, field), strict=True):
            differences.add(f"imu {field}.{axis}", stamp, getattr(vector, axis), value)
    differences.add("imu yaw", stamp, quaternion_yaw(recorded.orientation),
                    2.0 * math.atan2(expected.orientation[2], expected.orientation[3]),
                    angle=True)


def _report(run, bag, differences: Differences, compared: dict, first: int, last: int) -> None:
    settings = run.settings
    detail = f"dt {settings.dt:g}" if settings.fixed_step else \
        f"rtol {settings.rtol:g}, atol {settings.atol:g}"
    print(f"re-simulated {bag.path} ({run.source} run of scene '{run.scene.name}', "
          f"{settings.method}, {detail}): {compared[JOINT_STATES_TOPIC]} /joint_states and "
          f"{compared[ODOM_TOPIC]} /odom messages"
          f"{f' and {compared[IMU_TOPIC]} /imu' if IMU_TOPIC in compared else ''} from t = "
          f"{first / NS:.9f} to "
          f"{last / NS:.9f} s")
    order = ["x", "y", "yaw", *(f"{name} position" for name in run.names),
             *(f"{name} velocity" for name in run.names), "v", "omega",
             *(f"{name} effort" for name in run.names),
             *(f"imu {field}.{axis}" for field in FIELDS for axis in "xyz"), "imu yaw"]
    rows = [(name, differences.largest[name]) for name in order if name in differences.largest]
    width = max(len(name) for name, _ in rows) + 2
    print(f"{'quantity':<{width}}largest |recorded - resimulated|   at t (s)")
    for name, (difference, stamp) in rows:
        where = f"{stamp / NS:.9f}" if difference > 0 else "-"
        mark = "   > tolerance" if difference > differences.tolerance else ""
        print(f"{name:<{width}}{difference:<34.6g}{where}{mark}")
    failed = differences.failed()
    if failed:
        stamp, quantity, recorded, resimulated = differences.first_failure
        print(f"DIFFERENT: {len(failed)} quantities exceed the tolerance {differences.tolerance:g}"
              f" ({', '.join(failed)}); first at t = {stamp / NS:.9f} s: {quantity} recorded "
              f"{recorded!r}, re-simulated {resimulated!r}")
    elif differences.tolerance == 0:
        print("IDENTICAL: the run is reproduced bit for bit")
    else:
        print(f"OK: every difference is within the tolerance {differences.tolerance:g}")
