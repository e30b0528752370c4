"""Plausibility bounds: outside them a value is a mistake, not physics (docs/errors.md).

The one home of every bound an input is checked against — scene files (`scene`), the command
line (`simulate`), a bag's run metadata (`recording.bag_format`) and the node's parameters —
so that a value one entry point takes is never refused by another. Ranges are (low, high),
both ends included unless the checker says otherwise; single numbers bound a magnitude. It
imports nothing (the bottom of the scene layer).
"""

# --- the robot and its initial state (scene files)
MAX_LINKS = 64                     # arm links (the dynamics is O(n) per step, the checks O(n²))
MASS = (1e-6, 1e15)                # kg, base mass and payload (1e15: an immovable base)
LENGTH = (1e-6, 1e3)               # m: rod lengths, half track, offsets
RADIUS = (1e-4, 1e2)               # m, wheel radius
DENSITY = (1e-9, 1e6)              # kg/m, rod mass per length
INERTIA = (0.0, 1e15)              # kg·m² (per length for rods: kg·m)
ANGLE = 1e6                        # rad, |initial angles|
SPEED = 1e4                        # m/s or rad/s, |initial velocities|
EFFORT = 1e6                       # N or N·m, |efforts| and effort limits
GRAVITY = (0.0, 100.0)             # m/s²
DAMPING = (0.0, 1e6)               # N·m·s/rad, N·s/m

# --- the run: duration, integrator, sampling (scene files, simulate, bag metadata)
DURATION = (0.0, 1e6)              # s (exclusive lower end)
DT = (1e-9, 1.0)                   # s, the fixed step
RTOL = (1e-14, 1.0)
ATOL = (1e-20, 1.0)
MAX_STEPS = 10_000_000             # duration / dt of a fixed-step run
SAMPLE_RATE = (1e-6, 1e6)          # Hz: simulate's --sample-rate, a bag's recorded rate
MAX_SAMPLES = 1_000_000            # duration × sample rate (a CSV of ~200 MB for two links)
RECORDED_DURATION = (1e-9, DURATION[1])   # s, a headless bag's duration (a run that ran)
WHEEL_SPEED_GAIN = (0.0, 1e6)      # kp N·m·s/rad, ki N·m/rad: the wheel-speed loop's gains
# the arm PID's kp, ki, kd (N·m/rad, N·m/(rad·s), N·m·s/rad; N/m … for a slide)
ARM_GAIN = (0.0, 1e9)
# the arm feed-forward's relative model error (mass, inertia): −0.9 = 10 % of the plant's
MODEL_ERROR = (-0.9, 10.0)
MODEL_PAYLOAD = (-1.0, MASS[1])    # kg the feed-forward assumes; negative: the scene's payload
TRAJECTORY_POINTS = 100_000        # points of one arm trajectory
REVOLUTE_TARGET = 1e4              # rad, |a revolute joint's set-point or trajectory point|
CONTROL_RATE = (0.0, 1e6)          # Hz: the controllers' update rate (0: continuous controllers)

# --- the node's parameters (besides the gains and the integrator overrides, 0 = the scene's)
PUBLISH_RATE = (0.001, 100000.0)   # Hz of simulated time
REAL_TIME_FACTOR = (0.0, 10000.0)  # simulated s per wall s; 0 = as fast as possible
COMMAND_TIMEOUT = (0.0, 1.0e6)     # s of simulated time; 0 disables
SYNC_TIMEOUT = (0.001, 3600.0)     # wall s
INTEGRATOR_OVERRIDE = (0.0, 1.0)   # integrator.dt, .rtol, .atol
PORT = (0, 65535)                  # the live view's TCP port (node: 0 = off; simulate: 0 = any)
LINGER = (0.0, 1e7)                # s simulate --view serves on after the run
QOS_DEPTH = (1, 100_000)           # a topic's history depth (a QoS override, a bag's QoS)
RECORDING_BAGS = 100               # bags one recording node opens (one per time line)
IMU_SEED = (0, 2 ** 63 - 1)        # the IMU noise's seed (a ROS integer parameter is int64)
