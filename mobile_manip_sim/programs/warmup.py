"""Compile and cache every kernel path once, at set-up (`tools/bootstrap.sh`, or
`python -m mobile_manip_sim.programs.warmup` after a colcon build), so that no run — the node
above all — compiles at run time. numba keeps the machine code beside the sources (`__pycache__`); a
read-only install that was never warmed still runs, compiling in memory on first use.

It runs each integrator on scenes that take every branch of the engine: end stops hit, rods
resting and released, the Zeno guard, sampling, the wheel-speed loop, damping and locked joints;
then every arm controller mode with every feed-forward (`scene.arm_controller.MODES`), so a node
in any mode compiles nothing after its start-up line (it loads what its run needs before it:
`Simulation.load_kernels`).

The batch's lanes (their vector blocks, and each lane alone) compile for minutes of their own, in
a second process beside the methods: numba compiles on one core, and the machine has two or
more (each process caches what it compiles; a kernel both need is compiled by both, and either
copy is the same).

It talks as it goes (a bootstrap's log must never stay silent for long): how long it takes, up
front; each kernel as it starts; and, while one compiles, a line of progress every few seconds
(`progress.Progress`, whole lines, terminal or not), all on stderr, each line flushed.
"""
import subprocess
import sys
import time
import warnings
from importlib import resources

from ..dynamics.jit import ENABLED
from ..engine.simulation import Simulation
from ..runtime.progress import Progress
from ..scene.arm_controller import FEEDFORWARDS, MODES, ArmController
from ..scene.loading import make_integrator, scene_from_text
from ..scene.methods import METHODS

SCENES = ("paper_two_link.yaml", "hard_impacts.yaml", "effect_joint_damping.yaml",
          "effect_locked_joints.yaml")
EXPECTED = "3 to 9 minutes on two cores"   # cold: 161 s before the vector lanes, 519 s loaded


def kernels():
    """(scene file, method) of every run the warm-up makes: SciPy's solvers need one scene."""
    return [(name, method) for name in SCENES for method, entry in METHODS.items()
            if entry.compiled or name == SCENES[0]]


def warm(stream=sys.stderr) -> float:
    start = time.perf_counter()
    todo = kernels()
    # Progress counts parts: each method (its first run compiles its kernels, nearly all the
    # time; the other scenes then take the branches left, in a second or so), the arm
    # controllers, and the batch's lanes (their vector blocks: minutes of their own).
    parts = len(METHODS) + 2
    progress = Progress("warmup", parts, "parts compiled", rate_unit="parts/min",
                        per=60.0, lines=True, always=True, stream=stream)
    progress.note(f"warmup: compiling {len(todo)} kernels ({len(METHODS)} methods on "
                  f"{len(SCENES)} scenes), once: {EXPECTED}; later runs load them from the cache")
    lanes = subprocess.Popen([sys.executable, "-m", __spec__.name, BATCH_LANES])
    try:
        with progress, warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)   # a scene's advice, not ours
            _methods_and_controllers(todo, progress, start)
            progress.update(len(METHODS) + 1)
            progress.note(f"warmup: waiting for the batch's compiled lanes "
                          f"({time.perf_counter() - start:.0f} s)")
            while lanes.poll() is None:
                time.sleep(0.2)   # a poll, so that Ctrl-C acts at once
            if lanes.returncode:
                raise SystemExit(f"warmup: the batch's lanes failed (status {lanes.returncode})")
            progress.update(parts)
    finally:
        if lanes.poll() is None:
            lanes.kill()
            lanes.wait()
    return time.perf_counter() - start


def _methods_and_controllers(todo, progress, start) -> None:
    """Every method on the scenes of `kernels()`, then every arm controller."""
    scenes = {}
    for done, (name, method) in enumerate(todo):
        progress.update(min(done, len(METHODS)))
        progress.note(f"warmup: [{done + 1}/{len(todo)}] {method} on {name} "
                      f"({time.perf_counter() - start:.0f} s)")
        if name not in scenes:
            text = resources.files("mobile_manip_sim").joinpath("config", name).read_text()
            scenes[name] = scene_from_text(text, name)
        scene = scenes[name]
        settings = make_integrator(scene.integrator, method)
        _exercise(Simulation(scene, settings))
        if name == SCENES[0] and METHODS[method].compiled:
            # a run with an arm controller: its compiled code is a second specialisation of
            # every kernel taking the system record (`engine.system.EffortSystemData`)
            _exercise(Simulation(scene, settings, ArmController("joint_trajectory")))
    progress.update(len(METHODS))
    modes = dict.fromkeys(mode for mode, _ in controllers())
    progress.note(f"warmup: the arm controllers ({', '.join(modes)}) "
                  f"({time.perf_counter() - start:.0f} s)")
    scene = scenes[SCENES[0]]
    for mode, feedforward in controllers():
        sim = Simulation(scene, arm_controller=ArmController(mode, feedforward=feedforward))
        sim.load_kernels()
        sim.advance_to(0.05)


def _exercise(sim) -> None:
    """Sample, steer the base, stop it, check the energy and load what a node's run calls."""
    sim.sample([0.01 * k for k in range(1, 31)])
    sim.set_base_velocity(0.3, 0.5)
    sim.advance_to(0.35)
    sim.set_efforts(wheels=[0.0, 0.0])
    sim.energy_error()
    sim.load_kernels()


def batch_lanes(stream=sys.stderr) -> None:
    """The batch's compiled lanes, for sweeps: in vector blocks and each lane alone."""
    start = time.perf_counter()
    print("warmup: the batch's compiled lanes, for sweeps, in a second process", file=stream,
          flush=True)
    from ..batch import Batch
    from ..scene.loading import load_scene
    scene = load_scene()
    for vector in (True, False):
        Batch(scene, [{"integrator.method": "rk4"}] * 2, threads=1,
              vector=vector).sample([0.01, 0.02])
    print(f"warmup: the batch's compiled lanes done ({time.perf_counter() - start:.0f} s)",
          file=stream, flush=True)


def controllers():
    """(mode, feed-forward) of every arm controller (the compiled law is one kernel for all:
    each pair's Python-side calls are loaded once)."""
    return [(name, feedforward) for name, mode in MODES.items() if mode.controlled
            for feedforward in FEEDFORWARDS]


BATCH_LANES = "--batch-lanes"   # the second process's part


def main() -> int:
    if not ENABLED:
        print("warmup: numba is off (MOBILE_MANIP_SIM_NO_JIT or not installed): nothing to compile",
              flush=True)
        return 0
    if sys.argv[1:] == [BATCH_LANES]:
        batch_lanes()
        return 0
    print(f"warmup: every kernel compiled and cached in {warm():.0f} s", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
