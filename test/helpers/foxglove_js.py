"""A third-party Foxglove WebSocket client for the tests: test/foxglove_client.js under Node.js
with @foxglove/ws-protocol (and the Foxglove app's ros2msg/CDR decoders), installed from npm
once into a cache folder keyed by the package list (~10 s the first time, then nothing)."""
import hashlib
import json
import os
import pathlib
import shutil
import subprocess

ROOT = pathlib.Path(__file__).resolve().parent
SCRIPT = ROOT / "foxglove_client.js"
PACKAGES = ("@foxglove/ws-protocol@0.8.0", "@foxglove/rosmsg@5.0.5",
            "@foxglove/rosmsg2-serialization@3.1.0", "ws@8.23.0")
CACHE = pathlib.Path(os.environ.get("XDG_CACHE_HOME", pathlib.Path.home() / ".cache"))


def install() -> pathlib.Path:
    """The node_modules folder holding the client's packages (installed now if missing)."""
    for tool in ("node", "npm"):
        if shutil.which(tool) is None:
            raise RuntimeError(f"{tool} is not on PATH: the live-view tests need Node.js and npm")
    key = hashlib.sha256(" ".join(PACKAGES).encode()).hexdigest()[:16]
    prefix = CACHE / "mobile_manip_sim" / f"foxglove-js-{key}"
    modules = prefix / "node_modules"
    if not all((modules / name.rsplit("@", 1)[0] / "package.json").exists() for name in PACKAGES):
        prefix.mkdir(parents=True, exist_ok=True)
        result = subprocess.run(["npm", "install", "--prefix", str(prefix), "--no-audit",
                                 "--no-fund", "--no-save", *PACKAGES],
                                capture_output=True, text=True, timeout=600)
        if result.returncode != 0:
            raise RuntimeError(f"npm install failed:\n{result.stdout[-2000:]}\n"
                               f"{result.stderr[-2000:]}")
    return modules


def run(modules: pathlib.Path, url: str, wanted: dict, timeout: float = 60.0) -> list[dict]:
    """Connect to ``url``, subscribe to each topic of ``wanted`` (topic → messages to wait
    for) and return the client's events once each has delivered its count."""
    env = dict(os.environ, NODE_PATH=str(modules))
    result = subprocess.run(["node", str(SCRIPT), url, *(f"{t}:{n}" for t, n in wanted.items())],
                            env=env, capture_output=True, text=True, timeout=timeout)
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-2000:]
    return [json.loads(line) for line in result.stdout.splitlines()]
