"""dynamics/vector.py and lane_arrays.py: `Vec4`, four float64 lanes in one 256-bit register, and
`LaneArray`.

Every operation is checked against the same numba function compiled for plain floats, lane by
lane, bit for bit (``np.array_equal``, never a tolerance): what makes the lanes body of the
dynamics equal its scalar runs. The values include signed zeros, subnormals, infinities and
NaN, where an operation that is "almost" IEEE shows.
"""
import math
import os
import re
import subprocess
import sys

import numba
import numpy as np
import pytest

from mobile_manip_sim.dynamics import jit

pytestmark = pytest.mark.skipif(not jit.ENABLED, reason="the lanes need numba")

if jit.ENABLED:
    from mobile_manip_sim.dynamics.lane_arrays import LaneArray
    from mobile_manip_sim.dynamics.vector import Lanes, make_vec4, splat

SPECIAL = [0.0, -0.0, 5e-324, -2.2e-308, 1.0, -1.5, 3.0, 1e308, math.inf, -math.inf, math.nan]


def operands(seed, count=64):
    """(count, 4) pairs of lanes: random magnitudes over many decades, then the special values."""
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(count, 4)) * 10.0 ** rng.integers(-8, 9, size=(count, 4))
    b = rng.normal(size=(count, 4)) * 10.0 ** rng.integers(-8, 9, size=(count, 4))
    special = np.array([[x, y, y, x] for x in SPECIAL for y in SPECIAL[::-1]])
    return np.vstack([a, special[:, :4]]), np.vstack([b, special[:, ::-1]])


def formula(a, b):
    """Every operator and function the dynamics use, with numbers meeting lanes."""
    c = a * b + 0.5 - a / b
    d = (c - 2) * (-a) + (+b)
    d -= 3.0 * a
    d *= b
    d /= 7
    return (c, d, a ** 2, b ** 3, (a - b) ** 3, math.sqrt(a * a + b * b), math.sin(a),
            math.cos(b), 1.0 / b, 2 - a, b ** 0, (a * a) ** b, math.exp(-abs(b)))


scalar_formula = numba.njit(error_model="numpy")(formula)
lanes_formula = numba.njit(error_model="numpy")(formula)


def lane_results(a, b):
    """formula over Lanes, as a (terms, 4) array."""
    return np.array([r.values for r in lanes_formula(Lanes(a), Lanes(b))])


def scalar_results(a, b):
    return np.array([scalar_formula(x, y) for x, y in zip(a, b, strict=True)]).T


def test_every_operation_equals_the_scalar_one_in_every_lane_bit_for_bit():
    A, B = operands(1)
    with np.errstate(all="ignore"):
        for a, b in zip(A, B, strict=True):
            got, expected = lane_results(a, b), scalar_results(a, b)
            same = (got == expected) | (np.isnan(got) & np.isnan(expected))
            assert same.all(), (a, b, np.argwhere(~same))
            # signed zeros too: == does not see −0.0 against 0.0
            assert np.array_equal(np.signbit(got) | np.isnan(got),
                                  np.signbit(expected) | np.isnan(expected))


def test_a_lane_follows_its_own_operands():
    """Swapping two lanes' operands swaps their results and nothing else."""
    A, B = operands(2, count=8)
    for a, b in zip(A[:8], B[:8], strict=True):
        swapped = lane_results(a[[1, 0, 2, 3]], b[[1, 0, 2, 3]])
        assert np.array_equal(swapped, lane_results(a, b)[:, [1, 0, 2, 3]])
        assert not np.array_equal(swapped[:, 0], lane_results(a, b)[:, 0])


@numba.njit
def accumulate(values, weights):
    """A number that becomes lanes (unification), a mixed tuple indexed at run time, in-place
    operators on a LaneArray, its shape, a row view."""
    total = 0.0
    for i in range(values.shape[0]):
        total += values[i, 0] * weights[i]
    mixed = (0.0, 1.0, total)
    s = 0.0
    for i in range(3):
        s += mixed[i]
    row = values[1]
    row[1] = s
    values[0, 1] += 2.0
    values[0, 0] = 1
    return total, s


def test_unification_mixed_tuples_and_lane_arrays():
    rng = np.random.default_rng(3)
    values = rng.normal(size=(3, 2, 4))
    weights = rng.normal(size=(3, 4))
    before = values.copy()
    lanes = LaneArray(values)
    assert lanes.shape == (3, 2)
    total, s = accumulate(lanes, LaneArray(weights))
    for j in range(4):
        column = before[..., j].copy()
        expected = accumulate(column, weights[:, j].copy())
        assert (total.values[j], s.values[j]) == expected
        assert np.array_equal(values[..., j], column)


@numba.njit
def build(x, y):
    return make_vec4(x, 2.0, 3, -y), splat(x), splat(4)


def test_building_lanes_and_boxing():
    v, s, i = build(1.5, 2.5)
    assert v == Lanes((1.5, 2.0, 3.0, -2.5))
    assert s.values == (1.5,) * 4 and i.values == (4.0,) * 4
    with pytest.raises(ValueError, match="4 values"):
        Lanes((1.0, 2.0))
    with pytest.raises(ValueError, match="C-contiguous"):
        LaneArray(np.zeros((3, 4))[:, ::2])


def test_the_machine_code_is_vector_arithmetic_without_fused_multiply_adds():
    """vmulpd/vaddpd/vdivpd, four lanes an instruction; no scalar arithmetic for the lanes and no
    vfmadd (a fused multiply-add rounds once: not the scalar code's bits)."""
    fresh = numba.njit(lambda a, b: (a * b + a) / b - a * a)
    fresh(Lanes((1, 2, 3, 4)), Lanes((5, 6, 7, 8)))
    asm = fresh.inspect_asm(fresh.signatures[0])
    body = re.split(r"^_ZN7cpython", asm, flags=re.M)[0]   # the function, not its wrapper
    for instruction in ("vmulpd", "vaddpd", "vdivpd", "vsubpd"):
        assert re.search(rf"\b{instruction}\b", body), instruction
    for instruction in ("vmulsd", "vaddsd", "vdivsd", "vfmadd"):
        assert not re.search(rf"\b{instruction}", body), instruction


CACHED_KERNELS = '''
import math
from mobile_manip_sim.dynamics.jit import jit, jit_inline

@jit_inline
def inner(x):
    return math.cos(x) * 2.0

@jit
def helper(x):
    return x + 1.0

@jit
def outer(x):
    return inner(x) + helper(x)
'''


def test_a_cache_holding_lanes_does_not_break_a_later_scalar_compile(tmp_path):
    """A kernel's on-disk cache that also holds a lanes specialization imports the lane types
    when numba reads it. If that happened in the middle of typing another kernel (one that calls
    math.cos), numba would see two different types of math.cos and fail; so the lane types are
    registered as soon as the kernels' compiler is set up (`jit.py`). Two processes: the first
    caches `helper` for lanes, the second compiles `outer` (math.cos, then `helper`)."""
    (tmp_path / "kernels_with_lanes.py").write_text(CACHED_KERNELS)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path)] + sys.path))
    first = ("from mobile_manip_sim.dynamics.vector import Lanes; import kernels_with_lanes as k;"
             " print(k.helper(Lanes((1, 2, 3, 4))))")
    second = "import kernels_with_lanes as k; print(k.outer(0.0))"
    for code, expected in ((first, "Lanes((2.0, 3.0, 4.0, 5.0))"), (second, "3.0")):
        done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                              text=True, timeout=600)
        assert done.returncode == 0, done.stderr[-2000:]
        assert done.stdout.strip() == expected
