"""The Zeno guard holds only true accumulations, and the energy it removes is booked apart
(docs/model.md, "Resting, leaving, and no Zeno"; core/include/mms/stops.hpp `zeno_guard`,
`impact`).

The reference is exact and independent of the engine: two collinear rods on a fixed base with no
gravity move freely at constant l̇ between impacts (M along (l̇1, l̇2) is the constant
[[2, 1], [1, 1]]), so the cascade of rigid impacts is computed event by event in closed form
here, each impact by the single-contact law of docs/model.md.
"""
import math

import numpy as np
import pytest

from engine_cases import paper_doc, simulation
from mobile_manip_sim.core import zeno_guard
from mobile_manip_sim.engine import events, layout

LD_1, LD_2 = layout.u_slide(1), layout.u_slide(2)
M = np.array([[2.0, 1.0], [1.0, 1.0]])   # along (l̇1, l̇2): rod 2 slides along rod 1's end
GAP_1 = 0.0105                          # m: rod 1 from its upper stop at t = 0

METHODS = [("rk4", dict(dt=1e-3)), ("semi_implicit_euler", dict(dt=1e-3)),
           ("euler", dict(dt=1e-3)),
           ("rk45", dict(rtol=1e-8, atol=1e-11)), ("dop853", dict(rtol=1e-10, atol=1e-13)),
           ("dop853", dict(rtol=1e-4, atol=1e-7)),
           ("radau", dict(rtol=1e-8, atol=1e-11)), ("bdf", dict(rtol=1e-8, atol=1e-11))]
IDS = [f"{m}-{next(iter(s.values())):g}" for m, s in METHODS]


def cascade_doc(delay, restitution=1.0):
    """Both rods (1 kg, 1 m) at +1 m/s towards their upper stops; rod 2 reaches its stop
    ``delay`` s after rod 1 (at t = 0.0105 s); e as given, rest_speed 0."""
    doc = paper_doc()
    for link in doc["robot"]["arm"]["links"]:
        link.update(joint_rpy=[0.0, 0.0, 0.0], length=1.0, mass_per_length=1.0, stroke=[0.0, 1.0])
    doc["initial"] = {"joints": [0.0, 1.0 - GAP_1, 0.0, 1.0 - GAP_1 - delay],
                      "velocity": [0.0, 0.0, 0.0, 1.0, 0.0, 1.0]}
    doc["efforts"] = {"wheels": [0.0, 0.0], "joints": [0.0, 0.0, 0.0, 0.0]}
    doc["effects"] = {"fixed_base": True,
                      "stroke_limits": {"restitution": restitution, "rest_speed": 0.0}}
    return doc


def exact_cascade(delay, e, t_end=0.02):
    """The rigid cascade, event by event: [(t, rod, l̇ before, l̇ after)], the final l̇ and T.
    Rod k at its upper stop (l_k = 1) moving out is hit by the single-contact law:
    u⁺ = u⁻ − (1 + e) (e_kᵀ u⁻ / (M⁻¹)_kk) M⁻¹ e_k."""
    Minv = np.linalg.inv(M)
    l = np.array([1.0 - GAP_1, 1.0 - GAP_1 - delay])
    u = np.array([1.0, 1.0])
    t, hits = 0.0, []
    for _ in range(10_000):
        times = [(1.0 - l[k]) / u[k] if u[k] > 0.0 else math.inf for k in range(2)]
        k = int(np.argmin(times))
        if t + times[k] > t_end:
            break
        t += times[k]
        l += u * times[k]
        l[k] = 1.0
        before = u[k]
        u = u - (1.0 + e) * u[k] / Minv[k, k] * Minv[:, k]
        hits.append((t, k + 1, before, u[k]))
    return hits, u, 0.5 * u @ M @ u


@pytest.mark.parametrize("delay", [300e-9, 30e-6], ids=["300ns", "30us"])
def test_the_exact_cascade_is_four_impacts_and_keeps_its_energy(delay):
    hits, u, T = exact_cascade(delay, 1.0)
    assert [k for _, k, _, _ in hits] == [1, 2, 1, 2]
    assert u == pytest.approx([-1.0, -1.0], abs=1e-12) and T == pytest.approx(2.5, abs=1e-12)


@pytest.mark.parametrize("method, settings", METHODS, ids=IDS)
@pytest.mark.parametrize("delay", [300e-9, 30e-6], ids=["300ns", "30us"])
def test_a_finite_cascade_between_coupled_rods_is_never_held(method, settings, delay):
    """e = 1, rest_speed 0: rod 1 hits twice within 150 ns (300 ns case), which is no
    accumulation — four impacts, (−1, −1) m/s, T = 2.5 J kept, no hold, energy error ~0."""
    with pytest.warns(RuntimeWarning) if method == "semi_implicit_euler" else _no_warning():
        sim = simulation(cascade_doc(delay), method, **settings)
    sim.advance_to(0.02)
    expected, _, _ = exact_cascade(delay, 1.0)
    assert [i.link for i in sim.impacts] == [k for _, k, _, _ in expected]
    for impact, (t, _, before, after) in zip(sim.impacts, expected, strict=True):
        assert impact.time == pytest.approx(t, abs=1e-9)
        assert impact.ld_before == pytest.approx(before, abs=1e-9)
        assert impact.ld_after == pytest.approx(after, abs=1e-9)
        assert not impact.held and impact.hold_energy == 0.0
    assert sim.u[[LD_1, LD_2]] == pytest.approx([-1.0, -1.0], abs=1e-9)
    T = 0.5 * sim.u[[LD_1, LD_2]] @ M @ sim.u[[LD_1, LD_2]]
    assert T == pytest.approx(2.5, abs=1e-9)
    assert sim.holds == 0 and sim.hold_energy == 0.0
    assert abs(sim.energy_error()) < 1e-9


@pytest.mark.parametrize("method, settings", METHODS[:1] + METHODS[3:5] + METHODS[6:7],
                         ids=IDS[:1] + IDS[3:5] + IDS[6:7])
@pytest.mark.parametrize("restitution", [0.5, 0.9])
def test_an_inelastic_cascade_loses_exactly_the_exact_cascades_energy(method, settings,
                                                                      restitution):
    delay = 300e-9
    expected, u, T = exact_cascade(delay, restitution)
    sim = simulation(cascade_doc(delay, restitution), method, **settings)
    sim.advance_to(0.02)
    assert len(sim.impacts) == len(expected)
    assert sim.holds == 0
    assert sim.u[[LD_1, LD_2]] == pytest.approx(u, abs=1e-9)
    assert sim.impact_energy_lost == pytest.approx(2.5 - T, abs=1e-9)
    assert sum(i.energy_lost for i in sim.impacts) == pytest.approx(2.5 - T, abs=1e-9)
    assert abs(sim.energy_error()) < 1e-9


class _no_warning:
    def __enter__(self):
        import warnings
        self._catch = warnings.catch_warnings()
        self._catch.__enter__()
        warnings.simplefilter("error")

    def __exit__(self, *exc):
        return self._catch.__exit__(*exc)


# --- the guard's evidence, on impact times and speeds alone ---------------------------------

def guard(times, speeds, T=1.0, k=1, side=-1, n_links=2):
    run = np.zeros((n_links, 2, events.RUN_FIELDS))
    return [float(zeno_guard(run, k, side, t, v, T))
            for t, v in zip(times, speeds, strict=True)]


def test_one_or_two_short_intervals_are_evidence_only_with_an_energy_allowance():
    """A short interval is evidence; what a hold may then remove is ZENO_SHARE of the largest
    kinetic energy at that stop — the engine holds only if the hold costs no more."""
    allowed = guard([0.0, 0.045, 0.045 + 24e-6, 0.045 + 24.1e-6], [5.0, 5.0, 4.0, 4.5], T=14.3)
    assert allowed[:3] == [-1.0, -1.0, -1.0]    # 45 ms then 24 µs: no evidence
    assert allowed[3] == pytest.approx(events.ZENO_SHARE * 14.3)   # 100 ns: evidence


def test_a_geometric_run_is_evidence_where_its_tail_fits_in_zeno_tail():
    ratio = 0.5
    intervals = 0.1 * ratio ** np.arange(40)
    times = np.concatenate([[0.0], np.cumsum(intervals)])
    speeds = 3.0 * ratio ** np.arange(41)
    allowed = guard(times, speeds)
    first = next(i for i, a in enumerate(allowed) if a >= 0.0)
    tail = intervals[first - 1] * ratio / (1.0 - ratio)
    assert tail <= events.ZENO_TAIL < tail / ratio
    assert first >= events.ZENO_RUN + 1


def test_runs_that_do_not_shrink_in_speed_are_no_geometric_evidence():
    intervals = 0.01 * 0.1 ** np.arange(4)          # shrinking fast, but the speed does not
    times = np.concatenate([[0.0], np.cumsum(intervals)])
    assert all(a < 0.0 for a in guard(times, np.full(times.size, 2.0)))
    assert not any(a >= 0 for a in guard(0.02 * np.arange(500), np.full(500, 1.0)))
