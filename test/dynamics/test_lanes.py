"""dynamics/lanes.py: four different robots in one call of the vector-lanes dynamics, each lane
equal bit for bit (``np.array_equal``) to the engine's scalar right-hand side of its own robot
(`engine.system.System.derivative`: configuration rate, applied efforts and damping, articulated
forward dynamics), with random masses, lengths, joint rotations, payloads, gravity on or off,
states past the strokes, and locked pseudo-velocities shared by the block.
"""
import numpy as np
import pytest

import robots
from mobile_manip_sim.dynamics import Dynamics, jit

pytestmark = pytest.mark.skipif(not jit.ENABLED, reason="the lanes need numba")

if jit.ENABLED:
    from mobile_manip_sim.dynamics import lanes
    from mobile_manip_sim.dynamics.vector import Lanes
    from mobile_manip_sim.engine.system import System

# (links, locked pseudo-velocities of the block)
CASES = [(1, ()), (2, ()), (3, ()), (4, ()), (1, (0, 1)), (2, (3,)), (3, (2, 5)), (4, (1, 9))]


def scalar_runs(seed, n, locked):
    """Four random robots with n links, each with its engine `System`, state and efforts, and
    the scalar derivative at that state: (systems, states, derivatives)."""
    rng = np.random.default_rng(seed)
    systems, states, derivatives = [], [], []
    for j in range(lanes.WIDTH):
        model = robots.random_robot(rng, n)
        gravity = 0.0 if (seed + j) % 3 == 0 else rng.uniform(1.0, 12.0)
        tip = 0.0 if j % 2 else rng.uniform(0.1, 3.0)
        damping = rng.uniform(0.0, 2.0, model.n_u) if j != 1 else None
        system = System(Dynamics(model, gravity=gravity, tip_mass=tip), damping, list(locked))
        system.Q_cmd[:] = rng.normal(size=model.n_u) * 5.0
        q, u = robots.random_state(rng, model, beyond=0.1)
        s = system.state(q, u)
        systems.append(system)
        states.append(s)
        derivatives.append(system.derivative(s))
    return systems, states, derivatives


def lanes_rates(systems, states):
    """The four runs in one call of `lanes.rates`: (q̇, u̇, workspace), each (…, 4)."""
    data = [system.data for system in systems]
    nq, nu = systems[0].dynamics.model.n_q, systems[0].dynamics.model.n_u
    n = systems[0].dynamics.model.n_links
    model = lanes.lanes_model([d.model for d in data])
    ws = lanes.lanes_workspace(n)
    qdot, ud = lanes.lanes_state([np.zeros(nq)] * 4), lanes.lanes_state([np.zeros(nu)] * 4)
    # the applied forces each scalar derivative assembled (efforts, damping) are its Q
    lanes.rates(model, lanes.lanes_state([s[:nq] for s in states]),
                lanes.lanes_state([s[nq:nq + nu] for s in states]),
                lanes.lanes_state([d.Q.copy() for d in data]), Lanes([d.gravity for d in data]),
                data[0].free, ws, qdot, ud)
    return qdot.array, ud.array, ws


@pytest.mark.parametrize("n, locked", CASES)
def test_every_lane_equals_its_scalar_derivative_bit_for_bit(n, locked):
    for seed in range(3):
        systems, states, derivatives = scalar_runs(100 * n + seed, n, locked)
        nq, nu = systems[0].dynamics.model.n_q, systems[0].dynamics.model.n_u
        qdot, ud, ws = lanes_rates(systems, states)
        for j, (system, ds) in enumerate(zip(systems, derivatives, strict=True)):
            assert np.array_equal(qdot[:, j], ds[:nq]), (j, qdot[:, j] - ds[:nq])
            assert np.array_equal(ud[:, j], ds[nq:nq + nu]), (j, ud[:, j] - ds[nq:nq + nu])
            assert all(ud[k, j] == 0.0 for k in locked)
            # what a locked slide transmits, read off the same pass
            for k in range(1, n + 1):
                if 2 * k + 1 in locked:
                    assert ws.slide_force.array[k, j] == system.dynamics.ws.slide_force[k]


def test_lanes_follow_their_own_robot():
    """Each lane's result is its own robot's and no other's; swapping two lanes' robots and
    states swaps their results and leaves the others bit for bit."""
    systems, states, derivatives = scalar_runs(7, 2, ())
    nq = systems[0].dynamics.model.n_q
    qdot, ud, _ = lanes_rates(systems, states)
    for j in range(4):
        for k in range(4):
            if j != k:
                assert not np.array_equal(ud[:, j], derivatives[k][nq:nq + ud.shape[0]])
    order = [2, 1, 0, 3]
    qdot_s, ud_s, _ = lanes_rates([systems[i] for i in order], [states[i] for i in order])
    assert np.array_equal(qdot_s, qdot[:, order]) and np.array_equal(ud_s, ud[:, order])


def test_lanes_model_refuses_mixed_topologies():
    rng = np.random.default_rng(0)
    models = [Dynamics(robots.random_robot(rng, n)).model_record for n in (1, 1, 2, 1)]
    with pytest.raises(ValueError, match="different numbers of links"):
        lanes.lanes_model(models)
    with pytest.raises(ValueError, match="4 models"):
        lanes.lanes_model(models[:3])


def test_many_blocks_in_one_call_equal_their_scalar_runs():
    """`rates_blocks`: eight runs (two blocks of four, the model of each lane its own) in one
    compiled call, each equal to its engine derivative bit for bit."""
    systems, states, derivatives = [], [], []
    for seed in (11, 12):
        s, x, d = scalar_runs(seed, 3, (3,))
        systems += s
        states += x
        derivatives += d
    model = systems[0].dynamics.model
    nq, nu = model.n_q, model.n_u
    data = [system.data for system in systems]
    qdot = np.zeros((2, nq, 4))
    ud = np.zeros((2, nu, 4))
    lanes.rates_blocks(lanes.model_stack([d.model for d in data]),
                       lanes.block_states([s[:nq] for s in states]),
                       lanes.block_states([s[nq:nq + nu] for s in states]),
                       lanes.block_states([d.Q.copy() for d in data]),
                       lanes.block_states([[d.gravity] for d in data]), data[0].free,
                       lanes.lanes_workspace(model.n_links), qdot, ud)
    for i, ds in enumerate(derivatives):
        assert np.array_equal(qdot[i // 4, :, i % 4], ds[:nq])
        assert np.array_equal(ud[i // 4, :, i % 4], ds[nq:nq + nu])
    with pytest.raises(ValueError, match="multiple of 4"):
        lanes.block_states([np.zeros(3)] * 6)
