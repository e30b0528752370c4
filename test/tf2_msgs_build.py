"""tf2_msgs for the tests: built once by tools/build_tf2_msgs.sh into a cache keyed by the
script's content (~1 min the first time, then nothing), and the environment a process needs to
import it. The build's steps and reasons: tools/build_tf2_msgs.sh and docs/interfaces.md."""
import hashlib
import os
import pathlib
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parent.parent
SCRIPT = ROOT / "tools" / "build_tf2_msgs.sh"
CACHE = pathlib.Path(os.environ.get("XDG_CACHE_HOME", pathlib.Path.home() / ".cache"))


def build() -> pathlib.Path:
    """The install prefix of tf2_msgs (built now if the cache lacks it)."""
    key = hashlib.sha256(SCRIPT.read_bytes()).hexdigest()[:16]
    out = CACHE / "mobile_manip_sim" / f"tf2_msgs-{key}"
    prefix = out / "install" / "tf2_msgs"
    if not (prefix / "share" / "tf2_msgs" / "package.xml").exists():
        result = subprocess.run(["bash", str(SCRIPT), str(out), sys.executable],
                                capture_output=True, text=True, timeout=900)
        if result.returncode != 0:
            raise RuntimeError(f"tools/build_tf2_msgs.sh failed:\n{result.stdout[-3000:]}\n"
                               f"{result.stderr[-3000:]}")
    return prefix


def environment(prefix: pathlib.Path, env: dict) -> dict:
    """`env` plus the paths that make `import tf2_msgs` work in a child process."""
    site = next((prefix / "lib").glob("python3.*/site-packages"))
    extended = dict(env)
    for key, value in (("PYTHONPATH", site), ("LD_LIBRARY_PATH", prefix / "lib")):
        extended[key] = os.pathsep.join(filter(None, [str(value), env.get(key, "")]))
    return extended
