"""Stroke end stops (docs/model.md "Stroke end stops", engine/stops.py): located impacts, the
impulse law's energy loss, resting and leaving, no tunnelling, no Zeno, impulse vs the paper's
reflect.

Several cases have exact answers: a rod whose l̇ row of M is diagonal and whose h_l is constant
moves as l̈ = F/m, a quadratic in t that RK4 and every adaptive method reproduce to round-off, so
impact times and speeds are checked against closed forms.
"""
import copy
import math

import numpy as np
import pytest
from scipy import integrate

from engine_cases import one_link_doc, paper_doc, sampled, simulation
from mobile_manip_sim.core import zeno_guard
from mobile_manip_sim.engine import events, layout
from mobile_manip_sim.engine.simulation import Simulation
from mobile_manip_sim.scene.loading import load_scene, make_integrator

L_1, L_2 = layout.q_slide(1), layout.q_slide(2)   # l_1, l_2 in q
LD_1 = layout.u_slide(1)   # l̇_1 in u

TIGHT = dict(rtol=1e-11, atol=1e-13)
SCIPY = {"rk45": integrate.RK45, "dop853": integrate.DOP853, "radau": integrate.Radau,
         "bdf": integrate.BDF}


class ImpactProbe(Simulation):
    """A Simulation whose recorded impacts come with (q, u⁻, u⁺, free DOFs, held) each, from the
    engine's own impact log (`Simulation.impact_details`); `held`: stopped dead by a Zeno guard
    rather than by the impact law."""

    @property
    def probed(self):
        return [tuple(detail) for detail in self.impact_details]


def probe(doc, method, **settings) -> ImpactProbe:
    return ImpactProbe(simulation(doc, method, **settings).scene)


def bouncing_doc(restitution, **effects):
    """The paper robot, gravity off, zero efforts, both rods rattling in 0.1 m strokes."""
    doc = paper_doc(efforts={}, effects={"stroke_limits": {"restitution": restitution,
                                                           "rest_speed": 1e-6}, **effects})
    for link in doc["robot"]["arm"]["links"]:
        link["stroke"] = [0.45, 0.55]
    doc["initial"]["velocity"] = [0.3, 0.5, 1.0, 4.0, -1.5, -3.0]
    return doc


def assert_in_stroke(sim, states, tol=1e-9):
    for k in range(1, sim.model.n_links + 1):
        lo, hi = sim.stroke[k - 1]
        l = states[:, layout.q_slide(k)]
        assert l.min() >= lo - tol and l.max() <= hi + tol, (k, l.min() - lo, l.max() - hi)


# --- energy --------------------------------------------------------------------------------

@pytest.mark.parametrize("method, settings, tol", [
    ("dop853", TIGHT, 1e-9),
    ("rk4", dict(dt=1e-4), 1e-9),
    ("rk45", dict(rtol=1e-8, atol=1e-11), 1e-6),
])
def test_energy_is_kept_across_many_elastic_impacts(method, settings, tol):
    """e = 1, zero efforts, no dissipation: T + V is constant through 100+ impacts."""
    sim = simulation(bouncing_doc(1.0), method, **settings)
    E0 = sim.total_energy()
    _, states = sampled(sim, 2.0, 100)
    assert len(sim.impacts) >= 100
    assert {i.link for i in sim.impacts} == {1, 2}
    assert {i.stop for i in sim.impacts} == {"lower", "upper"}
    assert not any(i.resting for i in sim.impacts)
    assert max(abs(i.energy_lost) for i in sim.impacts) < 1e-13 * E0
    assert abs(sim.total_energy() - E0) < tol * E0
    assert abs(sim.energy_error()) < tol * E0
    assert_in_stroke(sim, states)


@pytest.mark.parametrize("restitution", [0.0, 0.5, 0.9])
@pytest.mark.parametrize("fixed_base", [False, True])
def test_each_impact_loses_the_energy_of_the_impulse_law(restitution, fixed_base):
    """ΔT = ½(1 − e²)(l̇⁻)² / (e_kᵀ M⁻¹ e_k), M restricted to the free DOFs, at each impact."""
    effects = {"fixed_base": True} if fixed_base else {}
    doc = bouncing_doc(restitution, **effects)
    doc["robot"]["arm"]["links"][0]["stroke"] = [0.3, 0.7]  # fewer, varied impacts
    sim = probe(doc, "dop853", **TIGHT)
    E0 = sim.total_energy()
    sim.advance_to(1.0 if restitution else 2.0)
    assert len(sim.impacts) >= (5 if restitution else 3) and len(sim.probed) == len(sim.impacts)
    expected_total = 0.0
    for impact, (q, u_before, u_after, free, held) in zip(sim.impacts, sim.probed, strict=True):
        j = 2 * impact.link + 1
        M = sim.dynamics.mass_matrix(q)[np.ix_(free, free)]
        w = np.linalg.solve(M, np.eye(len(free))[free.index(j)])   # M⁻¹ e_k
        slow = restitution * abs(impact.ld_before) < sim.stop_law.rest_speed
        e = 0.0 if held or slow else restitution
        expected = 0.5 * (1.0 - e ** 2) * impact.ld_before ** 2 / w[free.index(j)]
        T_before = 0.5 * u_before[free] @ M @ u_before[free]
        T_after = 0.5 * u_after[free] @ M @ u_after[free]
        assert impact.ld_before == u_before[j] and impact.ld_after == u_after[j]
        assert u_after[j] == pytest.approx(-e * u_before[j], abs=1e-15)
        assert T_before - T_after == pytest.approx(expected, rel=1e-9, abs=1e-12)
        # a hold's share is booked apart from the law's
        assert impact.energy_lost + impact.hold_energy == pytest.approx(expected, rel=1e-9,
                                                                        abs=1e-12)
        assert held == impact.held and (held or impact.hold_energy == 0.0)
        expected_total += expected
    # The trajectory itself lost exactly that much: an energy check independent of the
    # engine's bookkeeping (zero efforts, no dissipation).
    assert E0 - sim.total_energy() == pytest.approx(expected_total, rel=1e-8, abs=1e-9)
    assert abs(sim.energy_error() + sim.hold_energy) < 1e-9 * E0
    if fixed_base:
        assert np.all(sim.u[:2] == 0.0)


# --- pressing, resting, leaving ------------------------------------------------------------

PUSH_METHODS = [("rk4", dict(dt=1e-3)), ("semi_implicit_euler", dict(dt=1e-3)),
                ("dop853", dict(rtol=1e-9, atol=1e-12)), ("radau", dict(rtol=1e-6, atol=1e-9))]


def push_doc(F, stops=True):
    """One inclined rod on the free base, gravity off, a constant force F along it."""
    return one_link_doc(stroke=(0.1, 0.9), joints=(0.3, 0.5), joint_efforts=(0.0, F),
                        effects={"stroke_limits": {}} if stops else {})


@pytest.mark.parametrize("method, settings", PUSH_METHODS, ids=[m for m, _ in PUSH_METHODS])
@pytest.mark.parametrize("side", [-1, 1], ids=["lower", "upper"])
def test_a_rod_pushed_into_its_stop_rests_and_leaves_when_pulled(side, method, settings):
    F = 5.0 * side
    stop = 0.1 if side < 0 else 0.9
    # Work: one call to the end, with and without the stop.
    free_run = simulation(push_doc(F, stops=False), method, **settings)
    free_run.advance_to(0.8)
    with_stop = simulation(push_doc(F), method, **settings)
    with_stop.advance_to(0.8)
    assert with_stop.steps <= 2 * free_run.steps + 5
    # Dense samples: never out of the stroke, resting at the stop once it got there.
    sim = simulation(push_doc(F), method, **settings)
    _, states = sampled(sim, 0.8, 1000)
    assert_in_stroke(sim, states)
    assert len(sim.impacts) == 1
    impact = sim.impacts[0]
    assert impact.stop == ("lower" if side < 0 else "upper") and impact.resting
    assert impact.ld_after == 0.0 and side * impact.ld_before > 0.4
    after = np.arange(states.shape[0]) / 1000 > impact.time
    assert np.all(states[after, layout.q_slide(1)] == stop)
    assert np.all(states[after, layout.ld(sim.nq, 1)] == 0.0)
    assert sim.resting[0] == side
    # Reverse the force: the rod leaves at once and moves away from the stop.
    sim.set_efforts(joints=(0.0, -F))
    assert sim.resting[0] == 0
    _, later = sampled_from(sim, 0.8, 1.0, 1000)
    l = later[:, layout.q_slide(1)]
    assert np.all(-side * np.diff(l) > 0.0)
    assert -side * (l[-1] - stop) > 0.05
    assert len(sim.impacts) == 1


def sampled_from(sim, t0, t1, rate):
    times = t0 + np.arange(1, int(round((t1 - t0) * rate)) + 1) / rate
    states = np.empty((times.size, sim.s.size))
    for i, t in enumerate(times):
        sim.advance_to(t)
        states[i] = sim.s
    return times, states


def test_a_resting_rod_leaves_when_the_command_changes_not_a_step_later():
    """Zero-order hold: a rod released by a new command moves from that instant on, so the
    fixed-step run agrees with a tight adaptive one (a one-step lag would cost ~1e-3 m here)."""
    finals = []
    for method, settings in (("rk4", dict(dt=1e-3)), ("dop853", TIGHT)):
        sim = simulation(push_doc(5.0), method, **settings)
        sim.advance_to(0.8)
        assert sim.resting[0] == 1
        sim.set_efforts(joints=(0.0, -5.0))
        sim.advance_to(1.0)
        finals.append(sim.s.copy())
    assert np.max(np.abs(finals[0] - finals[1])) < 1e-9


def test_a_rod_pressed_by_less_than_the_stop_holds_stays():
    """The net generalized force decides: pulling with less than the press leaves it resting."""
    sim = simulation(push_doc(5.0), "rk4", dt=1e-3)
    sim.advance_to(0.8)
    sim.set_efforts(joints=(0.0, 1.0))
    sim.advance_to(1.0)
    assert sim.resting[0] == 1 and sim.q[L_1] == 0.9 and sim.u[LD_1] == 0.0


VERTICAL = dict(joints=(math.pi / 2, 0.5), stroke=(0.0, 1.0))   # rod 1 straight up


@pytest.mark.parametrize("method, settings", [("rk4", dict(dt=1e-3)), ("dop853", TIGHT)])
def test_a_bouncing_rod_comes_to_rest_without_zeno(method, settings):
    """A vertical rod falls onto its lower stop under gravity with e = 0.5: impacts at the
    closed-form times t_n = t_0 + Σ 2 eⁱ v_0 / g, until the rebound is below rest_speed; then it
    rests, stays under a lift below its weight, and leaves under a lift above it."""
    e, g, rest_speed = 0.5, 10.0, 1e-3
    doc = one_link_doc(**VERTICAL, effects={"gravity": g, "stroke_limits": {
        "restitution": e, "rest_speed": rest_speed}})
    sim = simulation(doc, method, **settings)
    M = sim.dynamics.mass_matrix(sim.q)
    assert np.allclose(np.delete(M[3], 3), 0.0, atol=1e-15)   # l̇ does not couple here
    sim.advance_to(1.5)
    v0 = math.sqrt(2.0 * g * 0.5)
    t = math.sqrt(2.0 * 0.5 / g)
    speed = v0
    for n, impact in enumerate(sim.impacts):
        assert impact.stop == "lower" and impact.link == 1
        assert impact.time == pytest.approx(t, abs=1e-9), n
        assert impact.ld_before == pytest.approx(-speed, abs=1e-9), n
        if e * speed < rest_speed:
            assert impact.resting and impact.ld_after == 0.0
            break
        assert not impact.resting
        t += 2.0 * e * speed / g
        speed *= e
    else:
        pytest.fail("the rod never came to rest")
    assert n == len(sim.impacts) - 1 and 5 < n < 20
    assert sim.resting[0] == -1 and sim.q[L_1] == 0.0 and sim.u[LD_1] == 0.0
    sim.set_efforts(joints=(0.0, 9.0))      # less than the weight μ L g = 10 N
    sim.advance_to(1.6)
    assert sim.resting[0] == -1 and sim.q[L_1] == 0.0
    sim.set_efforts(joints=(0.0, 12.0))     # more: l̈ = 2 m/s² upward
    sim.advance_to(1.7)
    assert sim.resting[0] == 0
    assert sim.q[L_1] == pytest.approx(0.5 * 2.0 * 0.1 ** 2, rel=1e-9)


@pytest.mark.parametrize("method, settings", [("rk4", dict(dt=1e-3)), ("rk4", dict(dt=0.05)),
                                              ("dop853", TIGHT), ("radau", dict(rtol=1e-8))])
def test_a_rod_chattering_with_no_rest_speed_is_held_at_the_zeno_point(method, settings):
    """rest_speed 0: no velocity threshold ends the bounces, only the engine's Zeno guard. The
    rod must come to rest at the accumulation time t_0 + (2 v_0 / g) e / (1 − e), neither stall
    in the event loop nor slip through the stop."""
    e, g = 0.5, 10.0
    doc = one_link_doc(**VERTICAL, effects={"gravity": g, "stroke_limits": {
        "restitution": e, "rest_speed": 0.0}})
    sim = simulation(doc, method, **settings)
    _, states = sampled(sim, 1.2, 100)
    assert_in_stroke(sim, states)
    v0 = math.sqrt(2.0 * g * 0.5)
    t_zeno = math.sqrt(2.0 * 0.5 / g) + 2.0 * v0 / g * e / (1.0 - e)
    assert sim.resting[0] == -1 and sim.q[L_1] == 0.0 and sim.u[LD_1] == 0.0
    assert sim.impacts[-1].resting and sim.impacts[-1].time == pytest.approx(t_zeno, abs=1e-6)
    assert len(sim.impacts) < 200


# --- the Zeno guard (events.zeno_guard: one for every method, on the impact times) ---------

@pytest.mark.parametrize("method, settings", [("rk4", dict(dt=1e-3)), ("rk4", dict(dt=0.05)),
                                              ("dop853", TIGHT),
                                              ("rk45", dict(rtol=1e-8, atol=1e-11)),
                                              ("radau", dict(rtol=1e-8))])
def test_every_method_holds_a_chattering_rod_at_the_same_impact(method, settings):
    """The same guard governs fixed-step and adaptive methods and reads the impacts alone: the
    rod chattering with no rest speed (e = 0.5, intervals and speeds halving) is held at the
    impact where the tail still to come fits in ZENO_TAIL — the same impact, by count, for every
    method and step — and the guard replayed on the logged impacts picks that very impact. The
    hold removes a negligible energy, booked apart from the law's."""
    e, g = 0.5, 10.0
    doc = one_link_doc(**VERTICAL, effects={"gravity": g, "stroke_limits": {
        "restitution": e, "rest_speed": 0.0}})
    sim = simulation(doc, method, **settings)
    sim.advance_to(1.2)
    held = [i for i, detail in enumerate(sim.impact_details) if detail.held]
    assert held == [len(sim.impacts) - 1] and sim.resting[0] == -1
    assert all(i.link == 1 and i.stop == "lower" for i in sim.impacts)
    # closed form: impact n arrives at v_0 eⁿ after an interval Δ_n = (2 v_0 / g) eⁿ (n ≥ 1), so
    # from n = 2 on both shrink; the guard sees an accumulation at the first n with either
    # Δ_n ≤ ZENO_TAIL, or ZENO_RUN shrinking intervals (n ≥ ZENO_RUN + 1) and a geometric tail
    # Δ_n · e / (1 − e) ≤ ZENO_TAIL
    v0 = math.sqrt(2.0 * g * 0.5)
    first = next(n for n in range(1, 200)
                 if 2.0 * v0 / g * e ** n <= events.ZENO_TAIL
                 or n >= events.ZENO_RUN + 1
                 and 2.0 * v0 / g * e ** n * e / (1.0 - e) <= events.ZENO_TAIL)
    assert len(sim.impacts) == first + 1
    run = np.zeros((1, 2, events.RUN_FIELDS))
    replay = [zeno_guard(run, 1, -1, i.time, abs(i.ld_before), 1.0) >= 0.0
              for i in sim.impacts]
    assert replay.index(True) == held[0]
    assert sim.holds == 1 and sim.impacts[-1].held
    assert 0.0 <= sim.hold_energy <= events.ZENO_SHARE * 0.5 * v0 ** 2


@pytest.mark.parametrize("method, settings", [("rk4", dict(dt=1e-3)), ("dop853", TIGHT),
                                              ("radau", dict(rtol=1e-8))])
def test_two_rods_trading_impacts_with_no_rest_speed_both_end_held(method, settings):
    """Rod 2 pushed into its upper stop by 20 N, rod 1 falling onto its lower one (revolute
    joints locked, gravity, e = 0.5, rest_speed 0): each rod's small bounces kick the other off
    its stop, which cannot pull, so the two trade ever smaller impacts. No rest speed ends that;
    the guard's runs per rod and stop do, and both rods end held with a bounded number of
    impacts."""
    doc = paper_doc(efforts={"wheels": [0.0, 0.0], "joints": [0.0, 0.0, 0.0, 20.0]},
                    effects={"gravity": 10.0, "wheel_inertia": True,
                             "locked_joints": ["arm_revolute_1", "arm_revolute_2"],
                             "stroke_limits": {"restitution": 0.5, "rest_speed": 0.0}})
    sim = simulation(doc, method, **settings)
    _, states = sampled(sim, 1.0, 100)
    assert_in_stroke(sim, states)
    assert list(sim.resting) == [-1, 1]
    assert {(i.link, i.stop) for i in sim.impacts} == {(1, "lower"), (2, "upper")}
    assert len(sim.impacts) < 1000
    sim.advance_to(1.5)   # and they stay held
    assert list(sim.resting) == [-1, 1]


# --- no tunnelling -------------------------------------------------------------------------

def fast_rod_doc(side, restitution, fixed_step, overshoot):
    """Rod 1 on a fixed base, gravity off, q̇ = 0: l̈ = F/m exactly (m = μL = 1 kg).

    It runs at a stop and a strong constant force turns it back `overshoot` m past the stop, so
    the stop is crossed and recrossed inside one step: for rk4 with dt = 0.05 by construction,
    for the adaptive methods as checked against SciPy's own steps in the test.
    """
    if fixed_step:   # from 0.02 m inside at 5 m/s: out and back well within 0.05 s
        l0, speed = 0.98, 5.0
        accel = speed ** 2 / (2.0 * (0.02 + overshoot))
    else:            # from mid-stroke at 10 m/s²
        l0, accel = 0.5, 10.0
        speed = math.sqrt(2.0 * accel * (0.5 + overshoot))
    if side < 0:
        l0 = 1.0 - l0
    return (one_link_doc(joints=(0.0, l0), velocity=(0.0, 0.0, 0.0, side * speed),
                         joint_efforts=(0.0, -side * accel),
                         effects={"fixed_base": True,
                                  "stroke_limits": {"restitution": restitution}}),
            l0, speed, accel)


def engine_step_ends(doc, method, settings, t_end):
    """l_1 at the end of every step of the engine's compiled solve over [0, t_end], stops off.
    Targets do not cut its steps, so advancing through many small targets visits each step in
    hand (the compiled stepper's) without changing them."""
    doc = copy.deepcopy(doc)
    del doc["effects"]["stroke_limits"]
    sim = simulation(doc, method, **settings)
    ends = {}
    for t in np.linspace(0.0, t_end, 2001)[1:]:
        sim.advance_to(t)
        ends[sim._stepper.step_in_hand()[0]] = sim._stepper.step_end()[layout.q_slide(1)]
    assert len(ends) > 1
    return list(ends.values())


@pytest.mark.parametrize("method", ["rk4", "dop853", "rk45", "radau", "bdf"])
@pytest.mark.parametrize("side", [-1, 1], ids=["lower", "upper"])
@pytest.mark.parametrize("restitution", [0.0, 1.0])
@pytest.mark.parametrize("overshoot", [1e-2, 1e-6])
def test_a_rod_that_crosses_and_returns_within_one_step_is_caught(method, side, restitution,
                                                                  overshoot):
    fixed = method == "rk4"
    settings = (dict(dt=0.05) if fixed else dict(rtol=1e-6, atol=1e-9) if method == "bdf"
                else dict(rtol=1e-8, atol=1e-11))
    doc, l0, speed, accel = fast_rod_doc(side, restitution, fixed, overshoot)
    stop = 1.0 if side > 0 else 0.0
    t_end = 0.05 if fixed else 2.0 * speed / accel
    # The crossing time: l0 + side (speed t − accel t²/2) = stop.
    distance = abs(stop - l0)
    t_hit = (speed - math.sqrt(speed ** 2 - 2.0 * accel * distance)) / accel
    ld_hit = side * (speed - accel * t_hit)
    sim = simulation(doc, method, **settings)
    # Premise: no step of the method ends past the stop (a sign-change test would miss it).
    if fixed:
        assert side * (l0 + side * (speed * 0.05 - 0.5 * accel * 0.05 ** 2) - stop) < 0.0
    else:
        solver = SCIPY[method](lambda _t, y: sim.system.derivative(y), 0.0, sim.s.copy(), t_end,
                               **settings)
        ends = []
        while solver.status == "running":
            solver.step()
            ends.append(solver.y[layout.q_slide(1)])
        assert all(side * (l - stop) < 0.0 for l in ends)
    if method in ("rk45", "dop853"):   # … nor of the engine's own solve
        assert all(side * (l - stop) < 0.0 for l in engine_step_ends(doc, method, settings, t_end))
    sim.advance_to(t_end)
    assert len(sim.impacts) >= 1
    impact = sim.impacts[0]
    assert impact.stop == ("upper" if side > 0 else "lower")
    tol = 1e-9 if method != "bdf" else 1e-6
    assert impact.time == pytest.approx(t_hit, abs=tol)
    assert impact.ld_before == pytest.approx(ld_hit, abs=tol)
    assert impact.ld_after == pytest.approx(-restitution * ld_hit, abs=tol)
    lo, hi = sim.stroke[0]
    assert lo - 1e-9 <= sim.q[L_1] <= hi + 1e-9


@pytest.mark.parametrize("method, settings", [("rk4", dict(dt=0.01)), ("euler", dict(dt=0.01)),
                                              ("dop853", TIGHT), ("rk45", dict(rtol=1e-6))])
def test_a_rod_faster_than_its_stroke_per_step_bounces_at_every_stop(method, settings):
    """20 m/s in a 0.1 m stroke with e = 1: two impacts per 0.01 s step, at t = 0.0025 + 0.005 i."""
    doc = one_link_doc(joints=(0.0, 0.5), stroke=(0.45, 0.55), velocity=(0.0, 0.0, 0.0, 20.0),
                       effects={"fixed_base": True, "stroke_limits": {"restitution": 1.0}})
    sim = simulation(doc, method, **settings)
    _, states = sampled(sim, 0.1, 100)
    assert_in_stroke(sim, states)
    times = [impact.time for impact in sim.impacts]
    assert times == pytest.approx(0.0025 + 0.005 * np.arange(20), abs=1e-12)
    assert [impact.stop for impact in sim.impacts] == ["upper", "lower"] * 10
    assert sim.q[L_1] == pytest.approx(0.5, abs=1e-12) and sim.u[LD_1] == 20.0


# --- the impact law ------------------------------------------------------------------------

def first_impact(doc, law, restitution):
    doc = dict(doc)
    doc["effects"] = dict(doc["effects"], stroke_limits={"restitution": restitution, "law": law})
    sim = probe(doc, "dop853", **TIGHT)
    while not sim.probed and sim.t < 2.0:
        sim.advance_to(sim.t + 0.01)
    assert sim.probed, "no impact within 2 s"
    return sim, sim.probed[0]


@pytest.mark.parametrize("restitution", [0.0, 0.6, 1.0])
def test_impulse_and_reflect_differ_where_the_mass_matrix_couples(restitution):
    """Paper robot, free base: the l̇_1 row of M has off-diagonal terms, so the impulse moves the
    other velocities (M Δu ∥ e_k: momentum changes only along the struck DOF), reflect does not."""
    doc = bouncing_doc(1.0)
    results = {}
    for law in ("impulse", "reflect"):
        sim, (q, u_before, u_after, free, _) = first_impact(doc, law, restitution)
        impact = sim.impacts[0]
        j = 2 * impact.link + 1
        M = sim.dynamics.mass_matrix(q)
        assert np.max(np.abs(np.delete(M[j], j))) > 0.05
        assert u_after[j] == pytest.approx(-restitution * u_before[j], abs=1e-15)
        others = np.delete(np.arange(len(u_before)), j)
        if law == "reflect":
            assert np.all(u_after[others] == u_before[others])
        else:
            assert np.max(np.abs(u_after[others] - u_before[others])) > 1e-2
            momentum_change = M @ (u_after - u_before)
            assert np.max(np.abs(momentum_change[others])) < 1e-12 * np.abs(momentum_change[j])
        results[law] = (impact.time, u_after)
    assert results["impulse"][0] == results["reflect"][0]   # same approach, same instant
    assert np.max(np.abs(results["impulse"][1] - results["reflect"][1])) > 1e-2


@pytest.mark.parametrize("case", ["fixed_base_spinning_rod", "free_base_vertical_rod"])
def test_impulse_and_reflect_agree_where_the_mass_matrix_does_not_couple(case):
    """Where e_k is an eigenvector of M (the l̇ row diagonal), both laws are the same map."""
    if case == "fixed_base_spinning_rod":
        # Joint axis vertical, base held: M = diag(I(l), m) over (q̇_1, l̇_1) at every l; the
        # spin flings the rod out against its upper stop, again and again.
        doc = one_link_doc(joint_rpy=(0.0, 0.0, 0.0), joints=(0.0, 0.6), stroke=(0.2, 0.8),
                           velocity=(0.0, 0.0, 6.0, 0.0), effects={"fixed_base": True})
        free = [2, 3]
    else:
        # Rod straight up on the axis through A: sliding it moves no other DOF.
        doc = one_link_doc(**VERTICAL, effects={"gravity": 10.0})
        free = [0, 1, 2, 3]
    runs = {}
    for law in ("impulse", "reflect"):
        sim, (q, *_) = first_impact(doc, law, 0.6)
        M = sim.dynamics.mass_matrix(q)[np.ix_(free, free)]
        row = M[free.index(3)]
        assert np.max(np.abs(np.delete(row, free.index(3)))) < 1e-14 * row[free.index(3)]
        sim.advance_to(1.0)
        assert len(sim.impacts) >= 3
        runs[law] = sim
    impulse, reflect = runs["impulse"], runs["reflect"]
    assert [i.time for i in impulse.impacts] == pytest.approx([i.time for i in reflect.impacts],
                                                              abs=1e-12)
    assert np.max(np.abs(impulse.s - reflect.s)) < 1e-12
    # … and it conserves what it should: e = 0.6 loses exactly ½ (1 − e²) m (l̇⁻)² per impact.
    for impact in impulse.impacts:
        assert impact.energy_lost == pytest.approx(0.5 * 0.64 * impact.ld_before ** 2, rel=1e-12)


def test_a_rod_leaving_its_stop_is_released_at_the_located_instant():
    """The paper run: rod 2 rests at its lower stop from 0.59 s; rod 1's impact at 0.78 s throws
    it off (its stop could only have held it by pulling: the unilateral law), it lands again at
    0.96 s and is pulled off near 1.13 s. The release is located inside the step (like an
    impact), so fixed-step runs converge to the tight reference across it; deciding at step ends
    left a 4e-4 error at every dt."""
    scene = load_scene()

    def states(method, **settings):
        sim = Simulation(scene, make_integrator(scene.integrator, method=method, **settings))
        rows = []
        for j in range(1, 151):
            sim.advance_to(j * 0.01)
            rows.append(sim.s[:-1].copy())
        return np.array(rows), sim

    reference, tight = states("dop853", rtol=1e-13, atol=1e-14)
    assert [impact.link for impact in tight.impacts] == [2, 1, 2]
    assert tight.resting[1] == 0 and tight.q[L_2] > 0.1        # rod 2 really left its stop
    coarse, _ = states("rk4", dt=3e-4)
    fine, _ = states("rk4", dt=1e-4)
    assert np.abs(coarse - reference).max() < 1e-8
    assert np.abs(fine - reference).max() < 1e-10
