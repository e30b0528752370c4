"""Compile and cache every kernel path once, at set-up (`tools/bootstrap.sh`, or
`python -m mobile_manip_sim.warmup` after a colcon build), so that no run — the node above all —
compiles at run time. numba keeps the machine code beside the sources (`__pycache__`); a
read-only install that was never warmed still runs, compiling in memory on first use.

It runs each integrator on scenes that take every branch of the engine: end stops hit, rods
resting and released, the Zeno guard, sampling, the wheel-speed loop, damping and locked joints.
"""
import sys
import time

from importlib import resources

from .dynamics.jit import ENABLED
from .engine.simulation import Simulation
from .methods import METHODS
from .scene import make_integrator, scene_from_text

SCENES = ("paper_two_link.yaml", "hard_impacts.yaml", "effect_joint_damping.yaml",
          "effect_locked_joints.yaml")


def warm(stream=sys.stderr) -> float:
    start = time.perf_counter()
    for name in SCENES:
        text = resources.files("mobile_manip_sim").joinpath("config", name).read_text()
        scene = scene_from_text(text, name)
        for method, entry in METHODS.items():
            if not entry.compiled and name != SCENES[0]:   # SciPy's solvers: one scene is enough
                continue
            sim = Simulation(scene, make_integrator(scene.integrator, method))
            sim.sample([0.01 * k for k in range(1, 31)])
            sim.set_base_velocity(0.3, 0.5)
            sim.advance_to(0.35)
            sim.set_efforts(wheels=[0.0, 0.0])
            sim.energy_error()
        print(f"warmup: {name} compiled ({time.perf_counter() - start:.0f} s)", file=stream)
    return time.perf_counter() - start


def main() -> int:
    if not ENABLED:
        print("warmup: numba is off (MOBILE_MANIP_SIM_NO_JIT or not installed): nothing to compile")
        return 0
    print(f"warmup: every kernel compiled and cached in {warm():.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
