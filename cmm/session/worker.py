"""Heavy session work in a worker process, away from the station's machine loop and web servers.

The station process runs the machine loop, the viser server and the pendant
server in one interpreter, under one interpreter lock. Summarising,
reporting, exporting or re-evaluating a 200,000-hit session (a 61 MB journal)
is seconds of pure-Python work; in the station process it would compete with
the machine loop for that lock on every bus reply (and once it did: the jog
release took up to 2.9 s while observers opened a big session). Those jobs
end in small results (a summary, the paths of written files, a few counts),
so they run in a separate process: :class:`SessionWorker` (a
``ProcessPoolExecutor`` started with ``forkserver``, never ``fork``: the
station has threads that may hold locks), at a lower CPU priority than the
station (``WORKER_NICE``) so the machine loop wins a busy CPU.

Opening a session *for replay* is not sent here: the replay's objects (every
event and hit) must live in the station process, and rebuilding them from any
transfer format costs as much as parsing the journal there (msgspec, a
200,000-line journal in about a second, in small pieces the loop can
interleave with).

A worker that dies (out of memory, killed) fails the job with
:class:`WorkerError` in an operator's words; the next job starts a new worker.

    worker = shared_worker()
    paths = worker.call(report, "sessions", "bracket-7", "sessions", part_mesh)
"""

from __future__ import annotations

import atexit
import multiprocessing
import os
import threading
import time
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import replace
from pathlib import Path
from typing import Any, Callable

WORKER_NICE = 5  # niceness of the worker: it yields the CPU to the station (machine loop, web)
StoreSpec = Any  # a directory path or a postgresql:// URL (what open_store takes)


class WorkerError(RuntimeError):
    """The worker process failed as a whole (not the job's own error)."""


def _start_worker(station_pid: int) -> None:
    try:  # absolute: a station at raised priority must not pass it on to its bulk work
        if os.getpriority(os.PRIO_PROCESS, 0) < WORKER_NICE:
            os.setpriority(os.PRIO_PROCESS, 0, WORKER_NICE)
    except (AttributeError, OSError):
        pass

    def watch() -> None:  # a killed station cannot tell its workers to stop: they see it is gone
        while True:
            time.sleep(1.0)
            try:
                os.kill(station_pid, 0)
            except ProcessLookupError:
                os._exit(0)
            except OSError:
                pass
    threading.Thread(target=watch, name="station-watch", daemon=True).start()


class SessionWorker:
    """A pool of ``processes`` worker processes (started on first use); ``call`` / ``submit`` run a task."""

    def __init__(self, processes: int = 1) -> None:
        self.processes = processes
        self._pool: ProcessPoolExecutor | None = None
        self._lock = threading.Lock()

    def _executor(self) -> ProcessPoolExecutor:
        with self._lock:
            if self._pool is None:
                methods = multiprocessing.get_all_start_methods()
                ctx = multiprocessing.get_context("forkserver" if "forkserver" in methods else "spawn")
                self._pool = ProcessPoolExecutor(self.processes, mp_context=ctx, initializer=_start_worker,
                                                 initargs=(os.getpid(),))
            return self._pool

    def _broken(self, pool: ProcessPoolExecutor) -> None:
        with self._lock:
            if self._pool is pool:
                self._pool = None
        pool.shutdown(wait=False, cancel_futures=True)

    def submit(self, fn: Callable[..., Any], *args: Any) -> Future:
        """Run ``fn(*args)`` (a module-level function; arguments and result are pickled) in the worker.
        If the worker dies, the future fails with BrokenProcessPool and the next job starts a new one."""
        pool = self._executor()
        try:
            future = pool.submit(fn, *args)
        except BrokenProcessPool:  # it died since the last job: one new worker, one more try
            self._broken(pool)
            pool = self._executor()
            future = pool.submit(fn, *args)

        def check(f: Future, pool: ProcessPoolExecutor = pool) -> None:
            if not f.cancelled() and isinstance(f.exception(), BrokenProcessPool):
                self._broken(pool)
        future.add_done_callback(check)
        return future

    def call(self, fn: Callable[..., Any], *args: Any, timeout: float | None = None) -> Any:
        """``fn(*args)`` in the worker; its exception is raised here. A dead worker raises WorkerError."""
        try:
            return self.submit(fn, *args).result(timeout)
        except BrokenProcessPool:
            raise WorkerError("the session worker process stopped unexpectedly (out of memory?): "
                              "nothing was written; try again") from None

    def close(self, grace: float = 5.0) -> None:
        """Stop the worker processes (a new job starts them again): queued jobs are cancelled, a running one
        gets ``grace`` seconds to finish before its process is terminated (a report file may then be missing;
        the journals are never written by the worker, except a re-evaluation's new session)."""
        with self._lock:
            pool, self._pool = self._pool, None
        if pool is None:
            return
        processes = list((getattr(pool, "_processes", None) or {}).values())
        pool.shutdown(wait=False, cancel_futures=True)
        end = time.monotonic() + grace
        for p in processes:
            p.join(max(0.0, end - time.monotonic()))
            if p.is_alive():
                p.terminate()
                p.join(1.0)


_shared: SessionWorker | None = None
_shared_lock = threading.Lock()


def shared_worker() -> SessionWorker:
    """The process-wide worker every UI tab uses (one process: the machine has two cores)."""
    global _shared
    with _shared_lock:
        if _shared is None:
            _shared = SessionWorker(1)
        return _shared


def _close_shared() -> None:
    if _shared is not None:
        _shared.close(grace=2.0)


# at interpreter exit, before concurrent.futures waits for the running job (its exit hooks run in reverse order)
getattr(threading, "_register_atexit", atexit.register)(_close_shared)


# --- tasks (run in the worker process) --------------------------------------------------------------------


def _load(store: StoreSpec, name: str) -> Any:
    from ..journal.store import load_session, open_store

    return load_session(open_store(store), name)


def _mesh(session: Any, part: Any) -> Any:
    from .export import resolve_part_mesh

    return resolve_part_mesh(session, part)


def summary(store: StoreSpec, name: str) -> dict[str, Any]:
    """``Session.summary()`` of a recorded session."""
    return _load(store, name).summary()


def trend_series(store: StoreSpec, name: str) -> list[str]:
    """The series a recorded session's runs were added to as parts (its ``trend`` events), in order."""
    out: list[str] = []
    for e in _load(store, name).events:
        if e.get("kind") == "trend" and e.get("series") and e["series"] not in out:
            out.append(str(e["series"]))
    return out


def report(store: StoreSpec, name: str, out_dir: str | Path, part: Any = None, colour_scale: Any = None,
           trends: Any = None) -> list[Path]:
    """Write ``<name>-report.html`` and ``<name>-features.csv`` into ``out_dir``; their paths. ``colour_scale``:
    the colour map's bands (the 3D view's :class:`~cmm.metrology.colour_scale.ColourScale`); ``trends``: the
    control charts to include (:class:`~cmm.session.trends_chart.TrendChart` list, as ``cmm report --trend``)."""
    from .report import write_features_csv, write_report

    session = _load(store, name)
    mesh = _mesh(session, part)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    return [write_report(session, out / f"{name}-report.html", mesh=mesh, colour_scale=colour_scale, trends=trends),
            write_features_csv(session, out / f"{name}-features.csv", mesh=mesh)]


def qif(store: StoreSpec, name: str, out_dir: str | Path, part: Any = None) -> list[Path]:
    """Write ``<name>.qif`` (QIF 3 Results, :mod:`cmm.session.qif`) into ``out_dir``, naming the report
    ``<name>-report.html`` beside it when one was written; its path in a list."""
    from .qif import write_qif

    session = _load(store, name)
    mesh = _mesh(session, part)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    report = out / f"{name}-report.html"
    return [write_qif(session, out / f"{name}.qif", mesh=mesh, report=str(report) if report.exists() else None)]


def export(store: StoreSpec, name: str, out_dir: str | Path, part: Any = None, csv: bool = True,
           json: bool = True) -> list[Path]:
    """Write ``<name>.csv`` (hits) and/or ``<name>.json`` (whole session) into ``out_dir``; their paths."""
    from .export import write_csv, write_json

    session = _load(store, name)
    mesh = _mesh(session, part)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files = []
    if csv:
        files.append(write_csv(session, out / f"{name}.csv", mesh))
    if json:
        files.append(write_json(session, out / f"{name}.json", mesh))
    return files


def reevaluate(store: StoreSpec, name: str, new: str, tip_radius: float = 0.0,
               method: str | None = None, tolerances: Any = None) -> dict[str, Any]:
    """Re-evaluate ``name`` from its raw counts into the new session ``new``; its hit and feature counts, the
    features that could not be refitted (``errors``: their messages) and the DMIS tolerances left out (``left_out``:
    one sentence, or ""). ``tolerances``: see :func:`cmm.session.reevaluate.reevaluate` (the caller's, a module-level
    function: it is pickled by name)."""
    from .qif_dmis import left_out
    from .reevaluate import reevaluate as derive
    from ..journal.store import open_store, write_session

    session = _load(store, name)
    settings = session.probe_settings()
    if tip_radius:
        settings = replace(settings, tip_radius=float(tip_radius))
    derived = derive(session, settings, method=method, name=new, tolerances=tolerances)
    write_session(open_store(store), new, derived.events)
    return {"hits": len(derived.hits), "features": len(derived.features),
            "errors": [m for _, m in derived.state.errors[len(session.state.errors):]], "left_out": left_out(derived)}


def crash() -> None:
    """End the worker process abruptly (tests: a worker that dies fails its job, the next job works)."""
    os._exit(3)


class Summaries:
    """Session summaries computed by the worker, shared by every tab: each journal version is read once.

    ``get(store, name, key)`` returns the summary, or None while the worker computes it (``wait`` blocks
    until it is there). ``key`` names the version (events and modification time): a new version is read again.
    """

    def __init__(self, worker: SessionWorker | None = None) -> None:
        self.worker = worker
        self._done: dict[tuple[str, str], tuple[Any, Future]] = {}  # the finished future: a summary or its error
        self._pending: dict[tuple[str, str, Any], Future] = {}
        self._lock = threading.RLock()  # a future already done runs its callback (which locks) at once

    def get(self, store: StoreSpec, name: str, key: Any, *, wait: bool = False,
            timeout: float | None = 120.0) -> dict | None:
        where = (str(store), name)
        with self._lock:
            done = self._done.get(where)
            future = done[1] if done is not None and done[0] == key else self._pending.get((*where, key))
            if future is None:
                worker = self.worker or shared_worker()
                future = worker.submit(summary, store, name)
                self._pending[(*where, key)] = future
                future.add_done_callback(lambda f, w=where, k=key: self._finish(w, k, f))
        if not wait and not future.done():
            return None
        try:
            return future.result(timeout)
        except BrokenProcessPool:
            raise WorkerError("the session worker process stopped unexpectedly while reading "
                              f"{name!r}; the list shows it again when a new worker has read it") from None

    def _finish(self, where: tuple[str, str], key: Any, future: Future) -> None:
        with self._lock:
            self._pending.pop((*where, key), None)
            if not future.cancelled() and not isinstance(future.exception(), BrokenProcessPool):
                self._done[where] = (key, future)  # a damaged journal's error is kept too: not re-read every list

    def forget(self, store: StoreSpec, name: str) -> None:
        with self._lock:
            self._done.pop((str(store), name), None)


_summaries = Summaries()


def shared_summaries() -> Summaries:
    return _summaries
