"""What a rosdep + colcon install relies on: package.xml names every third-party package the
code imports, and the shipped parameter file is exactly the node's parameters."""
import ast
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import yaml

from mobile_manip_sim.node import PARAMETERS

ROOT = Path(__file__).resolve().parents[2]

# Import name → rosdep key, or → "pip:NAME" for a package rosdep has no rule for (then it is a
# line of requirements.txt). A new third-party import must be added here AND to package.xml or
# requirements.txt (test_rosdep_keys.py checks that package.xml's keys resolve).
ROSDEP_KEYS = {
    "numpy": "python3-numpy", "scipy": "python3-scipy", "yaml": "python3-yaml",
    "matplotlib": "python3-matplotlib", "pinocchio": "pinocchio",
    "mujoco": "python3-mujoco-pip", "zstandard": "pip:zstandard", "mcap": "pip:mcap",
    "distributed": "pip:dask[distributed]", "dask": "pip:dask[distributed]",
    "pyarrow": "pip:pyarrow", "foxglove": "pip:foxglove-sdk", "viser": "pip:viser",
}


def pip_requirements() -> set:
    """The requirements.txt lines (what rosdep cannot install), as "pip:NAME"."""
    lines = (ROOT / "requirements.txt").read_text().splitlines()
    return {f"pip:{line.strip()}" for line in lines if line.strip() and not line.startswith("#")}


def third_party_imports() -> dict:
    """Top-level module → a file of the package that imports it (absolute imports only)."""
    found = {}
    for path in sorted((ROOT / "mobile_manip_sim").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            else:
                continue
            for name in names:
                top = name.split(".")[0]
                if top not in sys.stdlib_module_names and top != "mobile_manip_sim":
                    found.setdefault(top, path.relative_to(ROOT))
    return found


def test_every_third_party_import_is_a_package_xml_dependency():
    root = ET.parse(ROOT / "package.xml").getroot()
    declared = {element.text.strip() for element in root
                if element.tag.endswith("depend") and element.text} | pip_requirements()
    imports = third_party_imports()
    assert {"numpy", "rclpy", "matplotlib", "zstandard"} <= set(imports)
    assert "numba" not in imports and "llvmlite" not in imports   # one engine: the C++ core
    missing = {module: str(path) for module, path in imports.items()
               if ROSDEP_KEYS.get(module, module) not in declared}
    assert not missing, f"imported but not in package.xml nor requirements.txt: {missing}"


def leaves(tree: dict, prefix: str = "") -> dict:
    flat = {}
    for key, value in tree.items():
        name = f"{prefix}{key}"
        flat.update(leaves(value, name + ".") if isinstance(value, dict) else {name: value})
    return flat


def test_the_shipped_params_file_is_exactly_the_nodes_parameters_at_their_defaults():
    document = yaml.safe_load((ROOT / "config" / "simulator.params.yaml").read_text())
    assert list(document) == ["/**"]    # whatever the node's name or namespace
    shipped = leaves(document["/**"]["ros__parameters"])
    assert shipped == {name: spec[0] for name, spec in PARAMETERS.items()}
    assert all(type(shipped[name]) is type(spec[0]) for name, spec in PARAMETERS.items())
    text = (ROOT / "config" / "simulator.params.yaml").read_text()
    assert "not implemented" not in text


def test_what_the_documented_commands_write_is_ignored_by_git():
    """Running the commands of the README and docs/ in a clone leaves `git status` clean: every
    --out and --record target they name (and simulate's default run.csv) is in .gitignore."""
    import re
    import subprocess
    text = "\n".join(page.read_text() for page in [ROOT / "README.md",
                                                   *sorted((ROOT / "docs").glob("*.md"))])
    flags = r"(?:(?<=\s)(?:--out|--record|-o) |record:=)"
    written = set(re.findall(flags + r"([\w.][\w./-]*)", text)) | {"run.csv"}
    written -= {"FILE.csv", "DIR", "bench/", "null"}   # placeholders; bench/ holds the
    # committed report; record:=null is quoted as refused
    assert {"paper_run.csv", "heavy.csv", "run1", "sweep_out", "figures/"} <= written, written
    for name in sorted(written):
        path = name.rstrip("/") + ("/REPORT.png" if name.endswith("/") or "." not in name else "")
        ignored = subprocess.run(["git", "check-ignore", "-q", "--no-index", path], cwd=ROOT)
        assert ignored.returncode == 0, f"{path} (written by a documented command) is not ignored"
