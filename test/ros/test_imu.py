"""The IMU (imu.py) reads the dynamics: specific force (REP-145: +g up at rest) and the body rate
from the right-hand side at the sample, checked against facts that cannot be tuned — rest, a
turn, the finite difference of the velocity of a tight run — and its noise against the settings
(statistics, a pure function of seed and sample index). Reading it never changes the run."""
import copy

import numpy as np
import pytest
import yaml

from mobile_manip_sim.engine.simulation import Simulation
from mobile_manip_sim.ros.imu import Imu, ImuNoise, ImuReading
from mobile_manip_sim.scene.coordinates import OMEGA, YAW, X, Y
from mobile_manip_sim.scene.errors import UserError
from mobile_manip_sim.scene.loading import IntegratorSettings, load_scene, parse_scene
from test_urdf import PAPER

G = 10.0


def document():
    return yaml.safe_load(PAPER.read_text())


def base_only(velocity=(0.0, 0.0)):
    doc = document()
    doc["robot"]["arm"] = {"mount": [0.0, 0.0, 0.2], "links": []}
    doc["robot"].pop("limits")   # the paper robot's motors: for its two links
    doc["initial"] = {"velocity": list(velocity)}
    doc["efforts"] = {}
    doc["effects"] = {"gravity": G, "wheel_inertia": True}
    return parse_scene(doc, "base_only")


def tight(method="dop853"):
    return IntegratorSettings(method=method, dt=1e-3, rtol=1e-12, atol=1e-14)


def test_at_rest_it_reads_plus_g_up_and_no_rate():
    sim = Simulation(base_only(), tight())
    imu = Imu()
    for k, t in enumerate((0.0, 0.5, 1.0)):
        sim.advance_to(t)
        reading = imu.read(sim, k)
        assert reading.linear_acceleration == (0.0, 0.0, G)
        assert reading.angular_velocity == (0.0, 0.0, 0.0)
        assert reading.orientation == (0.0, 0.0, 0.0, 1.0)


def test_at_rest_with_the_arm_held_upright_it_reads_plus_g_to_round_off():
    """The paper robot, both rods vertical and held by their slides (F_1 carries both rods,
    F_2 rod 2): the arm pushes the base straight down only."""
    doc = document()
    doc["initial"] = {"joints": [np.pi / 2, 0.5, 0.0, 0.5]}
    doc["efforts"] = {"wheels": [0.0, 0.0], "joints": [0.0, 2.0 * G, 0.0, 1.0 * G]}
    sim = Simulation(parse_scene(doc, "upright"), tight())
    reading = Imu().read(sim, 0)
    assert np.max(np.abs(np.subtract(reading.linear_acceleration, (0.0, 0.0, G)))) < 1e-12
    assert np.max(np.abs(reading.angular_velocity)) == 0.0


@pytest.mark.parametrize("omega", [0.7, -2.5])
def test_turning_at_omega_the_z_rate_is_omega(omega):
    sim = Simulation(base_only(velocity=(0.0, omega)), tight())
    imu = Imu()
    assert imu.read(sim, 0).angular_velocity == (0.0, 0.0, omega)
    for k in range(1, 5):
        sim.advance_to(0.1 * k)
        rate = imu.read(sim, k).angular_velocity
        assert rate[:2] == (0.0, 0.0) and rate[2] == sim.u[OMEGA]
    # the turn swings the offset centre of mass: the axle accelerates forward, v̇ = d ω² > 0 at 0
    start = Imu().read(Simulation(base_only(velocity=(0.0, omega)), tight()), 0)
    assert start.linear_acceleration[0] > 0.0 and start.linear_acceleration[2] == G


def test_acceleration_is_the_derivative_of_the_base_velocity():
    """The paper's run (base and arm accelerating) before its first impact, sampled at 1 kHz by
    DOP853 at rtol 1e-12 every 0.2 ms: the specific force minus gravity, turned into odom, equals
    the central difference of the velocity of A, (ẋ, ẏ), to 1e-6 m/s² (its truncation error
    ~3e-8)."""
    scene = load_scene(PAPER)
    sim = Simulation(scene, tight())
    imu = Imu()
    h = 2e-4
    times = np.arange(0.0, 0.4 + 1e-12, h)
    velocity, force = [], []
    for k, t in enumerate(times):
        sim.advance_to(float(t))
        qdot = sim.qdot()
        velocity.append(qdot[[X, Y]])
        reading = imu.read(sim, k)
        c, s = np.cos(sim.q[YAW]), np.sin(sim.q[YAW])
        fx, fy, fz = reading.linear_acceleration
        force.append((c * fx - s * fy, s * fx + c * fy))
        assert fz == G
    assert not sim.impacts
    velocity, force = np.array(velocity), np.array(force)
    difference = (velocity[2:] - velocity[:-2]) / (2 * h)
    assert np.max(np.abs(force[1:-1])) > 0.1             # the base does accelerate
    assert np.max(np.abs(difference - force[1:-1])) < 1e-6


@pytest.mark.parametrize("method", ["rk4", "dop853"])
def test_reading_the_imu_leaves_the_run_bit_identical(method):
    scene = load_scene(PAPER)
    settings = IntegratorSettings(method=method, dt=1e-3, rtol=1e-8, atol=1e-10)
    plain, read = Simulation(scene, settings), Simulation(scene, settings)
    imu = Imu(ImuNoise(angular_velocity_stddev=(0.1, 0.1, 0.1), seed=3))
    for k, t in enumerate(np.arange(0.0, 1.5 + 1e-12, 0.01)):   # through the paper's impacts
        plain.advance_to(float(t))
        read.advance_to(float(t))
        imu.read(read, k)
        assert np.array_equal(plain.s, read.s), t
    assert plain.impacts and len(plain.impacts) == len(read.impacts)
    assert plain.rhs_evaluations == read.rhs_evaluations


NOISE = ImuNoise(angular_velocity_stddev=(0.01, 0.02, 0.03),
                 angular_velocity_bias=(0.001, -0.002, 0.5),
                 linear_acceleration_stddev=(0.2, 0.0, 1.5),
                 linear_acceleration_bias=(-0.1, 0.3, 0.0), seed=1234)
TRUTH = ImuReading((0.0, 0.0, 0.0, 1.0), (0.1, -0.2, 0.3), (1.0, 2.0, G))


def test_noise_statistics_match_the_settings():
    n = 20000
    samples = [NOISE.disturb(TRUTH, k) for k in range(n)]
    for field in ("angular_velocity", "linear_acceleration"):
        values = np.array([getattr(sample, field) for sample in samples])
        sigma = np.array(getattr(NOISE, f"{field}_stddev"))
        expected = np.array(getattr(TRUTH, field)) + np.array(getattr(NOISE, f"{field}_bias"))
        # mean within 5 standard errors; a zero σ gives exactly the biased truth
        assert np.all(np.abs(values.mean(axis=0) - expected) <= 5 * sigma / np.sqrt(n) + 1e-12)
        assert np.allclose(values.std(axis=0), sigma, rtol=0.03, atol=1e-12)   # ±6 std errors
        assert np.all(values[:, sigma == 0] == expected[sigma == 0])
        assert NOISE.variances(field) == tuple(sigma ** 2)
    # white: consecutive samples uncorrelated, axes independent
    gyro = np.array([s.angular_velocity for s in samples])
    assert abs(np.corrcoef(gyro[:-1, 0], gyro[1:, 0])[0, 1]) < 0.03
    assert abs(np.corrcoef(gyro[:, 0], gyro[:, 1])[0, 1]) < 0.03
    assert all(s.orientation == TRUTH.orientation for s in samples)


def test_noise_is_a_pure_function_of_seed_and_sample_index():
    forward = [NOISE.disturb(TRUTH, k) for k in range(50)]
    backward = [NOISE.disturb(TRUTH, k) for k in reversed(range(50))][::-1]
    assert forward == backward
    assert len(set(forward)) == 50
    other = copy.replace(NOISE, seed=1235) if hasattr(copy, "replace") else ImuNoise(
        NOISE.angular_velocity_stddev, NOISE.angular_velocity_bias,
        NOISE.linear_acceleration_stddev, NOISE.linear_acceleration_bias, 1235)
    disturbed = [other.disturb(TRUTH, k) for k in range(50)]
    assert all(a != b for a, b in zip(forward, disturbed, strict=True))
    assert ImuNoise().disturb(TRUTH, 7) == TRUTH


def test_a_noisy_run_is_read_again_identically():
    scene = load_scene(PAPER)
    runs = []
    for _ in range(2):
        sim, imu = Simulation(scene, tight()), Imu(NOISE)
        readings = []
        for k, t in enumerate(np.arange(0.0, 0.3 + 1e-12, 0.01)):
            sim.advance_to(float(t))
            readings.append(imu.read(sim, k))
        runs.append(readings)
    assert runs[0] == runs[1]


@pytest.mark.parametrize("settings, key", [
    ({"angular_velocity_stddev": [0.1, 0.1]}, "imu.noise.angular_velocity_stddev"),
    ({"angular_velocity_stddev": [0.1, -0.1, 0.1]}, "imu.noise.angular_velocity_stddev[1]"),
    ({"linear_acceleration_bias": [0.0, float("nan"), 0.0]},
     "imu.noise.linear_acceleration_bias[1]"),
    ({"seed": -1}, "imu.noise.seed"),
    ({"seed": 1.5}, "imu.noise.seed"),
    ({"gyro_noise": 1.0}, "imu.noise.gyro_noise"),
])
def test_bad_noise_settings_are_one_line_errors_naming_the_key(settings, key):
    with pytest.raises(UserError) as error:
        ImuNoise.from_settings(settings)
    assert error.value.key == key and "\n" not in str(error.value)


def test_noise_settings_read_back():
    noise = ImuNoise.from_settings({"angular_velocity_stddev": [0.01, 0.02, 0.03], "seed": 9})
    assert noise.angular_velocity_stddev == (0.01, 0.02, 0.03) and noise.seed == 9
    assert noise.linear_acceleration_bias == (0.0, 0.0, 0.0) and not noise.perfect
