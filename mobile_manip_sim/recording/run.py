"""A recorded run as the plots and the browser view see it: the `Run` table, and one loader per
input kind — a CSV written by `simulate` (`load_csv`; its impacts beside it in
``RUN.impacts.csv``) or a recorded bag (`load_bag`, through `bag_format`) — producing the same
table.
"""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..dynamics import Dynamics
from ..ros.topics import ARM_TOPIC as ARM_COMMANDS
from ..ros.topics import CMD_VEL_TOPIC as CMD_VEL
from ..ros.topics import JOINT_STATES_TOPIC as JOINT_STATES
from ..ros.topics import ODOM_TOPIC as ODOM
from ..ros.topics import WHEEL_TOPIC as WHEEL_COMMANDS
from ..runtime.headless import csv_columns
from ..scene import schema
from ..scene.coordinates import ARM_U
from ..scene.effects import settings as effect_settings
from ..scene.errors import UserError
from ..scene.loading import Scene, load_scene
from . import bag_format
from .bag_format import IMPACT_FIELDS, impact_record


@dataclass
class Run:
    """One run, sampled: what every figure is drawn from (SI units, docs/model.md's vectors).

    ``q`` (N, n_q) and ``u`` (N, n_u) as in docs/model.md; ``qdot`` (N, n_q) the configuration rates
    (from a CSV: computed from ``u`` through the constraints; from a bag: as recorded — odometry
    twist and wheel velocities); ``energy`` T + V (J); ``efforts`` (N, 2 + 2n) the efforts in
    /joint_states order (τ_R, τ_L, τ_1, F_1, …; N·m or N) acting from each sample to the next
    (row k: over (t_k, t_{k+1})), or None when unknown; ``impacts`` the end-stop impacts as dicts
    (time, link, stop, ld_before, ld_after, energy_lost, resting).
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
    return effect_settings(scene).saturate(np.concatenate([scene.wheel_efforts,
                                                           scene.joint_efforts]))


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
    qdot = np.array([dynamics.configuration_rate(q_k, u_k) for q_k, u_k in zip(q, u, strict=True)])
    efforts = np.tile(scene_efforts(scene), (len(q), 1))
    return Run(source=path, kind="csv", scene=scene, t=columns["t"], q=q, u=u, qdot=qdot,
               energy=columns["energy"], efforts=efforts,
               effort_source="the scene's constant efforts",
               impacts=_read_impacts_csv(path, scene.robot.n_links))


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
    return [impact_record({name: row[header.index(name)] for name in IMPACT_FIELDS}, str(path),
                          i + 2, n_links) for i, row in enumerate(rows)]


def load_bag(path, scene_path=None) -> Run:
    """A recorded bag: /joint_states and /odom sampled at the /joint_states stamps; the scene
    from ``--scene`` or the ``scene.yaml`` attachment; impacts from ``impacts.json``."""
    from .bag_reader import open_bag  # mcap: only bags need it

    path = Path(path)
    bag = open_bag(path)
    topics = bag.topics()
    for topic in (JOINT_STATES, ODOM):
        if topic not in topics:
            raise UserError(str(path), f"no {topic} topic in the bag (has: "
                                       f"{_names(sorted(topics)) or 'no topics'})")
    scene = load_scene(scene_path) if scene_path is not None else bag_format.read_scene(bag)
    if scene is None:
        raise UserError(str(path), "no scene.yaml attachment (not recorded by mobile_manip_sim?); "
                                   "pass the run's scene with --scene")
    joint_ns, joint_log, positions, velocities, efforts = bag_format.read_joint_states(
        bag, scene.robot.joint_names(), scene.name)
    if not joint_ns:
        raise UserError(str(path), f"no messages on {JOINT_STATES}")
    odom_ns, odom_rows = bag_format.read_odometry(bag)
    if not odom_ns:
        raise UserError(str(path), f"no messages on {ODOM}")
    odom = []
    for x, y, o, v, v_lateral, omega in odom_rows:
        yaw = math.atan2(2.0 * (o.w * o.z + o.x * o.y), 1.0 - 2.0 * (o.y * o.y + o.z * o.z))
        odom.append([x, y, yaw, v, v_lateral, omega])

    sample_ns = _sample_ns(np.array(joint_ns), np.array(joint_log))
    t = sample_ns * 1e-9
    joints_q, joints_u = np.array(positions), np.array(velocities)
    odom = np.array(odom)
    order = np.argsort(odom_ns, kind="stable")
    odom_t, odom = np.array(odom_ns)[order] * 1e-9, odom[order]
    odom[:, 2] = np.unwrap(odom[:, 2])
    x, y, yaw, v, v_lateral, omega = (np.interp(t, odom_t, odom[:, k]) for k in range(6))

    q = np.column_stack([x, y, yaw, joints_q])
    u = np.column_stack([v, omega, joints_u[:, ARM_U]])   # the arm's joints are indexed as u
    # Rates as recorded: the base's world velocity from its body twist, the wheels' own speeds.
    cos, sin = np.cos(yaw), np.sin(yaw)
    qdot = np.column_stack([v * cos - v_lateral * sin, v * sin + v_lateral * cos, omega,
                            joints_u])

    effort_values, effort_source = _bag_efforts(bag, efforts, sample_ns, scene, topics)
    dynamics = dynamics_of(scene)
    energy = np.array([sum(dynamics.energy(q_k, u_k)) for q_k, u_k in zip(q, u, strict=True)])
    impacts = bag_format.read_impacts(bag, scene.robot.n_links)
    return Run(source=path, kind="bag", scene=scene, t=t, q=q, u=u, qdot=qdot, energy=energy,
               efforts=effort_values, effort_source=effort_source, impacts=impacts)


def _sample_ns(stamps: np.ndarray, log_ns: np.ndarray) -> np.ndarray:
    """Simulated time (ns) of each /joint_states sample: its header stamp (the simulator stamps
    with simulated time), or the log time when the publisher left stamps empty."""
    if np.all(stamps == 0):
        return log_ns - log_ns[0]
    return stamps


def _names(names: list[str], most: int = 10) -> str:
    """A bag's topic names as they can stand in one line: each `schema.label`led (an escape
    sequence or a newline in a name is shown, not sent to the terminal), at most `most`."""
    shown = ", ".join(schema.label(name, 80) for name in names[:most])
    return shown + (f" and {len(names) - most} more" if len(names) > most else "")


def _bag_efforts(bag, joint_efforts, sample_ns, scene, topics):
    """Efforts over each sample interval (t_k, t_{k+1}). From the recorded commands, where the
    bag has them: as applied, each held from the segment start it is stamped with (the time
    line's rule), so the one that applies over interval k is the latest stamped ≤ t_k. A
    velocity-mode bag has cmd_vel instead of wheel torques: the wheel-speed loop's torques vary
    within a segment, so the wheels take the mean of the torques at both ends (`_loop_torques`).
    Without commands: /joint_states' effort field (the efforts of the segment that
    ENDED at each stamp: row k is then taken from sample k + 1); else the scene's efforts."""
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
        target = columns[topic]
        history = bag_format.read_commands(bag, topic, target.stop - target.start)
        for k, stamp in enumerate(sample_ns):
            values = history.at(int(stamp))
            if values is not None:
                held[k, target] = values
    sources = list(recorded)
    if CMD_VEL in topics and WHEEL_COMMANDS not in topics and complete:
        held[:, :2] = _loop_torques(bag, np.array(joint_efforts, dtype=float)[:, :2], sample_ns,
                                    scene)
        sources.insert(0, f"{JOINT_STATES} wheel torques")
    return held, " and ".join(sources)


def _loop_torques(bag, torques: np.ndarray, sample_ns, scene) -> np.ndarray:
    """(N, 2) mean wheel torque of the speed loop over each interval: /joint_states carries
    the torque at the END of the segment that ended at each stamp (before the next cmd_vel
    applies); at a segment start the loop's proportional term jumps by kp times the change of
    the wheel-speed targets (the integral term is continuous), which the recorded cmd_vel and
    the bag's ``wheel_speed_kp`` give. Saturation at the effort limits is not modelled."""
    kp = float(bag.metadata().get(bag_format.METADATA_NAME, {}).get("wheel_speed_kp", 0.0))
    base = scene.robot.base
    history = bag_format.read_commands(bag, CMD_VEL, 2)
    targets = np.zeros((len(sample_ns), 2))
    for k, stamp in enumerate(sample_ns):
        command = history.at(int(stamp))
        if command is not None:
            v, omega = command
            targets[k] = [(v + base.half_track * omega) / base.wheel_radius,
                          (v - base.half_track * omega) / base.wheel_radius]
    start = torques + kp * np.diff(targets, axis=0, prepend=0.0)
    return 0.5 * (start + np.vstack([torques[1:], torques[-1:]]))
