"""The sweep file (YAML) → a validated `Spec` and its list of runs. Every mistake is one
`UserError` naming the key (``grid.integrator.dt``, ``random.vary.initial.velocity[2]``).

    scene: config/paper_two_link.yaml     # default: the embedded paper scene
    duration: 1.5                          # s (default: the scene's)
    sample_rate: 100                       # Hz: also write DIR/runs/run-N.csv (off by default)
    time_limit: 60                         # wall s per run; beyond it the run is failed
    chunk: 50                              # runs per Dask task (default: chosen from the count)
    grid: {integrator.method: [rk4, dop853], integrator.dt: [0.001, 0.002]}
    random: {count: 100, seed: 7, vary: {"initial.velocity[2]": {normal: [0.0, 0.1]}}}

A key with brackets is quoted inside a flow mapping ``{…}``; in block style it needs no quotes
(``config/sweeps/paper_mass_and_method.yaml``). Runs are numbered grid point by grid point (the
grid's first key varies slowest), each grid point with draws 0 … count − 1; the draws are the
same at every grid point.
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import schema
from ..errors import UserError
from ..scene import load_scene
from .overrides import check_known

DISTRIBUTIONS = {"uniform": "[low, high]", "normal": "[mean, standard deviation]",
                 "loguniform": "[low, high], both positive", "choice": "[value, …]"}
KEYS = ("scene", "duration", "sample_rate", "time_limit", "chunk", "grid", "random")


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

    def runs(self) -> list[dict]:
        """Every run's overrides {path: value}, indexed by run id."""
        points = [dict(zip(self.grid, values)) for values in itertools.product(*self.grid.values())]
        draws = self.draws()
        if not draws:
            return points
        return [{**point, **draw} for point in points for draw in draws]

    def draws(self) -> list[dict]:
        if not self.count:
            return []
        rng = np.random.default_rng(self.seed)
        columns = {path: _draw(rng, name, params, self.count) for path, (name, params) in self.vary.items()}
        return [{path: column[i] for path, column in columns.items()} for i in range(self.count)]


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
        if not candidate.is_absolute() and not candidate.exists() and (base_dir / candidate).exists():
            candidate = base_dir / candidate
        scene_path = str(candidate.resolve())
    try:
        scene = load_scene(scene_path)
    except UserError as error:
        raise UserError("scene", str(error)) from None
    document = scene.document
    grid = _grid(doc.get("grid"), document)
    count, seed, vary = _random(doc.get("random"), document)
    if not grid and not count:
        raise UserError("grid", "nothing to sweep: give a grid, a random section, or both")
    return Spec(scene_path=scene_path, document=document,
                duration=_positive(doc.get("duration", scene.duration), "duration"),
                sample_rate=None if doc.get("sample_rate") is None else _positive(doc["sample_rate"], "sample_rate"),
                time_limit=None if doc.get("time_limit") is None else _positive(doc["time_limit"], "time_limit"),
                chunk=None if doc.get("chunk") is None else _count(doc["chunk"], "chunk"),
                grid=grid, count=count, seed=seed, vary=vary)


def _positive(value, key) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
        raise UserError(key, f"expected a positive number, got {schema.short(value)}")
    return float(value)


def _count(value, key) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise UserError(key, f"expected a whole number ≥ 1, got {schema.short(value)}")
    return value


def _grid(grid, document) -> dict:
    if grid is None:
        return {}
    if not isinstance(grid, dict) or not grid:
        raise UserError("grid", f"expected a mapping of key paths to lists of values, got {schema.short(grid)}")
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
        raise UserError("random", f"expected a mapping with count, seed and vary, got {schema.short(section)}")
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
        raise UserError("random.vary", f"expected a mapping of key paths to distributions, got {schema.short(vary)}")
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
        raise UserError(key, f"unknown distribution {schema.short(name)} (choose one of: {choices})")
    if not isinstance(params, list) or not params:
        raise UserError(f"{key}.{name}", f"expected {DISTRIBUTIONS[name]}, got {schema.short(params)}")
    if name == "choice":
        return name, params
    numbers = len(params) == 2 and all(isinstance(p, (int, float)) and not isinstance(p, bool)
                                       and math.isfinite(p) for p in params)
    if not numbers:
        raise UserError(f"{key}.{name}", f"expected {DISTRIBUTIONS[name]}, got {schema.short(params)}")
    low, high = params
    if name == "normal" and high < 0 or name != "normal" and low > high:
        raise UserError(f"{key}.{name}", f"expected {DISTRIBUTIONS[name]}, got {schema.short(params)}")
    if name == "loguniform" and low <= 0:
        raise UserError(f"{key}.{name}", f"expected {DISTRIBUTIONS[name]}, got {schema.short(params)}")
    return name, [float(low), float(high)]


def _known(document, path, value, key) -> None:
    try:
        check_known(document, path, value)
    except UserError as error:
        raise UserError(key, error.problem) from None
