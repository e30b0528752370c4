"""DIR/runs.parquet: one row per run, kept on disk as runs complete and read back to resume.

Each finished chunk is written at once as its own small file, DIR/parts/part-<first run>.parquet
(written to a temporary name, then renamed: a part is whole or absent). runs.parquet is rebuilt
from all rows at most every few seconds and at the end, so it is never more than that behind; a
sweep killed outright leaves its parts, and the next run of the same command picks them up.
A write that fails (a full disk, a read-only or removed directory) is a `UserError` naming the
file: every part written before it stays, and so do the rows it holds.
"""
from __future__ import annotations

import json
import os
import re
import time
from contextlib import contextmanager
from pathlib import Path

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from ..scene.errors import UserError
from ..scene.schema import label

COUNTS = ("impacts", "steps", "rhs_evaluations")
FIGURES = ("energy_error", "stroke_violation", "constraint_residual", "cpu_s",
           "arm_tracking_rms", "arm_tracking_max")   # the last two: null without an arm controller


def schema(varied: dict, state_columns: list[str]) -> pa.Schema:
    """``varied`` {path: values seen}: a column per path, typed by its values."""
    fields = [pa.field("run", pa.int64())]
    fields += [pa.field(path, _type(values)) for path, values in varied.items()]
    fields += [pa.field("status", pa.string()), pa.field("error", pa.string())]
    fields += [pa.field(name, pa.float64()) for name in state_columns]
    fields += [pa.field("energy_error", pa.float64())]
    fields += [pa.field(name, pa.int64()) for name in COUNTS]
    fields += [pa.field(name, pa.float64()) for name in FIGURES if name != "energy_error"]
    fields += [pa.field("worker", pa.string())]
    return pa.schema(fields)


def _type(values) -> pa.DataType:
    if all(isinstance(v, bool) for v in values):
        return pa.bool_()
    if all(isinstance(v, int) and not isinstance(v, bool) for v in values):
        return pa.int64()
    if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values):
        return pa.float64()
    return pa.string()


def cell(value, data_type: pa.DataType):
    """A varied value as its column stores it (lists and mixed values as JSON text)."""
    if data_type == pa.string() and not isinstance(value, str):
        return json.dumps(value)
    if data_type == pa.float64() and value is not None:
        return float(value)
    return value


class Store:
    """The rows of one sweep directory: those on disk when it opened, plus each chunk added."""

    def __init__(self, directory: Path, table_schema: pa.Schema, fingerprint: str,
                 rewrite_every: float = 2.0):
        self.dir = Path(directory)
        self.schema = table_schema
        self.parts = self.dir / "parts"
        self.path = self.dir / "runs.parquet"
        self.rewrite_every = rewrite_every
        self._claim(fingerprint)
        with writing(self.parts):
            self.parts.mkdir(parents=True, exist_ok=True)
        self.tables: list[pa.Table] = []
        self.done: set[int] = set()
        for table in self._on_disk():
            self._keep(table)
        self._written = time.monotonic()

    def _claim(self, fingerprint: str) -> None:
        """DIR belongs to one sweep: refuse to mix another spec's runs into it."""
        with writing(self.dir):
            self.dir.mkdir(parents=True, exist_ok=True)
        stamp = self.dir / "sweep.json"
        if stamp.exists():
            if stamp.read_text() != fingerprint:
                raise UserError(str(self.dir), "holds the runs of a different sweep (scene, "
                                "duration, grid or random section differ); use another --out")
        else:
            with writing(stamp):
                stamp.write_text(fingerprint)

    def _on_disk(self) -> list[pa.Table]:
        tables = []
        whole = [self.path] if self.path.exists() else []
        for path in whole + sorted(self.parts.glob("part-*.parquet")):
            try:
                tables.append(pq.read_table(path, schema=self.schema))
            except (pa.ArrowInvalid, OSError):  # a torn file from a killed writer: redone
                pass
        return tables

    def _fresh(self, table: pa.Table) -> pa.Table:
        """The rows of runs not kept yet."""
        ids = table.column("run").to_pylist()
        fresh = [i for i, run in enumerate(ids) if run not in self.done]
        if len(fresh) < len(ids):
            table = table.take(pa.array(fresh, type=pa.int64()))
        return table

    def _keep(self, table: pa.Table) -> pa.Table:
        table = self._fresh(table)
        self.done.update(table.column("run").to_pylist())
        if table.num_rows:
            self.tables.append(table)
        return table

    def add(self, rows: list[dict], overrides: dict) -> int:
        """Write a finished chunk (rows from `runner.run_chunk`); returns the rows kept."""
        columns = {field.name: [] for field in self.schema}
        for row in rows:
            values = overrides[row["run"]]
            for field in self.schema:
                if field.name in values:
                    columns[field.name].append(cell(values[field.name], field.type))
                else:
                    columns[field.name].append(row.get(field.name))
        table = self._fresh(pa.table(columns, schema=self.schema))
        if table.num_rows:   # on disk before it counts as done: a failed write loses no claim
            first = table.column("run")[0].as_py()
            _write(table, self.parts / f"part-{first:08d}.parquet")
            self._keep(table)
            if time.monotonic() - self._written > self.rewrite_every:
                self.flush()
        return table.num_rows

    def table(self) -> pa.Table:
        if not self.tables:
            return self.schema.empty_table()
        table = pa.concat_tables(self.tables)
        return table.take(pc.sort_indices(table, [("run", "ascending")]))

    def flush(self, final: bool = False) -> None:
        """Rebuild runs.parquet from every row; ``final`` also drops the parts it now holds."""
        table = self.table()
        self.tables = [table] if table.num_rows else []
        _write(table, self.path)
        self._written = time.monotonic()
        if final:
            for path in self.parts.glob("part-*.parquet"):
                path.unlink(missing_ok=True)


@contextmanager
def writing(path: Path, *, name_file: bool = False):
    """An OSError within the block (ENOSPC, EROFS, EACCES, ENOENT) as a `UserError` naming
    `path` (with `name_file`, the file the error names, if any): one line, status 2."""
    try:
        yield
    except OSError as error:
        where = (name_file and error.filename) or path
        raise UserError(label(str(where), 160), f"cannot write ({_reason(error)})") from None


def _reason(error: OSError) -> str:
    """The system's words for an OSError, pyarrow's too (its "Error writing bytes to file.
    Detail: [errno 28] No space left on device" is cut to the last part)."""
    number = re.search(r"\[errno (\d+)\]", str(error), re.IGNORECASE)
    if number:
        return os.strerror(int(number[1]))
    return error.strerror or (str(error).splitlines() or [type(error).__name__])[0]


def _write(table: pa.Table, path: Path) -> None:
    temporary = path.with_name(path.name + ".tmp")
    try:
        with writing(path):
            pq.write_table(table, temporary)
            os.replace(temporary, path)
    except UserError:
        try:   # a torn file would only take space (`_on_disk` passes it over anyway)
            temporary.unlink(missing_ok=True)
        except OSError:
            pass
        raise


def read(directory) -> pa.Table:
    return pq.read_table(Path(directory) / "runs.parquet")
