"""`runtime.compiles.CompileWatch` counts what numba compiles (its ``numba:compile`` event), not
what it loads from its cache: the node's "nothing compiles after start-up" rests on it."""
import numba
import pytest

from mobile_manip_sim.dynamics.jit import ENABLED
from mobile_manip_sim.runtime.compiles import CompileWatch

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
