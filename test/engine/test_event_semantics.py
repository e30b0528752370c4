"""When events happen (docs/model.md, "Resting, leaving, and no Zeno"; engine/events.py, stops.py,
stepping.py): a resting rod
released at the located instant inside a step, rods reaching their stops together solved as one
impact whatever round-off says, settling that never pulls, and a Zeno guard set by the impact
times, not by the step or the tolerance.

Each case has an answer that cannot be tuned: a closed form (a rigid spin-up at constant angular
acceleration, a rod bouncing under gravity alone), docs/model.md's multi-contact law worked by hand,
or a sign (a stop only pushes).
"""
import math
import warnings

import numpy as np
import pytest

from engine_cases import one_link_doc, paper_doc, simulation
from mobile_manip_sim.core import zeno_guard
from mobile_manip_sim.engine import events, layout

L_2 = layout.q_slide(2)   # l_2 in q
LD_1, LD_2, QD_1 = layout.u_slide(1), layout.u_slide(2), layout.u_turn(1)   # l̇_1, l̇_2, q̇_1 in u

TIGHT = dict(rtol=1e-12, atol=1e-14)


# --- a release due inside a step ---------------------------------------------------------

J = 0.0008           # cross-section inertia per length (the paper's), kg·m
TAU, F1, F2 = 1.0, 5.0, -2.0


def spin_up_doc():
    """Fixed base, both joint axes vertical, the arm straight out along x_1 with revolute 2
    locked. Rod 1 (1 kg) rests at its upper stop (l1 = 1, pushed out by F1), rod 2 (1 kg) at its
    lower one (l2 = 0, pulled in by F2), so the arm is one rigid body spun up about joint 1 by a
    constant torque τ: ω = α t exactly, α = τ / I, I = 2 · (1/3) + 2 J. Rod 2's centre sits
    r = 0.5 m from the axis; its stop holds it while −F2 ≥ m ω² r, so it leaves at
    t* = √(−F2 / (m r)) / α, inside a step of every method below."""
    doc = paper_doc()
    links = doc["robot"]["arm"]["links"]
    for link in links:
        link.update(joint_rpy=[0.0, 0.0, 0.0], length=1.0, mass_per_length=1.0,
                    inertia_per_length=[J, J, J], stroke=[0.0, 1.0])
    doc["initial"] = {"joints": [0.0, 1.0, 0.0, 0.0], "velocity": [0.0] * 6}
    doc["efforts"] = {"wheels": [0.0, 0.0], "joints": [TAU, F1, 0.0, F2]}
    doc["effects"] = {"fixed_base": True, "locked_joints": ["arm_revolute_2"],
                      "stroke_limits": {"restitution": 0.0}}
    return doc


ALPHA = TAU / (2.0 / 3.0 + 2.0 * J)
T_RELEASE = math.sqrt(-F2 / (1.0 * 0.5)) / ALPHA
RELEASE_METHODS = [("rk4", dict(dt=1e-3)), ("semi_implicit_euler", dict(dt=1e-3)),
                   ("dop853", dict(rtol=1e-9, atol=1e-12))]


@pytest.mark.parametrize("method, settings", RELEASE_METHODS, ids=[m for m, _ in RELEASE_METHODS])
def test_a_release_due_inside_a_step_happens_at_the_closed_form_instant(method, settings):
    assert 1e-4 < T_RELEASE % 1e-3 < 9e-4   # not on the fixed-step grid
    doc = spin_up_doc()
    before = simulation(doc, method, **settings)
    before.advance_to(math.floor(T_RELEASE * 1e3) * 1e-3)   # the grid step before the release
    assert list(before.resting) == [1, -1]
    assert before.u[QD_1] == pytest.approx(ALPHA * before.t, rel=1e-12)   # the spin-up is exact
    before.advance_to(T_RELEASE - 1e-9)
    assert list(before.resting) == [1, -1]
    after = simulation(doc, method, **settings)
    after.advance_to(T_RELEASE + 1e-9)
    assert list(after.resting) == [1, 0]
    # inside a whole grid step: released within it, and then moving out (its stop never pulled)
    on_grid = simulation(doc, method, **settings)
    on_grid.advance_to(math.ceil(T_RELEASE * 1e3) * 1e-3)
    assert list(on_grid.resting) == [1, 0]
    on_grid.advance_to(on_grid.t + 2e-3)
    assert on_grid.q[L_2] > 0.0 and on_grid.u[LD_2] > 0.0
    assert all(i.time < 1e-6 and i.resting for i in on_grid.impacts)   # settling at the start


def spin_up_state(method, t_end, **settings):
    sim = simulation(spin_up_doc(), method, **settings)
    sim.advance_to(t_end)
    assert sim.resting[1] == 0
    return sim.s[:-1].copy()


@pytest.mark.parametrize("method, order", [("rk4", 4), ("semi_implicit_euler", 1)])
def test_after_a_release_inside_a_step_the_run_converges_at_the_methods_order(method, order):
    """0.3 s past the release (rod 2 sliding out of the spinning arm): the error against a tight
    reference falls as dt^order; a release held to the end of its step would cost O(dt)."""
    t_end = T_RELEASE + 0.3
    reference = spin_up_state("dop853", t_end, **TIGHT)
    errors = [np.abs(spin_up_state(method, t_end, dt=dt) - reference).max()
              for dt in (8e-3, 4e-3, 2e-3)]
    rates = [math.log2(a / b) for a, b in zip(errors[:-1], errors[1:], strict=True)]
    assert all(abs(rate - order) < 0.5 for rate in rates), (errors, rates)


# --- simultaneous impacts ----------------------------------------------------------------

def collinear_doc(dl2=0.0):
    """Fixed base, collinear arm, no gravity, no efforts: along (l̇1, l̇2) M = [[2, 1], [1, 1]].
    Rod 1 moves out at 1 m/s, 0.0105 m from its upper stop; rod 2 moves in at 0.5 m/s,
    0.00525 m (+ dl2) from its lower one: both arrive at t = 0.0105 s, e = 0.5.

    docs/model.md by hand: contacts σ = (−1, +1), W = Eᵀ M⁻¹ E = [[1, 1], [1, 2]], c⁻ = (−1, −0.5),
    (1 + e) c⁻ = (−1.5, −0.75). Both active: P = (2.25, −0.75), not ≥ 0; rod 1 alone: P1 = 1.5,
    w2 = 1.5 − 0.75 = 0.75 ≥ 0. So u⁺ = u⁻ + M⁻¹ E P = (−0.5, 1.0) m/s, T: 0.625 → 0.25 J, 0.375 J
    lost. Rod 2 first and then rod 1 would give (−0.3125, 1.1875) and 0.193 J."""
    doc = paper_doc()
    for link in doc["robot"]["arm"]["links"]:
        link.update(joint_rpy=[0.0, 0.0, 0.0], length=1.0, mass_per_length=1.0, stroke=[0.0, 1.0])
    doc["initial"] = {"joints": [0.0, 1.0 - 0.0105, 0.0, 0.00525 + dl2],
                      "velocity": [0.0, 0.0, 0.0, 1.0, 0.0, -0.5]}
    doc["efforts"] = {"wheels": [0.0, 0.0], "joints": [0.0, 0.0, 0.0, 0.0]}
    doc["effects"] = {"fixed_base": True, "stroke_limits": {"restitution": 0.5, "rest_speed": 1e-3}}
    return doc


@pytest.mark.parametrize("dl2", [0.0, 1e-15, -1e-15, 2e-10],
                         ids=["exact", "+1e-15", "-1e-15", "+2e-10"])
@pytest.mark.parametrize("method, settings",
                         [("rk4", dict(dt=1e-3)), ("semi_implicit_euler", dict(dt=1e-3)),
                          ("dop853", dict(rtol=1e-9, atol=1e-12)), ("radau", dict(rtol=1e-8))])
def test_two_rods_reaching_their_stops_together_are_one_impact(method, settings, dl2):
    sim = simulation(collinear_doc(dl2), method, **settings)
    sim.advance_to(0.02)
    assert [(i.link, i.stop) for i in sim.impacts] in ([(1, "upper"), (2, "lower")],
                                                       [(2, "lower"), (1, "upper")])
    assert sim.impacts[0].time == sim.impacts[1].time == pytest.approx(0.0105, abs=1e-9)
    j1, j2 = 3, 5
    detail = sim.impact_details[-1]
    assert detail.u_after[j1] == pytest.approx(-0.5, abs=1e-12)
    assert detail.u_after[j2] == pytest.approx(1.0, abs=1e-12)
    assert sum(i.energy_lost for i in sim.impacts) == pytest.approx(0.375, abs=1e-12)
    assert sim.u[LD_1] == pytest.approx(-0.5, abs=1e-12)
    assert sim.u[LD_2] == pytest.approx(1.0, abs=1e-12)
    assert not sim.resting.any()


def test_rods_farther_apart_in_time_than_the_tolerance_are_two_impacts():
    """Rod 2 arriving 1e-6 s before rod 1 (≫ SIMULTANEOUS): two impacts, rod 2's alone
    (P2 = 0.75 / 2: u = (0.625, 0.25)) and then rod 1's, the sequential answer."""
    assert events.SIMULTANEOUS < 1e-6
    sim = simulation(collinear_doc(-0.5e-6), "dop853", rtol=1e-10, atol=1e-13)
    sim.advance_to(0.02)
    assert [i.link for i in sim.impacts] == [2, 1]
    # rod 1, then 1e-6 m from its stop, covers it at 0.625 m/s
    assert sim.impacts[1].time - sim.impacts[0].time == pytest.approx(1.6e-6, rel=1e-6)
    assert sim.impact_details[0].u_after[[3, 5]] == pytest.approx([0.625, 0.25], abs=1e-9)
    assert sim.u[[3, 5]] == pytest.approx([-0.3125, 1.1875], abs=1e-9)
    assert sum(i.energy_lost for i in sim.impacts) == pytest.approx(0.625 - 0.431640625, abs=1e-9)


# --- a bouncing rod: one impact count whatever the method ---------------------------------

VERTICAL = dict(joints=(math.pi / 2, 0.5), stroke=(0.0, 1.0))   # rod 1 straight up


def test_a_bouncing_rods_impact_count_does_not_depend_on_the_tolerance():
    """A vertical rod dropped onto its lower stop (g = 10, e = 0.9) bounces at
    v_n = v_0 eⁿ until its rebound e v_n falls below rest_speed (4 mm/s: bounces of 4–8 mm/s
    come last, a few ms apart). Every method and tolerance resolves the same impacts: the Zeno
    guard looks at impact times, never at the step."""
    e, g, rest_speed = 0.9, 10.0, 4e-3
    v0 = math.sqrt(2.0 * g * 0.5)
    expected = next(n for n in range(1000) if e * v0 * e ** n < rest_speed) + 1
    assert 0.5 < (e * v0 * e ** (expected - 1)) / rest_speed < 0.95   # not near the threshold
    doc = one_link_doc(**VERTICAL, effects={"gravity": g, "stroke_limits": {
        "restitution": e, "rest_speed": rest_speed}})
    counts = {}
    for label, method, settings in [("rk4 1 ms", "rk4", dict(dt=1e-3)),
                                    *[(f"dop853 {r:g}", "dop853", dict(rtol=r, atol=r * 1e-3))
                                      for r in (1e-4, 1e-8, 1e-12)]]:
        sim = simulation(doc, method, **settings)
        sim.advance_to(25.0)
        counts[label] = len(sim.impacts)
        assert sim.resting[0] == -1 and sim.impacts[-1].resting
        assert not any(d.held for d in sim.impact_details)
        assert sim.impacts[-1].ld_before == pytest.approx(-v0 * e ** (expected - 1), rel=1e-6)
    assert set(counts.values()) == {expected}, counts


# --- the Zeno guard on the impacts (its evidence; the energy test is test_zeno_guard.py's) ----

def guard_calls(times, speeds=None, k=1, side=-1, n_links=2):
    """Whether the guard sees an accumulation at each impact (rod k at its stop ``side``)."""
    run = np.zeros((n_links, 2, events.RUN_FIELDS))
    speeds = np.ones(len(times)) if speeds is None else speeds
    return [zeno_guard(run, k, side, t, v, 1.0) >= 0.0
            for t, v in zip(times, speeds, strict=True)]


def test_the_zeno_guard_sees_an_accumulation_where_the_tail_of_a_geometric_run_fits():
    ratio = 0.5
    intervals = 0.1 * ratio ** np.arange(40)
    times = np.concatenate([[0.0], np.cumsum(intervals)])
    held = guard_calls(times, 2.0 * ratio ** np.arange(41))
    first = held.index(True)
    tail = intervals[first - 1] * ratio / (1.0 - ratio)    # what the guard estimates there
    assert tail <= events.ZENO_TAIL < tail / ratio
    assert not any(held[:first])


def test_the_zeno_guard_never_sees_an_accumulation_in_runs_that_do_not_shrink():
    assert not any(guard_calls(0.02 * np.arange(500)))                    # regular bounces
    assert not any(guard_calls(np.cumsum(1e-5 * 1.01 ** np.arange(300))))  # growing intervals


def test_the_zeno_guard_keeps_one_record_per_rod_and_stop():
    run = np.zeros((2, 2, events.RUN_FIELDS))
    t = np.cumsum(0.1 * 0.5 ** np.arange(30))
    v = 2.0 * 0.5 ** np.arange(30)
    held = []
    for i, ti in enumerate(t):   # rod 1's accumulating run, rod 2 hitting its upper stop
        held.append(zeno_guard(run, 1, -1, ti, v[i], 1.0) >= 0.0)   # regularly between
        assert zeno_guard(run, 2, 1, 1.0 + 0.05 * i, 1.0, 1.0) < 0.0
    assert held == guard_calls(t, v)


# --- no stop ever pulls -------------------------------------------------------------------

def two_pressed_rods_doc(rest_speed):
    """Rod 2 pushed into its upper stop by 20 N, rod 1 falling onto its lower one (revolute
    joints locked, gravity, e = 0.5): under the unilateral law each rod's last small bounces kick
    the other off its stop."""
    return paper_doc(efforts={"wheels": [0.0, 0.0], "joints": [0.0, 0.0, 0.0, 20.0]},
                     effects={"gravity": 10.0, "wheel_inertia": True,
                              "locked_joints": ["arm_revolute_1", "arm_revolute_2"],
                              "stroke_limits": {"restitution": 0.5, "rest_speed": rest_speed}})


def pushes_only(sim, detail, impact, tol):
    """σ · (M Δu)_j ≥ −tol on every contact of the impact (a stop only pushes)."""
    M = sim.dynamics.mass_matrix(detail.q)
    impulse = M @ (detail.u_after - detail.u_before)
    for k in range(1, sim.model.n_links + 1):
        j = layout.u_slide(k)
        l = detail.q[layout.q_slide(k)]
        lo, hi = sim.stroke[k - 1]
        if l == lo:
            assert impulse[j] >= -tol, (impact, impulse[j])
        elif l == hi:
            assert impulse[j] <= tol, (impact, impulse[j])


@pytest.mark.parametrize("method, settings",
                         [("rk4", dict(dt=1e-3)), ("dop853", dict(rtol=1e-10, atol=1e-12))])
def test_settling_impacts_never_let_a_stop_pull(method, settings):
    """rest_speed 0.05 m/s: the last impacts arrive slower than it and are solved with e = 0
    by the same unilateral law, so a neighbour that an impulse would throw off is thrown off
    (slowly) instead of being held by a pulling stop; only held (Zeno) impacts may hold a
    contact bilaterally, by at most the momentum of the tail they cut off."""
    sim = simulation(two_pressed_rods_doc(0.05), method, **settings)
    sim.advance_to(1.5)
    assert list(sim.resting) == [-1, 1]
    slow = [(i, d) for i, d in zip(sim.impacts, sim.impact_details, strict=True)
            if abs(i.ld_before) < 0.05 / 0.5 and not d.held]
    assert slow, "the scene has settling impacts"
    for impact, detail in slow:
        pushes_only(sim, detail, impact, 1e-12)
    for impact, detail in zip(sim.impacts, sim.impact_details, strict=True):
        pushes_only(sim, detail, impact, 1e-12 if not detail.held else 1e-4)


# --- semi-implicit Euler with stops that rebound --------------------------------------------

def test_semi_implicit_euler_with_rebounding_stops_warns_in_one_line():
    with pytest.warns(RuntimeWarning,
                      match="semi_implicit_euler with end stops that rebound") as caught:
        simulation(collinear_doc(), "semi_implicit_euler", dt=1e-3)
    assert len(caught) == 1 and "\n" not in str(caught[0].message)
    plastic = collinear_doc()
    plastic["effects"]["stroke_limits"]["restitution"] = 0.0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        simulation(plastic, "semi_implicit_euler", dt=1e-3)     # no rebound: no warning
        simulation(collinear_doc(), "rk4", dt=1e-3)
