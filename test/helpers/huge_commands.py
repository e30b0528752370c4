"""Huge finite commands right after a reset, for every method, in their own process (a regression
that loops would hang this process, not the test run: the caller's timeout is the safety net).

Each case: reset, the command, advance to 0.01 s; then reset, zero efforts, advance to 0.01 s
again (a failure must leave a simulation that a reset brings back). One JSON line per case:
{method, command, values, error (type name or null), message, steps, recovered}.

    python huge_commands.py             # the fixed cases (COMMANDS)
    python huge_commands.py SEED COUNT  # and COUNT random ones per method, drawn with SEED
"""
import json
import math
import sys
import warnings

import numpy as np

from engine_cases import paper_doc, simulation
from mobile_manip_sim.engine.step_watch import BUDGET_STEPS
from mobile_manip_sim.scene.errors import UserError
from mobile_manip_sim.scene.methods import IDS, METHODS

# (command, values): wheels (τ_R, τ_L) N·m, cmd_vel (v, ω), joints (4 efforts), all (all six)
COMMANDS = [("wheels", [1e300, 1e300]), ("wheels", [1e308, 1e308]), ("wheels", [-1e308, 1e308]),
            ("wheels", [1e30, -1e30]), ("cmd_vel", [1e300, 0.0]), ("cmd_vel", [1e308, 1e308]),
            ("cmd_vel", [1e30, 1e30]), ("joints", [1e300] * 4), ("all", [1e308] * 6)]


def random_commands(seed: int, count: int):
    """`count` commands of magnitudes 1e20 to 1.8e308, random signs, random groups."""
    rng = np.random.default_rng(seed)
    sizes = {"wheels": 2, "cmd_vel": 2, "joints": 4, "all": 6}
    for _ in range(count):
        group = str(rng.choice(list(sizes)))
        exponents = rng.uniform(20.0, math.log10(np.finfo(float).max), sizes[group])
        yield group, (rng.choice([-1.0, 1.0], exponents.size) * 10.0 ** exponents).tolist()


def apply(sim, group, values):
    if group == "wheels":
        sim.set_efforts(wheels=values)
    elif group == "cmd_vel":
        sim.set_base_velocity(*values)
    elif group == "joints":
        sim.set_efforts(joints=values)
    else:
        sim.set_efforts(wheels=values[:2], joints=values[2:])


def run(sim, group, values) -> dict:
    sim.reset()
    error, message = None, ""
    try:
        apply(sim, group, values)
        sim.advance_to(0.01)
    except (UserError, RuntimeError) as caught:   # SimulationError, StepLimitError: RuntimeErrors
        error, message = type(caught).__name__, str(caught)
    steps = sim.steps
    sim.reset()
    sim.set_efforts(wheels=[0.0, 0.0], joints=[0.0] * (sim.nu - 2))
    sim.advance_to(0.01)
    return {"command": group, "values": values, "error": error, "message": message, "steps": steps,
            "recovered": sim.t == 0.01 and bool(np.all(np.isfinite(sim.s)))}


def check_huge_command(case):
    """One line of the right kind; no more steps than the step watch allows; a reset recovers."""
    method, error, message = case["method"], case["error"], case["message"]
    assert error in ("UserError", "SimulationError", "StepLimitError"), case
    assert "\n" not in message and len(message) < 300, message
    if error == "UserError":   # its forces overflow: refused, naming the command
        assert message.startswith(f"efforts.{case['command'].replace('all', 'wheels')}: "), message
        assert case["steps"] == 0
    elif METHODS[method].fixed_step:   # the numbers go bad within the first steps
        assert error == "SimulationError" and "non-finite" in message, message
    else:   # every adaptive method: the step watch's one line, naming the setting
        assert error == "StepLimitError" and message.startswith("integrator.rtol: t = "), message
        assert f"{method} cannot follow" in message, message
    assert case["steps"] <= BUDGET_STEPS
    assert case["recovered"], case


def main() -> int:
    seed, count = (int(sys.argv[1]), int(sys.argv[2])) if len(sys.argv) > 2 else (0, 0)
    warnings.simplefilter("ignore", RuntimeWarning)   # semi-implicit Euler's rebound warning
    for method in METHODS:
        sim = simulation(paper_doc(), method)
        sim.advance_to(0.01)   # a run before the reset, as on a node
        for group, values in [*COMMANDS, *random_commands(seed * 100 + IDS[method], count)]:
            print(json.dumps({"method": method, **run(sim, group, values)}), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
