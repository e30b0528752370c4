"""What a run loads: `simulate` and the node import neither SciPy's solvers and linear algebra
(only radau and bdf need SciPy; scipy.integrate alone is 56 MB) nor matplotlib, and no compiler
(numba, LLVM): the engine is compiled ahead of time. Facts about ``sys.modules`` in a fresh
interpreter, not timings."""
import json
import subprocess
import sys

import pytest

HEAVY = ("scipy.integrate", "scipy.linalg", "scipy.sparse", "matplotlib", "numba", "llvmlite")

SIMULATE = """
import json, sys
from mobile_manip_sim.programs import simulate
simulate.main(["--method", {method!r}, "--duration", "0.3", "--out", {out!r}])
print(json.dumps(sorted(sys.modules)))
"""

NODE = """
import json, sys
import mobile_manip_sim.node
from mobile_manip_sim.engine.simulation import Simulation
from mobile_manip_sim.scene.loading import load_scene, make_integrator
scene = load_scene(None)
Simulation(scene, make_integrator(scene.integrator, "rk4", 0.001)).advance_to(0.3)
print(json.dumps(sorted(sys.modules)))
"""


def modules_after(code: str) -> set[str]:
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                            timeout=600, check=True)
    return set(json.loads(result.stdout.splitlines()[-1]))


def heavy(modules: set[str]) -> list[str]:
    return sorted(name for name in modules
                  if any(name == prefix or name.startswith(prefix + ".") for prefix in HEAVY))


@pytest.mark.parametrize("method", ["rk4", "dop853"])
def test_simulate_imports_neither_scipy_solvers_nor_matplotlib(tmp_path, method):
    assert heavy(modules_after(SIMULATE.format(method=method, out=str(tmp_path / "run.csv")))) == []


def test_simulate_imports_scipy_integrate_for_radau_only(tmp_path):
    # the check above can see SciPy: a run that needs it has it
    modules = modules_after(SIMULATE.format(method="radau", out=str(tmp_path / "run.csv")))
    assert "scipy.integrate" in modules


def test_the_node_module_and_an_rk4_run_import_neither_scipy_solvers_nor_matplotlib():
    assert heavy(modules_after(NODE)) == []
