"""The node's command line before rcl sees it: `--help`, and the parameter values rcl would
take silently or refuse in several lines (a blank ``-p NAME:=``, a bool spelled ``yes``, a line
break in a ``-p`` rule, a params file it would block on or expand without end). No ROS."""
from __future__ import annotations

import sys

from ..scene.errors import UserError
from . import parameters
from .parameters import NODE_NAME, PARAMETERS

MAX_PARAMS_FILE = 1 << 20  # bytes: a parameters file larger than this is refused
HELP_FLAGS = ("-h", "--help")
YAML_BOOLS = {"true": True, "True": True, "TRUE": True,
              "false": False, "False": False, "FALSE": False}   # YAML 1.2's, as the schema reads


def _arguments(argv) -> list[str]:
    return list(sys.argv[1:] if argv is None else argv)


def wants_help(argv) -> bool:
    """-h or --help before --ros-args."""
    args = _arguments(argv)
    ours = args[:args.index("--ros-args")] if "--ros-args" in args else args
    return any(arg in HELP_FLAGS for arg in ours)


def help_text() -> str:
    lines = ["usage: simulator [--ros-args [-p NAME:=VALUE]... [--params-file FILE] "
             "[-r FROM:=TO]...]",
             "",
             f"The ROS 2 node {NODE_NAME}: a simulated mobile manipulator (its interface: "
             f"docs/node.md).",
             "",
             "parameters (* may be set while the node runs):"]
    for name, spec in PARAMETERS.items():
        default = spec.default
        shown = ("true" if default else "false") if isinstance(default, bool) else repr(default)
        bounds = f" in {parameters.bounds(name)}" if spec.range else ""
        lines.append(f"  {name}{' *' if spec.dynamic else ''} = {shown}{bounds}")
        lines.append(f"      {spec.description}")
    from .qos import CHOICES, DEPTH, QOS_OVERRIDES  # rclpy: only when help is asked for
    lines += ["", "QoS overrides (read-only; one set per published topic, as rclpy nodes take "
                  "them):"]
    for policy, choices in CHOICES.items():
        lines.append(f"  {QOS_OVERRIDES}<topic>.publisher.{policy} = {' | '.join(choices)}")
    lines += [f"  {QOS_OVERRIDES}<topic>.publisher.{DEPTH} = an integer of at least 1",
              "      <topic> is the resolved name: /odom, or /robot1/odom under -r "
              "__ns:=/robot1; a topic the node does not publish is refused."]
    return "\n".join(lines)


def check(argv) -> None:
    """The parameter overrides and params files in ``argv``: UserError (one line) naming the
    first that rcl must not see."""
    args = _arguments(argv)
    for flag, value in zip(args, args[1:], strict=False):
        if flag in ("-p", "--param"):
            _check_override(value)
        elif flag == "--params-file":
            _check_params_file(value)


def _check_override(rule: str) -> None:
    """``-p [NODE:]NAME:=VALUE`` for one of our parameters."""
    target, separator, text = rule.partition(":=")
    name = target.rsplit(":", 1)[-1]
    if "\n" in rule or "\r" in rule:   # YAML's line breaks
        from ..scene import schema
        raise UserError(schema.label(name), f"-p {schema.short(rule)} holds a line break "
                                            f"(rcl would fold it into a space, or refuse it in "
                                            f"several lines)")
    if not separator:
        return   # rcl's to judge
    if text.strip() == "":
        raise UserError(name, f"no value after ':=' (an empty string is written "
                              f"-p \"{name}:=''\")")
    spec = PARAMETERS.get(name)   # unknown names are refused once the node starts
    if spec is not None and isinstance(spec.default, bool) and text.strip() not in YAML_BOOLS:
        raise UserError(name, f"expected true or false, got {text!r}")


def _check_params_file(path: str) -> None:
    """Read first by the schema's YAML loader (a regular UTF-8 file within its size, nesting,
    alias-expansion and duplicate-key limits) and refused here in one line: rcl would block on
    a FIFO, expand an alias bomb without end, silently take the last of two duplicate keys, or
    take ``yes`` for true; and it fails with its own multi-line errors."""
    from ..scene import schema

    what = schema.label(path, 160)
    try:
        text = schema.read_text_file(path, what, limit=MAX_PARAMS_FILE, kind="parameters file")
        document = schema.load_yaml(text, what=what)
    except UserError as error:
        text = str(error) if error.key == what else f"{what}: {error}"
        raise UserError("--params-file", text) from None
    if not isinstance(document, dict):
        return   # rcl's to judge
    for node in document.values():
        values = node.get("ros__parameters") if isinstance(node, dict) else None
        for name, value in _leaves(values if isinstance(values, dict) else {}):
            if name not in PARAMETERS:
                continue
            if value is None:
                raise UserError("--params-file", f"{what}: {name}: no value")
            if isinstance(PARAMETERS[name].default, bool) and not isinstance(value, bool):
                raise UserError("--params-file", f"{what}: {name}: expected true or false, "
                                                 f"got {schema.short(value)}")


def _leaves(tree: dict, prefix: str = ""):
    for key, value in tree.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            yield from _leaves(value, name + ".")
        else:
            yield name, value
