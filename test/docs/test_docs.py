"""The docs run: every `bash`, `python` and `console` block of README.md and docs/*.md is executed,
so an example or a quoted output line that drifts from what the code does fails here.

Rules (also in docs/architecture.md, "The docs are tested"):
- the blocks of one page run in order, in one scratch directory holding links to the
  repository's ``config/``, ``tools/`` and ``docs/`` and ``.venv`` (the running interpreter's
  prefix), so a page reads as a session: a later block may use what an earlier one wrote;
- ``bash`` blocks run with ``set -euo pipefail`` and must exit 0; ``python`` blocks must exit 0;
- a ``console`` block is ``$ command`` lines each followed by the lines it prints (stdout and
  stderr together); each printed line must match its quoted line, ``…`` standing for any text
  (a wall time, a real-time factor, the digits of a round-off);
- a block preceded by ``<!-- no-run: REASON -->`` is not run (it needs the ``ros2`` CLI, a
  running node, a ROS install or a download); the reason is required;
- a ``yaml`` block preceded by ``<!-- file: PATH -->`` must stand in that file word for word;
  any other ``yaml`` block must load with the project's YAML loader, and a scene must parse.

Beside the blocks: no file of the repository refers to anything outside it, every node
parameter is documented in docs/node.md, the README's Layout names every folder of the package,
and every page of docs/ is reachable from docs/index.md.
"""
import os
import re
import subprocess
import sys
import textwrap
from dataclasses import dataclass
from pathlib import Path

import pytest
import yaml

from mobile_manip_sim.scene import schema
from mobile_manip_sim.scene.loading import parse_scene

ROOT = Path(__file__).resolve().parents[2]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
RUN = ("bash", "sh", "python", "console")
BLOCK_TIMEOUT = 300   # s: a hung example fails instead of hanging the suite
FENCE = re.compile(r"^( *)```(\S*)\s*$")
MARKER = re.compile(r"^\s*<!--\s*(no-run|file):\s*(.*?)\s*-->\s*$")


@dataclass
class Block:
    page: Path
    line: int          # 1-based line of the opening fence
    language: str
    text: str
    marker: tuple[str, str] | None   # ("no-run", reason) or ("file", path)

    def __str__(self) -> str:
        page = self.page.relative_to(ROOT) if self.page.is_relative_to(ROOT) else self.page.name
        return f"{page}:{self.line} ({self.language})"


def blocks(page: Path) -> list[Block]:
    """The fenced blocks of a Markdown page, each with the marker on the line before it."""
    lines = page.read_text(encoding="utf-8").splitlines()
    found, i = [], 0
    while i < len(lines):
        opening = FENCE.match(lines[i])
        if not opening:
            i += 1
            continue
        indent, language = opening.group(1), opening.group(2)
        previous = next((line for line in reversed(lines[:i]) if line.strip()), "")
        marker = MARKER.match(previous)
        end = next((j for j in range(i + 1, len(lines)) if lines[j].strip() == "```"), None)
        assert end is not None, f"{page.name}:{i + 1}: a fence that never closes"
        body = [line[len(indent):] if line.startswith(indent) else line
                for line in lines[i + 1:end]]
        found.append(Block(page, i + 1, language, "\n".join(body) + "\n",
                           marker.groups() if marker else None))
        i = end + 1
    return found


def scratch(tmp_path: Path) -> Path:
    for name in ("config", "tools", "docs"):
        (tmp_path / name).symlink_to(ROOT / name)
    (tmp_path / ".venv").symlink_to(Path(sys.executable).parent.parent)
    return tmp_path


def run(command: list[str], cwd: Path, block: Block) -> str:
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    try:
        done = subprocess.run(command, cwd=cwd, env=env, capture_output=True, text=True,
                              timeout=BLOCK_TIMEOUT)
    except subprocess.TimeoutExpired:
        pytest.fail(f"{block}: still running after {BLOCK_TIMEOUT} s:\n{block.text}")
    if done.returncode != 0:
        pytest.fail(f"{block} exited {done.returncode}:\n{block.text}\n--- stdout\n"
                    f"{done.stdout[-3000:]}\n--- stderr\n{done.stderr[-3000:]}")
    return done.stdout


def matches(quoted: str, printed: str) -> bool:
    pattern = ".*".join(re.escape(part) for part in quoted.split("…"))
    return re.fullmatch(pattern, printed) is not None


def run_console(block: Block, cwd: Path) -> None:
    sessions = []
    for line in block.text.splitlines():
        if line.startswith("$ "):
            sessions.append((line[2:], []))
        else:
            assert sessions, f"{block}: output before the first '$ ' line"
            sessions[-1][1].append(line.rstrip())
    for command, quoted in sessions:
        done = subprocess.run(["bash", "-c", command], cwd=cwd, stdout=subprocess.PIPE,
                              stderr=subprocess.STDOUT, text=True, timeout=BLOCK_TIMEOUT,
                              env=dict(os.environ, PYTHONUNBUFFERED="1"))
        printed = done.stdout.rstrip("\n").splitlines()
        while quoted and not quoted[-1]:
            quoted.pop()
        assert len(printed) == len(quoted) and all(map(matches, quoted, printed)), (
            f"{block}: `{command}` printed\n" + "\n".join(printed) + "\nbut the page quotes\n"
            + "\n".join(quoted))


def check_yaml(block: Block) -> None:
    if block.marker and block.marker[0] == "file":
        path = ROOT / block.marker[1]
        assert block.text in path.read_text(encoding="utf-8"), (
            f"{block}: not word for word in {block.marker[1]}")
        return
    document = schema.load_yaml(block.text, what=str(block))
    if isinstance(document, dict) and "robot" in document:
        parse_scene(document)


@pytest.mark.parametrize("page", PAGES, ids=[page.name for page in PAGES])
def test_every_example_of_the_page_runs_and_prints_what_it_quotes(page, tmp_path):
    cwd = scratch(tmp_path)
    for index, block in enumerate(blocks(page)):
        if block.marker and block.marker[0] == "no-run":
            assert block.marker[1], f"{block}: a no-run marker needs its reason"
            continue
        if block.language == "yaml":
            check_yaml(block)
        elif block.language in ("bash", "sh"):
            script = cwd / f"block_{index}.sh"
            script.write_text("set -euo pipefail\n" + block.text)
            run(["bash", str(script)], cwd, block)
        elif block.language == "python":
            script = cwd / f"block_{index}.py"
            script.write_text(block.text)
            run([sys.executable, str(script)], cwd, block)
        elif block.language == "console":
            run_console(block, cwd)


def test_the_block_reader_sees_markers_fences_and_indented_blocks(tmp_path):
    page = tmp_path / "page.md"
    page.write_text("text\n\n<!-- no-run: needs ros2 CLI -->\n```bash\nros2 topic list\n```\n"
                    "- a list item:\n\n  ```python\n  print(1)\n  ```\n```\nplain\n```\n")
    found = blocks(page)
    assert [(b.language, b.text, b.marker) for b in found] == [
        ("bash", "ros2 topic list\n", ("no-run", "needs ros2 CLI")),
        ("python", "print(1)\n", None),
        ("", "plain\n", None)]
    pattern = "simulated 1.5 s in … s wall, 83 steps"
    assert matches(pattern, "simulated 1.5 s in 0.3 s wall, 83 steps")
    assert not matches(pattern, "simulated 1.5 s in 0.3 s wall, 84 steps")


def test_every_page_with_examples_has_one_that_runs():
    """A page whose every block is marked no-run would test nothing. A page of prose and tables
    alone (the index, an explanation) has no block to run."""
    for page in PAGES:
        found = [b for b in blocks(page) if b.language in RUN]
        runnable = [b for b in found if not b.marker]
        if found:
            assert runnable, f"{page.name}: no block runs"
    assert [page.name for page in PAGES if page.name != "index.md"
            and any(b.language in RUN for b in blocks(page))]


def test_every_docs_page_is_linked_from_the_index_and_every_local_link_resolves():
    index = (ROOT / "docs" / "index.md").read_text(encoding="utf-8")
    unlisted = [page.name for page in PAGES[1:]
                if page.name != "index.md" and f"]({page.name}" not in index]
    assert unlisted == [], "pages missing from docs/index.md"
    broken = []
    for page in PAGES:
        text = page.read_text(encoding="utf-8")
        for target, anchor in re.findall(r"\]\(([^)#\s]*)(?:#([^)\s]*))?\)", text):
            if "://" in target or target.startswith("mailto:") or not (target or anchor):
                continue
            linked = (page.parent / target) if target else page
            if not linked.exists():
                broken.append(f"{page.relative_to(ROOT)}: {target}")
            elif anchor and linked.suffix == ".md" and anchor not in anchors(linked):
                broken.append(f"{page.relative_to(ROOT)}: {target}#{anchor}")
    assert broken == [], "links to files or headings that do not exist"


def anchors(page: Path) -> set[str]:
    """The anchors GitHub gives a page's headings: lower case, punctuation dropped, spaces
    turned into hyphens (fenced blocks skipped)."""
    text = re.sub(r"^```.*?^```", "", page.read_text(encoding="utf-8"), flags=re.S | re.M)
    headings = re.findall(r"^#{1,6} +(.+?) *$", text, flags=re.M)
    return {re.sub(r"[^\w\- ]", "", heading.lower()).replace(" ", "-") for heading in headings}



def repository_files() -> list[Path]:
    try:
        listed = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard"],
                                cwd=ROOT, capture_output=True, text=True, check=True).stdout
        return [ROOT / name for name in listed.splitlines() if (ROOT / name).is_file()]
    except (OSError, subprocess.CalledProcessError):   # not a git checkout (a source copy)
        skip = {".git", ".venv", "build", "install", "log", "__pycache__"}
        return [p for p in ROOT.rglob("*") if p.is_file() and not skip & set(p.parts)]


# What a clone does not have: the development notes beside the repository, and this machine.
OUTSIDE = re.compile(r"\.\./shared|(?<![\w.])shared/\w+\.md|/work/"
                     r"|\b(?:MODEL|TF2_MSGS|ROSBAG2|PITFALLS|STYLE)\.md")


def test_no_file_refers_to_anything_outside_the_repository():
    offending = []
    for path in repository_files():
        if path == Path(__file__).resolve() or path.suffix in (".png", ".mcap", ".parquet"):
            continue
        try:
            text = path.read_text(encoding="utf-8")
        except UnicodeDecodeError:
            continue
        for number, line in enumerate(text.splitlines(), 1):
            if OUTSIDE.search(line):
                offending.append(f"{path.relative_to(ROOT)}:{number}: {line.strip()}")
    assert not offending, "references outside the repository:\n" + "\n".join(offending)


def parameter_names(mapping: dict, prefix: str = "") -> list[str]:
    names = []
    for key, value in mapping.items():
        if isinstance(value, dict):
            names += parameter_names(value, f"{prefix}{key}.")
        else:
            names.append(prefix + key)
    return names


def test_every_node_parameter_is_documented_in_node_md():
    shipped = yaml.safe_load((ROOT / "config" / "simulator.params.yaml").read_text())
    names = parameter_names(shipped["/**"]["ros__parameters"])
    page = (ROOT / "docs" / "node.md").read_text(encoding="utf-8")
    assert len(names) > 10
    assert [name for name in names if f"`{name}`" not in page] == []


def test_the_readme_layout_names_every_folder_and_the_readme_stays_short():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    layout = readme[readme.index("\n## Layout\n"):]
    package = ROOT / "mobile_manip_sim"
    modules = [p.name for p in package.glob("*.py") if p.name != "__init__.py"]
    packages = [f"{p.name}/" for p in package.iterdir() if (p / "__init__.py").is_file()]
    missing = [name for name in modules + packages if f"`{name}`" not in layout
               and f"`mobile_manip_sim/{name}`" not in layout and f", `{name}`" not in layout]
    assert missing == []
    # 265: the ros2_control route (its URDF block, controllers.yaml, the commands) is on it
    assert len(readme.splitlines()) <= 265, "the README is the front door: details go in docs/"


def test_the_readme_and_the_ros_route_give_the_same_controllers_yaml():
    """README.md's compact controllers.yaml is docs/ros.md's, value for value, and the URDF
    block both quote opens as `describe --ros2-control` writes it."""
    def of(page):
        return [block for block in blocks(ROOT / page)
                if block.language == "yaml" and block.text.startswith("controller_manager:")]
    readme, route = of("README.md"), of("docs/ros.md")
    assert len(readme) == len(route) == 1
    assert yaml.safe_load(readme[0].text) == yaml.safe_load(route[0].text)
    from mobile_manip_sim.ros.urdf import robot_description
    from mobile_manip_sim.scene import load_scene
    urdf = robot_description(load_scene(), ros2_control={})
    for page in ("README.md", "docs/ros.md"):
        block = next(b for b in blocks(ROOT / page) if b.language == "xml")
        hardware = block.text[:block.text.index("</hardware>")]
        assert textwrap.indent(hardware, "  ") in urdf, page


def test_the_example_in_the_sweep_spec_docstring_is_a_valid_spec():
    from mobile_manip_sim.sweep import spec
    example = textwrap.dedent(spec.__doc__.split("\n\n")[1])
    parsed = spec.parse_spec(schema.load_yaml(example, what="sweep/spec.py"), base_dir=ROOT)
    assert len(parsed.runs()) == 4 * 100


@pytest.mark.parametrize("tool", ["simulate", "describe", "plot", "replay", "sweep", "bench"])
def test_every_flag_of_every_tool_is_in_the_command_line_reference(tool):
    """The docs name every option the tool's --help lists (docs/simulate.md is the command-line
    reference; replay's are in bags.md, the live view's in view.md)."""
    done = subprocess.run([str(Path(sys.executable).parent / tool), "--help"], capture_output=True,
                          text=True, timeout=BLOCK_TIMEOUT)
    assert done.returncode == 0, done.stderr
    flags = set(re.findall(r"(?<![\w-])(--[a-z][\w-]*)", done.stdout)) - {"--help"}
    assert flags, done.stdout
    reference = "".join(page.read_text(encoding="utf-8") for page in PAGES[1:])
    assert sorted(flag for flag in flags if flag not in reference) == []
