"""Lanes built from a template: a batch's lanes that differ from one another only in numbers.

Building a lane the plain way parses its scene (`scene_with`) and builds its `Simulation`: about
1.4 ms of Python per lane, as much as half its physics. But the lanes of a sweep mostly differ
in a few numbers — a mass, an effort, an initial rate, the step — while everything that sets the
*structure* of the records (the robot's links, the effects, the method, the controller) is the
same. So the lanes are grouped by their other overrides; each group's scene is parsed and its
`Simulation` built once (the template), and every lane of the group is a copy of the template's
records with its own numbers written where the scene parser and the `Simulation` put them:

- ``robot.arm.links[i].mass_per_length``: the robot's μ_i and the model record's ``mu[i]``
  (effort mode only: an arm controller's default gains and feed-forward model derive from the
  masses);
- ``efforts.wheels[i]``, ``efforts.joints[i]``: the scene's efforts (effort mode only for the
  joints: a controlled arm refuses joint efforts), applied by the lane's own `reset`;
- ``initial.velocity[i]``: the scene's initial rates, applied by `reset`;
- ``integrator.dt``: the integrator settings (fixed-step methods), the clock's step by `reset`.

A lane's copy is then `reset`, so its state, efforts and energy reference are computed by the
very code of a `Simulation` of its own. A number is taken this way only when the scene parser
would certainly accept it (a float inside the key's documented bounds); anything else — a
value out of bounds, an integer, a key not listed, a template that does not build — goes the
plain way, so a bad value fails its lane with the parser's own one-line error. Tests compare
every array of a copied lane's records, and its scene, with those of the plain build.
"""
from __future__ import annotations

import dataclasses
import functools
import math
from collections import Counter

import numpy as np

from ..dynamics import Dynamics
from ..engine.simulation import Simulation
from ..engine.system import System
from ..runtime.memory import collector_paused
from ..scene.limits import DENSITY, DT, EFFORT, SPEED
from ..scene.loading import Scene, check_work, parse_scene
from ..scene.overrides import document_with, parse_path, scene_with


def build_lanes(document: dict, overrides: list[dict], check=None,
                scene: Scene | None = None) -> tuple[list, list]:
    """(scenes, sims): each lane's `Scene` and `Simulation` (for a lane that cannot be built, the
    exception in place of its scene and None for its simulation). `check(scene)` may refuse a
    lane's scene (raise) before its simulation is built; `scene`, the document's own scene, is
    taken as it is by lanes without overrides."""
    split = [_split(values) for values in overrides]
    keys = [_key(rest) if fast else None for fast, rest in split]
    shared = Counter(key for key in keys if key is not None)
    templates: dict = {}
    scenes, sims = [], []
    with collector_paused():   # many small records made and kept: its passes cost more
        for values, (fast, rest), key in zip(overrides, split, keys, strict=True):
            template = None
            if shared[key] > 1:   # a template pays from the second lane of its group on
                if key not in templates:
                    templates[key] = Template.of(document, rest, shared[key])
                template = templates[key]
            lane = None
            if template is not None and template.accepts(fast):
                lane = template.scene_with
            try:
                if lane is not None:
                    built = lane(fast)
                elif not values and scene is not None:
                    built = scene
                else:
                    built = scene_with(document, values)
                if check is not None:
                    check(built)
                sim = template.lane(built, fast) if lane is not None else Simulation(built)
            except Exception as error:   # the lane is failed with its reason; the others go on
                built, sim = error, None
            scenes.append(built)
            sims.append(sim)
    return scenes, sims


# --- the numbers a lane may change ---------------------------------------------------------

def _family(parts: list):
    """The fast key family of a parsed key path, or None."""
    if (len(parts) == 5 and parts[:3] == ["robot", "arm", "links"] and isinstance(parts[3], int)
            and parts[4] == "mass_per_length"):
        return "mass"
    if len(parts) == 3 and isinstance(parts[2], int) and (
            parts[:2] in (["efforts", "wheels"], ["efforts", "joints"],
                          ["initial", "velocity"])):
        return ".".join(parts[:2])
    if parts == ["integrator", "dt"]:
        return "dt"
    return None


@functools.lru_cache(maxsize=4096)
def _fast_key(path: str):
    """(family, index) of a key path of a fast family, or None (another key, or not a path)."""
    try:
        parts = parse_path(path)
    except Exception:
        return None
    family = _family(parts)
    if family is None:
        return None
    return family, next((part for part in parts if isinstance(part, int)), 0)


def _split(values: dict) -> tuple[dict, dict]:
    """The overrides split into fast ones {(family, index): value} and the rest; no fast ones
    when a path is not a key path, or two paths overlap (one inside the other)."""
    fast, rest = {}, {}
    for path, value in values.items():
        found = _fast_key(path) if isinstance(path, str) else None
        if found is None:
            rest[path] = value
        else:
            fast[found] = value
    prefixes = [str(path) for path in rest]
    for path in values:
        if path not in rest and any(path.startswith(p) or p.startswith(path) for p in prefixes):
            return {}, values
    if len(fast) != sum(path not in rest for path in values):
        return {}, values   # one number given twice (two spellings of one path)
    return fast, rest


def _key(rest: dict):
    """A hashable key of the non-fast overrides (in their order: set in that order)."""
    try:
        return tuple((path, repr(value)) for path, value in rest.items())
    except Exception:
        return None


def _inside(value, lo: float, hi: float) -> bool:
    """A float the scene parser takes as it is (`schema.number`): finite, within [lo, hi]."""
    return isinstance(value, float) and math.isfinite(value) and lo <= value <= hi


class Template:
    """One group's scene and `Simulation`, and the plan to copy its records (`_Plan`)."""

    def __init__(self, raw: dict, scene: Scene, sim: Simulation, lanes: int = 1):
        self.raw = raw   # the document its scene was parsed from (the lanes' numbers set in it)
        self.scene, self.sim = scene, sim
        self.plan = _Plan(sim, lanes)
        robot = scene.robot
        self.effort_mode = not sim.arm_controller.active
        self.sizes = {"mass": robot.n_links, "efforts.wheels": 2,
                      "efforts.joints": scene.joint_efforts.size,
                      "initial.velocity": robot.n_u, "dt": 1}
        # the lanes' μ go into the lane's robot, from which its compiled core is made; the
        # feed-forward must compute with that one (no model error: no masses of its own)
        self.own_masses = sim.system.data.ff_masses.size == 0

    @classmethod
    def of(cls, document: dict, rest: dict, lanes: int = 1) -> Template | None:
        """The template of the lanes with these other overrides, or None (they are built the
        plain way: an adaptive method, or a scene or simulation that does not build)."""
        try:
            raw = document_with(document, rest)
            scene = parse_scene(raw, "scene")
            if not scene.integrator.fixed_step:
                return None
            template = cls(raw, scene, Simulation(scene), lanes)
        except Exception:
            return None
        return None if template.plan.shares_memory() else template

    def accepts(self, fast: dict) -> bool:
        """Whether every fast number of a lane is one the parser takes as it is, with nothing
        else of the scene depending on it."""
        for (family, index), value in fast.items():
            if not 0 <= index < self.sizes[family] or not _settable(self.raw, _PATHS[family],
                                                                    index):
                return False
            if family == "mass":
                ok = self.effort_mode and self.own_masses and _inside(value, *DENSITY)
            elif family == "efforts.joints":
                ok = self.effort_mode and _inside(value, -EFFORT, EFFORT)
            elif family == "efforts.wheels":
                ok = _inside(value, -EFFORT, EFFORT)
            elif family == "initial.velocity":
                ok = _inside(value, -SPEED, SPEED)
            else:   # dt
                ok = _inside(value, *DT)
            if not ok:
                return False
        return True

    def scene_with(self, fast: dict) -> Scene:
        """The lane's scene: the template's with the fast numbers written where `parse_scene`
        puts them (and its document as `parse_scene` fills it in). Raises what the parse would
        raise at its end (`check_work`, with the lane's step)."""
        scene = self.scene
        robot, integrator = scene.robot, scene.integrator
        arrays = {"efforts.wheels": None, "efforts.joints": None, "initial.velocity": None}
        masses = None
        document = _copied(scene.document)
        for (family, index), value in fast.items():
            if family == "mass":
                masses = np.array(robot.mass_per_length) if masses is None else masses
                masses[index] = float(value)
                _set(document, ["robot", "arm", "links", index, "mass_per_length"], value)
            elif family == "dt":
                integrator = dataclasses.replace(integrator, dt=float(value))
                _set(document, ["integrator", "dt"], float(value))
            else:
                if arrays[family] is None:
                    arrays[family] = np.array(_field(scene, family), dtype=float)
                arrays[family][index] = float(value)
                _set(document, family.split(".") + [index], float(value))
        if masses is not None:
            masses.setflags(write=False)
            robot = dataclasses.replace(robot, mass_per_length=masses)
        lane = Scene(
            name=scene.name, robot=robot, initial_q=scene.initial_q,
            initial_u=_or(arrays["initial.velocity"], scene.initial_u),
            wheel_efforts=_or(arrays["efforts.wheels"], scene.wheel_efforts),
            joint_efforts=_or(arrays["efforts.joints"], scene.joint_efforts),
            effects=scene.effects, integrator=integrator, duration=scene.duration,
            document=document, controller=scene.controller, limits=scene.limits)
        if integrator is not scene.integrator:
            check_work(lane.duration, integrator, "duration", "integrator.dt")
        return lane

    def lane(self, scene: Scene, fast: dict) -> Simulation:
        """The lane's `Simulation`: the template's records copied, the lane's robot (its μ) and a
        compiled core of its own (`Dynamics.for_lane`), then `reset` (state, efforts, clock,
        energy reference and stepper of its own)."""
        sim = self.plan.copy()
        sim.scene, sim.settings, sim.model = scene, scene.integrator, scene.robot
        sim.dynamics.for_lane(scene.robot)
        sim.reset()
        return sim


# each family's key path (its index: the int)
_PATHS = {"mass": ["robot", "arm", "links", int, "mass_per_length"],
          "efforts.wheels": ["efforts", "wheels", int],
          "efforts.joints": ["efforts", "joints", int],
          "initial.velocity": ["initial", "velocity", int], "dt": ["integrator", "dt"]}


def _settable(raw: dict, path: list, index: int) -> bool:
    """Whether `set_path` sets this leaf in the raw document without an error: each list on the
    way exists and holds the index, a missing mapping is one it would create."""
    node = raw
    for depth, part in enumerate(path):
        last = depth == len(path) - 1
        if part is int:
            if not isinstance(node, list) or index >= len(node):
                return False
            node = node[index]
            continue
        if not isinstance(node, dict):
            return False
        if part not in node:
            return last or int not in path[depth + 1:]
        node = node[part]
    return True


def _field(scene: Scene, family: str) -> np.ndarray:
    return {"efforts.wheels": scene.wheel_efforts, "efforts.joints": scene.joint_efforts,
            "initial.velocity": scene.initial_u}[family]


def _or(array, default):
    return default if array is None else array


def _copied(document: dict) -> dict:
    """A copy of a scene document whose mappings and lists are new objects down to the leaves
    a lane may set (`_set`); the rest is shared with the template's (never written)."""
    return dict(document)


def _set(document: dict, parts: list, value) -> None:
    """Set a leaf, copying each mapping or list on the way that is still the template's."""
    node = document
    for part in parts[:-1]:
        child = node[part]
        copied = dict(child) if isinstance(child, dict) else list(child)
        node[part] = copied
        node = copied
    node[parts[-1]] = value


# --- copies of a simulation's records ------------------------------------------------------

ZERO_BLOCK_BYTES = 2 << 20   # under numpy's huge-page threshold (4 MiB): see `_Plan`

# objects whose attributes are copied (their arrays and records anew, the rest shared)
OWNERS = (Simulation, System, Dynamics)


class _Plan:
    """How to copy a `Simulation`'s records: walked once over the template into a list of
    steps, the copy then makes every array afresh (same layout, same writeability), rebuilds
    every record (namedtuple), plain tuple of records and object of `OWNERS` around them, keeps
    which arrays are one and the same (the system's ``resting`` is the stops'), and shares
    everything else (the scene's objects). Each copy's `reset` then makes its own compiled
    stepper on its own arrays."""

    def __init__(self, template, copies: int = 1):
        self.nodes: list = []      # per slot: a shared value, or None for one made per copy
        self.steps: list = []      # (kind, slot, …) in the order they are made
        self.arrays: list = []
        self._index: dict = {}     # id of a walked node → its slot
        self._keep: list = []      # the walked nodes, alive while the plan is
        self.root = self._walk(template)
        # The all-zero arrays of `copies` copies (the stop logs, some 300 kB per lane) as slices
        # of zeroed blocks: pages the operating system maps when a lane first writes them (a
        # few impact rows), not ones cleared and mapped for every copy. Each block stays under
        # ZERO_BLOCK_BYTES: numpy asks for huge pages on arrays of 4 MiB or more, and a lane's
        # first impact row then cleared 2 MiB (all of the logs of 1024 lanes: 0.7 s of a 2 s
        # batch of 1024 paper runs spent by the kernel clearing pages).
        self.copies, self._zero_blocks = copies, {}

    def _walk(self, node) -> int:
        known = self._index.get(id(node))
        if known is not None:
            return known
        slot = len(self.nodes)
        self._index[id(node)] = slot
        self._keep.append(node)
        if not _holds_arrays(node):
            self.nodes.append(node)
            return slot
        self.nodes.append(None)
        if isinstance(node, np.ndarray):
            plain = node.flags.c_contiguous and node.flags.writeable
            if plain and node.size > 64 and not node.any():   # (the impact logs: pages the
                self.steps.append((_ZEROS, slot, node))         # lane may never touch)
            else:
                self.steps.append((_ARRAY if plain else _LAYOUT, slot, node))
            self.arrays.append(node)
        elif isinstance(node, tuple) and hasattr(node, "_fields"):
            self.steps.append((_RECORD, slot, type(node), [self._walk(item) for item in node]))
        elif isinstance(node, OWNERS):   # made first: an attribute may refer back to it
            self.steps.append((_OBJECT, slot, type(node)))
            attributes = dict(vars(node))
            owned = [(name, self._walk(value)) for name, value in attributes.items()
                     if _holds_arrays(value)]
            self.steps.append((_FILL, slot, attributes, owned))
        elif type(node) is tuple:
            self.steps.append((_TUPLE, slot, [self._walk(item) for item in node]))
        else:   # a list (the impact lists, which `reset` makes anew)
            self.steps.append((_LIST, slot, list(node)))
        return slot

    def shares_memory(self) -> bool:
        """Whether an array of the records is a view of another one (a copy would part them)."""
        ids = {id(array) for array in self.arrays}
        for array in self.arrays:
            base = array.base
            while base is not None:
                if id(base) in ids:
                    return True
                base = getattr(base, "base", None)
        return False

    def _zeros(self, array: np.ndarray) -> np.ndarray:
        per_block = min(self.copies, ZERO_BLOCK_BYTES // max(array.nbytes, 1))
        if per_block < 2:
            return np.zeros(array.shape, array.dtype)
        block, used = self._zero_blocks.get(id(array), (None, per_block))
        if used == per_block:
            block, used = np.zeros((per_block,) + array.shape, array.dtype), 0
        self._zero_blocks[id(array)] = (block, used + 1)
        return block[used]

    def copy(self):
        nodes = self.nodes.copy()
        for step in self.steps:
            kind, slot = step[0], step[1]
            if kind is _ARRAY:
                nodes[slot] = step[2].copy()
            elif kind is _RECORD:
                nodes[slot] = step[2](*[nodes[i] for i in step[3]])
            elif kind is _OBJECT:
                nodes[slot] = step[2].__new__(step[2])
            elif kind is _FILL:
                state = dict(step[2])
                for name, i in step[3]:
                    state[name] = nodes[i]
                nodes[slot].__dict__.update(state)
            elif kind is _TUPLE:
                nodes[slot] = tuple([nodes[i] for i in step[2]])
            elif kind is _ZEROS:
                nodes[slot] = self._zeros(step[2])
            elif kind is _LAYOUT:
                nodes[slot] = _copy(step[2])
            else:
                nodes[slot] = list(step[2])
        return nodes[self.root]


_ARRAY, _ZEROS, _RECORD, _OBJECT, _FILL, _TUPLE, _LAYOUT, _LIST = (
    "array", "zeros", "record", "object", "fill", "tuple", "layout", "list")


def _holds_arrays(value) -> bool:
    """Whether `value` is copied for each lane (an array, a record, an object of `OWNERS`, a
    list, or a tuple of some)."""
    return isinstance(value, (np.ndarray, list, *OWNERS)) or (
        isinstance(value, tuple) and (hasattr(value, "_fields")
                                      or any(_holds_arrays(item) for item in value)))


def _copy(array: np.ndarray) -> np.ndarray:
    """A copy of the same layout and writeability."""
    copied = array.copy(order="K")
    if not array.flags.writeable:
        copied.setflags(write=False)
    return copied
