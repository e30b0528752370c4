"""tf2_msgs and control_msgs for the tests: built once by tools/build_interfaces.sh into a cache
keyed by the script's and the definitions' content (a few minutes the first time, then nothing),
and the environment a process needs to import them. The build's steps and reasons:
tools/build_interfaces.sh and docs/interfaces.md."""
import hashlib
import os
import pathlib
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "tools" / "build_interfaces.sh"
DEFINITIONS = ROOT / "tools" / "interfaces"
PACKAGES = ("tf2_msgs", "control_msgs")
EXPORTS = "exports.sh"   # what the script printed on stdout, kept beside the build
CACHE = pathlib.Path(os.environ.get("XDG_CACHE_HOME", pathlib.Path.home() / ".cache"))


def key() -> str:
    """A hash of everything the build reads from the repository: the script and the packages'
    files (names and contents)."""
    digest = hashlib.sha256(SCRIPT.read_bytes())
    for package in PACKAGES:
        for path in sorted((DEFINITIONS / package).rglob("*")):
            if path.is_file():
                digest.update(str(path.relative_to(DEFINITIONS)).encode() + b"\0")
                digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


def build() -> pathlib.Path:
    """The install prefix holding both packages (built now if the cache lacks it)."""
    out = CACHE / "mobile_manip_sim" / f"interfaces-{key()}"
    prefix = out / "install"
    if not (out / EXPORTS).exists():
        result = subprocess.run(["bash", str(SCRIPT), str(out), *PACKAGES],
                                env=dict(os.environ, PYTHON=sys.executable),
                                capture_output=True, text=True, timeout=1800)
        if result.returncode != 0:
            raise RuntimeError(f"tools/build_interfaces.sh failed:\n{result.stdout[-3000:]}\n"
                               f"{result.stderr[-3000:]}")
        (out / EXPORTS).write_text(result.stdout)   # last: a build cut short is built again
    return prefix


def environment(prefix: pathlib.Path, env: dict) -> dict:
    """`env` plus the paths that make `import tf2_msgs, control_msgs` work in a child process."""
    site = next((prefix / "lib").glob("python3.*/site-packages"))
    extended = dict(env)
    for name, value in (("PYTHONPATH", site), ("LD_LIBRARY_PATH", prefix / "lib")):
        extended[name] = os.pathsep.join(filter(None, [str(value), env.get(name, "")]))
    return extended
