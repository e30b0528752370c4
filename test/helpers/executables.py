"""Where the tests find the package's console scripts: beside the running interpreter (the venv's
bin/, which CI does not put on PATH), else on PATH. A missing one fails the test, never skips it."""
import shutil
import sys
from pathlib import Path


def executable(name: str) -> str:
    found = shutil.which(name, path=str(Path(sys.executable).parent)) or shutil.which(name)
    if found is None:
        raise FileNotFoundError(f"console script {name!r} is not installed (pip install -e .)")
    return found
