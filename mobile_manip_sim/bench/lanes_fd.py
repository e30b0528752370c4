"""One forward-dynamics evaluation per lane: the vector-lanes body (`dynamics/lanes.py`, four
runs in 256-bit registers) against the scalar kernel, in flops per cycle.

- **Flops** are counted, not estimated: the paper robot's right-hand side dynamics (frames,
  configuration rate, articulated forward dynamics: `lanes.rates`) run once as plain Python (a
  child process with the compiler off) on numbers that count every +, −, ×, ÷ done on them, and
  every sine and cosine. Operations between two constants are not counted (LLVM folds them).
- **Time** is CPU time of compiled loops calling the body again and again (`loops.per_call`):
  the scalar kernel on one run, the lanes body on a block of four different runs (the paper
  robot with four payloads and states), per lane.
- **Peaks**: one cycle of this CPU retires at most two 256-bit multiplies (or fused
  multiply-adds) and two 256-bit additions (AMD Zen 2/3: two multiply/FMA pipes, two add pipes):
  16 double flops per cycle without fused multiply-adds on a balanced mix, 16 on FMAs alone
  (the figure usually quoted), 4 for one lane of scalar code. A loop of independent vector
  multiplications and additions measures what this machine gives (`peak_flops_per_ns`), which
  does not depend on the clock read from /proc/cpuinfo (a virtual machine may report its
  nominal clock there).
- **Instructions**: the machine code of the body, compiled afresh (numba's cached code keeps no
  assembly), counted by mnemonic.
"""
from __future__ import annotations

import json
import math
import os
import re
import subprocess
import sys
from dataclasses import dataclass, field

import numpy as np

from ..dynamics import lanes
from ..dynamics.jit import ENABLED, jit
from ..scene.loading import load_scene
from . import loops
from .batch import clock_ghz
from .tables import table, verdict

PEAK_VECTOR = 16.0   # double flops per cycle: 2 × 4-wide multiply + 2 × 4-wide add (or 2 FMA)
PEAK_SCALAR = PEAK_VECTOR / 4   # one lane of the same pipes
GOAL = 3.0           # the lanes body within 3× of the vector peak
MNEMONICS = ("vmulpd", "vaddpd", "vsubpd", "vdivpd", "vmulsd", "vaddsd", "vsubsd", "vdivsd",
             "vfmadd", "call")


@dataclass
class LanesResult:
    flops: dict = field(default_factory=dict)      # counted operations of one evaluation
    scalar_ns: float = math.nan                    # ns per evaluation, scalar kernel
    lanes_ns: float = math.nan                     # ns per lane-evaluation, lanes body
    blocks_ns: float = math.nan                    # … 64 runs (16 blocks) in one call
    peak_per_ns: float = math.nan                  # flops per ns of the mul + add loop
    ghz: float = math.nan                          # /proc/cpuinfo's clock
    instructions: dict = field(default_factory=dict)   # {"lanes": {...}, "scalar": {...}}
    bits_equal: bool = False

    @property
    def total_flops(self) -> int:
        return sum(self.flops.get(k, 0) for k in ("add", "sub", "mul", "div"))


# ------------------------------------------------------------------------- compiled loops

@jit
def rates_loop(model, q, u, Q, g, free, ws, qdot, ud, count):
    """`lanes.rates` count times: scalar records or a block of four lanes alike."""
    for _ in range(count):
        lanes.rates(model, q, u, Q, g, free, ws, qdot, ud)


@jit
def rates_blocks_loop(stack, q, u, Q, g, free, ws, qdot, ud, count):
    """`lanes.rates_blocks` count times."""
    for _ in range(count):
        lanes.rates_blocks(stack, q, u, Q, g, free, ws, qdot, ud)


@jit
def mul_add_loop(x, m, count):
    """6 independent multiply chains and 6 independent add chains, count rounds: 12 operations a
    round, enough in flight to hide their 3-cycle latency on two pipes of each kind, few enough
    to stay in the 16 vector registers; no fused multiply-add."""
    p0, p1, p2, p3, p4, p5 = x, x + 1.0, x + 2.0, x + 3.0, x + 4.0, x + 5.0
    a0, a1, a2, a3, a4, a5 = x, x - 1.0, x - 2.0, x - 3.0, x - 4.0, x - 5.0
    for _ in range(count):
        p0, p1, p2, p3, p4, p5 = p0 * m, p1 * m, p2 * m, p3 * m, p4 * m, p5 * m
        a0, a1, a2, a3, a4, a5 = a0 + m, a1 + m, a2 + m, a3 + m, a4 + m, a5 + m
    return p0 + p1 + p2 + p3 + p4 + p5 + a0 + a1 + a2 + a3 + a4 + a5


# ------------------------------------------------------------------------------ the inputs

def paper_blocks(seed: int = 28):
    """The paper robot: its scalar records and state, and a block of four lanes of it (four
    payloads, four states), with Q the scene's efforts. (scalar args, lanes args)."""
    from ..dynamics.records import make_model, make_workspace
    from ..dynamics.vector import Lanes
    scene = load_scene()
    robot, effects = scene.robot, scene.effects
    n, nq, nu = robot.n_links, robot.n_q, robot.n_u
    rng = np.random.default_rng(seed)
    Q = np.concatenate([[0.0, 0.0], scene.joint_efforts])
    tips = [0.0, 0.5, 1.0, 2.0]
    models = [make_model(robot, tip, effects.wheel_inertia) for tip in tips]
    qs = [np.array(scene.initial_q) + rng.normal(size=nq) * 0.1 for _ in tips]
    us = [rng.normal(size=nu) for _ in tips]
    free = lanes.all_free(n)
    scalar = (models[0], qs[0], us[0], Q, float(effects.gravity), free, make_workspace(n),
              np.zeros(nq), np.zeros(nu))
    block = (lanes.lanes_model(models), lanes.lanes_state(qs), lanes.lanes_state(us),
             lanes.lanes_state([Q] * 4), Lanes([effects.gravity] * 4), free,
             lanes.lanes_workspace(n), lanes.lanes_state([np.zeros(nq)] * 4),
             lanes.lanes_state([np.zeros(nu)] * 4))
    return scalar, block, (models, qs, us, Q, float(effects.gravity), free)


def paper_stack(runs: int = 64, seed: int = 29):
    """`runs` runs of the paper robot (payloads 0 … 2 kg, states around the initial one) as
    blocks for `lanes.rates_blocks`: its arguments."""
    from ..dynamics.records import make_model
    scene = load_scene()
    robot, effects = scene.robot, scene.effects
    rng = np.random.default_rng(seed)
    Q = np.concatenate([[0.0, 0.0], scene.joint_efforts])
    models = [make_model(robot, tip, effects.wheel_inertia) for tip in np.linspace(0, 2, runs)]
    qs = [np.array(scene.initial_q) + rng.normal(size=robot.n_q) * 0.1 for _ in models]
    us = [rng.normal(size=robot.n_u) for _ in models]
    return (lanes.model_stack(models), lanes.block_states(qs), lanes.block_states(us),
            lanes.block_states([Q] * runs), lanes.block_states([[effects.gravity]] * runs),
            lanes.all_free(robot.n_links), lanes.lanes_workspace(robot.n_links),
            lanes.block_states([np.zeros(robot.n_q)] * runs),
            lanes.block_states([np.zeros(robot.n_u)] * runs))


def bits_equal(block, inputs) -> bool:
    """After a lanes call, every lane's q̇ and u̇ equal the scalar body's on that lane's run."""
    from ..dynamics.records import make_workspace
    models, qs, us, Q, g, free = inputs
    lanes.rates(*block)
    qdot, ud = block[7].array, block[8].array
    for j, (model, q, u) in enumerate(zip(models, qs, us, strict=True)):
        qd_j, ud_j = np.zeros(len(q)), np.zeros(len(u))
        lanes.rates(model, q, u, Q, g, free, make_workspace(model.L.shape[0]), qd_j, ud_j)
        if not (np.array_equal(qd_j, qdot[:, j]) and np.array_equal(ud_j, ud[:, j])):
            return False
    return True


# ------------------------------------------------------------------------- flops, counted

def count_flops() -> dict:
    """Operations of one paper-robot `lanes.rates` evaluation, counted in a child process that
    runs the kernels as plain Python (`_count_here`)."""
    env = dict(os.environ, MOBILE_MANIP_SIM_NO_JIT="1")
    code = "import json; from mobile_manip_sim.bench import lanes_fd; " \
           "print(json.dumps(lanes_fd._count_here()))"
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                          check=True)
    return json.loads(done.stdout.splitlines()[-1])


def _count_here() -> dict:
    import collections
    import operator

    from ..dynamics import jit as jit_module
    from ..dynamics.records import make_workspace
    if jit_module.ENABLED:
        raise RuntimeError("flops are counted with the compiler off (MOBILE_MANIP_SIM_NO_JIT=1)")
    counts = collections.Counter()

    def counted(name, function):
        def method(self, other):
            if not isinstance(other, (int, float)):
                return NotImplemented
            counts[name] += 1
            return Number(function(float(self), float(other)))
        return method

    class Number(float):
        """A float that counts the arithmetic done on it (numba's unrolled x ** k included)."""
        __add__ = counted("add", operator.add)
        __radd__ = counted("add", lambda a, b: b + a)
        __sub__ = counted("sub", operator.sub)
        __rsub__ = counted("sub", lambda a, b: b - a)
        __mul__ = counted("mul", operator.mul)
        __rmul__ = counted("mul", lambda a, b: b * a)
        __truediv__ = counted("div", operator.truediv)
        __rtruediv__ = counted("div", lambda a, b: b / a)

        def __neg__(self):
            counts["neg"] += 1
            return Number(-float(self))

        def __pow__(self, k):
            counts["mul"] += int(k).bit_length() - 1 + bin(int(k)).count("1") - 1
            return Number(float(self) ** k)

    for name in ("sin", "cos"):
        original = getattr(math, name)

        def trig(x, original=original, name=name):
            counts[name] += 1
            return Number(original(x))
        setattr(math, name, trig)

    def numbers(array):
        return np.vectorize(Number, otypes=[object])(np.asarray(array, dtype=float))

    scalar, _, _ = paper_blocks()
    model, q, u, Q, g, free, ws, qdot, ud = scalar
    model = model._replace(
        base=type(model.base)(*(Number(v) for v in model.base)),
        **{k: numbers(getattr(model, k)) for k in ("mount", "R0", "L", "mu", "J")},
        tip_mass=Number(model.tip_mass))
    ws = type(ws)(**{k: (v if k == "moving" else numbers(v)) for k, v in
                     make_workspace(model.L.shape[0])._asdict().items()})
    out = numbers(qdot), numbers(ud)
    lanes.rates(model, numbers(q), numbers(u), numbers(Q), Number(g), free, ws, *out)
    return dict(counts)


# ------------------------------------------------------------------------ peaks, machine

def peak_flops_per_ns(target: float) -> float:
    """Flops per ns of `mul_add_loop` on four lanes (12 vector operations a round)."""
    from ..dynamics.vector import Lanes
    seconds = loops.per_call(mul_add_loop, Lanes((1.0, 1.1, 1.2, 1.3)),
                             Lanes((1.0000001, 0.9999999, 1.0, 1.0)), target=target)
    return 12 * 4 / (seconds * 1e9)


def instruction_counts(args) -> dict:
    """Mnemonic counts in the machine code of `lanes.rates` compiled afresh for ``args``."""
    import numba
    fresh = numba.njit(_nrt=False, error_model="numpy", fastmath=False)(lanes.rates.py_func)
    fresh(*args)
    asm = "\n".join(fresh.inspect_asm().values())
    body = re.split(r"^_ZN7cpython", asm, flags=re.M)[0]   # the kernel, not the Python wrapper
    return {name: len(re.findall(rf"\b{name}\w*", body)) for name in MNEMONICS}


def measure(progress, quick: bool = False) -> LanesResult:
    result = LanesResult()
    if not ENABLED:
        progress("numba is off: no lanes")
        return result
    target = 0.02 if quick else 0.1
    scalar, block, inputs = paper_blocks()
    result.bits_equal = bits_equal(block, inputs)
    result.flops = count_flops()
    progress(f"one evaluation: {result.total_flops} flops counted ({result.flops})")
    result.scalar_ns = loops.per_call(rates_loop, *scalar, target=target) * 1e9
    result.lanes_ns = loops.per_call(rates_loop, *block, target=target) * 1e9 / lanes.WIDTH
    stack = paper_stack()
    result.blocks_ns = loops.per_call(rates_blocks_loop, *stack, target=target) * 1e9 / (
        stack[1].shape[0] * lanes.WIDTH)
    result.peak_per_ns = peak_flops_per_ns(target)
    result.ghz = clock_ghz()
    progress(f"scalar {result.scalar_ns:.0f} ns, lanes {result.lanes_ns:.0f} ns per lane "
             f"(×{result.scalar_ns / result.lanes_ns:.2f}), 64 runs a call "
             f"{result.blocks_ns:.0f} ns per lane; mul + add loop "
             f"{result.peak_per_ns:.1f} flops/ns; lanes equal their scalar runs bit for bit: "
             f"{result.bits_equal}")
    result.instructions = {"lanes": instruction_counts(block),
                           "scalar": instruction_counts(scalar)}
    progress(f"machine code: {result.instructions}")
    return result


def section(result: LanesResult, number: int = 10) -> str:
    flops, counts = result.total_flops, result.flops
    # the clock while the vector units are busy: the mul + add loop at its 16 flops per cycle
    clock = result.peak_per_ns / PEAK_VECTOR
    rate = {"scalar": flops / result.scalar_ns, "lanes": flops / result.lanes_ns}   # per ns
    cycle = {name: value / clock for name, value in rate.items()}
    below = PEAK_VECTOR / cycle["lanes"]
    rows = [("flops of one evaluation (counted)",
             f"{flops}: + {counts.get('add', 0)}, − {counts.get('sub', 0)}, "
             f"× {counts.get('mul', 0)}, ÷ {counts.get('div', 0)} (besides: "
             f"{counts.get('neg', 0)} negations, {counts.get('sin', 0)} sin, "
             f"{counts.get('cos', 0)} cos)", ""),
            ("scalar kernel, one run",
             f"{result.scalar_ns:.0f} ns: {cycle['scalar']:.2f} flops/cycle "
             f"({cycle['scalar'] / PEAK_SCALAR * 100:.0f} % of the scalar peak {PEAK_SCALAR:g}, "
             f"{cycle['scalar'] / PEAK_VECTOR * 100:.0f} % of the vector peak)", ""),
            ("vector lanes, four runs a call, per lane",
             f"{result.lanes_ns:.0f} ns: {cycle['lanes']:.2f} flops/cycle "
             f"({cycle['lanes'] / PEAK_VECTOR * 100:.0f} % of the vector peak; "
             f"×{result.scalar_ns / result.lanes_ns:.2f} the scalar kernel)",
             verdict(below <= GOAL, f"{below:.1f}× below the vector peak; goal within "
                                    f"{GOAL:g}×")),
            ("64 runs in one call (16 blocks of four), per lane",
             f"{result.blocks_ns:.0f} ns: {flops / result.blocks_ns / clock:.2f} flops/cycle", ""),
            ("independent 4-wide multiplies and adds (the peak, measured)",
             f"{result.peak_per_ns:.1f} flops/ns: {PEAK_VECTOR:g} flops/cycle at "
             f"{clock:.2f} GHz (/proc/cpuinfo says {result.ghz:.2f} GHz)", ""),
            ("every lane = its scalar run, bit for bit", "yes" if result.bits_equal else "NO",
             "")]
    lines = [f"## {number}. One forward-dynamics evaluation per lane: vector lanes", "",
             "The paper robot's right-hand-side dynamics (frames, configuration rate, "
             "articulated forward dynamics), compiled once for one run (the scalar kernel) and "
             "once for a block of four runs in 256-bit registers (the same source with four "
             "lanes, `dynamics/lanes.py`; the four runs carry different payloads and states). "
             "CPU time of compiled loops calling it; flops counted by running the same source "
             "on numbers that count their arithmetic. Flops per cycle are taken at the clock "
             "the peak loop shows (it cannot exceed 16 flops a cycle), so each ratio to the "
             "peak is a ratio of two measurements.", "",
             table(("", "measured", "verdict"), rows), "",
             "Peaks, double flops per cycle: this core issues two 4-wide multiplies (or fused "
             "multiply-adds) and two 4-wide additions a cycle: 16 for a balanced mix of "
             "multiplies and additions without fused multiply-adds (8 for either kind alone), "
             "16 for fused multiply-adds alone; one lane of scalar code, 4. The lanes use no "
             "fused multiply-adds: one rounds once where the scalar kernel rounds twice, and a "
             "lane would no longer equal its own run. Each sine and cosine is the C library's, "
             "lane by lane, for the same reason.", ""]
    mix = result.instructions
    if mix:
        names = MNEMONICS
        lines += ["Machine code of the body, instructions counted in its assembly (each written "
                  "once; the loops over links run theirs once per link; `call` counts the "
                  "C library's sin/cos/sincos and numba's helpers):", "",
                  table(("",) + names, [(name,) + tuple(counts.get(m, 0) for m in names)
                                        for name, counts in mix.items()]), ""]
    return "\n".join(lines)
