"""The sweep file (YAML) → a validated `Spec` and its list of runs. Every mistake is one
`UserError` naming the key (``grid.integrator.dt``, ``random.vary.initial.velocity[2]``).

    scene: config/paper_two_link.yaml     # default: the embedded paper scene
    duration: 1.5                          # s (default: the scene's)
    sample_rate: 100                       # Hz: also write DIR/runs/run-N.csv (off by default)
    time_limit: 60                         # wall s per run; beyond it the run is failed
    chunk: 50                              # runs per Dask task (default: chosen from the count)
    grid: {integrator.method: [rk4, semi_implicit_euler], integrator.dt: [0.001, 0.002]}
    random: {count: 100, seed: 7, vary: {"initial.velocity[2]": {normal: [0.0, 0.1]}}}

Runs are numbered grid point by grid point (the grid's first key varies slowest), each grid point
with draws 0 … count − 1; the draws are the same at every grid point.

The limits are `simulate`'s: duration and sample rate within its bounds, and no run of more than
its fixed steps or samples (`scene.check_work`, for the base scene here and for every run's own
integrator when it runs); at most MAX_RUNS runs (grid points × draws); a key path varied once
(in the grid or in random.vary, not both; no value twice in a grid list); a uniform draw whose
range is a finite number.

A grid point that differs from an earlier one only in settings its method ignores — the step
``integrator.dt`` of an adaptive method (dop853 × dt), the tolerances ``integrator.rtol`` and
``integrator.atol`` of a fixed-step one — would run the same run again: it is dropped, and
`Spec.duplicates` says so in one line (the sweep prints it).
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..scene import schema
from ..scene.errors import UserError
from ..scene.limits import DURATION, SAMPLE_RATE
from ..scene.loading import check_work, load_scene
from ..scene.methods import METHODS
from ..scene.overrides import check_known, parse_path, path_label

DISTRIBUTIONS = {"uniform": "[low, high]", "normal": "[mean, standard deviation]",
                 "loguniform": "[low, high], both positive", "choice": "[value, …]"}
KEYS = ("scene", "duration", "sample_rate", "time_limit", "chunk", "grid", "random")
MAX_RUNS = 1_000_000   # runs of one sweep: a row each in runs.parquet, held in memory
DEFAULT_SAMPLE_RATE = 100.0   # Hz: simulate's default grid (the runs' numbers depend on it)


@dataclass(frozen=True)
class Spec:
    scene_path: str | None
    document: dict                       # the base scene's document, defaults applied
    duration: float
    sample_rate: float | None
    time_limit: float | None
    chunk: int | None
    grid: dict = field(default_factory=dict)          # path → list of values
    count: int = 0
    seed: int = 0
    vary: dict = field(default_factory=dict)          # path → (distribution, parameters)

    @property
    def varied(self) -> list[str]:
        return list(self.grid) + [path for path in self.vary if path not in self.grid]

    def points(self) -> tuple[list[dict], int]:
        """The grid points, each once (`_unused`), and how many were dropped as repeats."""
        points, seen = [], set()
        for values in itertools.product(*self.grid.values()):
            point = dict(zip(self.grid, values, strict=True))
            ignored = _unused(point, self.document)
            key = tuple((path, repr(value)) for path, value in point.items()
                        if path not in ignored)
            if key not in seen:
                seen.add(key)
                points.append(point)
        return points, math.prod(len(values) for values in self.grid.values()) - len(points)

    def duplicates(self) -> str | None:
        """One line on the grid points dropped as repeats of earlier ones, or None."""
        dropped = self.points()[1]
        if not dropped:
            return None
        return (f"sweep: {dropped} grid point{'s' if dropped > 1 else ''} dropped: "
                f"integrator.dt does not apply to an adaptive method, nor integrator.rtol or "
                f"atol to a fixed-step one, so {'they' if dropped > 1 else 'it'} would repeat "
                f"earlier runs (each row keeps the first such point's values)")

    def runs(self) -> list[dict]:
        """Every run's overrides {path: value}, indexed by run id."""
        points = self.points()[0]
        draws = self.draws()
        if not draws:
            return points
        return [{**point, **draw} for point in points for draw in draws]

    def draws(self) -> list[dict]:
        if not self.count:
            return []
        rng = np.random.default_rng(self.seed)
        columns = {path: _draw(rng, name, params, self.count)
                   for path, (name, params) in self.vary.items()}
        return [{path: column[i] for path, column in columns.items()} for i in range(self.count)]


def _unused(point: dict, document: dict) -> set:
    """The integrator settings of ``point`` that its method ignores."""
    method = point.get("integrator.method", document.get("integrator", {}).get("method"))
    entry = METHODS.get(method) if isinstance(method, str) else None   # else refused later
    if entry is None:
        return set()
    return {"integrator.rtol", "integrator.atol"} if entry.fixed_step else {"integrator.dt"}


def _draw(rng, name, params, count) -> list:
    if name == "uniform":
        return rng.uniform(params[0], params[1], count).tolist()
    if name == "normal":
        return rng.normal(params[0], params[1], count).tolist()
    if name == "loguniform":
        return np.exp(rng.uniform(math.log(params[0]), math.log(params[1]), count)).tolist()
    return [params[i] for i in rng.integers(0, len(params), count).tolist()]


def load_spec(path: str) -> Spec:
    what = schema.label(str(path), 160)
    text = schema.read_text_file(path, what, kind="sweep file")
    return parse_spec(schema.load_yaml(text, what=what), base_dir=Path(path).parent)


def parse_spec(doc, base_dir: Path = Path(".")) -> Spec:
    if not isinstance(doc, dict):
        raise UserError("sweep", f"expected a mapping, got {schema.short(doc)}")
    for key in doc:
        if key not in KEYS:
            raise UserError(str(key), f"unknown key (allowed: {', '.join(KEYS)})")
    scene_path = doc.get("scene")
    if scene_path is not None:
        if not isinstance(scene_path, str):
            raise UserError("scene", f"expected a file name, got {schema.short(scene_path)}")
        candidate = Path(scene_path)
        if (not candidate.is_absolute() and not candidate.exists()
                and (base_dir / candidate).exists()):
            candidate = base_dir / candidate
        scene_path = str(candidate.resolve())
    try:
        scene = load_scene(scene_path)
    except UserError as error:
        raise UserError("scene", str(error)) from None
    document = scene.document
    duration = schema.number(doc.get("duration", scene.duration), "duration", positive=True,
                             hi=DURATION[1])
    sample_rate = doc.get("sample_rate")
    if sample_rate is not None:
        sample_rate = schema.number(sample_rate, "sample_rate", lo=SAMPLE_RATE[0],
                                    hi=SAMPLE_RATE[1])
    check_work(duration, scene.integrator, "duration", "integrator.dt",
               sample_rate or DEFAULT_SAMPLE_RATE, "sample_rate")
    grid = _grid(doc.get("grid"), document)
    count, seed, vary = _random(doc.get("random"), document)
    if not grid and not count:
        raise UserError("grid", "nothing to sweep: give a grid, a random section, or both")
    _check_varied_once(grid, vary)
    runs = math.prod(len(values) for values in grid.values()) * max(1, count)
    if runs > MAX_RUNS:
        raise UserError("grid" if grid else "random.count",
                        f"{runs:.6g} runs (grid points × draws) is more than {MAX_RUNS}")
    return Spec(scene_path=scene_path, document=document, duration=duration,
                sample_rate=sample_rate,
                time_limit=(None if doc.get("time_limit") is None
                            else _positive(doc["time_limit"], "time_limit")),
                chunk=None if doc.get("chunk") is None else _count(doc["chunk"], "chunk"),
                grid=grid, count=count, seed=seed, vary=vary)


def _positive(value, key) -> float:
    if (isinstance(value, bool) or not isinstance(value, (int, float))
            or not math.isfinite(value) or value <= 0):
        raise UserError(key, f"expected a positive number, got {schema.short(value)}")
    return float(value)


def _count(value, key) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= MAX_RUNS:
        raise UserError(key,
                        f"expected a whole number from 1 to {MAX_RUNS}, got {schema.short(value)}")
    return value


def _check_varied_once(grid: dict, vary: dict) -> None:
    """Each key path varied by one entry (``initial.velocity[2]`` and ``[02]`` are one path),
    each grid value given once: a path varied twice runs the same run again, or hides one."""
    seen = {}
    for key, path in ([(f"grid.{path}", path) for path in grid]
                      + [(f"random.vary.{path}", path) for path in vary]):
        canonical = path_label(parse_path(path))
        if canonical in seen:
            raise UserError(key, f"varies {canonical} again (already in {seen[canonical]})")
        seen[canonical] = key
    for path, values in grid.items():
        for i, value in enumerate(values):
            if any(type(value) is type(other) and value == other for other in values[:i]):
                raise UserError(f"grid.{path}[{i}]", f"{schema.short(value)} is listed twice")


def _grid(grid, document) -> dict:
    if grid is None:
        return {}
    if not isinstance(grid, dict) or not grid:
        raise UserError("grid", "expected a mapping of key paths to lists of values, "
                                f"got {schema.short(grid)}")
    out = {}
    for path, values in grid.items():
        key = f"grid.{path}"
        if not isinstance(values, list) or not values:
            raise UserError(key, f"expected a non-empty list of values, got {schema.short(values)}")
        _known(document, str(path), values[0], key)
        out[str(path)] = values
    return out


def _random(section, document) -> tuple[int, int, dict]:
    if section is None:
        return 0, 0, {}
    if not isinstance(section, dict):
        raise UserError("random", "expected a mapping with count, seed and vary, "
                                  f"got {schema.short(section)}")
    for key in section:
        if key not in ("count", "seed", "vary"):
            raise UserError(f"random.{key}", "unknown key (allowed: count, seed, vary)")
    if "count" not in section:
        raise UserError("random.count", "missing")
    count = _count(section["count"], "random.count")
    seed = section.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise UserError("random.seed", f"expected a whole number ≥ 0, got {schema.short(seed)}")
    vary = section.get("vary")
    if not isinstance(vary, dict) or not vary:
        raise UserError("random.vary", "expected a mapping of key paths to distributions, "
                                       f"got {schema.short(vary)}")
    out = {}
    for path, distribution in vary.items():
        key = f"random.vary.{path}"
        name, params = _distribution(distribution, key)
        _known(document, str(path), _draw(np.random.default_rng(0), name, params, 1)[0], key)
        out[str(path)] = (name, params)
    return count, seed, out


def _distribution(value, key) -> tuple[str, list]:
    choices = ", ".join(f"{name}: {shape}" for name, shape in DISTRIBUTIONS.items())
    if not isinstance(value, dict) or len(value) != 1:
        raise UserError(key, f"expected one distribution ({choices}), got {schema.short(value)}")
    (name, params), = value.items()
    if name not in DISTRIBUTIONS:
        raise UserError(key,
                        f"unknown distribution {schema.short(name)} (choose one of: {choices})")
    if not isinstance(params, list) or not params:
        raise UserError(f"{key}.{name}",
                        f"expected {DISTRIBUTIONS[name]}, got {schema.short(params)}")
    if name == "choice":
        return name, params
    numbers = len(params) == 2 and all(isinstance(p, (int, float)) and not isinstance(p, bool)
                                       and math.isfinite(p) for p in params)
    if not numbers:
        raise UserError(f"{key}.{name}",
                        f"expected {DISTRIBUTIONS[name]}, got {schema.short(params)}")
    low, high = params
    if name == "uniform" and not math.isfinite(high - low):
        raise UserError(f"{key}.{name}", f"the range {schema.short(params)} is wider than the "
                                         f"largest float")
    if name == "normal" and high < 0 or name != "normal" and low > high:
        raise UserError(f"{key}.{name}",
                        f"expected {DISTRIBUTIONS[name]}, got {schema.short(params)}")
    if name == "loguniform" and low <= 0:
        raise UserError(f"{key}.{name}",
                        f"expected {DISTRIBUTIONS[name]}, got {schema.short(params)}")
    return name, [float(low), float(high)]


def _known(document, path, value, key) -> None:
    try:
        check_known(document, path, value)
    except UserError as error:
        raise UserError(key, error.problem) from None
