"""`sweep`: many runs of one scene on a Dask cluster, one row each in DIR/runs.parquet.

    sweep SPEC.yaml --out DIR [--local | --scheduler ADDRESS] [--workers N]
                              [--connect-timeout S]

Without --scheduler a LocalCluster of N worker processes (default: the cores) runs on this
machine; with it the sweep goes to a running scheduler (`dask scheduler` and `dask worker` on
other machines, or dask-jobqueue's SLURMCluster). Each Dask task is a chunk of runs stepped as
one batch (`mobile_manip_sim.batch`). With --local there is no Dask at all: this process runs the
chunks one after another, each a batch on N threads (default: the cores). Running the same
command again on DIR runs only what is missing; Ctrl-C keeps every finished run.
"""
from __future__ import annotations

import contextlib
import json
import logging
import math
import os
import signal
import sys
import time
import warnings
from pathlib import Path

from ..runtime import cli
from ..runtime.progress import Progress
from ..scene.errors import UserError
from .spec import Spec, load_spec

DASK_CHUNK = 500    # runs per Dask task at most (a batch each; fewer when runs are few)
LOCAL_CHUNK = 1000  # runs per batch without Dask: a part of runs.parquet each


def _main(argv) -> int:
    parser = cli.ArgumentParser(prog="sweep", description=__doc__.split("\n\n")[0])
    parser.add_argument("spec", type=cli.path, help="the sweep file (YAML)")
    parser.add_argument("--out", type=cli.path, required=True, metavar="DIR",
                        help="directory for runs.parquet and REPORT.md")
    parser.add_argument("--scheduler", metavar="ADDRESS",
                        help="a running Dask scheduler (tcp://host:port)")
    parser.add_argument("--local", action="store_true",
                        help="no Dask: run the batches in this process, on N threads")
    parser.add_argument("--workers", type=int,
                        help="LocalCluster worker processes, or threads with --local "
                             "(default: the cores)")
    parser.add_argument("--connect-timeout", type=float, default=10.0, metavar="S",
                        help="seconds to wait for the scheduler (default 10)")
    args = parser.parse_args(argv)
    if args.workers is not None and args.workers < 1:
        raise UserError("--workers", f"must be at least 1, got {args.workers}")
    if args.local and args.scheduler:
        raise UserError("--local", "runs without Dask: it takes no --scheduler")
    spec = load_spec(args.spec)
    with Progress("sweep", None, f"expanding the spec and reading {args.out}"):
        from . import results, runner  # after the spec is checked: bad input is answered at once
        runs = spec.runs()
        varied = {path: [run[path] for run in runs] for path in spec.varied}
        columns = runner.state_columns(len(spec.document["robot"].get("arm", {}).get("links",
                                                                                     [])))
        store = results.Store(Path(args.out), results.schema(varied, columns), fingerprint(spec))
        todo = [i for i in range(len(runs)) if i not in store.done]
    if spec.duplicates():
        print(spec.duplicates(), flush=True)
    start = time.perf_counter()
    if todo:
        status = _sweep(args, spec, runs, todo, store)
        if status:
            return status
    else:   # finished already: no cluster to start (a LocalCluster costs seconds to minutes)
        print(f"sweep: {len(runs)} runs, all already in {args.out}: nothing to run",
              flush=True)
    store.flush(final=True)
    table = store.table()
    failed = table.column("status").to_pylist().count("failed")
    from . import report
    with results.writing(Path(args.out), name_file=True):
        report.write(Path(args.out), table, spec)
    print(f"sweep: {table.num_rows} runs, {table.num_rows - failed} ok, {failed} failed, "
          f"{time.perf_counter() - start:.1f} s wall → {args.out}/runs.parquet, "
          f"{args.out}/REPORT.md")
    return 0


def _sweep(args, spec: Spec, runs: list, todo: list, store) -> int:
    """Run ``todo`` on the cluster; 130 on Ctrl-C, 143 on SIGTERM (every finished run kept, one
    line), else 0. A stop is answered in every phase, the cluster's start and its workers'
    getting ready included, and after a chunk's rows are written when it was dropped inside a
    finalizer. A write that fails is a `UserError` saying what is kept."""
    client = cluster = progress = None
    stopped = False
    try:
        with cli.stop_signals():
            if args.local:
                workers = args.workers or os.cpu_count() or 1
                chunk = spec.chunk or LOCAL_CHUNK
            else:
                client, cluster = _connect(args)
                workers = max(1, len(client.scheduler_info()["workers"]) or (args.workers or 1))
                chunk = spec.chunk or max(1, min(DASK_CHUNK,
                                                 math.ceil(len(todo) / (8 * workers))))
            chunks = [todo[i:i + chunk] for i in range(0, len(todo), chunk)]
            print(f"sweep: {len(runs)} runs, {len(store.done)} already in {args.out}, "
                  f"{len(todo)} to do in {len(chunks)} chunks of ≤ {chunk} on "
                  f"{_where(args, workers)}", flush=True)
            progress = Progress("sweep", len(runs), "runs", done=len(store.done))
            if args.local:
                _run_local(workers, spec, runs, chunks, store, progress, args.out)
            else:
                _run(client, spec, runs, chunks, store, progress, args.out)
    except (KeyboardInterrupt, cli.Terminated) as stop:
        stopped = True
        _quiet_dask()
        if progress is not None:
            progress.close()
        kept = _kept(store, len(runs), args.out)
        print(f"sweep: {'interrupted' if isinstance(stop, KeyboardInterrupt) else 'terminated'}; "
              f"{kept}", file=sys.stderr, flush=True)
        return 130 if isinstance(stop, KeyboardInterrupt) else cli.EXIT_TERMINATED
    except UserError as error:   # a write that failed (the spec was checked before)
        stopped = True
        _quiet_dask()
        if progress is not None:
            progress.close()
        raise UserError(error.key, f"{error.problem}; {_kept(store, len(runs), args.out)}") \
            from None
    except BaseException:
        stopped = True
        _quiet_dask()
        raise
    finally:
        if client is not None:
            _close(client, cluster, fast=stopped)
    progress.close()
    return 0


def _kept(store, total: int, out: str) -> str:
    """What a sweep that stops early keeps, as its one line ends: runs.parquet rebuilt if it can
    be (else the parts stay, and the next run of the command reads them)."""
    try:
        store.flush()
        where = f"{out}/runs.parquet"
    except UserError:
        where = f"{out}/parts"
    return (f"{len(store.done)} of {total} runs are in {where} "
            "(run the same command to finish)")


def _quiet_dask() -> None:
    """When the sweep stops early: the cluster's own complaints while it is torn down (workers
    that stopped mid-task, broadcasts to them, heartbeats to a closed scheduler) are the stop
    itself, not news."""
    families = ("distributed", "tornado", "asyncio")
    names = [name for name in logging.root.manager.loggerDict   # children set their own level
             if name.split(".")[0] in families]
    for name in (*families, *names):
        logging.getLogger(name).setLevel(logging.CRITICAL)


def fingerprint(spec: Spec) -> str:
    """What decides the runs and their numbers (not the time limit, chunking or cluster)."""
    return json.dumps({"document": spec.document, "duration": spec.duration,
                       "sample_rate": spec.sample_rate,
                       "grid": spec.grid, "count": spec.count, "seed": spec.seed,
                       "vary": spec.vary}, sort_keys=True, default=str)


def _connect(args):
    from distributed import Client, LocalCluster
    if args.scheduler:
        with Progress("sweep", None, f"connecting to {args.scheduler}"):
            try:
                client = Client(args.scheduler, timeout=f"{args.connect_timeout}s")
            except (OSError, TimeoutError, ValueError) as error:
                raise UserError("--scheduler", f"cannot reach {args.scheduler} "
                                f"({_first_line(error)})") from None
        cluster = None
    else:
        workers = args.workers or os.cpu_count() or 1
        with Progress("sweep", None, f"starting a LocalCluster of {workers} worker"
                                     f"{'s' if workers > 1 else ''}"):
            # the workers' own log lines stay off the terminal: every run's outcome comes back
            # through its future (a failed run is a row; a lost worker's chunk runs again or is
            # a failed row), and what a worker logs besides is transient (a heartbeat missed on
            # a loaded machine printed a 30-line traceback mid-sweep, and the sweep went on)
            with warnings.catch_warnings():   # "Port 8787 is already in use": another
                warnings.simplefilter("ignore")   # cluster's; ours serves no dashboard anyway
                cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                       dashboard_address=None, silence_logs=logging.CRITICAL)
            client = Client(cluster)
    from .runner import IgnoreInterrupts
    try:
        if cluster is not None:
            with Progress("sweep", None, "the workers get ready"):
                _register(client, IgnoreInterrupts())
    except BaseException:
        _close(client, cluster, fast=True)
        raise
    return client, cluster


PLUGIN_TRIES = 5


def _register(client, plugin) -> None:
    """Register a worker plugin on every worker, present and future. The scheduler keeps it
    before it asks the workers, so a worker that joins later gets it; a worker lost while it is
    asked (killed, its machine gone) fails the request, which is asked again of the workers
    left. After PLUGIN_TRIES failures the sweep goes on without it (a worker without it dies of
    a Ctrl-C with a traceback, and its runs go to the others). A lost scheduler is one line
    (`LostScheduler`)."""
    for _ in range(PLUGIN_TRIES):
        try:
            client.register_plugin(plugin)
            return
        except (OSError, TimeoutError, RuntimeError) as error:   # CommClosedError is an OSError
            if client.status not in ("running", "connecting"):
                raise LostScheduler(_first_line(error)) from None


class LostScheduler(UserError):
    """The scheduler went away (killed, its machine gone) while the sweep used it."""

    def __init__(self, reason: str):
        super().__init__("--scheduler", f"lost the scheduler ({reason})")


def _first_line(error: BaseException) -> str:
    return (str(error).splitlines() or [""])[0] or type(error).__name__


def _where(args, workers: int) -> str:
    if args.local:
        return f"this process (no Dask), {workers} thread{'s' if workers > 1 else ''}"
    if args.scheduler:
        return f"{args.scheduler} ({workers} workers now)"
    return f"a LocalCluster of {workers} worker{'s' if workers > 1 else ''}"


def _csv_dir(spec: Spec, out: str) -> str | None:
    return str(Path(out).resolve() / "runs") if spec.sample_rate else None


def _run_local(threads: int, spec: Spec, runs: list, chunks: list, store, progress,
               out: str) -> None:
    """Without Dask: each chunk one batch on `threads` threads in this process, its rows
    written as soon as it ends (a part each, as a Dask task's)."""
    from . import runner
    failures = 0
    for ids in chunks:
        rows = runner.run_block(spec.document, [(i, runs[i]) for i in ids], spec.duration,
                                spec.sample_rate, spec.time_limit, _csv_dir(spec, out), threads)
        rows = [{**row, "worker": "local"} for row in rows]
        failures = _keep(store, rows, runs, progress, failures)


def _run(client, spec: Spec, runs: list, chunks: list, store, progress, out: str) -> None:
    from distributed import as_completed
    from distributed.client import FutureCancelledError
    from distributed.scheduler import KilledWorker

    from . import runner
    csv_dir = _csv_dir(spec, out)
    logging.getLogger("distributed.client").addFilter(_Refetched)
    futures = {}
    failures = 0
    for ids in chunks:
        task = [(i, runs[i]) for i in ids]
        future = client.submit(runner.run_chunk, spec.document, task, spec.duration,
                               spec.sample_rate,
                               spec.time_limit, csv_dir, pure=False, key=f"runs-{ids[0]}-{ids[-1]}")
        futures[future] = ids
    for future in as_completed(futures):
        ids = futures[future]
        try:
            rows = _fetch(client, future)
        except KilledWorker as error:
            rows = [{"run": i, "status": "failed",
                     "error": f"KilledWorker: every worker that ran it died ({error})"}
                    for i in ids]
        except Exception as error:
            # The client cancels every future when it loses the scheduler: not a failed run
            if isinstance(error, FutureCancelledError) or client.status != "running":
                raise LostScheduler("its connection closed") from None
            rows = [{"run": i, "status": "failed",
                     "error": f"{type(error).__name__}: {error}".splitlines()[0]}
                    for i in ids]
        failures = _keep(store, rows, runs, progress, failures)


FETCH_LOOK = 0.2   # s between looks at a chunk's rows still being fetched


def _fetch(client, future) -> list:
    """The rows of a finished chunk, fetched from its worker through the scheduler. A worker
    lost meanwhile (killed, its machine gone) can leave that fetch retrying the dead address for
    the scheduler's connect timeout (distributed.comm.timeouts.connect, 30 s) while the chunk
    already runs again elsewhere: the fetch is given up once the scheduler no longer lists the
    workers it had the rows on, and made again when the rows are back. distributed's own line
    for a fetch that failed, the chunk rescheduled ("Couldn't gather …"), is no news either:
    a worker lost mid-sweep costs no run and says nothing (`_Refetched`)."""
    import asyncio

    from distributed import wait
    while True:
        holders = set(client.who_has(future).get(future.key, ()))
        fetch = asyncio.run_coroutine_threadsafe(client.gather(future, asynchronous=True),
                                                 client.loop.asyncio_loop)
        while True:
            try:
                return fetch.result(timeout=FETCH_LOOK)
            except TimeoutError:
                pass
            if future.status != "finished" or \
                    not holders <= set(client.who_has(future).get(future.key, ())):
                fetch.cancel()
                break
        wait(future)   # computed again (or failed for good: the next fetch raises its error)


class _Refetched:
    """A logging filter for distributed's client: drops its warning that a finished chunk's
    rows could not be fetched and the chunk runs again (its worker was lost; `_fetch`)."""

    @staticmethod
    def filter(record) -> bool:
        return not str(record.msg).startswith("Couldn't gather")


def _keep(store, rows: list, runs: list, progress, failures: int) -> int:
    """A finished chunk's rows into the table and the progress line (returns the failures so
    far); then a Ctrl-C that was dropped meanwhile (raised inside the parquet writer's
    finalizer) ends the sweep."""
    store.add(rows, runs)
    failures += sum(row["status"] == "failed" for row in rows)
    progress.update(progress.done + len(rows), f", {failures} failed")
    cli.raise_dropped_stop()
    return failures


def _close(client, cluster, fast: bool = False) -> None:
    """Close the client (a scheduler of the user's then forgets the sweep's queued tasks) and
    our LocalCluster, silently. `fast` (a stop, a failure): our workers are killed first — a
    worker inside a compiled call would finish its chunk before a polite close."""
    _quiet_dask()
    try:
        if fast and cluster is not None:
            _kill_workers(cluster)
        with contextlib.suppress(Exception):
            client.close(timeout=2 if fast else 10)
    finally:
        if cluster is not None:
            with contextlib.suppress(Exception):
                cluster.close(timeout=2 if fast else 10)


def _kill_workers(cluster) -> None:
    """SIGKILL the worker processes of our LocalCluster. Each nanny is told first that its
    worker is closing (else it would start a new one, and closing the cluster would wait for
    that one's start), and closes itself when it sees its worker gone."""
    from distributed.core import Status
    for nanny in list(getattr(cluster, "workers", {}).values()):
        process = getattr(getattr(nanny, "process", None), "process", None)
        pid = getattr(process, "pid", None)
        if pid:
            nanny.status = Status.closing_gracefully
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGKILL)


def main(argv=None) -> int:
    """The `sweep` executable. Stopped (Ctrl-C, SIGTERM), it ends the process at once once its
    line is said and the cluster closed (`cli.exit_at_once`): the stop is the user's, and the
    interpreter's teardown was most of its time."""
    status = cli.run(_main, argv, sigterm=True)
    if status in (130, cli.EXIT_TERMINATED):
        cli.exit_at_once(status)
    return status


if __name__ == "__main__":
    raise SystemExit(main())
