"""One safe YAML loader and the small validators every input uses (scene files, sweep specs, the
node's parameters file, bag metadata: ``recording/bag_format.py``,
``recording/rosbag2_metadata.py``). Every mistake is a `UserError` naming its key path, in one
line, with the offending value shortened.

`load_yaml(source, what=...)` reads a `Path` (a regular file of at most MAX_FILE_BYTES; FIFOs,
devices and directories are refused without being read) or a `str` of YAML text, and parses it
as YAML 1.2 core schema (``1e-10`` is a number; ``yes``/``on``/``017``/``1:30`` are strings or
decimal, not YAML 1.1 booleans, octals or sexagesimals) with these limits:

- at most MAX_DEPTH levels of nesting;
- at most MAX_NODES nodes once aliases are expanded (a "billion laughs" bomb is refused before
  anything is built), and no recursive aliases;
- no duplicate keys in a mapping;
- integers of more than MAX_INT_DIGITS digits are kept as `HugeNumber` and refused by `number`;
- an explicit tag must be one of the core schema's (``!!str !!int !!float !!bool !!null !!seq
  !!map``) and its value must be of that kind (``!!float abc``, ``!!int 1.5``, ``!!bool yes`` are
  refused), and a ``%YAML`` directive other than ``%YAML 1.2`` is refused (YAML 1.1 would read
  ``yes`` as true: we do not).
"""
from __future__ import annotations

import json
import math
import os
import re
import reprlib
import stat
from pathlib import Path

import numpy as np
import yaml

from .errors import UserError

MAX_FILE_BYTES = 1 << 20      # 1 MiB: a scene is a few kB
MAX_DEPTH = 64                # nesting levels
MAX_NODES = 100_000           # YAML nodes after alias expansion
MAX_INT_DIGITS = 30           # longer integers cannot be physical quantities
MAX_JSON_BYTES = 64 << 20     # a bag's impacts.json: ~300 000 impacts

_short = reprlib.Repr()
_short.maxlevel, _short.maxlist, _short.maxtuple, _short.maxdict = 2, 4, 4, 4
_short.maxstring, _short.maxother, _short.maxlong = 40, 40, 40


def short(value) -> str:
    """A repr of `value` of bounded length, whatever its size."""
    if isinstance(value, HugeNumber):
        return f"{value[:12]}…({len(value)} digits)"
    return clip(_short.repr(value), 80)


def clip(text: str, limit: int = 160) -> str:
    """`text` itself (no quotes) if short, else its head and tail around an ellipsis."""
    text = str(text)
    return text if len(text) <= limit else f"{text[:limit // 2]}…{text[-limit // 2:]}"


def label(key, limit: int = 40) -> str:
    """A key (or a file name) as it can stand in a one-line message: itself when it is a short,
    printable string, else its shortened repr."""
    if (isinstance(key, str) and not isinstance(key, HugeNumber) and key.strip()
            and key.isprintable()):
        return clip(key, limit)
    return short(key)


class HugeNumber(str):
    """An integer literal too long to be a quantity; `number` refuses it, naming the key."""


# --- the loader -----------------------------------------------------------------------------

class _Loader(yaml.SafeLoader):
    """SafeLoader with YAML 1.2 core resolvers, duplicate-key, depth and expansion checks."""

    yaml_implicit_resolvers: dict = {}

    def __init__(self, stream, what: str):
        super().__init__(stream)
        self.what = what
        self._depth = 0

    def compose_node(self, parent, index):
        self._depth += 1
        if self._depth > MAX_DEPTH:
            mark = self.peek_event().start_mark
            raise UserError(self.what,
                            f"nested deeper than {MAX_DEPTH} levels (line {mark.line + 1})")
        try:
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1

    def process_directives(self):
        value = super().process_directives()
        if self.yaml_version not in (None, (1, 2)):
            major, minor = self.yaml_version
            raise yaml.parser.ParserError(None, None, f"a %YAML {major}.{minor} directive: these "
                                          f"files are read as YAML 1.2 (remove the directive)",
                                          self.peek_token().start_mark)
        return value

    def compose_document(self):
        node = super().compose_document()
        _check_expansion(node, self.what)
        return node

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            self.flatten_mapping(node)
            seen = set()
            for key_node, _ in node.value:
                key = self.construct_object(key_node, deep=True)
                try:
                    duplicate = key in seen
                    seen.add(key)
                except TypeError:
                    raise UserError(self.what, f"a mapping key must be a scalar, got {short(key)} "
                                               f"(line {key_node.start_mark.line + 1})") from None
                if duplicate:
                    raise UserError(label(key),
                                    f"duplicate key (line {key_node.start_mark.line + 1})")
        return super().construct_mapping(node, deep=deep)


def _check_expansion(root, what: str) -> None:
    """Count nodes as if every alias were copied; refuse cycles and more than MAX_NODES."""
    sizes: dict[int, int] = {}
    stack = [(root, False)]
    open_nodes = set()
    while stack:
        node, children_done = stack.pop()
        key = id(node)
        if children_done:
            open_nodes.discard(key)
            children = _children(node)
            sizes[key] = 1 + sum(sizes[id(child)] for child in children)
            if sizes[key] > MAX_NODES:
                raise UserError(what, f"expands to more than {MAX_NODES} YAML nodes (aliases?)")
            continue
        if key in sizes:
            continue
        if key in open_nodes:
            raise UserError(what, f"recursive alias (line {node.start_mark.line + 1})")
        open_nodes.add(key)
        stack.append((node, True))
        for child in _children(node):
            if id(child) in open_nodes:
                raise UserError(what, f"recursive alias (line {child.start_mark.line + 1})")
            if id(child) not in sizes:
                stack.append((child, False))


def _children(node):
    if isinstance(node, yaml.SequenceNode):
        return node.value
    if isinstance(node, yaml.MappingNode):
        return [item for pair in node.value for item in pair]
    return []


def _core_scalar(loader, node, kind: str) -> str:
    """The text of a scalar node tagged !!<kind>, which must match the core schema's pattern for
    that kind (an explicit tag on a value of another kind is refused, naming the line)."""
    text = loader.construct_scalar(node)
    if not isinstance(node, yaml.ScalarNode) or not _CORE_PATTERNS[kind].match(text):
        raise yaml.constructor.ConstructorError(
            None, None, f"!!{kind} {clip(repr(text), 40)} is not a YAML 1.2 {kind}",
            node.start_mark)
    return text


def _int(loader, node):
    return _int_value(_core_scalar(loader, node, "int"))


def _int_value(text: str):
    sign, digits = (text[0], text[1:]) if text[:1] in "+-" else ("", text)
    if len(digits) > MAX_INT_DIGITS:
        return HugeNumber(text)
    base = {"0o": 8, "0x": 16}.get(digits[:2].lower(), 10)
    value = int(digits[2:] if base != 10 else digits, base)
    return -value if sign == "-" else value


def _float(loader, node):
    text = _core_scalar(loader, node, "float").lower()
    if text.lstrip("+-") in (".inf",):
        return -math.inf if text.startswith("-") else math.inf
    if text == ".nan":
        return math.nan
    try:
        return float(text)
    except ValueError:   # an integer form tagged !!float: 0x1f, 0o17 (a ValueError escaped)
        value = _int_value(text)
        return value if isinstance(value, HugeNumber) else float(value)


def _bool(loader, node):
    return _core_scalar(loader, node, "bool").lower() == "true"


def _null(loader, node):
    _core_scalar(loader, node, "null")


def _not_core(loader, node):
    tag = node.tag.replace("tag:yaml.org,2002:", "!!")
    raise yaml.constructor.ConstructorError(
        None, None, f"the tag {clip(tag, 40)} is not one of YAML 1.2's core schema "
        f"(!!str, !!int, !!float, !!bool, !!null, !!seq, !!map)", node.start_mark)


_RESOLVERS = [  # YAML 1.2 core schema (https://yaml.org/spec/1.2.2/#1032-tag-resolution)
    ("tag:yaml.org,2002:null", r"^(?:~|null|Null|NULL|)$", list("~nN") + [""]),
    ("tag:yaml.org,2002:bool", r"^(?:true|True|TRUE|false|False|FALSE)$", list("tTfF")),
    ("tag:yaml.org,2002:int", r"^(?:[-+]?[0-9]+|0o[0-7]+|0x[0-9a-fA-F]+)$", list("-+0123456789")),
    ("tag:yaml.org,2002:float",
     r"^(?:[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?"
     r"|[-+]?\.(?:inf|Inf|INF)|\.nan|\.NaN|\.NAN)$", list("-+.0123456789")),
]
_CORE_PATTERNS = {tag.rsplit(":", 1)[1]: re.compile(pattern) for tag, pattern, _ in _RESOLVERS}
_CORE_PATTERNS["float"] = re.compile(f"{_RESOLVERS[2][1]}|{_RESOLVERS[3][1]}")  # !!float 1 is 1.0
for _tag, _pattern, _first in _RESOLVERS:
    _Loader.add_implicit_resolver(_tag, re.compile(_pattern), _first)
_Loader.add_implicit_resolver("tag:yaml.org,2002:merge", re.compile(r"^(?:<<)$"), ["<"])
_Loader.add_constructor("tag:yaml.org,2002:int", _int)
_Loader.add_constructor("tag:yaml.org,2002:float", _float)
_Loader.add_constructor("tag:yaml.org,2002:bool", _bool)
_Loader.add_constructor("tag:yaml.org,2002:null", _null)
for _tag in ("timestamp", "binary", "set", "omap", "pairs"):
    _Loader.add_constructor(f"tag:yaml.org,2002:{_tag}", _not_core)


def read_text_file(path, what: str | None = None, limit: int = MAX_FILE_BYTES,
                   kind: str = "file") -> str:
    """The UTF-8 text of a regular file of at most `limit` bytes; anything else one UserError
    (``cannot read <kind> (reason)``)."""
    path = Path(path)
    what = what or label(str(path), 160)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except OSError as error:
        raise UserError(what, f"cannot read {kind} ({error.strerror})") from None
    info = os.fstat(fd)
    if not stat.S_ISREG(info.st_mode):
        os.close(fd)
        raise UserError(what, "not a regular file")
    with os.fdopen(fd, "rb") as handle:
        if info.st_size > limit:
            raise UserError(what, f"larger than {limit} bytes")
        try:
            data = handle.read(limit + 1)
        except OSError as error:
            raise UserError(what, f"cannot read {kind} ({error.strerror})") from None
    if len(data) > limit:
        raise UserError(what, f"larger than {limit} bytes")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as error:
        raise UserError(what, f"not UTF-8 text (byte {error.start})") from None


def load_yaml(source, what: str = "input"):
    """Parse YAML from a `Path` (a file) or a `str` (the text); see the module docstring."""
    if isinstance(source, Path):
        source = read_text_file(source, what)
    if len(source) > MAX_FILE_BYTES:
        raise UserError(what, f"larger than {MAX_FILE_BYTES} bytes")
    loader = None
    try:
        loader = _Loader(source, what)
        return loader.get_single_data()
    except yaml.YAMLError as error:
        mark = getattr(error, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark else ""
        problem = getattr(error, "problem", None) or str(error).splitlines()[0]
        raise UserError(what, f"not valid YAML{where}: {problem}") from None
    except RecursionError:
        raise UserError(what, "nested too deeply") from None
    finally:
        if loader is not None:
            loader.dispose()


def load_json(data: bytes, what: str, limit: int = MAX_JSON_BYTES):
    """Parse JSON bytes (a bag attachment) of at most `limit` bytes; too large, not UTF-8, not
    JSON or nested past the interpreter's recursion limit → one UserError."""
    if len(data) > limit:
        raise UserError(what, f"larger than {limit} bytes")
    try:
        return json.loads(data.decode("utf-8"))
    except UnicodeDecodeError as error:
        raise UserError(what, f"not UTF-8 text (byte {error.start})") from None
    except ValueError as error:   # JSONDecodeError, or an integer of more than 4300 digits
        raise UserError(what, f"not valid JSON ({clip(str(error).splitlines()[0], 100)})") from None
    except RecursionError:
        raise UserError(what, "nested too deeply") from None


# --- validators -----------------------------------------------------------------------------

def number(value, path, *, lo=None, hi=None, positive=False, nonnegative=False,
           unit="") -> float:
    """A finite real number in [lo, hi] (lo excluded if `positive`)."""
    if isinstance(value, HugeNumber):
        raise UserError(path, f"number too large, got {short(value)}")
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        what = "null" if value is None else short(value)
        raise UserError(path, f"expected a number, got {what}")
    if isinstance(value, int) and abs(value) > 1e300:
        raise UserError(path, f"number too large, got {short(value)}")
    value = float(value)
    if not math.isfinite(value):
        raise UserError(path, f"must be finite, got {value}")
    if positive and value <= 0:
        raise UserError(path, f"must be positive, got {value:.6g}")
    if nonnegative and value < 0:
        raise UserError(path, f"must not be negative, got {value:.6g}")
    if lo is not None and value < lo or hi is not None and value > hi:
        low = "[" + (f"{lo:g}" if lo is not None else "(0" if positive else "-∞")
        low = low[1:] if low.startswith("[(") else low
        high = "∞" if hi is None else f"{hi:g}"
        raise UserError(path, f"must be in {low}, {high}]{unit}, got {value:.6g}")
    return value


def integer(value, path, *, lo=None, hi=None) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or isinstance(value, HugeNumber):
        raise UserError(path, f"expected an integer, got {short(value)}")
    if lo is not None and value < lo or hi is not None and value > hi:
        raise UserError(path, f"must be in [{lo}, {hi}], got {short(value)}")
    return value


def string(value, path, *, max_length=200) -> str:
    if not isinstance(value, str) or isinstance(value, HugeNumber):
        raise UserError(path, f"expected a string, got {'null' if value is None else short(value)}")
    if len(value) > max_length:
        raise UserError(path, f"longer than {max_length} characters")
    return value


def flag(value, path) -> bool:
    if not isinstance(value, bool):
        raise UserError(path, "expected true or false, got "
                              f"{'null' if value is None else short(value)}")
    return value


def mapping(value, path) -> dict:
    if not isinstance(value, dict):
        raise UserError(path,
                        f"expected a mapping, got {'null' if value is None else short(value)}")
    return value


def sequence(value, path, *, max_length=None) -> list:
    if not isinstance(value, (list, tuple)):
        raise UserError(path, f"expected a list, got {'null' if value is None else short(value)}")
    if max_length is not None and len(value) > max_length:
        raise UserError(path, f"at most {max_length} entries, got {len(value)}")
    return list(value)


def vector(value, length, path, **checks):
    """A list of `length` numbers (each checked by `number` with `checks`), as a numpy array."""
    if not isinstance(value, (list, tuple)):
        raise UserError(path, f"expected a list of {length} numbers, got {short(value)}")
    if len(value) != length:
        raise UserError(path, f"expected {length} values, got {len(value)}")
    return np.array([number(v, f"{path}[{i}]", **checks) for i, v in enumerate(value)])


def vector_or_scalar(value, length, path, **checks):
    """`vector`, or one number standing for all `length` values."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return np.full(length, number(value, path, **checks))
    return vector(value, length, path, **checks)


def keys(doc: dict, path: str, required=(), optional=()) -> None:
    """Unknown keys and missing required keys are errors."""
    prefix = f"{path}." if path else ""
    allowed = list(required) + list(optional)
    for key in doc:
        if key not in allowed:
            raise UserError(f"{prefix}{label(key)}", f"unknown key (allowed: {_listed(allowed)})")
    for key in required:
        if key not in doc:
            raise UserError(f"{prefix}{key}", "missing")


def _listed(names: list, room: int = 200) -> str:
    """``names`` comma-separated, cut after ``room`` characters with a count of the rest, so an
    error line stays one short line however many keys a map allows."""
    shown = []
    for name in names:
        if len(", ".join([*shown, name])) > room:
            return f"{', '.join(shown)}, … and {len(names) - len(shown)} more"
        shown.append(name)
    return ", ".join(shown)


def string_map(value, path, *, max_entries=1000, max_length=10_000) -> dict[str, str]:
    """A flat mapping of strings to strings (bag metadata)."""
    value = mapping(value, path)
    if len(value) > max_entries:
        raise UserError(path, f"at most {max_entries} entries, got {len(value)}")
    for key, item in value.items():
        string(key, f"{path}", max_length=200)
        string(item, f"{path}.{label(key)}", max_length=max_length)
    return value
