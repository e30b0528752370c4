"""Run a test module's function in a child process with the kernels as plain Python
(``MOBILE_MANIP_SIM_NO_JIT=1``), for the tests that compare that path with the compiled one."""
import json
import os
import subprocess
import sys
from pathlib import Path

# the folders of the test modules (test/scene, test/engine …)
FOLDERS = sorted(p for p in Path(__file__).resolve().parents[1].iterdir()
                 if p.is_dir() and p.name not in ('helpers', '__pycache__'))


def without_jit(module: str, function: str):
    """``module.function()`` (a test module of any folder of test/; JSON-able result) without
    numba."""
    folders = [str(Path(__file__).parent)] + [str(f) for f in FOLDERS]
    script = (f"import json, sys\nsys.path[:0] = {folders!r}\n"
              f"from {module} import {function}\nprint(json.dumps({function}()))\n")
    env = dict(os.environ, MOBILE_MANIP_SIM_NO_JIT="1")
    done = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True,
                          check=True, timeout=600)
    return json.loads(done.stdout)
