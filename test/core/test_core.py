"""The compiled core (mobile_manip_sim/core: C++ templates generic in their scalar) against
itself across its scalars — every lane of a vector block is its own double run bit for bit, a dual
number's value is the double run bit for bit and its derivatives agree with central differences of
the double run — and the wheel-speed loop against its documented law. And the build itself: IEEE
arithmetic, no fast-math, no contraction of a*b + c into one rounding. (Its physics against
independent formulations: test/dynamics, Pinocchio's among them.)
"""
from fractions import Fraction

import numpy as np
import pytest

import robots
from differences import best_agreement
from mobile_manip_sim.core import build_info, compiled_dynamics, multiply_add
from mobile_manip_sim.scene.loading import load_scene

LINK_COUNTS = [0, 1, 2, 3, 5, 8]


def case(seed, n):
    """A random robot of n links with a payload (or none), a random state with extensions up to
    10 % past the stops, accelerations, forces, gravity and a random set of locked
    pseudo-velocities, and its compiled core."""
    rng = np.random.default_rng(seed)
    robot = robots.random_robot(rng, n)
    tip = 0.0 if seed % 3 == 0 else float(rng.uniform(0.1, 3.0))
    q, u = robots.random_state(rng, robot, beyond=0.1)
    nu = robot.n_u
    moving = (rng.uniform(size=nu) > 0.3).astype(float)
    return dict(rng=rng, robot=robot, tip=tip, q=q, u=u, ud=rng.normal(size=nu),
                Q=rng.normal(size=nu), g=float(rng.uniform(0.0, 12.0)), moving=moving,
                core=compiled_dynamics(robot, tip))


def identical(a, b):
    return np.array_equal(np.asarray(a), np.asarray(b)) and np.asarray(a).shape == np.shape(b)


@pytest.mark.parametrize("n", [0, 2, 5])
def test_every_lane_equals_its_own_run_bit_for_bit(n):
    """Runs of different states and locked sets in vector blocks of `lane_width` (a short last
    block too): each row is the double run of its own inputs."""
    width = build_info()["lane_width"]
    c = case(100 + n, n)
    rng, robot, core = c["rng"], c["robot"], c["core"]
    runs = 2 * width + 3
    states = [robots.random_state(rng, robot, beyond=0.1) for _ in range(runs)]
    q = np.array([s[0] for s in states])
    u = np.array([s[1] for s in states])
    Q = rng.normal(size=(runs, robot.n_u))
    moving = (rng.uniform(size=(runs, robot.n_u)) > 0.3).astype(float)
    lanes = core.forward_dynamics_lanes(q, u, Q, c["g"], moving)
    for i in range(runs):
        assert identical(lanes[i], core.forward_dynamics(q[i], u[i], Q[i], c["g"], moving[i]))
    assert len({lanes[i].tobytes() for i in range(runs)}) == runs   # the lanes did differ


def system_case(seed, n):
    """`case` with damping on every pseudo-velocity (or none when seed is even) and the state
    s = (q, u, e, W) of the engine's layout."""
    c = case(seed, n)
    nu = c["robot"].n_u
    c["damping"] = c["rng"].uniform(0.0, 0.5, nu) if seed % 2 else np.zeros(0)
    c["s"] = np.concatenate([c["q"], c["u"], c["rng"].normal(size=3)])
    return c


@pytest.mark.parametrize("method", ["", "euler", "semi_implicit_euler", "rk4"])
@pytest.mark.parametrize("n", [0, 1, 2, 4, 8])
def test_dual_jacobians_agree_with_central_differences_of_the_double_map(n, method):
    """∂/∂(x, τ) of the rates (method "") and of one step, by dual numbers, against central
    differences of the double map (Richardson-extrapolated, the best of a sweep of steps):
    1e-8 relative to the Jacobian's size; the dual value is the double map bit for bit."""
    c = system_case(200 + n, n)
    core, s, g = c["core"], c["s"], c["g"]
    nq, nu, h = c["robot"].n_q, c["robot"].n_u, 0.005
    rng = c["rng"]
    B = rng.normal(size=(nu, 3))          # three effort directions
    tau0 = np.zeros(3)

    def mapped(x, tau):
        state = np.concatenate([x, s[nq + nu:]])
        Q = c["Q"] + B @ tau
        args = (Q, c["damping"], c["moving"], g)
        out = core.step(method, state, h, *args) if method else core.rates(state, *args)
        return out[:nq + nu]
    value, d_dx, d_dtau = core.jacobians(method, s, h, c["Q"], B, c["damping"], c["moving"], g)
    x = s[:nq + nu]
    assert identical(value, mapped(x, tau0))
    assert best_agreement(lambda x: mapped(x, tau0), x, d_dx) <= 1e-8
    assert best_agreement(lambda tau: mapped(x, tau), tau0, d_dtau) <= 1e-8
    if not method:
        locked = [nq + k for k in range(nu) if not c["moving"][k]]
        assert not np.any(d_dx[locked]) and not np.any(d_dtau[locked])   # u̇ ≡ 0 there


def test_the_build_does_ieee_arithmetic_without_contraction():
    """a·b + c rounds twice as IEEE says, unless the compiler fused it into one FMA (as GCC does
    by default where the CPU has FMA): the chosen operands make the two results differ."""
    info = build_info()
    assert info["fast_math"] is False
    assert "-ffp-contract=off" in info["flags"].split()
    assert not any("fast-math" in flag and not flag.startswith("-fno-")
                   for flag in info["flags"].split())
    a, b, c = 1.0 + 2.0 ** -30, 1.0 - 2.0 ** -30, -1.0
    fused = float(Fraction(a) * Fraction(b) + Fraction(c))   # one rounding
    twice = a * b + c                                         # two (CPython is IEEE)
    assert fused != twice
    assert multiply_add(a, b, c) == twice
    assert info["lane_width"] in (4, 8)


def test_arrays_of_the_wrong_size_are_refused_naming_the_argument():
    core = compiled_dynamics(load_scene().robot)
    q, u = np.zeros(core.n_q), np.zeros(core.n_u)
    with pytest.raises(ValueError, match=r"^q: expected 9 numbers, got 8$"):
        core.forward_dynamics(q[:-1], u, u, 9.81, np.ones(core.n_u))
    with pytest.raises(ValueError, match=r"^moving: expected 6 numbers, got 7$"):
        core.forward_dynamics(q, u, u, 9.81, np.ones(core.n_u + 1))


@pytest.mark.parametrize("method", ["euler", "semi_implicit_euler", "rk4"])
@pytest.mark.parametrize("n", [0, 2, 3])
def test_runs_stepped_in_lanes_equal_their_runs_stepped_alone_bit_for_bit(method, n):
    """Runs of different states, efforts and locked sets, with damping, advanced 200 steps: in
    vector blocks of `lane_width` (a short last block too) and one by one in double, the same bits;
    and the runs differ from each other (the lanes are not one run repeated)."""
    c = system_case(300 + n, n)
    rng, robot, core = c["rng"], c["robot"], c["core"]
    runs = build_info()["lane_width"] + 3
    s = np.array([np.concatenate([*robots.random_state(rng, robot), np.zeros(3)])
                  for _ in range(runs)])
    Q = rng.normal(size=(runs, robot.n_u))
    moving = (rng.uniform(size=(runs, robot.n_u)) > 0.2).astype(float)
    damping = rng.uniform(0.0, 0.3, robot.n_u)
    args = (method, s, 1e-3, 200, Q, damping, moving, c["g"])
    lanes, alone = core.advance(*args, True), core.advance(*args, False)
    assert identical(lanes, alone)
    assert len({row.tobytes() for row in lanes}) == runs and np.isfinite(lanes).all()
    # and a run alone is the step applied 200 times
    x = s[1]
    for _ in range(200):
        x = core.step(method, x, 1e-3, Q[1], damping, moving[1], c["g"])
    assert identical(alone[1], x)


@pytest.mark.parametrize("n", [0, 2])
def test_the_wheel_speed_loop_follows_its_documented_law(n):
    """A base under velocity commands: each wheel's PI loop on its speed θ̇ = (v ± b ω)/r,
    τ = sat(kp (θ̇* − θ̇) + ki e) within ±limit, its integral back-calculated while saturated
    (ė = error + (τ − raw)/kp, control_toolbox's BACK_CALCULATION), the torques entering as
    Q_v = (τ_R + τ_L)/r, Q_ω = b (τ_R − τ_L)/r (docs/model.md): the core's right-hand side and the
    law written here, on states where the loops run free and saturate either way."""
    from mobile_manip_sim.core import WheelLoop
    c = system_case(400 + n, n)
    core, rng, robot = c["core"], c["rng"], c["robot"]
    nq, nu = robot.n_q, robot.n_u
    r, b = robot.base.wheel_radius, robot.base.half_track
    loop = WheelLoop()
    saturated = 0
    for trial in range(40):
        loop.kp, loop.ki = rng.uniform(0.5, 5.0), rng.uniform(0.0, 30.0)
        loop.limit_R, loop.limit_L = rng.uniform(0.05, 2.0, 2) if trial % 4 else (np.inf,) * 2
        loop.target_R, loop.target_L = rng.normal(0.0, 10.0, 2)
        s = c["s"].copy()
        s[nq:] = np.concatenate([rng.normal(size=nu), rng.normal(0.0, 0.2, 2), [0.0]])
        u, e = s[nq:nq + nu], s[nq + nu:nq + nu + 2]
        ds = core.rates(s, c["Q"], c["damping"], c["moving"], c["g"], loop)
        tau, rates = [], []
        for target, speed, integral, limit in ((loop.target_R, (u[0] + b * u[1]) / r, e[0],
                                                loop.limit_R),
                                               (loop.target_L, (u[0] - b * u[1]) / r, e[1],
                                                loop.limit_L)):
            error = target - speed
            raw = loop.kp * error + loop.ki * integral
            torque = min(max(raw, -limit), limit)
            tau.append(torque)
            rates.append(error + (torque - raw) / loop.kp)
            saturated += torque != raw
        assert ds[nq + nu:nq + nu + 2] == pytest.approx(rates, rel=1e-12, abs=1e-12), trial
        Q = c["Q"].copy()
        Q[0], Q[1] = (tau[0] + tau[1]) / r, b * (tau[0] - tau[1]) / r
        if c["damping"].size:
            Q -= c["damping"] * u
        ud = core.forward_dynamics(s[:nq], u, Q, c["g"], c["moving"])
        assert ds[nq:nq + nu] == pytest.approx(ud, rel=1e-12, abs=1e-12), trial
    assert saturated > 0   # some torques were clipped (the back-calculation acted)


@pytest.mark.parametrize("n", [0, 2, 5])
def test_configuration_rates_of_many_rows_are_each_rows_own(n):
    """`configuration_rates` (the sweep's residual check reads it) on rows (q, u, …) of different
    states: each row is `configuration_rate` of its own q and u, bit for bit; rows too short are
    refused naming the argument."""
    c = system_case(700 + n, n)
    rng, robot, core = c["rng"], c["robot"], c["core"]
    rows = np.array([np.concatenate([*robots.random_state(rng, robot), rng.normal(size=3)])
                     for _ in range(7)])
    rates = core.configuration_rates(rows)
    nq = robot.n_q
    for row, rate in zip(rows, rates, strict=True):
        assert identical(rate, core.configuration_rate(row[:nq], row[nq:nq + robot.n_u]))
    assert len({rate.tobytes() for rate in rates}) == len(rows)
    with pytest.raises(ValueError, match=r"^samples: expected rows of at least"):
        core.configuration_rates(rows[:, :nq])
