"""`rosdep install --from-paths src -y --ignore-src` succeeds: every key of package.xml has a
rosdep rule on ROS 2 Jazzy (Ubuntu noble, Debian), as read from rosdistro's rosdep/base.yaml,
rosdep/python.yaml and jazzy/distribution.yaml (test/package/data/rosdep_keys.yaml records the
facts and
where they came from). What rosdep cannot install is a pip requirement (requirements.txt),
named in package.xml's export and in setup.py's install_requires."""
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[2]
FACTS = yaml.safe_load((Path(__file__).resolve().parent / "data" / "rosdep_keys.yaml").read_text())


def package_keys() -> dict:
    """Every dependency key of package.xml → its tag (exec_depend, test_depend, …)."""
    root = ET.parse(ROOT / "package.xml").getroot()
    return {element.text.strip(): element.tag for element in root
            if element.tag.endswith("depend")}


def requirements() -> list:
    lines = (ROOT / "requirements.txt").read_text().splitlines()
    return [line.strip() for line in lines if line.strip() and not line.startswith("#")]


def test_the_facts_say_where_they_came_from():
    source = FACTS["source"]
    assert source["repository"] == "ros/rosdistro"
    assert re.fullmatch(r"[0-9a-f]{40}", source["commit"])
    assert set(source["files"]) == {"rosdep/base.yaml", "rosdep/python.yaml",
                                    "jazzy/distribution.yaml"}
    for key, rule in FACTS["resolves"].items():
        assert rule["file"] in source["files"], key
        if rule["file"] != "jazzy/distribution.yaml":   # a system package: both platforms
            assert rule["ubuntu"] and rule["debian"], key
    assert not set(FACTS["resolves"]) & set(FACTS["no_rule"])


def test_every_key_of_package_xml_resolves_on_jazzy():
    keys = package_keys()
    assert len(keys) > 15 and "rclpy" in keys and "python3-scipy" in keys
    unresolved = sorted(set(keys) - set(FACTS["resolves"]))
    assert not unresolved, (f"package.xml keys rosdep cannot resolve on Jazzy: {unresolved}; "
                            f"make them pip requirements (requirements.txt)")


def test_what_rosdep_cannot_install_is_a_pip_requirement_named_where_users_look():
    """The packages without a rule (mcap, zstandard, pyarrow, dask, foxglove-sdk, viser) are in
    requirements.txt, which package.xml's export names; pip install . gets them from setup.py."""
    listed = {re.split(r"[\[<>=]", line)[0] for line in requirements()}
    assert {"mcap", "zstandard", "pyarrow", "dask", "foxglove-sdk", "viser",
            "mcap-ros2-support"} <= listed
    no_rule = set(FACTS["no_rule"])
    for name in listed:
        assert f"python3-{name}" in no_rule or f"python3-{name}-pip" in no_rule, name
        assert f"python3-{name}-pip" not in package_keys(), name
    export = ET.parse(ROOT / "package.xml").getroot().find("export")
    assert export.findtext("pip_requirements") == "requirements.txt"
    setup = (ROOT / "setup.py").read_text()
    runtime = requirements()[:requirements().index("mcap-ros2-support")]
    for requirement in runtime:
        assert f'"{requirement}"' in setup, requirement
    docs = (ROOT / "docs" / "ros.md").read_text()
    assert "pip install" in docs and "requirements.txt" in docs
