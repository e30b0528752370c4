"""`runtime.compiles.CompileWatch` counts what numba compiles (its ``numba:compile`` event), not
what it loads from its cache: the node's "nothing compiles after start-up" rests on it, and so
does `CompileNotice`, what the node says when its start-up compiles."""
import threading

import numba
import pytest

from mobile_manip_sim.dynamics.jit import ENABLED
from mobile_manip_sim.runtime.compiles import CompileNotice, CompileWatch

pytestmark = pytest.mark.skipif(not ENABLED, reason="numba is off: nothing compiles")


def test_a_compile_is_counted_with_its_name_and_reported_and_a_second_call_is_not():
    @numba.njit(cache=False)
    def doubled(x):
        return 2.0 * x

    said = []
    watch = CompileWatch(said.append).start()
    try:
        assert doubled(1.5) == 3.0
        assert watch.count == 1 and said == watch.names
        assert watch.names[0].endswith("doubled")
        assert doubled(2.5) == 5.0   # the same types: no compile
        assert doubled(2) == 4.0     # an int: another specialisation, compiled
        assert watch.count == 2
    finally:
        watch.stop()
    assert doubled(True) == 2.0      # after stop: not counted
    assert watch.count == 2


def test_a_start_that_compiles_says_so_first_then_how_far_it_is_and_a_warmed_one_says_nothing():
    # waiting (test/helpers) is not imported at the top: run_mode's processes import this
    # module without the tests' path
    from numba.core import event

    from waiting import HANG

    @numba.njit(cache=False)
    def tripled(x):
        return 3.0 * x

    said, progress = [], threading.Event()

    def say(line):
        said.append(line)
        if line.startswith("still compiling the kernels ("):
            progress.set()

    class HeldCompile(event.Listener):
        """Registered after the notice's watch: holds the compile until a progress line came
        (no timing: the compile lasts as long as it takes the ticker to speak)."""
        def on_start(self, ev):
            assert progress.wait(HANG), said

        def on_end(self, ev):
            pass

    held = HeldCompile()
    with CompileNotice(say, "compiling", every=0.01):
        event.register("numba:compile", held)
        try:
            assert tripled(1.0) == 3.0
        finally:
            event.unregister("numba:compile", held)
    assert said[0] == "compiling", said
    assert said[1].startswith("still compiling the kernels ("), said
    assert said[-1].startswith("kernels compiled in ") and said[-1].endswith("(1 of them)"), said

    said.clear()
    with CompileNotice(say, "compiling", every=0.01):
        assert tripled(2.0) == 6.0   # loaded, as from a warmed cache: no compile, no line
    assert said == []

    with pytest.raises(KeyboardInterrupt), CompileNotice(say, "compiling", every=60.0):
        assert tripled(2) == 6   # an int: compiled
        raise KeyboardInterrupt   # a stop halfway: no "compiled in" line
    assert said == ["compiling"]


def loaded_overloads() -> dict:
    """Every numba dispatcher of the package → how many compiled versions it holds (loaded from
    the cache or compiled) in this process."""
    import sys

    from numba.core.registry import CPUDispatcher
    found = {}
    for name, module in list(sys.modules.items()):
        if name.startswith("mobile_manip_sim") and module is not None:
            for attribute, value in vars(module).items():
                if isinstance(value, CPUDispatcher):
                    found[f"{name}.{attribute}"] = len(value.overloads)
    return found


def publication(sim, k: int) -> None:
    """What the node computes from the engine for publication ``k`` (shell._messages,
    view.messages): the joint states (q̇, the efforts acting: the wheel-speed loop's torques in
    velocity mode, the arm controller's output), /imu (u̇) and the live view's /energy."""
    from mobile_manip_sim.ros.imu import Imu
    from mobile_manip_sim.ros.messages import energy, state_messages
    state_messages(sim, k, sim.model.joint_names())
    Imu().read(sim, k)
    energy(sim)


def run_mode(mode: str) -> None:
    """A node's run in ``mode`` with each feed-forward, in this (fresh) process: every kernel
    it calls — steps, commands (effort and cmd_vel through the wheel-speed loop, and the
    release check they make), the arm's reference and efforts, what every publication reads,
    resets, a state set by hand — was loaded by `Simulation.load_kernels` (no dispatcher gains
    a version afterwards) and nothing compiles. Prints the offenders, or "none"."""
    import copy

    import numpy as np

    from mobile_manip_sim.engine.simulation import Simulation
    from mobile_manip_sim.ros.trajectory_goals import Trajectory
    from mobile_manip_sim.runtime.timeline import (
        apply_arm_command,
        apply_commands,
        start_node_time_line,
    )
    from mobile_manip_sim.scene.arm_controller import MODES, ArmController
    from mobile_manip_sim.scene.loading import load_scene, parse_scene

    doc = copy.deepcopy(load_scene().document)
    doc["integrator"] = {"method": "rk4", "dt": 1e-3}
    scene = parse_scene(doc)
    offenders = []
    for feedforward in ("none", "gravity", "computed_torque"):
        sim = Simulation(scene, arm_controller=ArmController(mode, feedforward=feedforward))
        sim.load_kernels()
        loaded = loaded_overloads()
        watch = CompileWatch().start()
        try:
            start_node_time_line(sim)
            publication(sim, 0)
            sim.advance_to(0.6)   # rod 2 comes to rest at its stop (test_set_state.py)
            publication(sim, 60)
            q = sim.q[5:].copy()
            efforts = None if MODES[mode].controlled else [0.0, 1.0, 0.0, 1.0]
            apply_commands(sim, [0.3, 0.5], efforts, velocity=True)   # base_command velocity
            sim.advance_to(0.65)
            publication(sim, 65)
            apply_commands(sim, [0.1, 0.0], efforts, velocity=False)
            if MODES[mode].controlled:
                apply_arm_command(sim, mode, (q * 0.5 if mode == "velocity" else q + 0.05)
                                  if MODES[mode].array else
                                  Trajectory(np.array([10 ** 8]), (q + 0.05)[None], None, None))
            sim.advance_to(0.7)
            publication(sim, 70)
            sim.acceleration()
            sim.joint_efforts_applied()
            if sim.arm_controller.active:
                sim.arm_reference(0.01)
            sim.set_state(sim.q.copy(), sim.u.copy())
            sim.advance_to(0.75)
            start_node_time_line(sim)
            sim.advance_to(0.8)
        finally:
            watch.stop()
        grown = [name for name, count in loaded_overloads().items()
                 if count > loaded.get(name, 0)]
        offenders += [f"{feedforward}: {name}" for name in watch.names + grown]
    print("offenders:", ", ".join(offenders) or "none")


@pytest.mark.parametrize("mode", ["effort", "position", "velocity", "joint_trajectory"])
def test_after_load_kernels_a_run_in_any_mode_loads_and_compiles_nothing(mode):
    """In a fresh process each (the kernels of an earlier run would hide a gap)."""
    import subprocess
    import sys
    from pathlib import Path
    here = Path(__file__).resolve().parent
    result = subprocess.run([sys.executable, "-c", f"import test_compiles; "
                                                   f"test_compiles.run_mode({mode!r})"],
                            cwd=here, capture_output=True, text=True, timeout=900)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "offenders: none", result.stdout
