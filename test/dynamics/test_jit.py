"""dynamics/jit.py: `Bound`, the compiled call that skips numba's argument typing after the
first call, gives the dispatcher's results — also when a kernel has several compiled overloads."""
import numpy as np
import pytest

from mobile_manip_sim.dynamics import jit
from mobile_manip_sim.engine import stepping
from mobile_manip_sim.engine.simulation import Simulation
from mobile_manip_sim.scene.loading import load_scene


@jit.jit
def _weighted_sum(values, weight):
    total = 0.0
    for i in range(values.shape[0]):
        total += weight * values[i]
    return total


def test_bound_kernel_equals_the_dispatcher_call_after_call():
    simulation = Simulation(load_scene())
    bound = jit.Bound(stepping.total_energy)
    for t in (0.01, 0.02, 0.3):
        simulation.advance_to(t)
        assert bound(simulation.system.data, simulation.s) == stepping.total_energy(
            simulation.system.data, simulation.s)


def test_bound_kernel_with_several_overloads_takes_the_one_of_its_arguments():
    floats, ints = np.arange(4.0), np.arange(4)
    _weighted_sum(ints, 2)            # a second overload, compiled first
    bound = jit.Bound(_weighted_sum)
    assert bound(floats, 0.5) == 3.0
    assert bound(floats, 2.0) == 12.0  # now through the bound entry point
    if jit.ENABLED:
        assert len(_weighted_sum.overloads) == 2


@pytest.mark.skipif(not jit.ENABLED, reason="numba is off")
def test_bound_kernel_reaches_compiled_code_directly():
    bound = jit.Bound(_weighted_sum)
    bound(np.ones(3), 1.0)
    assert bound._entry is not _weighted_sum   # the dispatcher is out of the way
    assert bound(np.ones(3), 2.0) == 6.0


@pytest.mark.skipif(not jit.ENABLED, reason="numba is off")
def test_caches_are_dropped_when_kernel_sources_change_and_kept_when_an_adapter_does(tmp_path):
    package = tmp_path / "package"
    sources = {"dynamics/workspace.py": "S = 6\n", "engine/system.py": "@jit\ndef f(): pass\n",
               "bench/loops.py": "@jit\ndef g(): pass\n", "node.py": "# publication jitter\n"}
    for name, text in sources.items():
        (package / name).parent.mkdir(parents=True, exist_ok=True)
        (package / name).write_text(text)
    cache = package / "engine" / "__pycache__" / "system.f-1.py311.nbi"

    def cached_after_editing(name: str) -> bool:
        cache.parent.mkdir(exist_ok=True)
        cache.write_bytes(b"index")
        (package / name).write_text(sources[name] + "# edited\n")
        jit._drop_stale_caches(package)
        return cache.exists()

    jit._drop_stale_caches(package)   # the first stamp
    assert cached_after_editing("node.py")
    assert not cached_after_editing("dynamics/workspace.py")   # constants frozen into kernels
    assert not cached_after_editing("bench/loops.py")
    assert not cached_after_editing("engine/system.py")
