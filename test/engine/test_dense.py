"""SciPy's Radau and BDF interpolants as the power series the core's events evaluate
(`scipy_steps.power_series`): they give SciPy's own values inside each step."""
import numpy as np
import pytest
from scipy import integrate

from mobile_manip_sim.engine.scipy_steps import power_series
from mobile_manip_sim.engine.simulation import Simulation
from mobile_manip_sim.scene.loading import load_scene


@pytest.mark.parametrize("solver_class", [integrate.Radau, integrate.BDF])
def test_scipys_interpolants_as_power_series_give_scipys_values(solver_class):
    sim = Simulation(load_scene())
    f = lambda _t, y: sim.system.derivative(y)   # noqa: E731
    solver = solver_class(f, 0.0, sim.s.copy(), 1.0, rtol=1e-6, atol=1e-8)
    orders = set()
    for _ in range(40):   # past BDF's ramp-up from order 1, through changes of its step
        y0, t0 = solver.y.copy(), solver.t
        solver.step()
        theirs = solver.dense_output()
        series = power_series(theirs)
        orders.add(len(series))
        h = solver.t - t0
        for theta in (0.0, 0.25, 0.5, 0.9, 1.0):
            powers = theta ** np.arange(1, len(series) + 1)
            ours = y0 + powers @ series
            scale = np.max(np.abs(theirs(t0 + theta * h)))
            error = np.max(np.abs(ours - theirs(t0 + theta * h)))
            assert error < 1e-13 * scale, (theta, len(orders))
    assert len(orders) > 1 if solver_class is integrate.BDF else orders == {3}
