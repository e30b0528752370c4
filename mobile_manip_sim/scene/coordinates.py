"""Where each coordinate sits in q and u — the one owner of these indices (docs/model.md).

``q = (x, y, yaw, θ_R, θ_L, q_1, l_1, …, q_n, l_n)`` (n_q = 2n + 5) and
``u = (v, ω, q̇_1, l̇_1, …, q̇_n, l̇_n)`` (n_u = 2n + 2); generalized forces ``Q`` and every
per-pseudo-velocity array (accelerations, the locked-DoF mask) are indexed as u. Rods are 1-based
(k = 1 … n) as in docs/model.md. The joints of /joint_states and the URDF
(`RobotModel.joint_names`: θ_R, θ_L, then q_k, l_k per rod) are q from index `JOINTS` on, and the
arm's share of them lines up with u from index 2 on.

Plain Python, imported by every layer (the scene's `RobotModel` takes its sizes from here); NumPy
code uses the slices. engine/layout.py adds the rest of the state vector ``s = (q, u, e, W)``. The
compiled core indexes q and u the same way (core/include/mms/model.hpp).
"""

# q: the base pose, the wheel angles
X, Y, YAW = 0, 1, 2
WHEEL_R, WHEEL_L = 3, 4
# u: the base's forward speed and yaw rate
V, OMEGA = 0, 1

BASE_POSE = slice(X, YAW + 1)          # (x, y, yaw) in q
WHEELS = slice(WHEEL_R, WHEEL_L + 1)    # (θ_R, θ_L) in q
JOINTS = slice(WHEEL_R, None)           # the joint_states positions in q: wheels, then arm
ARM_Q = slice(5, None)                  # (q_1, l_1, …, q_n, l_n) in q
ARM_U = slice(2, None)                  # (q̇_1, l̇_1, …) in u (and τ_1, F_1, … in Q)
BASE_U = slice(V, OMEGA + 1)            # (v, ω) in u
TURNS_Q, SLIDES_Q = slice(5, None, 2), slice(6, None, 2)    # every q_k, every l_k in q
TURNS_U, SLIDES_U = slice(2, None, 2), slice(3, None, 2)    # every q̇_k, every l̇_k in u


def q_turn(k):
    """Index of q_k, the angle of revolute joint k (1-based), in q."""
    return 3 + 2 * k


def q_slide(k):
    """Index of l_k, the extension of prismatic joint k (1-based), in q."""
    return 4 + 2 * k


def u_turn(k):
    """Index of q̇_k in u (and of τ_k in Q); `u_turn(k) + 1` is `u_slide(k)`."""
    return 2 * k


def u_slide(k):
    """Index of l̇_k in u (and of F_k in Q)."""
    return 2 * k + 1


def arm_u(j):
    """Index in u (and Q) of the arm's coordinate j (0-based: q̇_1, l̇_1, q̇_2, …)."""
    return 2 + j


def arm_turn(k):
    """Index of q̇_k (rod k, 1-based) among the arm's coordinates (an array of `arm_size(n)`)."""
    return 2 * k - 2


def arm_slide(k):
    """Index of l̇_k among the arm's coordinates."""
    return 2 * k - 1


def q_joint(j):
    """Index in q of joint j of `RobotModel.joint_names` (0, 1 the wheels; then q_k, l_k); for an
    arm coordinate j ≥ 2 it is also the q index of u's entry j."""
    return 3 + j


def rod(j):
    """The rod k (1-based) whose q̇_k or l̇_k is u's entry j ≥ 2."""
    return j // 2


def q_size(n):
    """n_q for n rods."""
    return 5 + 2 * n


def u_size(n):
    """n_u for n rods."""
    return 2 + 2 * n


def arm_size(n):
    """The arm's coordinates (q_1, l_1, …, q_n, l_n) for n rods: its joints, efforts, gains."""
    return 2 * n


def arm_width(n_u):
    """The arm's coordinates in a u of n_u entries (`arm_size` of its rods)."""
    return n_u - 2
