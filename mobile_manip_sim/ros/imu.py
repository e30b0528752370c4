"""An IMU on base_link (at A, the axle midpoint), read from the dynamics' own accelerations at
the sample, not from differences of samples. No ROS; messages.imu builds sensor_msgs/Imu.

REP-145: the accelerometer reads SPECIFIC FORCE, the acceleration minus gravity, so at rest on
flat ground it reads +g along the body's up axis; the rate gyro reads the body angular velocity.
The base moves in the plane (docs/model.md, a_A = v̇ x + v ω y), so in base_link

    linear_acceleration = (v̇, v ω, g),   angular_velocity = (0, 0, ω),   orientation = Rz(yaw),

with v̇ from the right-hand side the integrator follows (`Simulation.acceleration`).

Noise (all optional, per axis x, y, z): white noise of standard deviation σ and a constant bias
b on each of the two vectors; the orientation is exact. The noise of sample k is a pure function
of (seed, k) — a fresh generator seeded with both — so a run and its re-simulation read the same
noise, whatever was sampled before. Variances σ² go into the message's covariances.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ..scene import limits, schema
from ..scene.coordinates import OMEGA, YAW, V
from ..scene.errors import UserError

AXES = 3
FIELDS = ("angular_velocity", "linear_acceleration")
MAX_NOISE = 1e6     # rad/s, m/s²: a bound on σ and |b| that no real sensor reaches
NOISE_KEYS = tuple(f"{field}_{kind}" for field in FIELDS for kind in ("stddev", "bias"))
# A bag's metadata keys of the settings (few and short: a metadata error lists every key in one
# line): per field its σ and bias, x y z each; the seed.
METADATA_KEYS = {"angular_velocity": "imu_gyro", "linear_acceleration": "imu_accel"}
METADATA_SEED = "imu_seed"


class ImuReading(NamedTuple):
    """One sample in base_link: quaternion (x, y, z, w), rad/s, m/s²."""

    orientation: tuple
    angular_velocity: tuple
    linear_acceleration: tuple


@dataclass(frozen=True)
class ImuNoise:
    """Per-axis standard deviations and biases (rad/s for angular_velocity, m/s² for
    linear_acceleration) and the seed; the defaults are a perfect sensor."""

    angular_velocity_stddev: tuple = (0.0, 0.0, 0.0)
    angular_velocity_bias: tuple = (0.0, 0.0, 0.0)
    linear_acceleration_stddev: tuple = (0.0, 0.0, 0.0)
    linear_acceleration_bias: tuple = (0.0, 0.0, 0.0)
    seed: int = 0

    @staticmethod
    def from_settings(settings: dict, path: str = "imu.noise") -> "ImuNoise":
        """From a mapping of the field names above (each vector 3 numbers, σ ≥ 0); a bad value
        is a `UserError` naming ``path.key``."""
        schema.mapping(settings, path)
        schema.keys(settings, path, optional=(*NOISE_KEYS, "seed"))
        values = {}
        for key, value in settings.items():
            where = f"{path}.{key}"
            if key == "seed":
                values[key] = schema.integer(value, where, lo=limits.IMU_SEED[0],
                                             hi=limits.IMU_SEED[1])
                continue
            vector = schema.sequence(value, where, max_length=AXES)
            if len(vector) != AXES:
                raise UserError(where, f"expected {AXES} numbers (x, y, z), got {len(vector)}")
            values[key] = tuple(schema.number(v, f"{where}[{i}]", lo=-MAX_NOISE, hi=MAX_NOISE,
                                              nonnegative=key.endswith("stddev"))
                                for i, v in enumerate(vector))
        return ImuNoise(**values)

    def as_metadata(self) -> dict:
        """The settings as a bag's metadata strings (METADATA_KEYS: per field "σx σy σz bx by
        bz", floats repr-exact; the seed), which `from_metadata` reads back equal."""
        values = {name: " ".join(repr(float(v)) for kind in ("stddev", "bias")
                                 for v in getattr(self, f"{field}_{kind}"))
                  for field, name in METADATA_KEYS.items()}
        values[METADATA_SEED] = str(self.seed)
        return values

    @staticmethod
    def from_metadata(metadata: dict, path: str) -> "ImuNoise":
        """The settings a bag's metadata map records (a bag without them: a perfect sensor);
        a bad value is a `UserError` naming ``path.key``."""
        settings = {}
        try:
            if METADATA_SEED in metadata:
                where = f"{path}.{METADATA_SEED}"
                settings["seed"] = int(metadata[METADATA_SEED])
            for field, name in METADATA_KEYS.items():
                if name in metadata:
                    where = f"{path}.{name}"
                    values = [float(v) for v in metadata[name].split()]
                    if len(values) != 2 * AXES:
                        raise UserError(where, f"expected {2 * AXES} numbers (σ x y z, bias x "
                                               f"y z), got {len(values)}")
                    settings[f"{field}_stddev"] = values[:AXES]
                    settings[f"{field}_bias"] = values[AXES:]
        except ValueError:
            raise UserError(where, f"not numbers: {schema.short(metadata[where.split('.')[-1]])}"
                            ) from None
        try:
            return ImuNoise.from_settings(settings, path)
        except UserError as error:   # name the metadata key
            key = error.key[len(path) + 1:]
            field = next((f for f in METADATA_KEYS if key.startswith(f)), None)
            name = METADATA_SEED if field is None else METADATA_KEYS[field]
            raise UserError(f"{path}.{name}", f"{key}: {error.problem}") from None

    @property
    def perfect(self) -> bool:
        return not any(any(getattr(self, f"{field}_{kind}")) for field in FIELDS
                       for kind in ("stddev", "bias"))

    def variances(self, field: str) -> tuple:
        """σ² per axis of ``field`` (angular_velocity or linear_acceleration)."""
        return tuple(s * s for s in getattr(self, f"{field}_stddev"))

    def disturb(self, reading: ImuReading, k: int) -> ImuReading:
        """``reading`` as the noisy sensor gives it at sample ``k``."""
        if self.perfect:
            return reading
        white = np.random.default_rng([self.seed, k]).standard_normal(2 * AXES)
        noisy = []
        for i, field in enumerate(FIELDS):
            true = getattr(reading, field)
            sigma, bias = getattr(self, f"{field}_stddev"), getattr(self, f"{field}_bias")
            noisy.append(tuple(float(true[j] + bias[j] + sigma[j] * white[AXES * i + j])
                               for j in range(AXES)))
        return ImuReading(reading.orientation, *noisy)


def true_reading(q, u, u_dot, gravity: float) -> ImuReading:
    """What a perfect IMU at A reads at (q, u) with pseudo-accelerations ``u_dot``."""
    yaw, v, omega, v_dot = float(q[YAW]), float(u[V]), float(u[OMEGA]), float(u_dot[V])
    half = 0.5 * yaw
    return ImuReading((0.0, 0.0, float(np.sin(half)), float(np.cos(half))),
                      (0.0, 0.0, omega), (v_dot, v * omega, float(gravity)))


class Imu:
    """The IMU of one simulation: ``read(sim, k)`` at sample k."""

    def __init__(self, noise: ImuNoise | None = None):
        self.noise = noise or ImuNoise()

    def read(self, sim, k: int) -> ImuReading:
        reading = true_reading(sim.q, sim.u, sim.acceleration(), sim.dynamics.gravity)
        return self.noise.disturb(reading, k)

