"""The arm controller inside the simulated system (`engine/arm_control.py`, the commands of
`engine/arm_commands.py`): what it does (holds, settles, tracks), facts that cannot be tuned
(its feedforwards against Pinocchio's independent model, the arm following q̈_ref exactly under
computed torque, the energy balance with its work), and that effort mode is main's engine."""
import copy
import subprocess
from pathlib import Path

import numpy as np
import pytest

import robots
from executables import executable
from mobile_manip_sim.dynamics import Dynamics
from mobile_manip_sim.engine import layout
from mobile_manip_sim.engine.arm_control import default_controller, for_robot
from mobile_manip_sim.engine.simulation import Simulation
from mobile_manip_sim.engine.system import ARM_CONTROL_STAGE, RHS_EVALS
from mobile_manip_sim.scene.arm_controller import ArmController, ModelError
from mobile_manip_sim.scene.errors import UserError
from mobile_manip_sim.scene.loading import load_scene, make_integrator, parse_scene
from mobile_manip_sim.scene.methods import NAMES as METHOD_NAMES
from pinocchio_reference import build_projected_model

DATA = Path(__file__).resolve().parent / "data"
SETTLING_TIME = 0.5   # s: docs/controllers.md (0.43 s measured with rk4 at 1 kHz)
STEP = np.array([0.2, 0.1, -0.2, 0.1])   # rad, m, rad, m
ZERO_GAINS = dict(kp=0.0, ki=0.0, kd=0.0)


def paper_scene(method="rk4", **effects):
    """The paper robot at rest with no efforts (rk4 at 1 kHz unless told), plus `effects`; its
    controllers continuous (controller.rate 0: the law of engine/arm_control.py at every
    evaluation, which these tests check; the sampled controllers' are test_sampled_controllers)."""
    doc = copy.deepcopy(load_scene().document)
    doc["efforts"] = {"wheels": [0.0, 0.0], "joints": [0.0] * 4}
    doc["controller"] = {"rate": 0}
    doc["integrator"] = ({"method": "rk4", "dt": 1e-3} if method == "rk4"
                         else {"method": method, "rtol": 1e-10, "atol": 1e-12})
    doc["effects"].update(effects)
    return parse_scene(doc)


def paper(mode="position", method="rk4", effects=None, **control):
    return Simulation(paper_scene(method, **(effects or {})),
                      arm_controller=ArmController(mode, **control))


def arm(sim):
    return sim.q[layout.arm_q(0):].copy()


# --- effort mode: main's engine, no controller stage ------------------------------------------

@pytest.mark.parametrize("name, flags", [
    ("dop853", []),
    ("rk4", ["--method", "rk4", "--dt", "0.001"]),
    ("sie", ["--method", "semi_implicit_euler", "--dt", "0.001", "--set",
             "effects.joint_damping=0.1", "--set", "effects.effort_limits.joints=5"]),
])
def test_effort_mode_runs_are_bit_identical_to_main(tmp_path, name, flags):
    """test/engine/data/recorded_paper_*: `simulate` of the paper scene in effort mode, samples
    and impacts, byte for byte. Recorded before the arm controller existed, and again when the
    release watch inside steps came (its evaluations moved the last digits: 4e-14 at most).
    Regenerate them only for a change of the physics that is meant."""
    out = tmp_path / f"paper_{name}.csv"
    subprocess.run([executable("simulate"), *flags, "--out", str(out)], check=True,
                   capture_output=True, timeout=600)
    for suffix in (".csv", ".impacts.csv"):
        mine = out.with_name(f"paper_{name}{suffix}").read_bytes()
        assert mine == (DATA / f"recorded_paper_{name}{suffix}").read_bytes()


def test_effort_mode_has_no_controller_states_and_runs_no_controller_stage():
    sim = Simulation(paper_scene())
    assert not sim.arm_controller.active
    assert sim.s.size == layout.state_size(sim.nu)
    sim.advance_to(0.1)
    assert sim.system.counters[ARM_CONTROL_STAGE] == 0
    held = paper()
    assert held.s.size == layout.state_size(held.nu) + held.nu - 1   # z (n_arm) and τ
    held.advance_to(0.1)
    assert held.system.counters[ARM_CONTROL_STAGE] == held.system.counters[RHS_EVALS] > 0


# --- what it does ------------------------------------------------------------------------------

def test_position_mode_holds_the_arm_against_gravity_for_10_s():
    sim = paper()
    q0 = arm(sim)
    rows = sim.sample(np.arange(1, 1001) * 0.01)
    drift = np.abs(rows[:, layout.arm_q(0):layout.arm_q(0) + 4] - q0).max()
    assert drift <= 1e-3                      # rad or m (measured: about 1e-5)
    assert np.abs(sim.joint_efforts_applied()).max() > 1.0   # it does hold something up


def test_a_step_of_the_position_command_settles_within_2_percent():
    sim = paper()
    q0 = arm(sim)
    target = q0 + STEP
    sim.set_arm_positions(target)
    times = np.arange(1, 3001) * 1e-3
    rows = sim.sample(times)
    error = np.abs(rows[:, layout.arm_q(0):layout.arm_q(0) + 4] - target) / np.abs(STEP)
    outside = np.flatnonzero(error.max(axis=1) > 0.02)
    settled_at = times[outside[-1]] if outside.size else 0.0
    assert 0.1 < settled_at <= SETTLING_TIME


@pytest.mark.parametrize("method", ["rk4", "dop853"])
def test_with_the_arm_held_cmd_vel_tracks_within_1_percent_after_1_s(method):
    """The arm in position mode (defaults), cmd_vel 0.3 m/s, 0.5 rad/s through
    the wheel-speed loop at its default gains: within 1 % from 1 s to 4 s (measured: 1e-4)."""
    sim = paper(method=method)
    sim.set_base_velocity(0.3, 0.5)
    worst = 0.0
    for k in range(100, 401):
        sim.advance_to(k * 0.01)
        worst = max(worst, abs(sim.u[0] / 0.3 - 1.0), abs(sim.u[1] / 0.5 - 1.0))
    assert worst <= 0.01


@pytest.mark.parametrize("method", METHOD_NAMES)
def test_every_integrator_carries_the_controller(method):
    """The controller's states ride along with every method (fixed step, compiled adaptive,
    SciPy's radau and bdf): a step of the set-point under computed torque, 1 s later, is within
    2 % of the step, and the energy balance is within each method's order."""
    scene = paper_scene()
    settings = make_integrator(scene.integrator, method, dt=1e-3, rtol=1e-8, atol=1e-10)
    sim = Simulation(scene, settings, ArmController("position", feedforward="computed_torque"))
    target = arm(sim) + STEP
    sim.set_arm_positions(target)
    sim.advance_to(1.0)
    assert np.all(np.abs(arm(sim) - target) <= 0.02 * np.abs(STEP))
    assert abs(sim.energy_error()) < (0.1 if method in ("euler", "semi_implicit_euler") else 1e-5)


def tracking_error(feedforward, **gains):
    """RMS and max error (per joint) over 2 s of a 1 Hz sinusoid about the initial pose, sent
    as a trajectory with velocities and accelerations (quintic) every 10 ms."""
    sim = paper("joint_trajectory", feedforward=feedforward, **gains)
    q0, w = arm(sim), 2.0 * np.pi
    amplitude = np.array([0.2, 0.05, 0.3, 0.05])
    T = np.arange(1, 201) * 0.01
    sim.set_arm_trajectory(T, q0 + np.outer(np.sin(w * T), amplitude),
                           np.outer(w * np.cos(w * T), amplitude),
                           np.outer(-w * w * np.sin(w * T), amplitude))
    times = np.arange(1, 2001) * 1e-3
    rows = sim.sample(times)
    error = rows[:, layout.arm_q(0):layout.arm_q(0) + 4] - (q0 + np.outer(np.sin(w * times),
                                                                          amplitude))
    return np.sqrt(np.mean(error ** 2)), np.abs(error).max()


def test_computed_torque_tracks_a_1_hz_sinusoid_far_better_than_pid_alone():
    pid_rms, _ = tracking_error("none")
    ct_rms, _ = tracking_error("computed_torque")
    assert ct_rms <= 0.25 * pid_rms          # measured: ~1/300


# --- facts that cannot be tuned ------------------------------------------------------------------

def random_states(sim, count, seed):
    rng = np.random.default_rng(seed)
    for _ in range(count):
        q = np.array(sim.q) + rng.normal(0.0, 0.3, sim.nq)
        q[layout.arm_q(1)], q[layout.arm_q(3)] = rng.uniform(0.1, 0.9, 2)   # l_1, l_2
        yield q, rng.normal(0.0, 1.0, sim.nu)


def test_the_gravity_feedforward_is_pinocchios_gravity_vector():
    sim = paper(feedforward="gravity", **ZERO_GAINS)
    pin = build_projected_model(sim.model, gravity=10.0, tip_mass=0.0, wheel_inertia=True)
    for q, u in random_states(sim, 5, seed=1):
        sim.s[:sim.nq], sim.s[sim.nq:sim.nq + sim.nu] = q, u    # at any velocity: G(q)
        expected = pin.bias(q, np.zeros(sim.nu))[2:]
        assert np.allclose(sim.joint_efforts_applied(), expected, rtol=1e-10, atol=1e-10)


def test_the_gravity_feedforward_is_the_inverse_dynamics_at_rest_on_random_robots():
    """The controller's reduced gravity pass (ω = α = 0: every point accelerates by g ẑ) against
    the inverse dynamics at u = u̇ = 0, on robots with random joint orientations, rods,
    cross-sections and a payload, at random states and velocities (G depends on q alone)."""
    rng = np.random.default_rng(5)
    for n in (1, 3, 6):
        doc = robots.random_robot_document(rng, n, gravity=9.81)
        doc["effects"]["payload"] = 0.7
        doc["controller"] = {"rate": 0}
        sim = Simulation(parse_scene(doc), arm_controller=ArmController(
            "position", feedforward="gravity", **ZERO_GAINS))
        for _ in range(3):
            q, u = robots.random_state(rng, sim.model)
            sim.s[:sim.nq], sim.s[sim.nq:sim.nq + sim.nu] = q, u
            expected = sim.dynamics.inverse_dynamics(q, np.zeros(sim.nu), np.zeros(sim.nu))[2:]
            assert np.allclose(sim.joint_efforts_applied(), expected, rtol=1e-12, atol=1e-12)


def test_computed_torque_makes_the_arm_follow_the_reference_acceleration_exactly():
    """Zero PID gains: the feedforward alone gives the arm q̈_ref whatever the base does (its
    acceleration solved, not assumed), with wheel torques, damping and an accelerating
    reference; and it equals Pinocchio's M u̇* + h − Q_damp with u̇* from the base's rows."""
    damping = {"joint_damping": [0.3, 0.2, 0.1, 0.4], "wheel_damping": 0.05}
    sim = paper("joint_trajectory", feedforward="computed_torque", effects=damping, **ZERO_GAINS)
    pin = build_projected_model(sim.model, gravity=10.0, tip_mass=0.0, wheel_inertia=True)
    c = sim.effects.generalized_damping(sim.model.base)
    sim.set_efforts(wheels=[0.3, -0.1])
    for q, u in random_states(sim, 5, seed=2):
        sim.s[:sim.nq], sim.s[sim.nq:sim.nq + sim.nu] = q, u
        sim.set_arm_trajectory([0.5], [q[5:] + 0.3], [np.ones(4)], [np.full(4, 2.0)])
        sim.s[layout.reference_clock(sim.nq, sim.nu)] = 0.2   # inside the quintic
        qdd_ref = sim.arm_reference()[2]
        assert np.abs(qdd_ref).max() > 1.0
        ud = sim.acceleration()
        assert np.allclose(ud[2:], qdd_ref, rtol=1e-9, atol=1e-9)
        M, h = pin.mass_matrix(q), pin.bias(q, u)
        Q_base = np.array(sim.system.Q_cmd[:2]) - c[:2] * u[:2]
        base = np.linalg.solve(M[:2, :2], Q_base - h[:2] - M[:2, 2:] @ qdd_ref)
        expected = M[2:, :2] @ base + M[2:, 2:] @ qdd_ref + h[2:] + c[2:] * u[2:]
        assert np.allclose(sim.joint_efforts_applied(), expected, rtol=1e-9, atol=1e-9)
        assert np.allclose(ud[:2], base, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("effects, locked", [({"fixed_base": True}, [0, 1]),
                                             ({"locked_joints": ["arm_revolute_2"]}, [4]),
                                             ({"effort_limits": {"wheels": 0.01}}, [])])
def test_computed_torque_is_exact_with_locked_pseudo_velocities(effects, locked):
    """A fixed base (u̇_b = 0) or a locked arm joint (u̇ = 0): the free arm joints still get
    exactly q̈_ref from the feedforward alone (zero gains), while wheel torques act."""
    sim = paper("joint_trajectory", feedforward="computed_torque", effects=effects, **ZERO_GAINS)
    sim.set_efforts(wheels=[0.3, -0.1])
    sim.set_arm_trajectory([0.5], [arm(sim) + STEP], [np.ones(4)], [np.full(4, 2.0)])
    sim.s[layout.reference_clock(sim.nq, sim.nu)] = 0.2
    sim.s[sim.nq:sim.nq + sim.nu] = np.where(np.isin(np.arange(sim.nu), locked), 0.0, 0.4)
    ud, qdd_ref = sim.acceleration(), sim.arm_reference()[2]
    free = [j for j in range(4) if 2 + j not in locked]
    assert np.allclose(ud[2:][free], qdd_ref[free], rtol=1e-9, atol=1e-9)
    assert np.all(ud[locked] == 0.0)


@pytest.mark.parametrize("feedforward", ["none", "gravity", "computed_torque"])
def test_the_energy_balance_holds_with_the_controller_working(feedforward):
    """T + V − W = const with W the work of the controller's efforts (and a wheel torque):
    dop853 at rtol 1e-10 through a step, a trajectory and a hold."""
    sim = paper("joint_trajectory", method="dop853", feedforward=feedforward)
    sim.set_efforts(wheels=[0.05, -0.02])
    q0 = arm(sim)
    sim.set_arm_trajectory([0.3, 0.8], [q0 + STEP, q0 - STEP])
    sim.advance_to(1.0)
    sim.hold_arm()
    sim.advance_to(1.5)
    assert abs(sim.work) > 0.1
    assert abs(sim.energy_error()) < 1e-8 * max(1.0, abs(sim.work))


def test_saturated_efforts_stay_at_the_limit_and_the_integral_stops():
    """A step the limit cannot reach quickly: the efforts never pass the limit, and while the
    output is pinned at it in the error's direction, ż = 0 (anti-windup)."""
    limits = [6.0, 30.0, 10.0, 10.0]
    sim = paper(effects={"effort_limits": {"joints": limits}})
    sim.set_arm_positions(arm(sim) + np.array([0.6, 0.0, 0.0, 0.0]))
    i_z = layout.arm_integrals(sim.nq, sim.nu)
    pinned = 0
    for k in range(1, 101):
        sim.advance_to(k * 0.005)
        efforts = sim.joint_efforts_applied()
        assert np.all(np.abs(efforts) <= limits)
        if efforts[0] == 6.0:
            pinned += 1
            assert sim.system.derivative(sim.s)[i_z] == 0.0
    assert pinned > 5


# --- commands ------------------------------------------------------------------------------------

def test_a_run_re_simulates_bit_for_bit():
    def run():
        sim = paper("joint_trajectory", method="dop853", feedforward="computed_torque")
        q0 = arm(sim)
        sim.advance_to(0.1)
        sim.set_arm_trajectory([0.2, 0.5], [q0 + STEP, q0], [np.ones(4), np.zeros(4)])
        sim.advance_to(0.37)
        sim.hold_arm()
        sim.advance_to(0.6)
        return sim.s.copy()
    assert np.array_equal(run(), run())


def test_a_command_restarts_the_reference_clock_at_the_state_now():
    sim = paper("joint_trajectory")
    sim.advance_to(0.2)
    target = arm(sim) + STEP
    sim.set_arm_trajectory([1.0], [target], [np.zeros(4)])
    assert sim.s[layout.reference_clock(sim.nq, sim.nu)] == 0.0
    q_ref, qd_ref, _ = sim.arm_reference()
    assert np.array_equal(q_ref, arm(sim))
    assert np.allclose(qd_ref, sim.u[2:], atol=1e-12)
    sim.advance_to(0.7)
    assert sim.s[layout.reference_clock(sim.nq, sim.nu)] == pytest.approx(0.5, abs=1e-12)
    assert np.array_equal(sim.arm_reference(0.5)[0], target)     # τ = 1 s: the last point …
    assert np.array_equal(sim.arm_reference(10.0)[0], target)    # … held after it


@pytest.mark.parametrize("call, key", [
    (lambda s: s.set_arm_positions([0.1, 0.2, 0.3]), "arm.positions: expected 4 values"),
    (lambda s: s.set_arm_positions([0.1, float("nan"), 0.3, 0.4]), "arm.positions: values must"),
    (lambda s: s.set_arm_positions([0.1, 1.2, 0.3, 0.4]),
     r"arm_prismatic_1: 1.2 m is outside the stroke \[0, 1\]"),
    (lambda s: s.set_arm_velocities([0.0] * 4), "arm.velocities: the arm controller is "
                                                "'position'"),
    (lambda s: s.set_arm_trajectory([0.5], [[0.0] * 4]), "arm.trajectory: the arm controller"),
    (lambda s: s.set_efforts(joints=[0.0] * 4), "efforts.joints: the arm is driven"),
])
def test_bad_commands_are_one_line_errors_naming_what_is_wrong(call, key):
    sim = paper()
    with pytest.raises(UserError, match=key):
        call(sim)


@pytest.mark.parametrize("args, key", [
    (([0.5, 0.5], [[0.3, 0.5, 0.0, 0.5]] * 2), r"arm.trajectory.times\[1\]: 0.5 s is not after"),
    (([-0.1], [[0.3, 0.5, 0.0, 0.5]]), "arm.trajectory.times: times must be finite"),
    (([0.5], [[0.3, 0.5, 0.0, 0.5]] * 2), "arm.trajectory.positions: expected 1 rows"),
    (([0.5], [[0.3, 0.5, 0.0, 0.5]], None, [[0.0] * 4]), "arm.trajectory.accelerations: need"),
    (([0.5, 1.0], [[0.3, 0.5, 0.0, 0.5], [0.3, 0.5, 0.0, -0.5]]),
     r"arm_prismatic_2: -0.5 m is outside the stroke \[0, 1\] \(arm.trajectory.positions\[1\]\)"),
])
def test_bad_trajectories_are_one_line_errors(args, key):
    sim = paper("joint_trajectory")
    with pytest.raises(UserError, match=key):
        sim.set_arm_trajectory(*args)


def test_a_point_that_gravity_pulls_beyond_the_effort_limit_is_refused():
    sim = paper(effects={"effort_limits": {"joints": [6.0, 9.0, 2.0, 3.0]}})
    with pytest.raises(UserError, match=r"arm_revolute_1: holding the pose of arm.positions "
                                        r"against gravity takes \d.* N·m, beyond its effort "
                                        r"limit 6 N·m"):
        sim.set_arm_positions([0.0, 1.0, 0.0, 1.0])   # stretched out level: ~12 N·m


def test_effort_mode_takes_no_arm_references():
    sim = Simulation(paper_scene())
    with pytest.raises(UserError, match="arm.hold: the arm is in effort mode"):
        sim.hold_arm()
    assert np.array_equal(sim.joint_efforts_applied(), np.zeros(4))


def test_gains_are_checked_and_filled_in():
    robot = paper_scene().robot
    with pytest.raises(UserError, match="arm_gains.kp: expected one number or 4"):
        for_robot(ArmController("position", kp=(1.0, 2.0)), robot)
    with pytest.raises(UserError, match="arm_gains.kd: expected numbers in"):
        ArmController("position", kd=-1.0)
    with pytest.raises(UserError, match="arm_controller: unknown mode 'torque'"):
        ArmController("torque")
    filled = for_robot(ArmController("velocity", kp=50.0), robot)
    assert filled.kp == (50.0,) * 4
    assert filled.kd == default_controller(robot, "velocity").kd == (17.0, 80.0, 3.4, 40.0)


# --- the feed-forward's model error (docs/controllers.md, "Model error") ----------------------

def smooth_tracking(model_error, duration=2.0):
    """Computed torque at the default gains on q_ref ≈ q0 + A (1 − cos ωt) (1 Hz, the arm's
    state at t = 0 on the reference: no transient), quintic points every 10 ms, dop853 at
    rtol 1e-10: (max |q − q_ref| per joint, the engine's own reference, max |τ_j| applied per
    joint, the kp of each joint)."""
    sim = paper("joint_trajectory", method="dop853", feedforward="computed_torque",
                model_error=model_error)
    q0, w = arm(sim), 2.0 * np.pi
    amplitude = np.array([0.2, 0.05, 0.3, 0.05])
    T = np.arange(1, int(duration * 100) + 1) * 0.01
    sim.set_arm_trajectory(T, q0 + np.outer(1.0 - np.cos(w * T), amplitude),
                           np.outer(w * np.sin(w * T), amplitude),
                           np.outer(w * w * np.cos(w * T), amplitude))
    worst, effort = np.zeros(4), np.zeros(4)
    for t in np.arange(1, int(duration * 200) + 1) * 5e-3:
        sim.advance_to(t)
        worst = np.maximum(worst, np.abs(arm(sim) - sim.arm_reference()[0]))
        effort = np.maximum(effort, np.abs(sim.joint_efforts_applied()))
    assert abs(sim.energy_error()) < 1e-7   # the plant's balance, whatever the controller's model
    return worst, effort, np.array(sim.arm_controller.kp)


def test_without_model_error_computed_torque_tracks_to_1e_10_and_the_plant_model_is_shared():
    exact = paper(feedforward="computed_torque", model_error=ModelError())
    assert exact.system.data.ff_masses.size == 0   # no masses of its own: the plant's record
    worst, _, _ = smooth_tracking(ModelError())
    assert worst.max() < 1e-9


@pytest.mark.parametrize("error", [ModelError(mass=0.2, inertia=0.2), ModelError(mass=-0.2)])
def test_with_a_model_error_the_tracking_error_stays_within_the_documented_bound(error):
    """docs/controllers.md: with every inertial parameter off by δ the feed-forward is off by
    about δ τ, a disturbance the PID (critically damped, |kp − M ω² + j kd ω| ≥ kp at every ω)
    turns into |e_j| ≤ 2 |δ| max|τ_j| / kp_j. The error grows with δ (linear: the same run at
    δ/2 has half the error, within 10 %)."""
    delta = max(abs(error.mass), abs(error.inertia))
    worst, effort, kp = smooth_tracking(error)
    assert np.all(worst <= 2.0 * delta * effort / kp)
    assert worst.max() > 1e3 * 1e-9   # far above the exact model's
    half = ModelError(mass=error.mass / 2, inertia=error.inertia / 2)
    ratio = worst.max() / smooth_tracking(half)[0].max()
    assert 1.8 < ratio < 2.2


def test_the_gravity_feedforward_of_a_heavier_model_is_the_gravity_of_that_model():
    """G is linear in the masses: +20 % on every mass (the paper robot has no payload) is 1.2 G;
    a payload the feed-forward assumes is the gravity of the robot carrying it (the project's
    inverse dynamics with that tip mass)."""
    exact = paper(feedforward="gravity", **ZERO_GAINS)
    heavier = paper(feedforward="gravity", model_error=ModelError(mass=0.2), **ZERO_GAINS)
    loaded = paper(feedforward="gravity", model_error=ModelError(payload=0.7), **ZERO_GAINS)
    dynamics = Dynamics(exact.model, gravity=10.0, tip_mass=0.7)
    for q, u in random_states(exact, 3, seed=4):
        for sim in (exact, heavier, loaded):
            sim.s[:sim.nq], sim.s[sim.nq:sim.nq + sim.nu] = q, u
        G = exact.joint_efforts_applied()
        assert np.allclose(heavier.joint_efforts_applied(), 1.2 * G, rtol=1e-12, atol=1e-12)
        at_rest = dynamics.inverse_dynamics(q, np.zeros(exact.nu), np.zeros(exact.nu))[2:]
        assert np.allclose(loaded.joint_efforts_applied(), at_rest, rtol=1e-10, atol=1e-10)


# --- continuous joints and the held last point, as joint_trajectory_controller --------------

TURN = 2.0 * np.pi


def started_at(q_arm, mode="joint_trajectory", **control):
    """The paper robot with its arm at q_arm (rad, m) at rest, its controller holding there."""
    doc = copy.deepcopy(paper_scene().document)
    doc["initial"]["joints"] = list(q_arm)
    return Simulation(parse_scene(doc), arm_controller=ArmController(mode, **control))


def test_a_continuous_joint_trajectory_from_3_to_minus_3_rad_turns_the_short_way():
    """revolute_1 is continuous: as jtc, the start state moves a whole turn towards the first
    point and the PID reads the shortest angle, so the joint turns +0.283 rad (to −3.0 + 2π)
    and holds there; the plain difference would swing it −6 rad."""
    sim = started_at([3.0, 0.5, -0.2, 0.5])
    target = [-3.0, 0.5, -0.2, 0.5]
    sim.set_arm_trajectory([1.0], [target])
    assert sim.arm_reference()[0][0] == pytest.approx(3.0 - TURN, abs=1e-14)
    rows = sim.sample(np.arange(1, 301) * 0.01)
    q1 = rows[:, layout.arm_q(0)]
    assert q1.min() > 3.0 - 0.01 and q1.max() < TURN - 3.0 + 0.01   # between, the short way
    assert q1[-1] == pytest.approx(TURN - 3.0, abs=2e-3)             # at −3.0, a turn up
    assert sim.arm_reference()[0][0] == -3.0
    assert np.abs(arm(sim)[1:] - target[1:]).max() < 2e-3


def test_the_pid_reads_the_shortest_angle_in_every_mode():
    """A set-point a whole turn and 0.1 rad away is 0.1 rad away for a continuous joint."""
    sim = started_at([0.3, 0.5, -0.2, 0.5], mode="position")
    sim.set_arm_positions([0.4 + TURN, 0.5, -0.2, 0.5])
    sim.advance_to(2.0)
    assert arm(sim)[0] == pytest.approx(0.4, abs=1e-3)


def test_after_the_last_point_the_reference_keeps_its_acceleration():
    """jtc samples the last point itself after its time (position, velocity, acceleration as
    given): computed torque's feed-forward keeps following that acceleration; a run with it
    re-simulates bit for bit."""
    def run():
        sim = started_at([0.3, 0.5, -0.2, 0.5], feedforward="computed_torque")
        sim.set_arm_trajectory([0.5], [[0.4, 0.5, -0.2, 0.5]], [[0.0] * 4],
                               [[0.5, 0.0, -0.5, 0.0]])
        sim.advance_to(0.8)
        return sim
    sim = run()
    q, qd, qdd = sim.arm_reference()
    assert q.tolist() == [0.4, 0.5, -0.2, 0.5] and qd.tolist() == [0.0] * 4
    assert qdd.tolist() == [0.5, 0.0, -0.5, 0.0]
    assert np.array_equal(run().s, sim.s)


def test_a_100000_point_trajectory_is_taken_without_a_python_loop_over_its_points():
    """Checked, arranged into segments and put into the engine with array operations: a few
    hundred Python calls whatever the count (it made some two million, a second in the
    node's stepping thread, during which /clock stopped). Counted, not timed; the reference is
    the one the points give (their last point held at the end)."""
    import sys
    sim = paper("joint_trajectory", effects={"stroke_limits": True})
    m = 100_000
    times = np.arange(1, m + 1) * 1e-3
    positions = np.tile(arm(sim), (m, 1))
    positions[:, 0] += np.linspace(0.0, 0.2, m)
    calls = [0]

    def count(frame, event, arg):
        if event == "call":
            calls[0] += 1
    sys.setprofile(count)
    try:
        sim.set_arm_trajectory(times, positions)
    finally:
        sys.setprofile(None)
    assert calls[0] < 2000, f"{calls[0]} Python calls for {m} points"
    sim.advance_to(0.05)
    np.testing.assert_allclose(sim.arm_reference()[0], positions[49], atol=1e-12)
