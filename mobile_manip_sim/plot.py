"""`plot`: the seed paper's figures, and an energy balance, from any run.

    plot RUN --out DIR [--scene FILE]

RUN is a CSV written by `simulate` (its impacts, if any, beside it in ``RUN.impacts.csv``; its
scene given by ``--scene`` or the embedded paper scene) or a recorded bag (a rosbag2 directory
or one ``.mcap`` file; its scene from the bag's ``scene.yaml`` attachment unless ``--scene``
overrides it). DIR receives one PNG per figure and an ``index.html`` showing them all.

One loader per input kind (`load_csv`, `load_bag`) produces the same in-memory `Run` table;
the figure functions (`FIGURES`) each turn a `Run` into one matplotlib `Figure` (Agg, no pyplot
state), and `plot` returns them by name so tests can inspect their lines.

The energy balance is ``(T + V)(t) − (T + V)(t₀) − W(t) + L(t)``, zero for exact physics:
W is the work of the efforts and of the scene's damping, L the kinetic energy lost in end-stop
impacts up to t. The simulator integrates W exactly; a CSV or bag holds only samples, so W is
rebuilt here at the sample rate: the efforts held over each sample interval are known exactly
from a bag's recorded commands (held from the segment start they are stamped with: the run's
time line, `timeline.CommandHistory`) and are the scene's constant ones for a CSV; the rates
are averaged
over the interval (trapezoid rule), split at the recorded impact times where the rates jump
(see `work`). The result is an approximation of order Δt²: 2.6 mJ at 100 Hz in the paper run
(energies of several J), 25 µJ at 1 kHz. Without the split at impacts it was 38 mJ at 100 Hz.
"""
from __future__ import annotations

import csv
import html
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
from matplotlib.figure import Figure

from . import cli, schema
from .dynamics import Dynamics, constraint_residuals
from .effects import settings as effect_settings
from .errors import UserError
from .scene import Scene, load_scene, scene_from_text
from .simulate import csv_columns
from .timeline import NS, CommandHistory
from .topics import ARM_TOPIC as ARM_COMMANDS
from .topics import CMD_VEL_TOPIC as CMD_VEL
from .topics import JOINT_STATES_TOPIC as JOINT_STATES
from .topics import ODOM_TOPIC as ODOM
from .topics import WHEEL_TOPIC as WHEEL_COMMANDS

RESIDUAL_FLOOR = 1e-17      # |residual| plotted at least this, so exact zeros show on a log axis
HEADING_MARKS = 12          # about this many heading arrows along the base's path
FIGURE_SIZE = (8.0, 4.8)    # inches
DPI = 120


# --- the run table ----------------------------------------------------------------------------

@dataclass
class Run:
    """One run, sampled: what every figure is drawn from (SI units, docs/model.md's vectors).

    ``q`` (N, n_q) and ``u`` (N, n_u) as in docs/model.md; ``qdot`` (N, n_q) the configuration rates
    (from a CSV: computed from ``u`` through the constraints; from a bag: as recorded — odometry
    twist and wheel velocities); ``energy`` T + V (J); ``efforts`` (N, 2 + 2n) the efforts in
    /joint_states order (τ_R, τ_L, τ_1, F_1, …; N·m or N) acting from each sample to the next
    (row k: over (t_k, t_{k+1})), or None when unknown; ``impacts`` the end-stop impacts as dicts (time, link, stop,
    ld_before, ld_after, energy_lost, resting).
    """

    source: Path
    kind: str                      # "csv" or "bag"
    scene: Scene
    t: np.ndarray
    q: np.ndarray
    u: np.ndarray
    qdot: np.ndarray
    energy: np.ndarray
    efforts: np.ndarray | None
    effort_source: str
    impacts: list[dict] = field(default_factory=list)

    @property
    def n_links(self) -> int:
        return self.scene.robot.n_links

    def joint_names(self) -> list[str]:
        return self.scene.robot.joint_names()


def dynamics_of(scene: Scene) -> Dynamics:
    """The simulator's dynamics for a scene (gravity, payload, wheel inertia as it runs them)."""
    return Dynamics(scene.robot, **effect_settings(scene).dynamics_options())


def scene_efforts(scene: Scene) -> np.ndarray:
    """The scene's constant efforts (τ_R, τ_L, τ_1, F_1, …), saturated as the simulator does."""
    return effect_settings(scene).saturate(np.concatenate([scene.wheel_efforts, scene.joint_efforts]))


# --- loaders ----------------------------------------------------------------------------------

def load_run(path, scene_path=None) -> Run:
    """A CSV from `simulate`, a bag directory or a ``.mcap`` file → `Run`."""
    path = Path(path)
    if not path.exists():
        raise UserError(str(path), "no such file or directory")
    if path.is_dir() or path.suffix == ".mcap":
        return load_bag(path, scene_path)
    if path.suffix == ".csv":
        return load_csv(path, scene_path)
    raise UserError(str(path), f"unknown kind of run {path.suffix or '(no suffix)'!r}: expected a "
                               "CSV from simulate (.csv), a bag directory or an .mcap file")


def load_csv(path, scene_path=None) -> Run:
    """A `simulate` CSV (and its ``.impacts.csv``); the scene defaults to the embedded one."""
    path = Path(path)
    scene = load_scene(scene_path)
    header, rows = _read_csv(path)
    expected = csv_columns(scene.robot.n_links)
    missing = [name for name in expected if name not in header]
    if missing:
        raise UserError(str(path), f"missing column{'s' if len(missing) > 1 else ''} "
                                   f"{', '.join(missing)} (a simulate CSV of scene "
                                   f"{scene.name!r} has: {', '.join(expected)})")
    extra = [name for name in header if name not in expected]
    if extra:
        raise UserError(str(path), f"columns {', '.join(extra)} are not those of scene "
                                   f"{scene.name!r} ({scene.robot.n_links} links); pass the "
                                   "run's scene with --scene")
    if not rows:
        raise UserError(str(path), "no data rows")
    table = _numbers(path, header, rows)
    columns = {name: table[:, header.index(name)] for name in expected}
    n_q, n_u = scene.robot.n_q, scene.robot.n_u
    q = np.column_stack([columns[name] for name in expected[1:1 + n_q]])
    u = np.column_stack([columns[name] for name in expected[1 + n_q:1 + n_q + n_u]])
    dynamics = dynamics_of(scene)
    qdot = np.array([dynamics.configuration_rate(q_k, u_k) for q_k, u_k in zip(q, u)])
    efforts = np.tile(scene_efforts(scene), (len(q), 1))
    return Run(source=path, kind="csv", scene=scene, t=columns["t"], q=q, u=u, qdot=qdot,
               energy=columns["energy"], efforts=efforts,
               effort_source="the scene's constant efforts", impacts=_read_impacts_csv(path, scene.robot.n_links))


def _read_csv(path: Path) -> tuple[list[str], list[list[str]]]:
    try:
        with path.open(newline="") as handle:
            rows = list(csv.reader(handle))
    except (OSError, UnicodeDecodeError) as error:
        raise UserError(str(path), f"cannot read ({getattr(error, 'strerror', None) or error})") \
            from None
    except csv.Error as error:
        raise UserError(str(path), f"not a valid CSV ({error})") from None
    if not rows:
        raise UserError(str(path), "empty file (no header)")
    return [name.strip() for name in rows[0]], [row for row in rows[1:] if row]


def _numbers(path: Path, header: list[str], rows: list[list[str]]) -> np.ndarray:
    table = np.empty((len(rows), len(header)))
    for i, row in enumerate(rows):
        if len(row) != len(header):
            raise UserError(str(path), f"line {i + 2}: {len(row)} values, the header has "
                                       f"{len(header)}")
        for j, text in enumerate(row):
            try:
                table[i, j] = float(text)
            except ValueError:
                raise UserError(str(path), f"line {i + 2}, column {header[j]}: "
                                           f"{text!r} is not a number") from None
    if not np.all(np.isfinite(table)):
        i, j = np.argwhere(~np.isfinite(table))[0]
        raise UserError(str(path), f"line {i + 2}, column {header[j]}: not finite")
    return table


IMPACT_FIELDS = ("time", "link", "stop", "ld_before", "ld_after", "energy_lost", "resting")


def _read_impacts_csv(run_path: Path, n_links: int) -> list[dict]:
    """``RUN.impacts.csv`` as `simulate` writes it; a run without impacts has no such file."""
    path = run_path.with_suffix(".impacts.csv")
    if not path.exists():
        return []
    header, rows = _read_csv(path)
    missing = [name for name in IMPACT_FIELDS if name not in header]
    if missing:
        raise UserError(str(path), f"missing column{'s' if len(missing) > 1 else ''} "
                                   f"{', '.join(missing)}")
    return [_impact({name: row[header.index(name)] for name in IMPACT_FIELDS}, str(path), i + 2,
                    n_links) for i, row in enumerate(rows)]


def _impact(record, where: str, line, n_links: int) -> dict:
    """One impact record (CSV strings or JSON values) → typed dict; a damaged one (a missing
    field, a non-number, a link the scene does not have) is one UserError naming it."""
    key = f"{where}: impact {line}"
    record = schema.mapping(record, key)
    missing = [name for name in IMPACT_FIELDS if name not in record]
    if missing:
        raise UserError(key, f"missing {', '.join(missing)}")

    def number(name):
        value = record[name]
        if isinstance(value, str):   # a CSV cell
            try:
                value = float(value)
            except ValueError:
                raise UserError(f"{key}.{name}", f"expected a number, got {schema.short(value)}") \
                    from None
        return schema.number(value, f"{key}.{name}")

    link = record["link"]
    if isinstance(link, str) and link.strip().isdigit() and len(link) <= schema.MAX_INT_DIGITS:
        link = int(link)
    resting = record["resting"]
    if isinstance(resting, str):
        resting = resting.strip().lower() in ("true", "1", "yes")
    impact = {"time": number("time"), "link": schema.integer(link, f"{key}.link", lo=1, hi=n_links),
              "stop": record["stop"], "ld_before": number("ld_before"),
              "ld_after": number("ld_after"), "energy_lost": number("energy_lost"),
              "resting": schema.flag(resting, f"{key}.resting")}
    if impact["stop"] not in ("lower", "upper"):
        raise UserError(f"{key}.stop", f"expected lower or upper, got {schema.short(impact['stop'])}")
    return impact


def load_bag(path, scene_path=None) -> Run:
    """A recorded bag: /joint_states and /odom sampled at the /joint_states stamps; the scene
    from ``--scene`` or the ``scene.yaml`` attachment; impacts from ``impacts.json``."""
    from rclpy.serialization import deserialize_message  # only bags need ROS message types
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import JointState

    from .recording.bag_reader import open_bag

    path = Path(path)
    bag = open_bag(path)
    topics = bag.topics()
    for topic in (JOINT_STATES, ODOM):
        if topic not in topics:
            raise UserError(str(path), f"no {topic} topic in the bag (has: "
                                       f"{', '.join(sorted(topics)) or 'no topics'})")
    attachments = bag.attachments()
    if scene_path is not None:
        scene = load_scene(scene_path)
    elif "scene.yaml" in attachments:
        try:
            text = attachments["scene.yaml"].decode("utf-8")
        except UnicodeDecodeError as error:
            raise UserError(f"{path}: scene.yaml", f"not UTF-8 text (byte {error.start})") from None
        scene = scene_from_text(text, f"{path}: scene.yaml")
    else:
        raise UserError(str(path), "no scene.yaml attachment (not recorded by mobile_manip_sim?); "
                                   "pass the run's scene with --scene")
    names = scene.robot.joint_names()

    def decode(message, message_type):
        try:
            return deserialize_message(message.data, message_type)
        except Exception as error:  # rclpy raises bare exceptions on bad CDR
            raise UserError(str(path), f"{message.topic}: undecodable message at "
                                       f"{message.log_time_ns} ns ({error})") from None

    joint_ns, joint_log, positions, velocities, efforts = [], [], [], [], []
    for message in bag.messages([JOINT_STATES]):
        state = decode(message, JointState)
        index = {name: i for i, name in enumerate(state.name)}
        absent = [name for name in names if name not in index]
        if absent:
            plural = "s" if len(absent) > 1 else ""
            raise UserError(str(path), f"{JOINT_STATES} lacks joint{plural} "
                                       f"{', '.join(absent)} of scene {scene.name!r}")
        order = [index[name] for name in names]
        position, velocity = list(state.position), list(state.velocity)
        if len(position) != len(state.name) or len(velocity) != len(state.name):
            raise UserError(str(path), f"{JOINT_STATES}: a message without position or velocity "
                                       "for every joint")
        joint_ns.append(state.header.stamp.sec * NS + state.header.stamp.nanosec)
        joint_log.append(message.log_time_ns)
        positions.append([position[i] for i in order])
        velocities.append([velocity[i] for i in order])
        effort = list(state.effort)
        efforts.append([effort[i] for i in order] if len(effort) == len(state.name) else None)
    if not joint_ns:
        raise UserError(str(path), f"no messages on {JOINT_STATES}")

    odom_t, odom = [], []
    for message in bag.messages([ODOM]):
        odometry = decode(message, Odometry)
        pose, twist = odometry.pose.pose, odometry.twist.twist
        o = pose.orientation
        yaw = math.atan2(2.0 * (o.w * o.z + o.x * o.y), 1.0 - 2.0 * (o.y * o.y + o.z * o.z))
        odom_t.append(odometry.header.stamp.sec + 1e-9 * odometry.header.stamp.nanosec)
        odom.append([pose.position.x, pose.position.y, yaw, twist.linear.x, twist.linear.y,
                     twist.angular.z])
    if not odom_t:
        raise UserError(str(path), f"no messages on {ODOM}")

    sample_ns = _sample_ns(np.array(joint_ns), np.array(joint_log))
    t = sample_ns * 1e-9
    joints_q, joints_u = np.array(positions), np.array(velocities)
    odom = np.array(odom)
    order = np.argsort(odom_t, kind="stable")
    odom_t, odom = np.array(odom_t)[order], odom[order]
    odom[:, 2] = np.unwrap(odom[:, 2])
    x, y, yaw, v, v_lateral, omega = (np.interp(t, odom_t, odom[:, k]) for k in range(6))

    q = np.column_stack([x, y, yaw, joints_q])
    u = np.column_stack([v, omega, joints_u[:, 2:]])
    # Rates as recorded: the base's world velocity from its body twist, the wheels' own speeds.
    cos, sin = np.cos(yaw), np.sin(yaw)
    qdot = np.column_stack([v * cos - v_lateral * sin, v * sin + v_lateral * cos, omega,
                            joints_u])

    effort_values, effort_source = _bag_efforts(bag, efforts, sample_ns, scene, decode, topics)
    dynamics = dynamics_of(scene)
    energy = np.array([sum(dynamics.energy(q_k, u_k)) for q_k, u_k in zip(q, u)])
    impacts = []
    if "impacts.json" in attachments:
        where = f"{path}: impacts.json"
        records = schema.sequence(schema.load_json(attachments["impacts.json"], where), where)
        impacts = [_impact(record, where, i + 1, scene.robot.n_links)
                   for i, record in enumerate(records)]
    return Run(source=path, kind="bag", scene=scene, t=t, q=q, u=u, qdot=qdot, energy=energy,
               efforts=effort_values, effort_source=effort_source, impacts=impacts)


def _sample_ns(stamps: np.ndarray, log_ns: np.ndarray) -> np.ndarray:
    """Simulated time (ns) of each /joint_states sample: its header stamp (the simulator stamps
    with simulated time), or the log time when the publisher left stamps empty."""
    if np.all(stamps == 0):
        return log_ns - log_ns[0]
    return stamps


def _bag_efforts(bag, joint_efforts, sample_ns, scene, decode, topics):
    """Efforts over each sample interval (t_k, t_{k+1}). From the recorded commands, where the
    bag has them: as applied, each held from the segment start it is stamped with (the time
    line's rule), so the one that applies over interval k is the latest stamped ≤ t_k. A
    velocity-mode bag has cmd_vel instead of wheel torques: the wheel-speed loop's torques vary
    within a segment, so the wheels take the mean of the torques at both ends (`_loop_torques`).
    Without commands: /joint_states' effort field (the efforts of the segment that
    ENDED at each stamp: row k is then taken from sample k + 1); else the scene's efforts."""
    from std_msgs.msg import Float64MultiArray

    recorded = [topic for topic in (WHEEL_COMMANDS, ARM_COMMANDS) if topic in topics]
    complete = all(effort is not None for effort in joint_efforts)
    held = np.tile(scene_efforts(scene), (len(sample_ns), 1))
    if not recorded:
        if not complete:
            return held, "the scene's constant efforts (none recorded)"
        ended = np.array(joint_efforts, dtype=float)
        return np.vstack([ended[1:], ended[-1:]]), f"{JOINT_STATES} effort"
    columns = {WHEEL_COMMANDS: slice(0, 2), ARM_COMMANDS: slice(2, held.shape[1])}
    for topic in recorded:
        history = CommandHistory()
        target = columns[topic]
        width = target.stop - target.start
        for message in bag.messages([topic]):
            values = list(decode(message, Float64MultiArray).data)
            if len(values) != width:
                raise UserError(topic, f"command of {len(values)} values, expected {width}")
            try:
                history.add(message.log_time_ns, values)
            except ValueError as error:
                raise UserError(topic, str(error)) from None
        for k, stamp in enumerate(sample_ns):
            values = history.at(int(stamp))
            if values is not None:
                held[k, target] = values
    sources = list(recorded)
    if CMD_VEL in topics and WHEEL_COMMANDS not in topics and complete:
        held[:, :2] = _loop_torques(bag, np.array(joint_efforts, dtype=float)[:, :2], sample_ns,
                                    scene, decode)
        sources.insert(0, f"{JOINT_STATES} wheel torques")
    return held, " and ".join(sources)


def _loop_torques(bag, torques: np.ndarray, sample_ns, scene, decode) -> np.ndarray:
    """(N, 2) mean wheel torque of the speed loop over each interval: /joint_states carries
    the torque at the END of the segment that ended at each stamp (before the next cmd_vel
    applies); at a segment start the loop's proportional term jumps by kp times the change of
    the wheel-speed targets (the integral term is continuous), which the recorded cmd_vel and
    the bag's ``wheel_speed_kp`` give. Saturation at the effort limits is not modelled."""
    from geometry_msgs.msg import Twist

    from .messages import command_values

    kp = float(bag.metadata().get("mobile_manip_sim", {}).get("wheel_speed_kp", 0.0))
    base = scene.robot.base
    history = CommandHistory((message.log_time_ns,
                              command_values(CMD_VEL, decode(message, Twist)))
                             for message in bag.messages([CMD_VEL]))
    targets = np.zeros((len(sample_ns), 2))
    for k, stamp in enumerate(sample_ns):
        command = history.at(int(stamp))
        if command is not None:
            v, omega = command
            targets[k] = [(v + base.half_track * omega) / base.wheel_radius,
                          (v - base.half_track * omega) / base.wheel_radius]
    start = torques + kp * np.diff(targets, axis=0, prepend=0.0)
    return 0.5 * (start + np.vstack([torques[1:], torques[-1:]]))


# --- quantities derived from a run ------------------------------------------------------------

def residuals(run: Run) -> np.ndarray:
    """(N, 2) docs/model.md's constraint residuals (no skid, no slip) at each sample, m/s."""
    return np.array([constraint_residuals(run.scene.robot, q_k, qdot_k)
                     for q_k, qdot_k in zip(run.q, run.qdot)])


def tip_path(run: Run) -> np.ndarray:
    """(N, 3) world position of the distal end of the last rod."""
    dynamics = dynamics_of(run.scene)
    return np.array([dynamics.tip_position(q_k) for q_k in run.q])


def joint_rates(run: Run) -> np.ndarray:
    """(N, 2 + 2n) rates conjugate to the efforts: θ̇_R, θ̇_L, q̇_1, l̇_1, …"""
    return np.column_stack([run.qdot[:, 3:5], run.u[:, 2:]])


def work(run: Run) -> np.ndarray:
    """(N,) work W(t) of efforts and damping since the first sample (J); see the module doc.

    Over each sample interval the efforts are held and the rates are linear (trapezoid rule).
    An interval that contains impacts is split at them: the rates jump there, so the trapezoid
    runs from the left sample to the first impact with the rates extrapolated from the left,
    and from the last impact to the right sample with the rates extrapolated from the right
    (between two impacts in one interval nothing is counted).
    """
    t, rates = run.t, joint_rates(run)
    efforts = run.efforts if run.efforts is not None else np.zeros_like(rates)
    c = damping_coefficients(run)
    impact_times = np.array(sorted(impact["time"] for impact in run.impacts))

    def impacts_in(k):  # impact times in (t_k, t_{k+1}]
        if k < 0 or k + 1 >= len(t):
            return impact_times[:0]
        return impact_times[(impact_times > t[k]) & (impact_times <= t[k + 1])]

    def segment(effort, t0, r0, t1, r1):  # ∫ effort·r − c·r² dt, r linear from r0 to r1
        mean = 0.5 * (r0 + r1)
        damping = 0.5 * ((r0 ** 2) @ c + (r1 ** 2) @ c)
        return (effort @ mean - damping) * (t1 - t0)

    def extrapolate(k_near, k_far, t_star):  # linear from two samples on the same side
        if 0 <= k_far < len(t) and len(impacts_in(min(k_near, k_far))) == 0 \
                and t[k_far] != t[k_near]:
            slope = (rates[k_near] - rates[k_far]) / (t[k_near] - t[k_far])
            return rates[k_near] + slope * (t_star - t[k_near])
        return rates[k_near]

    increments = np.empty(max(len(t) - 1, 0))
    for k in range(len(t) - 1):
        inside = impacts_in(k)
        if len(inside) == 0:
            increments[k] = segment(efforts[k], t[k], rates[k], t[k + 1], rates[k + 1])
            continue
        first, last = inside[0], inside[-1]
        increments[k] = (segment(efforts[k], t[k], rates[k], first, extrapolate(k, k - 1, first))
                         + segment(efforts[k], last, extrapolate(k + 1, k + 2, last),
                                   t[k + 1], rates[k + 1]))
    return np.concatenate([[0.0], np.cumsum(increments)])


def damping_coefficients(run: Run) -> np.ndarray:
    """(2 + 2n,) viscous coefficients on (θ̇_R, θ̇_L, q̇_1, l̇_1, …): torque or force −c·rate."""
    c = effect_settings(run.scene).rate_damping
    return np.zeros(2 + 2 * run.n_links) if c is None else c


def impact_losses(run: Run) -> np.ndarray:
    """(N,) kinetic energy lost in impacts after the first sample and up to each sample (J)."""
    losses = np.zeros_like(run.t)
    for impact in run.impacts:
        if impact["time"] > run.t[0]:
            losses[run.t >= impact["time"]] += impact["energy_lost"]
    return losses


# --- figures ----------------------------------------------------------------------------------

def _figure(run: Run, what: str) -> tuple[Figure, object]:
    figure = Figure(figsize=FIGURE_SIZE, dpi=DPI, layout="constrained")
    figure.suptitle(f"{run.scene.name}: {what}")
    return figure, figure.add_subplot()


def _no_arm(axes) -> None:
    axes.text(0.5, 0.5, "no arm links in this scene", ha="center", va="center",
              transform=axes.transAxes)


def _color(i: int) -> str:
    return f"C{i % 10}"


def _arm_series(run: Run, what: str, column: Callable[[int], np.ndarray], symbol: str,
                joint: Callable[[int], str], unit: str, quantity: str) -> tuple[Figure, object]:
    """One curve per link of ``column(i)`` (i = 0 … n−1) against time."""
    figure, axes = _figure(run, what)
    names = run.joint_names()
    for i in range(run.n_links):
        axes.plot(run.t, column(i), color=_color(i),
                  label=f"${symbol}_{{{i + 1}}}$  ({names[joint(i)]})")
    axes.set_xlabel("t (s)")
    axes.set_ylabel(f"{quantity} ({unit})")
    if run.n_links:
        axes.legend(loc="best")
    else:
        _no_arm(axes)
    axes.grid(True, alpha=0.3)
    return figure, axes


def figure_joint_angles(run: Run) -> Figure:
    """q_i(t): one curve per link."""
    return _arm_series(run, "joint angles", lambda i: run.q[:, 5 + 2 * i], "q",
                       lambda i: 2 + 2 * i, "rad", "joint angle")[0]


def figure_joint_rates(run: Run) -> Figure:
    """q̇_i(t): one curve per link."""
    return _arm_series(run, "joint rates", lambda i: run.u[:, 2 + 2 * i], r"\dot q",
                       lambda i: 2 + 2 * i, "rad/s", "joint rate")[0]


def figure_extensions(run: Run) -> Figure:
    """l_i(t): one curve per link, its two stroke ends dashed, each impacted link's impacts
    marked at their stop (one marker series per link with impacts)."""
    figure, axes = _arm_series(run, "rod extensions", lambda i: run.q[:, 6 + 2 * i], "l",
                               lambda i: 3 + 2 * i, "m", "rod extension")
    for i, (low, high) in enumerate(run.scene.robot.stroke):
        for end, value in (("min", low), ("max", high)):
            axes.axhline(value, color=_color(i), linestyle="--", linewidth=0.9,
                         label=f"stroke of $l_{{{i + 1}}}$" if end == "min" else None)
    for link, impacts in _impacts_by_link(run).items():
        stroke = run.scene.robot.stroke[link - 1]
        axes.plot([impact["time"] for impact in impacts],
                  [stroke[0] if impact["stop"] == "lower" else stroke[1] for impact in impacts],
                  linestyle="none", marker="X", markersize=9, color=_color(link - 1),
                  markeredgecolor="black", label=f"impact of rod {link}")
    if run.n_links:
        axes.legend(loc="best", fontsize="small")
    return figure


def figure_extension_rates(run: Run) -> Figure:
    """l̇_i(t): one curve per link, and per impacted link its approach speeds l̇⁻ at the impacts."""
    figure, axes = _arm_series(run, "extension rates", lambda i: run.u[:, 3 + 2 * i], r"\dot l",
                               lambda i: 3 + 2 * i, "m/s", "extension rate")
    for link, impacts in _impacts_by_link(run).items():
        axes.plot([impact["time"] for impact in impacts],
                  [impact["ld_before"] for impact in impacts], linestyle="none", marker="o",
                  markerfacecolor="none", markersize=8, color=_color(link - 1),
                  label=f"rod {link} just before impact")
    if run.n_links:
        axes.legend(loc="best", fontsize="small")
    return figure


def _impacts_by_link(run: Run) -> dict[int, list[dict]]:
    by_link: dict[int, list[dict]] = {}
    for impact in run.impacts:
        by_link.setdefault(impact["link"], []).append(impact)
    return dict(sorted(by_link.items()))


def figure_base_path(run: Run) -> Figure:
    """The base's path (point A) in the x–y plane with heading arrows, the ground projection
    of the last rod's tip (when there is an arm), and where each starts. Equal aspect."""
    figure, axes = _figure(run, "path in the plane")
    x, y, yaw = run.q[:, 0], run.q[:, 1], run.q[:, 2]
    axes.plot(x, y, color="C0", label="base (axle midpoint A)")
    paths = [np.column_stack([x, y])]
    if run.n_links:
        tip = tip_path(run)[:, :2]
        axes.plot(tip[:, 0], tip[:, 1], color="C3",
                  label=f"tip of rod {run.n_links} (ground projection)")
        paths.append(tip)
    starts = np.array([path[0] for path in paths])
    axes.plot(starts[:, 0], starts[:, 1], linestyle="none", marker="o", markersize=6,
              color="black", markerfacecolor="white", label=f"start (t = {run.t[0]:.3g} s)")
    points = np.vstack(paths)
    extent = max(float(np.ptp(points[:, 0])), float(np.ptp(points[:, 1])), 0.05)
    marks = heading_marks(x, y)
    length = 0.07 * extent
    axes.quiver(x[marks], y[marks], length * np.cos(yaw[marks]), length * np.sin(yaw[marks]),
                angles="xy", scale_units="xy", scale=1.0, color="C0", width=0.003,
                label="heading")
    axes.set_xlabel("x (m)")
    axes.set_ylabel("y (m)")
    axes.set_aspect("equal", adjustable="datalim")
    axes.legend(loc="best", fontsize="small")
    axes.grid(True, alpha=0.3)
    return figure


def heading_marks(x: np.ndarray, y: np.ndarray, count: int = HEADING_MARKS) -> np.ndarray:
    """Indices of about ``count`` samples evenly spaced along the path (by arc length, so a
    slow start does not crowd them; by sample when the base hardly moves), first included."""
    step = np.hypot(np.diff(x), np.diff(y))
    arc = np.concatenate([[0.0], np.cumsum(step)])
    if arc[-1] < 1e-9:
        return np.arange(0, len(x), max(1, len(x) // count))
    targets = np.linspace(0.0, arc[-1], count + 1)[:-1]
    return np.unique(np.searchsorted(arc, targets))


def figure_constraints(run: Run) -> Figure:
    """|no-skid| and |no-slip| residuals (docs/model.md) on a log scale, floored at 1e-17."""
    figure, axes = _figure(run, "nonholonomic constraints")
    values = np.maximum(np.abs(residuals(run)), RESIDUAL_FLOOR)
    axes.semilogy(run.t, values[:, 0], color="C0",
                  label=r"no skid: $|\dot x \sin\psi - \dot y \cos\psi|$")
    axes.semilogy(run.t, values[:, 1], color="C1",
                  label=r"no slip: $|\dot x \cos\psi + \dot y \sin\psi"
                        r" - r(\dot\theta_R + \dot\theta_L)/2|$")
    axes.set_ylim(RESIDUAL_FLOOR / 3, max(1e-12, float(values.max()) * 30))
    axes.set_xlabel("t (s)")
    axes.set_ylabel(f"|residual| (m/s), floor {RESIDUAL_FLOOR:g}")
    axes.legend(loc="best", fontsize="small")
    axes.grid(True, which="major", alpha=0.3)
    source = ("rates from u through the constraints" if run.kind == "csv"
              else "recorded odometry twist and wheel velocities")
    axes.set_title(source, fontsize="small")
    return figure


def figure_energy(run: Run) -> Figure:
    """Top: T + V − E₀, the work W of efforts and damping, the impact losses L.
    Bottom: the balance (T + V − E₀) − W + L, zero for exact physics."""
    figure = Figure(figsize=(FIGURE_SIZE[0], FIGURE_SIZE[1] * 1.3), dpi=DPI, layout="constrained")
    figure.suptitle(f"{run.scene.name}: energy balance")
    top, bottom = figure.subplots(2, 1, sharex=True, height_ratios=[2, 1])
    change = run.energy - run.energy[0]
    W, L = work(run), impact_losses(run)
    top.plot(run.t, change, color="C0", label=r"$T + V - E_0$")
    work_label = "W: work of efforts" + (" and damping" if _damped(run) else "")
    top.plot(run.t, W, color="C1", label=work_label)
    top.plot(run.t, L, color="C2", label="L: lost in impacts")
    top.set_ylabel("energy (J)")
    top.legend(loc="best", fontsize="small")
    top.grid(True, alpha=0.3)
    top.set_title(f"efforts: {run.effort_source}; W by the trapezoid rule at the sample "
                  "rate, split at impacts", fontsize="small")
    bottom.plot(run.t, change - W + L, color="C3", label=r"$T + V - E_0 - W + L$")
    bottom.set_xlabel("t (s)")
    bottom.set_ylabel("balance (J)")
    bottom.legend(loc="best", fontsize="small")
    bottom.grid(True, alpha=0.3)
    return figure


def _damped(run: Run) -> bool:
    return effect_settings(run.scene).rate_damping is not None


# name → (function, caption); the PNG is <name>.png
FIGURES: dict[str, tuple[Callable[[Run], Figure], str]] = {
    "joint_angles": (figure_joint_angles, "Joint angles q_i(t)."),
    "joint_rates": (figure_joint_rates, "Joint rates q̇_i(t)."),
    "extensions": (figure_extensions, "Rod extensions l_i(t); dashed: the stroke ends; "
                                      "crosses: end-stop impacts."),
    "extension_rates": (figure_extension_rates, "Extension rates l̇_i(t); circles: the "
                                                "approach speed just before each impact."),
    "base_path": (figure_base_path, "The base's path in the plane with heading arrows, and "
                                    "the last rod's tip projected on the ground."),
    "constraints": (figure_constraints, "The two nonholonomic constraint residuals "
                                        "(|value|, floored at 1e-17 so exact zeros show)."),
    "energy": (figure_energy, "Energy balance: T + V − E₀ − W + L is zero for exact physics; "
                              "W is rebuilt from the samples (trapezoid rule), so it is "
                              "approximate at the sample rate."),
}


def make_figures(run: Run) -> dict[str, Figure]:
    return {name: function(run) for name, (function, _) in FIGURES.items()}


def write_figures(run: Run, figures: dict[str, Figure], out_dir) -> list[Path]:
    """Save each figure as ``<name>.png`` in out_dir, and an ``index.html`` showing them."""
    out_dir = Path(out_dir)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        paths = []
        for name, figure in figures.items():
            path = out_dir / f"{name}.png"
            figure.savefig(path)
            paths.append(path)
        (out_dir / "index.html").write_text(_index_html(run, figures), encoding="utf-8")
    except OSError as error:
        raise UserError(str(out_dir), f"cannot write ({error.strerror or error})") from None
    return paths


def _index_html(run: Run, figures: dict[str, Figure]) -> str:
    title = html.escape(f"{run.scene.name}: {run.source.name}")
    items = "\n".join(
        f'<figure id="{name}"><img src="{name}.png" alt="{html.escape(FIGURES[name][1])}">'
        f"<figcaption>{html.escape(FIGURES[name][1])}</figcaption></figure>"
        for name in figures)
    impacts = len(run.impacts)
    return f"""<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<title>{title}</title>
<style>
body {{ font-family: sans-serif; margin: 1.5em; }}
figure {{ display: inline-block; margin: 0 1em 1.5em 0; vertical-align: top; }}
img {{ max-width: 100%; width: 760px; border: 1px solid #ddd; }}
figcaption {{ max-width: 760px; font-size: 0.9em; color: #333; }}
</style>
</head>
<body>
<h1>{title}</h1>
<p>{html.escape(run.kind)} run, {len(run.t)} samples from t = {run.t[0]:.6g} s to
{run.t[-1]:.6g} s, {run.n_links} links, {impacts} end-stop impact{'' if impacts == 1 else 's'};
efforts: {html.escape(run.effort_source)}.</p>
{items}
</body>
</html>
"""


def plot(run_path, out_dir, scene_path=None) -> dict[str, Figure]:
    """Load a run, draw every figure, write the PNGs and index.html; returns the figures."""
    run = load_run(run_path, scene_path)
    figures = make_figures(run)
    write_figures(run, figures, out_dir)
    return figures


def _main(argv) -> int:
    parser = cli.ArgumentParser(prog="plot", description=__doc__.split("\n\n")[0])
    parser.add_argument("run", metavar="RUN",
                        help="a CSV from simulate, a bag directory or an .mcap file")
    parser.add_argument("--out", required=True, metavar="DIR", help="directory for the figures")
    parser.add_argument("--scene", metavar="FILE",
                        help="the run's scene (default: a bag's own, or the embedded paper scene)")
    args = parser.parse_args(argv)
    figures = plot(args.run, args.out, args.scene)
    print(f"wrote {len(figures)} figures and index.html to {args.out}")
    return 0


def main(argv=None) -> int:
    return cli.run(_main, argv)


if __name__ == "__main__":
    raise SystemExit(main())
