"""Key paths (``robot.arm.links[0].mass_per_length``, ``initial.velocity[2]``) set in a scene's
YAML document, then validated by the scene parser exactly as a scene file is.

`simulate --set KEY=VALUE` and every run of a sweep go through `scene_with`; a sweep spec's keys
are checked by `check_known`.
"""
from __future__ import annotations

import copy
import re

from . import schema
from .errors import UserError
from .loading import Scene, parse_scene

_SEGMENT = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)((?:\[\d+\])*)$")


def parse_path(path: str) -> list:
    """``a.b[0].c`` → ["a", "b", 0, "c"]."""
    parts: list = []
    for segment in str(path).split("."):
        match = _SEGMENT.match(segment)
        if not match:
            raise UserError(str(path), "not a key path (names joined by '.', list indices as [N])")
        parts.append(match.group(1))
        parts += [int(index) for index in re.findall(r"\[(\d+)\]", match.group(2))]
    return parts


def path_label(parts: list) -> str:
    """["a", "b", 0, "c"] → ``a.b[0].c``: the one spelling of a key path."""
    text = ""
    for part in parts:
        text += f"[{part}]" if isinstance(part, int) else (f".{part}" if text else part)
    return text


def set_path(document: dict, path: str, value) -> None:
    """Set ``path`` in ``document`` in place; a missing mapping key is created (the parser then
    says whether the scene format knows it), a list index must exist."""
    parts = parse_path(path)
    node = document
    for depth, part in enumerate(parts):
        here = path_label(parts[:depth + 1])
        last = depth == len(parts) - 1
        if isinstance(part, int):
            if not isinstance(node, list):
                raise UserError(here, f"unknown key path: "
                                      f"{path_label(parts[:depth]) or 'the scene'} is not a list")
            if part >= len(node):
                raise UserError(here, f"unknown key path: index {part} out of range (the list "
                                      f"has {len(node)} entries)")
        elif not isinstance(node, dict):
            raise UserError(here, f"unknown key path: {path_label(parts[:depth])} is a value, "
                                  "not a mapping")
        elif part not in node and not last:
            if isinstance(parts[depth + 1], int):
                raise UserError(here, f"unknown key path: the scene has no list {here} "
                                "(an optional list must be set whole)")
            node[part] = {}
        if last:
            node[part] = value
        else:
            node = node[part]


def document_with(document: dict, overrides: dict) -> dict:
    """A copy of the scene ``document`` with every ``{key path: value}`` of ``overrides`` set."""
    changed = copy.deepcopy(document)
    for path, value in overrides.items():
        set_path(changed, path, value)
    return changed


def scene_with(document: dict, overrides: dict, name: str = "scene") -> Scene:
    """The scene ``document`` (a scene file's mapping, or `Scene.document`) with every
    ``{key path: value}`` of ``overrides`` set, validated by `parse_scene`."""
    return parse_scene(document_with(document, overrides), name)


def check_known(document: dict, path: str, value) -> None:
    """Raise `UserError` if the scene format has no key ``path``; a bad *value* passes (runs
    that carry it are recorded as failed)."""
    try:
        scene_with(document, {path: value})
    except UserError as error:
        known_prefix = path.startswith(error.key) or error.key.startswith(path)
        if error.problem.startswith("unknown key") and known_prefix:
            raise UserError(path, error.problem if error.key == path
                            else f"unknown key path: {error}") from None


def parse_assignments(assignments: list[str], flag: str = "--set") -> dict:
    """``["robot.base.mass=7", "integrator.method=rk4"]`` → {path: YAML value}."""
    overrides = {}
    for text in assignments:
        path, equals, value = text.partition("=")
        if not equals or not path.strip():
            raise UserError(flag, f"expected KEY=VALUE, got {text!r}")
        overrides[path.strip()] = schema.load_yaml(value,
                                                   what=f"{flag} {schema.label(path.strip())}")
    return overrides
