"""Effects (scene `effects:`, engine/system.py, engine/simulation.py): each changes what it should
and nothing else, each costs nothing when off (counted work, not timing), and every example scene
under config/ runs.

Independent references: closed forms where the motion has one (exponential decay under viscous
damping, constant acceleration of the base), Pinocchio (`pinocchio_reference.py`) for M and h,
Simpson's rule on dense samples for dissipated work, and a very stiff PD-held joint for a lock.
"""
import math

import numpy as np
import pytest

from engine_cases import CONFIG, base_only_doc, one_link_doc, paper_doc, sampled, simulation
from mobile_manip_sim.engine.simulation import Simulation
from mobile_manip_sim.engine.system import CROSSING_CHECKS, DAMPING_STAGE, REDUCED_SOLVE, RHS_EVALS
from mobile_manip_sim.scene.arm_controller import ArmController
from mobile_manip_sim.scene.coordinates import (
    ARM_Q,
    ARM_U,
    BASE_U,
    OMEGA,
    WHEEL_L,
    WHEEL_R,
    V,
    X,
    q_joint,
    q_slide,
    u_slide,
    u_turn,
)
from mobile_manip_sim.scene.effects import SETTING_OF_EFFECT, EffectSettings, settings
from mobile_manip_sim.scene.errors import UserError
from mobile_manip_sim.scene.loading import EFFECT_NAMES, load_scene, make_integrator, parse_scene
from pinocchio_reference import build_projected_model
from robots import random_state

TIGHT = dict(rtol=1e-12, atol=1e-14)
PAPER = paper_doc()
BASE = PAPER["robot"]["base"]


def free_arm_doc(**effects):
    """The paper robot moving in every coordinate, gravity on, no stops, plus `effects`."""
    doc = paper_doc()
    doc["effects"] = {"gravity": 10.0, "wheel_inertia": True, **effects}
    doc["initial"]["velocity"] = [0.3, 0.5, 1.0, 0.4, -1.5, 0.3]
    return doc


def random_states(sim, count, seed):
    rng = np.random.default_rng(seed)
    for _ in range(count):
        yield random_state(rng, sim.model)


def simpson(values, dt):
    """∫ over uniformly spaced samples (an even number of intervals)."""
    assert (len(values) - 1) % 2 == 0
    return dt / 3.0 * (values[0] + values[-1] + 4.0 * values[1:-1:2].sum()
                       + 2.0 * values[2:-1:2].sum())


# --- gravity -------------------------------------------------------------------------------

def test_gravity_off_means_no_potential_and_kinetic_energy_conserved():
    sim = simulation(free_arm_doc(gravity=0.0), "dop853", **TIGHT)
    sim.set_efforts(wheels=[0.0, 0.0], joints=[0.0] * 4)
    for q, u in random_states(sim, 5, seed=1):
        assert sim.dynamics.energy(q, u)[1] == 0.0
    T0 = sim.total_energy()
    _, states = sampled(sim, 0.5, 20)
    assert sim.dynamics.energy(sim.q, sim.u)[1] == 0.0
    assert abs(sim.total_energy() - T0) < 1e-10 * T0


def test_gravity_changes_only_the_potential_force():
    """Same M; h differs by a velocity-independent term equal to the rate of V along q̇."""
    on = simulation(free_arm_doc(gravity=10.0), "rk4")
    off = simulation(free_arm_doc(gravity=0.0), "rk4")
    for q, u in random_states(on, 5, seed=2):
        assert np.array_equal(on.dynamics.mass_matrix(q), off.dynamics.mass_matrix(q))
        h_gravity = on.dynamics.bias(q, u) - off.dynamics.bias(q, u)
        assert np.allclose(h_gravity, on.dynamics.bias(q, np.zeros_like(u)), rtol=0, atol=1e-12)
        qdot, eps = on.dynamics.configuration_rate(q, u), 1e-6
        dV = (on.dynamics.energy(q + eps * qdot, u)[1]
              - on.dynamics.energy(q - eps * qdot, u)[1]) / (2 * eps)
        assert h_gravity @ u == pytest.approx(dV, rel=1e-7, abs=1e-9)


def test_energy_is_conserved_with_gravity_and_zero_efforts():
    sim = simulation(free_arm_doc(), "dop853", **TIGHT)
    sim.set_efforts(wheels=[0.0, 0.0], joints=[0.0] * 4)
    E0 = sim.total_energy()
    sim.advance_to(0.5)
    assert abs(sim.total_energy() - E0) < 1e-9 * max(1.0, abs(E0))


# --- wheel inertia -------------------------------------------------------------------------

def test_wheel_inertia_adds_the_wheel_spin_to_the_base_block_only():
    on = simulation(free_arm_doc(wheel_inertia=True), "rk4")
    off = simulation(free_arm_doc(wheel_inertia=False), "rk4")
    I_w, r, b = BASE["wheel_inertia"], BASE["wheel_radius"], BASE["half_track"]
    expected = np.zeros((on.nu, on.nu))
    expected[0, 0], expected[1, 1] = 2 * I_w / r ** 2, 2 * I_w * b ** 2 / r ** 2
    for q, u in random_states(on, 5, seed=3):
        dM = on.dynamics.mass_matrix(q) - off.dynamics.mass_matrix(q)
        assert np.allclose(dM, expected, rtol=1e-12, atol=1e-13)
        assert np.allclose(on.dynamics.bias(q, u), off.dynamics.bias(q, u), rtol=0, atol=1e-12)


@pytest.mark.parametrize("wheel_inertia", [True, False])
def test_wheel_torque_accelerates_the_base_as_its_inertia_says(wheel_inertia):
    """Base alone, equal wheel torques from rest: x = ½ a t², a = (2τ/r) / (M + 2 I_w / r²)."""
    tau = 0.3
    sim = simulation(base_only_doc(wheel_efforts=(tau, tau),
                                   effects={"wheel_inertia": wheel_inertia}),
                     "rk4", dt=1e-3)
    sim.advance_to(0.5)
    I_w, r = BASE["wheel_inertia"] if wheel_inertia else 0.0, BASE["wheel_radius"]
    a = (2 * tau / r) / (BASE["mass"] + 2 * I_w / r ** 2)
    assert sim.q[X] == pytest.approx(0.5 * a * 0.5 ** 2, rel=1e-12)
    assert sim.u[V] == pytest.approx(a * 0.5, rel=1e-12)
    assert sim.q[WHEEL_R] == sim.q[WHEEL_L] == pytest.approx(sim.q[X] / r, rel=1e-12)   # no slip


def test_wheel_inertia_is_irrelevant_with_the_base_held():
    runs = []
    for flag in (True, False):
        sim = simulation(free_arm_doc(wheel_inertia=flag, fixed_base=True), "rk4", dt=1e-3)
        sim.advance_to(0.2)
        runs.append(sim.s[:-1].copy())
    assert np.array_equal(runs[0], runs[1])


# --- damping -------------------------------------------------------------------------------

JOINT_DAMPING = [0.5, 2.0, 0.3, 1.0]


def test_joint_damping_dissipates_exactly_the_viscous_work():
    """Zero efforts: E(0) − E(t) = ∫ Σ c_k u_k² dt (Simpson on 2 kHz samples), and the engine's
    energy balance, which books that work, stays at round-off."""
    sim = simulation(free_arm_doc(joint_damping=JOINT_DAMPING), "dop853", **TIGHT)
    sim.set_efforts(wheels=[0.0, 0.0], joints=[0.0] * 4)
    E0 = sim.total_energy()
    _, states = sampled(sim, 0.5, 2000)
    u = states[:, sim.nq:sim.nq + sim.nu]
    dissipated = simpson((u[:, ARM_U] ** 2 * JOINT_DAMPING).sum(axis=1), 1 / 2000)
    assert dissipated > 0.1
    assert E0 - sim.total_energy() == pytest.approx(dissipated, rel=1e-8)
    assert abs(sim.energy_error()) < 1e-9 * dissipated


def test_joint_damping_changes_only_the_viscous_force():
    """At the same state: Δu̇ = M⁻¹ (−c ⊙ u), Δq̇ = 0, ΔẆ = −Σ c u²."""
    damped = simulation(free_arm_doc(joint_damping=JOINT_DAMPING), "rk4")
    plain = simulation(free_arm_doc(), "rk4")
    c = np.array([0.0, 0.0, *JOINT_DAMPING])
    for q, u in random_states(plain, 5, seed=4):
        s = plain.system.state(q, u)
        d1, d0 = damped.system.derivative(s), plain.system.derivative(s)
        nq = plain.nq
        assert np.array_equal(d1[:nq], d0[:nq])
        M = plain.dynamics.mass_matrix(q)
        nu = plain.nu
        assert np.allclose(d1[nq:nq + nu] - d0[nq:nq + nu], np.linalg.solve(M, -c * u),
                           rtol=1e-10, atol=1e-12)
        assert d1[-1] - d0[-1] == pytest.approx(-(c * u * u).sum(), rel=1e-12)


@pytest.mark.parametrize("joint", ["revolute", "prismatic"])
def test_a_damped_joint_slows_exponentially(joint):
    """Base held, the other DOF of the pair locked, gravity off: one inertia I under −c u:
    u(t) = u₀ exp(−c t / I), with I = μ ∫ η² dη + J_zz L (revolute) or μ L (prismatic)."""
    c, u0, l = 0.4, 2.0, 0.6
    link = PAPER["robot"]["arm"]["links"][0]
    if joint == "revolute":
        mu, L, J_zz = link["mass_per_length"], link["length"], link["inertia_per_length"][2]
        inertia = mu * (l ** 3 - (l - L) ** 3) / 3.0 + J_zz * L
        damping, velocity, locked, j = [c, 0.0], (0.0, 0.0, u0, 0.0), "arm_prismatic_1", u_turn(1)
    else:
        inertia = link["mass_per_length"] * link["length"]
        damping, velocity, locked, j = [0.0, c], (0.0, 0.0, 0.0, u0), "arm_revolute_1", u_slide(1)
    doc = one_link_doc(joints=(0.3, l), velocity=velocity, effects={
        "fixed_base": True, "locked_joints": [locked], "joint_damping": damping})
    sim = simulation(doc, "dop853", **TIGHT)
    for t in (0.25, 0.5, 1.0):
        sim.advance_to(t)
        assert sim.u[j] == pytest.approx(u0 * math.exp(-c * t / inertia), rel=1e-9)
    coordinate = sim.q[q_joint(j)]
    start = 0.3 if joint == "revolute" else l
    assert coordinate - start == pytest.approx(u0 * inertia / c * (1 - math.exp(-c / inertia)),
                                               rel=1e-9)


@pytest.mark.parametrize("com_offset", [0.0, BASE["com_offset"]])
def test_wheel_damping_slows_the_base_as_rolling_resistance(com_offset):
    """Base alone rolling and turning: T(0) − T(t) = ∫ c (θ̇_R² + θ̇_L²) dt. With G on the axle
    (d = 0) v and ω decouple and decay with rates 2c/(r² M₀₀) and 2cb²/(r² M₁₁)."""
    c, v0, w0 = 0.02, 1.0, 2.0
    doc = base_only_doc(velocity=(v0, w0), effects={"wheel_damping": c, "wheel_inertia": True})
    doc["robot"]["base"]["com_offset"] = com_offset
    sim = simulation(doc, "dop853", **TIGHT)
    M = sim.dynamics.mass_matrix(sim.q)
    r, b = BASE["wheel_radius"], BASE["half_track"]
    E0 = sim.total_energy()
    _, states = sampled(sim, 1.0, 1000)
    if com_offset == 0.0:
        assert M[V, OMEGA] == 0.0
        assert sim.u[V] == pytest.approx(v0 * math.exp(-2 * c / r ** 2 / M[V, V]), rel=1e-9)
        assert sim.u[OMEGA] == pytest.approx(w0 * math.exp(-2 * c * b ** 2 / r ** 2
                                                           / M[OMEGA, OMEGA]), rel=1e-9)
    u = states[:, sim.nq:sim.nq + sim.nu]
    v, w = u[:, V], u[:, OMEGA]
    wheel_rates = np.array([(v + b * w) / r, (v - b * w) / r])
    dissipated = simpson(c * (wheel_rates ** 2).sum(axis=0), 1 / 1000)
    assert dissipated > 0.1 * E0
    assert E0 - sim.total_energy() == pytest.approx(dissipated, rel=1e-8)
    assert abs(sim.energy_error()) < 1e-10


# --- effort limits -------------------------------------------------------------------------

LIMITS = {"wheels": 0.15, "joints": [4.0, 6.0, 1.0, 0.5]}


def limited_run(wheels, joints, limits=LIMITS):
    doc = free_arm_doc(effort_limits=limits) if limits else free_arm_doc()
    sim = simulation(doc, "rk4", dt=1e-3)
    sim.set_efforts(wheels=wheels, joints=joints)
    _, states = sampled(sim, 0.2, 100)
    return sim, states


def test_effort_limits_saturate_the_commands():
    over, s_over = limited_run([1.0, -1.0], [10.0, -10.0, 5.0, -0.6])
    at, s_at = limited_run([0.15, -0.15], [4.0, -6.0, 1.0, -0.5])
    assert np.array_equal(s_over, s_at)
    assert list(over.wheel_efforts) == [0.15, -0.15]
    assert list(over.joint_efforts) == [4.0, -6.0, 1.0, -0.5]
    assert abs(over.energy_error()) < 1e-9   # the work booked is that of the saturated efforts


def test_effort_limits_leave_commands_within_them_alone():
    inside, s_inside = limited_run([0.1, -0.12], [3.0, 5.0, -0.5, 0.2])
    free, s_free = limited_run([0.1, -0.12], [3.0, 5.0, -0.5, 0.2], limits=None)
    assert np.array_equal(s_inside, s_free)


def test_effort_limits_saturate_the_scene_efforts_too():
    sim = simulation(paper_doc(effects={"effort_limits": LIMITS}), "rk4")
    assert list(sim.wheel_efforts) == [0.1, 0.15]               # the paper's 0.2 N·m capped
    assert list(sim.joint_efforts) == [4.0, 6.0, 0.0, 0.5]


def test_the_paper_robots_limits_are_enforced_at_them_and_not_below():
    """``effects.effort_limits: true`` on the paper scene enforces its robot's own efforts: the
    numbers of ``robot.limits.effort`` in the file, read here from the YAML. A command beyond
    them is clamped at them; one just within passes untouched (a clamp that must not fire); the
    wheel loop's and the arm controller's outputs are bounded by the same numbers."""
    declared = PAPER["robot"]["limits"]["effort"]
    limits = np.array(declared["wheels"] + declared["joints"], dtype=float)
    enforced = paper_doc()
    enforced["effects"]["effort_limits"] = True
    scene = parse_scene(enforced)
    sim = Simulation(scene)
    assert np.array_equal(sim.effects.effort_limits, limits)
    sim.set_efforts(wheels=limits[:2] * [1.25, -3.0], joints=limits[2:] * [1.01, -2.0, 5.0, -1.5])
    assert list(sim.wheel_efforts) == [limits[0], -limits[1]]
    assert list(sim.joint_efforts) == list(limits[2:] * [1, -1, 1, -1])
    within = limits * (1.0 - 1e-12) * [1, -1, -1, 1, -1, 1]
    sim.set_efforts(wheels=within[:2], joints=within[2:])
    assert np.array_equal(np.r_[sim.wheel_efforts, sim.joint_efforts], within)
    sim.set_base_velocity(1.0, 0.0)   # a wheel error of 12.5 rad/s: kp e = 25 N·m asked
    sim.advance_to(1e-3)              # the loop's update at t = 0 has acted
    assert sim.wheel_torques()[0] == limits[0]
    arm = Simulation(scene, arm_controller=ArmController("position"))
    arm.set_arm_positions(arm.q[5:] + [1.0, 0.0, 0.0, 0.0])   # kp · 1 rad asked of joint 1
    arm.advance_to(1e-3)
    applied = arm.joint_efforts_applied()
    assert applied[0] == limits[2] and np.all(np.abs(applied) <= limits[2:])


def test_effort_limits_true_takes_the_robots_and_needs_them():
    doc = paper_doc()
    doc["robot"]["limits"].pop("effort")
    doc["effects"]["effort_limits"] = True
    with pytest.raises(UserError, match=r"^effects\.effort_limits: true takes the robot's") \
            as error:
        parse_scene(doc)
    assert "\n" not in str(error.value)
    doc["effects"]["effort_limits"] = False
    assert settings(parse_scene(doc)).effort_limits is None


@pytest.mark.parametrize("limits, key", [
    ({"velocity": {"joints": [3.0, -0.5, 3.0, 0.5]}}, r"robot\.limits\.velocity\.joints\[1\]"),
    ({"effort": {"wheels": [1.0, 2.0, 3.0]}}, r"robot\.limits\.effort\.wheels"),
    ({"speed": {"wheels": 1.0}}, r"robot\.limits\.speed"),
    ({"effort": {"arm": 1.0}}, r"robot\.limits\.effort\.arm")])
def test_a_bad_robot_limit_is_a_one_line_error_naming_it(limits, key):
    doc = paper_doc()
    doc["robot"]["limits"] = limits
    with pytest.raises(UserError, match=rf"^{key}: ") as error:
        parse_scene(doc)
    assert "\n" not in str(error.value)


# --- locked joints and the fixed base ------------------------------------------------------

@pytest.mark.parametrize("name, j", [("arm_revolute_2", u_turn(2)),
                                     ("arm_prismatic_1", u_slide(1))])
def test_a_locked_joint_stays_fixed_and_moves_the_rest_like_a_stiff_joint(name, j):
    """Locked (removed from the problem) vs free but held by a PD of stiffness K updated every
    10 µs (rk4): the other coordinates agree to O(1/K) and converge as K grows."""
    locked = simulation(free_arm_doc(locked_joints=[name]), "dop853", **TIGHT)
    assert locked.u[j] == 0.0   # the scene's initial velocity of a locked DOF is dropped
    q0 = locked.q[q_joint(j)]
    _, states = sampled(locked, 0.05, 1000)
    assert np.all(states[:, q_joint(j)] == q0) and np.all(states[:, locked.nq + j] == 0.0)
    assert locked.system.counters[REDUCED_SOLVE] == locked.system.counters[RHS_EVALS]
    assert abs(locked.energy_error()) < 1e-10
    others = [i for i in range(locked.s.size - 1) if i not in (q_joint(j), locked.nq + j)]
    errors = []
    for K in (1e7, 1e8):
        stiff = simulation(free_arm_doc(), "rk4", dt=1e-5)
        stiff.s[stiff.nq + j] = 0.0
        C = 2.0 * math.sqrt(K * stiff.dynamics.mass_matrix(stiff.q)[j, j])   # critically damped
        efforts = np.array(stiff.joint_efforts)
        for i in range(1, 5001):
            command = efforts.copy()
            command[j - ARM_U.start] += K * (q0 - stiff.q[q_joint(j)]) - C * stiff.u[j]
            stiff.set_efforts(joints=command)
            stiff.advance_to(i * 1e-5)
        errors.append(np.max(np.abs(stiff.s[others] - locked.s[others])))
    assert errors[1] < 1e-6 and errors[0] > 5 * errors[1], errors


def test_locking_a_joint_with_a_typo_is_an_error_naming_it():
    from mobile_manip_sim.scene.errors import UserError
    with pytest.raises(UserError, match=r"effects\.locked_joints\[0\]"):
        simulation(free_arm_doc(locked_joints=["arm_revolute_3"]))


def test_fixed_base_holds_the_base_and_leaves_the_arm_alone_dynamics():
    """Base coordinates bit-for-bit constant; u̇ of the arm = M_arm⁻¹ (Q − h)_arm from Pinocchio's
    independent M and h with v = ω = 0."""
    sim = simulation(free_arm_doc(fixed_base=True), "dop853", **TIGHT)
    base = np.r_[:ARM_Q.start, sim.nq + BASE_U.start:sim.nq + BASE_U.stop]   # pose, wheels; v, ω
    base0 = sim.s[base]
    assert np.all(sim.u[BASE_U] == 0.0)
    _, states = sampled(sim, 0.3, 100)
    assert np.all(states[:, base] == base0)
    ref = build_projected_model(sim.model, 10.0, wheel_inertia=True)
    Q = np.array(sim.system.Q_cmd)
    for q, u in random_states(sim, 5, seed=5):
        u[BASE_U] = 0.0
        s = sim.system.state(q, u)
        ud = sim.system.derivative(s)[sim.nq:sim.nq + sim.nu]
        M, h = ref.mass_matrix(q), ref.bias(q, u)
        expected = np.linalg.solve(M[ARM_U, ARM_U], (Q - h)[ARM_U])
        assert np.all(ud[BASE_U] == 0.0)
        assert np.allclose(ud[ARM_U], expected, rtol=1e-9, atol=1e-9)


def test_fixed_base_moves_the_arm_like_an_immovable_base():
    """The same robot with a base 10¹² times heavier, free: the arm's motion agrees."""
    held = simulation(free_arm_doc(fixed_base=True), "dop853", **TIGHT)
    heavy_doc = free_arm_doc()
    heavy_doc["robot"]["base"] = dict(BASE, mass=BASE["mass"] * 1e12,
                                      yaw_inertia=BASE["yaw_inertia"] * 1e12)
    heavy_doc["initial"]["velocity"][BASE_U] = [0.0, 0.0]
    heavy = simulation(heavy_doc, "dop853", **TIGHT)
    for t in (0.1, 0.3):
        held.advance_to(t)
        heavy.advance_to(t)
        assert np.max(np.abs(heavy.q[ARM_Q] - held.q[ARM_Q])) < 1e-8
        assert np.max(np.abs(heavy.u[ARM_U] - held.u[ARM_U])) < 1e-8


# --- payload -------------------------------------------------------------------------------

@pytest.mark.parametrize("payload", [None, 0.7])
def test_payload_is_a_point_mass_at_the_tip(payload):
    effects = {"payload": payload} if payload else {}
    sim = simulation(free_arm_doc(**effects), "rk4")
    ref = build_projected_model(sim.model, 10.0, tip_mass=payload or 0.0, wheel_inertia=True)
    for q, u in random_states(sim, 5, seed=6):
        assert np.allclose(sim.dynamics.mass_matrix(q), ref.mass_matrix(q), rtol=1e-10, atol=1e-12)
        assert np.allclose(sim.dynamics.bias(q, u), ref.bias(q, u), rtol=1e-10, atol=1e-10)
        T, V = sim.dynamics.energy(q, u)
        assert T == pytest.approx(ref.kinetic_energy(q, u), rel=1e-12)
        assert V == pytest.approx(ref.potential_energy(q), rel=1e-12, abs=1e-12)


def test_payload_adds_only_the_tip_mass_terms():
    """M_payload − M = m J_tipᵀ J_tip, rank ≤ 3, J_tip the tip's velocity Jacobian in u."""
    m = 0.7
    loaded = simulation(free_arm_doc(payload=m), "rk4")
    plain = simulation(free_arm_doc(), "rk4")
    ref = build_projected_model(plain.model, 10.0, wheel_inertia=True)
    for q, _ in random_states(plain, 5, seed=7):
        eps = 1e-7
        J = np.empty((3, plain.nu))
        for k in range(plain.nu):
            du = np.zeros(plain.nu)
            du[k] = 1.0
            qdot = plain.dynamics.configuration_rate(q, du)
            J[:, k] = (ref.tip_position(q + eps * qdot)
                       - ref.tip_position(q - eps * qdot)) / (2 * eps)
        dM = loaded.dynamics.mass_matrix(q) - plain.dynamics.mass_matrix(q)
        assert np.allclose(dM, m * J.T @ J, rtol=1e-6, atol=1e-7)


def test_energy_is_conserved_with_a_payload():
    sim = simulation(free_arm_doc(payload=0.7), "dop853", **TIGHT)
    sim.set_efforts(wheels=[0.0, 0.0], joints=[0.0] * 4)
    E0 = sim.total_energy()
    sim.advance_to(0.5)
    assert abs(sim.total_energy() - E0) < 1e-9 * max(1.0, abs(E0))


# --- an effect that is off costs nothing ---------------------------------------------------

@pytest.mark.parametrize("method", ["rk4", "dop853"])
def test_an_effect_that_is_off_does_no_work(method):
    def counters(doc):
        sim = simulation(doc, method, dt=1e-3)
        sim.advance_to(0.3)
        stages = [RHS_EVALS, DAMPING_STAGE, REDUCED_SOLVE, CROSSING_CHECKS]
        return dict(zip(("rhs", "damping", "reduced", "crossing"), sim.system.counters[stages],
                        strict=True))

    bare = counters(free_arm_doc())
    assert bare["rhs"] > 0 and bare["damping"] == bare["reduced"] == bare["crossing"] == 0
    damped = counters(free_arm_doc(joint_damping=0.1))
    assert damped["damping"] == damped["rhs"]
    rolling = counters(free_arm_doc(wheel_damping=0.01))
    assert rolling["damping"] == rolling["rhs"]
    assert counters(free_arm_doc(wheel_damping=0.0))["damping"] == 0   # zero is off, not a stage
    locked = counters(free_arm_doc(locked_joints=["arm_revolute_2"]))
    assert locked["reduced"] == locked["rhs"] and locked["damping"] == 0
    held = counters(free_arm_doc(fixed_base=True))
    assert held["reduced"] == held["rhs"]
    stops = counters(free_arm_doc(stroke_limits={"restitution": 0.5}))
    assert stops["crossing"] > 0 and stops["damping"] == 0


# --- one owner: effects.settings ----------------------------------------------------------

# each effect turned on with a value that matters
EFFECT_ON = {"gravity": 10.0, "stroke_limits": {"restitution": 0.5}, "wheel_inertia": True,
             "joint_damping": 0.1, "wheel_damping": 0.01, "effort_limits": {"joints": 2.0},
             "locked_joints": ["arm_prismatic_1"], "fixed_base": True, "payload": 0.3}


def changed_settings(doc):
    """The EffectSettings fields that differ from those of the scene with no effect on."""
    def same(a, b):
        return (a is None) == (b is None) and (a is None or np.array_equal(a, b))

    bare = settings(parse_scene(paper_doc(effects={})))
    ours = settings(parse_scene(doc))
    return [name for name in EffectSettings.__dataclass_fields__
            if not same(getattr(ours, name), getattr(bare, name))]


def test_each_effect_sets_exactly_its_one_setting_and_off_leaves_it_absent():
    assert set(EFFECT_ON) == set(EFFECT_NAMES) == set(SETTING_OF_EFFECT)
    bare = settings(parse_scene(paper_doc(effects={})))
    assert bare == EffectSettings()   # every setting absent
    for name in EFFECT_NAMES:
        changed = changed_settings(paper_doc(effects={name: EFFECT_ON[name]}))
        assert changed == [SETTING_OF_EFFECT[name]]
    off = {"gravity": 0.0, "stroke_limits": False, "wheel_inertia": False, "wheel_damping": 0.0,
           "effort_limits": {}, "locked_joints": [], "fixed_base": False}
    assert changed_settings(paper_doc(effects=off)) == []


def test_the_engine_runs_the_settings_of_its_scene():
    doc = paper_doc(effects=dict(EFFECT_ON, locked_joints=["arm_revolute_2"]))
    sim = simulation(doc, "rk4")
    own = settings(parse_scene(doc))
    assert sim.dynamics.gravity == own.gravity == 10.0
    assert sim.dynamics.tip_mass == own.tip_mass == 0.3
    assert sim.dynamics.wheel_inertia and sim.model.base.wheel_inertia == BASE["wheel_inertia"]
    assert sim.system.permanently_locked == own.locked == (0, 1, 4)
    assert np.array_equal(sim.system.damping, own.generalized_damping(sim.model.base))
    assert sim.stop_law == own.stop_law and sim.stops.law.restitution == 0.5
    assert list(sim.joint_efforts) == list(own.saturate(PAPER["efforts"]["joints"], 2))


# --- the example scenes --------------------------------------------------------------------

EXAMPLES = sorted(p for p in CONFIG.glob("*.yaml") if not p.name.endswith(".params.yaml"))


def test_there_is_one_example_scene_per_effect():
    names = {p.stem for p in EXAMPLES}
    for effect in EFFECT_NAMES:
        assert f"effect_{effect}" in names
        scene = load_scene(CONFIG / f"effect_{effect}.yaml")
        assert effect in scene.effects.names_on()
        assert (CONFIG / f"effect_{effect}.yaml").read_text().startswith("#")   # says what it shows


@pytest.mark.parametrize("path", EXAMPLES, ids=[p.stem for p in EXAMPLES])
def test_every_example_scene_runs(path):
    scene = load_scene(path)
    sim = Simulation(scene, make_integrator(scene.integrator, "rk4"))
    start = sim.s.copy()
    sim.advance_to(0.2)
    assert sim.t == pytest.approx(0.2, abs=1e-12) and sim.steps >= 0.2 / scene.integrator.dt - 1
    assert not np.allclose(sim.s[:-1], start[:-1], rtol=0, atol=1e-6)   # something moved
    for k in range(1, scene.robot.n_links + 1):
        if scene.effects.stroke_limits:
            lo, hi = scene.robot.stroke[k - 1]
            assert lo - 1e-9 <= sim.q[q_slide(k)] <= hi + 1e-9
