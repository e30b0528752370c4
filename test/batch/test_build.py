"""Lanes built from a template (`batch/build.py`): a lane that differs from the others only in
numbers is a copy of its group's records with its numbers written in, and that copy equals, array
for array and bit for bit, the `Simulation` (and scene) that the plain build — `scene_with`, then
`Simulation` — makes of the same overrides; a number the parser would refuse fails its lane with
the parser's own line."""
from __future__ import annotations

import dataclasses
import math
import struct
import types

import numpy as np
import pytest

from mobile_manip_sim.batch import Batch, build
from mobile_manip_sim.batch.build import build_lanes
from mobile_manip_sim.batch.runs import error_line
from mobile_manip_sim.bench.scenes import paper_document, scene_file
from mobile_manip_sim.engine.simulation import Simulation
from mobile_manip_sim.runtime import headless
from mobile_manip_sim.runtime.timeline import sample_times
from mobile_manip_sim.scene.errors import UserError
from mobile_manip_sim.scene.limits import DENSITY, EFFORT, SPEED
from mobile_manip_sim.scene.overrides import scene_with
from robots import random_robot_document


def leaves(obj, path: str, seen: dict, out: list) -> list:
    """Every number, array and string reachable from `obj` (a simulation, a scene) with its
    path, arrays compared by their bits, and which paths are one and the same array."""
    if isinstance(obj, np.ndarray):
        if id(obj) in seen:
            out.append((path, "same array as", seen[id(obj)]))
            return out
        seen[id(obj)] = path
        out.append((path, obj.dtype.str, obj.shape, obj.flags.writeable, obj.flags.c_contiguous,
                    obj.tobytes()))
    elif isinstance(obj, float):
        out.append((path, type(obj).__name__, struct.pack("<d", obj)))
    elif obj is None or isinstance(obj, (bool, int, str, np.generic)):
        out.append((path, repr(obj)))
    elif isinstance(obj, (types.ModuleType, types.FunctionType, types.MethodType)):
        out.append((path, "callable"))
    elif isinstance(obj, dict):
        out.append((path, "dict", repr(obj)))
    elif isinstance(obj, (tuple, list)):
        names = getattr(obj, "_fields", None) or range(len(obj))
        out.append((path, type(obj).__name__, len(obj)))
        for name, item in zip(names, obj, strict=True):
            leaves(item, f"{path}.{name}", seen, out)
    elif not hasattr(obj, "__dict__"):   # a compiled core's object (its own arrays or the sim's)
        out.append((path, type(obj).__name__))
    elif dataclasses.is_dataclass(obj):
        out.append((path, type(obj).__name__))
        for f in dataclasses.fields(obj):
            leaves(getattr(obj, f.name), f"{path}.{f.name}", seen, out)
    else:
        out.append((path, type(obj).__name__))
        for name, value in sorted(vars(obj).items()):
            leaves(value, f"{path}.{name}", seen, out)
    return out


def assert_same(a, b, path: str):
    left, right = leaves(a, path, {}, []), leaves(b, path, {}, [])
    assert len(left) == len(right)
    for x, y in zip(left, right, strict=True):
        assert x == y, f"{x[0]} differs"


def scenes_to_test(rng) -> list[dict]:
    """Documents of differently built scenes: the paper's, a random robot with stops (as written
    and with its defaults filled in), one with
    effort limits (efforts saturated), locked joints (initial rates zeroed), a payload, and an
    arm controller (the arm's numbers then go the plain way)."""
    documents = [paper_document()]
    random = random_robot_document(rng, 3)
    random["effects"]["stroke_limits"] = {"restitution": 0.5, "rest_speed": 0.05}
    documents.append(random)   # as written: no efforts, no initial rates (set whole only)
    documents.append(scene_with(random, {}).document)   # every default filled in
    for name in ("effect_effort_limits.yaml", "effect_locked_joints.yaml", "effect_payload.yaml",
                 "arm_trajectory.yaml"):
        documents.append(scene_file(name).document)
    return documents


def random_overrides(rng, document: dict, count: int, method: str) -> list[dict]:
    """Lanes of the fast families, each a random subset with values inside their bounds, every
    lane with the same other overrides (the method)."""
    scene = scene_with(document, {})
    n, nu = scene.robot.n_links, scene.robot.n_u
    lanes = []
    for _ in range(count):
        lane = {"integrator.method": method}
        if rng.random() < 0.7 and n:
            lane[f"robot.arm.links[{rng.integers(n)}].mass_per_length"] = float(
                rng.uniform(DENSITY[0], min(DENSITY[1], 10.0)))
        if rng.random() < 0.7:
            lane[f"efforts.wheels[{rng.integers(2)}]"] = float(rng.uniform(-1.0, 1.0))
        if rng.random() < 0.7 and n:
            lane[f"efforts.joints[{rng.integers(2 * n)}]"] = float(rng.uniform(-20.0, 20.0))
        if rng.random() < 0.7:
            lane[f"initial.velocity[{rng.integers(nu)}]"] = float(rng.uniform(-2.0, 2.0))
        if rng.random() < 0.5:
            lane["integrator.dt"] = float(rng.choice([5e-4, 1e-3, 2e-3]))
        lanes.append(lane)
    return lanes


@pytest.fixture
def copied(monkeypatch) -> dict:
    """id of each lane built as a copy of a template (`Template.lane`) → id of its template."""
    made = {}
    lane = build.Template.lane

    def counted(self, *args):
        sim = lane(self, *args)
        made[id(sim)] = id(self)
        return sim
    monkeypatch.setattr(build.Template, "lane", counted)
    return made


def copies_of_one_template(copied: dict, *sims) -> bool:
    return len({copied.get(id(sim)) for sim in sims} - {None}) == 1 and all(
        id(sim) in copied for sim in sims)


@pytest.mark.filterwarnings("ignore:semi_implicit_euler with end stops")
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_lane_copied_from_its_template_equals_its_plain_build_array_for_array(seed, copied):
    rng = np.random.default_rng(seed)
    for document in scenes_to_test(rng):
        method = ("rk4", "euler", "semi_implicit_euler")[seed % 3]
        lanes = random_overrides(rng, document, 8, method)
        scenes, sims = build_lanes(document, lanes)
        for i, overrides in enumerate(lanes):
            try:
                plain = scene_with(document, overrides)
            except UserError as error:
                assert sims[i] is None and error_line(scenes[i]) == error_line(error)
                continue
            assert_same(scenes[i], plain, "scene")
            assert scenes[i].document == plain.document
            assert_same(sims[i], Simulation(plain), "sim")
    assert len(copied) >= 20   # most lanes were copies (checked: the copy, not the plain path)


def test_a_copied_lane_runs_as_its_own_simulate_run_with_impacts_in_some_lanes(copied):
    document = paper_document()
    rng = np.random.default_rng(7)
    lanes = [{"integrator.method": "rk4", "integrator.dt": float(rng.choice([1e-3, 2e-3])),
              "robot.arm.links[0].mass_per_length": float(rng.uniform(0.8, 1.2)),
              "efforts.joints[1]": float(rng.uniform(-5.0, 5.0)),
              "initial.velocity[3]": float(rng.uniform(-1.0, 1.0))} for _ in range(8)]
    duration, rate = 0.5, 50.0
    batch = Batch(document, lanes, threads=2)
    assert copies_of_one_template(copied, *(batch.lane(i) for i in range(8)))
    rows = batch.sample(np.fromiter(sample_times(duration, rate), float))
    impacts = []
    for i, overrides in enumerate(lanes):
        expected = []
        sim = headless.run(scene_with(document, overrides), duration, rate, None,
                           lambda sim, rows=expected: rows.append([*sim.s, sim.total_energy()]))
        assert np.array_equal(rows[i].view(np.int64), np.array(expected).view(np.int64))
        assert batch.lane(i).impacts == sim.impacts
        assert batch.lane(i).rhs_evaluations == sim.rhs_evaluations
        impacts.append(len(sim.impacts))
    assert 0 in impacts and max(impacts) > 0, impacts


@pytest.mark.parametrize("key, value", [
    ("robot.arm.links[0].mass_per_length", DENSITY[1] * 10.0),
    ("robot.arm.links[0].mass_per_length", -1.0),
    ("robot.arm.links[0].mass_per_length", math.nan),
    ("robot.arm.links[0].mass_per_length", "heavy"),
    ("robot.arm.links[5].mass_per_length", 1.0),
    ("efforts.joints[0]", math.inf),
    ("efforts.joints[0]", EFFORT * 2.0),
    ("efforts.wheels[1]", None),
    ("initial.velocity[2]", SPEED * 2.0),
    ("initial.velocity[9]", 0.0),
    ("integrator.dt", -1.0),
    ("integrator.dt", 1e-9),   # more steps than a run may take (check_work, at the end)
])
def test_a_number_the_parser_refuses_fails_its_lane_with_the_parsers_line(key, value, copied):
    document = paper_document()
    good = {"integrator.method": "rk4", "robot.arm.links[0].mass_per_length": 0.9,
            "efforts.joints[0]": 0.5, "initial.velocity[2]": 0.1, "integrator.dt": 1e-3}
    lanes = [good, {**good, key: value}, good]
    scenes, sims = build_lanes(document, lanes)
    with pytest.raises(Exception) as plain:
        Simulation(scene_with(document, lanes[1]))
    assert sims[1] is None and error_line(scenes[1]) == error_line(plain.value)
    assert "\n" not in error_line(scenes[1])
    assert copies_of_one_template(copied, sims[0], sims[2])


def immutable(value) -> bool:
    """A value two lanes may share: a number, string, None, a function or module, a frozen
    dataclass, or a tuple of such."""
    if value is None or isinstance(value, (bool, int, float, str, types.ModuleType,
                                           types.FunctionType, types.MethodType)):
        return True
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return value.__dataclass_params__.frozen
    if isinstance(value, tuple):
        return all(immutable(item) for item in value)
    return False


def test_two_copies_share_no_mutable_object(copied):
    """What a copy shares with another is immutable (so a lane's command or state never reaches
    another): every array, record and object of the simulation, its system and dynamics, is its
    own."""
    document = paper_document()
    lanes = [{"integrator.method": "rk4", "robot.arm.links[0].mass_per_length": m}
             for m in (0.9, 1.1)]
    _, (a, b) = build_lanes(document, lanes)
    assert copies_of_one_template(copied, a, b)
    pairs = [(a, b), (a.system, b.system), (a.dynamics, b.dynamics)]
    for one, other in pairs:
        for name, value in vars(one).items():
            if value is getattr(other, name):
                assert immutable(value), f"{type(one).__name__}.{name} is shared"
    for one, other in [(a.system.data, b.system.data), (a.stops, b.stops),
                       (a._scratch, b._scratch)]:
        for name, x, y in zip(one._fields, one, other, strict=True):
            assert x is not y or immutable(x), f"{type(one).__name__}.{name} is shared"


def test_no_copied_array_lies_in_a_block_that_numpy_backs_with_huge_pages(copied):
    """The copies' all-zero arrays (impact logs) are slices of shared zeroed blocks, so that the
    pages a lane never writes are never mapped. numpy asks for huge pages on any array of 4 MiB
    or more: in a block that large a lane's first impact row cleared 2 MiB, and 1024 lanes spent
    0.7 s of a 2 s batch in the kernel clearing pages. Every base array stays below that."""
    document = paper_document()
    _, sims = build_lanes(document, [{"integrator.method": "rk4",
                                      "robot.arm.links[0].mass_per_length": 0.8 + 1e-4 * i}
                                     for i in range(1024)])
    assert copies_of_one_template(copied, sims[0], sims[1])
    blocks, largest = set(), 0
    for sim in sims:
        for record in (sim.stops, sim._scratch, sim.system.data):
            for array in record:
                if isinstance(array, np.ndarray) and array.base is not None:
                    base = array.base
                    while getattr(base, "base", None) is not None:
                        base = base.base
                    if isinstance(base, np.ndarray):
                        blocks.add(id(base))
                        largest = max(largest, base.nbytes)
    assert blocks, "the zero blocks are gone: the test no longer sees what it guards"
    assert largest < 4 << 20
