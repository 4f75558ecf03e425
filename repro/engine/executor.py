"""Execution of a job graph (issue 4, item 3; back ends: issue 15, item 1).

:func:`execute` runs the graph that reaches ``targets``:

1. **Decide** (consumers first): a needed job whose object is in the store and verifies is a
   *hit*; a corrupt one is quarantined and becomes a run; a job nothing needs (everything
   downstream of it is stored) is not touched.  Forced kinds/labels and uncacheable jobs run.
2. **Run** the remaining jobs in dependency order through :meth:`Store.compute` (file lock per
   key, re-check, atomic publish), so two processes running the same graph compute each job
   once: the second waits on the lock and reads the first one's object (reported as a hit).

``jobs=1`` runs inline.  ``jobs=N>1`` uses a :class:`~concurrent.futures.ProcessPoolExecutor`
with the ``spawn`` start method, not threads: torch keeps process-global state (the default
generator that ``torch.nn`` initialisers draw from, the intra-op thread count), so concurrent
jobs in threads would perturb each other's random streams and thread settings; ``spawn`` (not
``fork``) because forking a process that has started torch/OpenMP threads can deadlock.  Each
job computes with its own ``threads`` when it declares them (a table's jobs do: the scale
profile's count, part of their keys, so ``--jobs`` changes only how many run side by side, never
a result); other jobs get ``threads_per_job`` (default ``cpu_count // N``; inline, the process's).

Back ends: the scheduling (what is ready, failure isolation, interrupt bookkeeping) is
:func:`_run_graph`'s; *where* a job computes is a :class:`Backend`'s: :class:`_PoolBackend`
(the process pool above) or, with ``backend=``, another one such as
:class:`repro.engine.ray_executor.RayBackend` (``repro run --executor ray``).  Every back end
runs a job through :func:`repro.engine.job_run.run_in_worker`, so keys, store protocol and
results do not depend on it; running one job (:func:`~repro.engine.job_run.run_job`) and the
job statuses are :mod:`repro.engine.job_run`'s.

Failures: by default a failing job stops the graph (the jobs not yet started are CANCELLED and
its exception is re-raised).  With ``keep_going=True`` (what a table run uses, so that one
broken method does not stop the other rows) only the failing job's dependents are CANCELLED,
every independent job still runs, and :func:`execute` returns; the report's
:meth:`ExecutionReport.failure_of` says which failure blocked a target.  A user error
(:class:`~repro.errors.ReproError`) and an interrupt stop the graph either way.

Interrupts: Ctrl-C (SIGINT) or ``kill`` (SIGTERM, turned into ``KeyboardInterrupt`` while the
graph runs) stops the graph; running jobs are interrupted, their temp output is removed, their
scratch folder (checkpoints) is kept, finished jobs stay published, the run record is marked
INTERRUPTED and ``KeyboardInterrupt`` is re-raised.  The same command again finds the finished
jobs as hits and hands the interrupted job its scratch folder to resume from.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import queue
import signal
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

from repro.engine import plan as planmod
from repro.errors import ReproError
from repro.engine.job import Job, topo_order
from repro.engine.job_run import (CANCELLED, COMPUTED, FAILED, HIT, INTERRUPTED, SKIPPED,
                                  beside_task, run_job, worker_init, worker_task)
from repro.store.object_files import StoredObject
from repro.store.objects import Store

log = logging.getLogger("repro.engine")


@dataclass
class JobResult:
    job: Job
    key: str
    status: str
    seconds: float = 0.0
    object: StoredObject | None = None
    error: str | None = None

    def as_record(self) -> dict[str, Any]:
        """The job's line in ``run.json`` (``jobs`` list)."""
        return {"kind": self.job.kind, "label": self.job.label, "impl": self.job.impl,
                "key": self.key, "seed": self.job.seed, "status": self.status,
                "seconds": round(float(self.seconds), 3), "error": self.error}


@dataclass
class ExecutionReport:
    """Per-job results, inputs before consumers."""

    results: list[JobResult] = field(default_factory=list)
    interrupted: bool = False
    #: per task of ``execute(beside=...)``, in order: None when it returned, else its error
    beside: list[str | None] = field(default_factory=list)

    def result(self, job_or_key: Job | str) -> JobResult:
        k = job_or_key.key() if isinstance(job_or_key, Job) else job_or_key
        for r in self.results:
            if r.key == k:
                return r
        raise KeyError(f"no job with key {k[:12]} in this report")

    def object(self, job: Job) -> StoredObject:
        r = self.result(job)
        if r.object is None:
            raise KeyError(f"job {job.name} has no loaded object (status {r.status})")
        return r.object

    def failure_of(self, targets: Iterable[Job]) -> JobResult | None:
        """The first FAILED job among ``targets`` and everything they depend on (None if the
        sub-graph holds no failure)."""
        keys = {j.key() for j in topo_order(list(targets))}
        for r in self.results:
            if r.key in keys and r.status == FAILED:
                return r
        return None

    @property
    def counts(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for r in self.results:
            out[r.status] = out.get(r.status, 0) + 1
        return out

    @property
    def all_hits(self) -> bool:
        """Nothing was computed: every job was a hit (or not needed)."""
        return all(r.status in (HIT, SKIPPED) for r in self.results)


class ProgressHook:
    """Receives progress events (all no-ops here; see ``repro.engine.progress``)."""

    def graph_started(self, entries: list[tuple[Job, str, str]]) -> None: ...
    def job_started(self, job: Job, key: str) -> None: ...
    def job_progress(self, job: Job, key: str, done: float, total: float | None,
                     message: str | None) -> None: ...
    def job_finished(self, result: JobResult) -> None: ...
    def graph_finished(self, report: ExecutionReport) -> None: ...


def dispatch_progress(msg, hook: ProgressHook, by_key: dict[str, Job]) -> None:
    """Hand one worker message ("start" or "progress", see
    :func:`repro.engine.job_run.run_in_worker`) to the hook.  A hook error is logged, never
    raised: it must not stop the thread draining the messages."""
    try:
        if msg[0] == "start":
            hook.job_started(by_key[msg[1]], msg[1])
        elif msg[0] == "progress":
            _, k, done, total, message = msg
            hook.job_progress(by_key[k], k, done, total, message)
    except Exception as e:
        log.warning("progress hook failed: %s", e)


@contextmanager
def _sigterm_as_interrupt(flag: dict):
    """While active (main thread only), SIGTERM raises ``KeyboardInterrupt``."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        flag["sigterm"] = True
        raise KeyboardInterrupt("SIGTERM")

    old = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


# ---------------------------------------------------------------------- the graph
def execute(targets: Iterable[Job], *, store: Store | None = None, jobs: int = 1,
            force: bool | str | Iterable[str] | None = None, hook: ProgressHook | None = None,
            recorder=None, threads_per_job: int | None = None,
            keep_going: bool = False, backend=None, beside: Sequence[Callable[[], Any]] = (),
            on_beside: Callable[[int, str | None], None] | None = None,
            failed: dict[str, JobResult] | None = None) -> ExecutionReport:
    """Run the graph reaching ``targets`` and return every job's (key, status, seconds, object).

    ``force``: ``True`` recomputes everything, a kind/label (or several) recomputes those.
    ``recorder``: a :class:`~repro.store.runs.RunRecorder`; it gets every job's record (keys
    read and written) and is marked INTERRUPTED or FAILED when the graph stops early.
    Re-raises ``KeyboardInterrupt`` and a failing job's exception (with a note naming the job),
    unless ``keep_going``: then a failing job only cancels its dependents (module docstring).
    ``backend``: run the jobs elsewhere than on this machine's process pool, e.g. a
    :class:`repro.engine.ray_executor.RayBackend`; called as ``backend(store, hook, by_key,
    threads_per_job)`` only when there is something to run, it returns a context manager that
    yields a :class:`Backend` (``jobs`` then does not apply).
    ``beside``: picklable callables that are not jobs (a run's evaluators) computed in the same
    process pool as the graph, queued before its jobs, so ``jobs`` workers stay busy while
    either has work (``jobs=1`` or a ``backend``: one after another here, before the graph);
    :attr:`ExecutionReport.beside` holds None or the error of each, ``on_beside(i, error)`` is
    called as each ends.  An interrupt stops them with the graph.
    ``failed``: jobs that failed earlier in the same command (key -> their FAILED result;
    :func:`repro.engine.runner.run_tables`' trainings beside the evaluators): recorded as
    failed again and their dependents cancelled, not run a second time (``keep_going``).
    """
    store = store or Store()
    hook = hook or ProgressHook()
    targets = list(targets)
    order = topo_order(targets)
    by_key = {j.key(): j for j in order}
    dec = planmod.decide(order, store, force, verify=True, targets=[t.key() for t in targets])
    results: dict[str, JobResult] = {}
    report = ExecutionReport()
    if recorder is not None and getattr(recorder, "status", None) == "QUEUED":
        recorder.start()

    def finish(r: JobResult) -> None:
        results[r.key] = r
        if recorder is not None:
            recorder.record_job(r.as_record())
        if r.status in (HIT, COMPUTED):
            try:
                planmod.record(store, r.job)
            except OSError as e:  # bookkeeping for --why must never fail a run
                log.warning("could not record plan for %s: %s", r.job.name, e)
        hook.job_finished(r)

    hook.graph_started([(j, j.key(), dec[j.key()].action) for j in order])
    for job in order:
        d = dec[job.key()]
        if d.action == planmod.HIT:
            finish(JobResult(job, job.key(), HIT, 0.0, d.obj))
        elif d.action == planmod.SKIP:
            finish(JobResult(job, job.key(), SKIPPED))
    to_run = [j for j in order if dec[j.key()].action == planmod.RUN]
    if failed and keep_going:
        to_run = _drop_known_failures(to_run, failed, finish)
    flag: dict[str, bool] = {}
    try:
        with _sigterm_as_interrupt(flag):
            _run_jobs(to_run, dec, results, finish, store=store, hook=hook, by_key=by_key,
                      jobs=jobs, threads_per_job=threads_per_job, keep_going=keep_going,
                      backend=backend, flag=flag,
                      beside=_Beside(list(beside), on_beside, report.beside))
    except KeyboardInterrupt:
        report.interrupted = True
        _stopped(report, to_run, order, results, finish)
        if recorder is not None:
            recorder.interrupt("interrupted (SIGTERM)" if flag.get("sigterm") else "interrupted")
        hook.graph_finished(report)
        raise
    except BaseException as e:
        _stopped(report, to_run, order, results, finish)
        failed = [r for r in report.results if r.status == FAILED]
        if recorder is not None:
            recorder.fail(failed[0].error if failed else f"{type(e).__name__}: {e}")
        hook.graph_finished(report)
        raise
    report.results = [results[j.key()] for j in order]
    hook.graph_finished(report)
    return report


def _drop_known_failures(to_run: list[Job], failed: dict[str, JobResult], finish) -> list[Job]:
    """``to_run`` without the jobs of ``failed`` (recorded with their earlier result) and
    their dependents (recorded CANCELLED), in order."""
    out, gone = [], set()
    for j in to_run:
        k = j.key()
        if k in failed:
            finish(failed[k])
            gone.add(k)
        elif any(i.key() in gone for i in j.inputs):
            finish(JobResult(j, k, CANCELLED, error="an input failed"))
            gone.add(k)
        else:
            out.append(j)
    return out


@dataclass
class _Beside:
    """:func:`execute`'s ``beside`` tasks, their callback and where their outcomes go."""

    tasks: list
    on_done: Callable[[int, str | None], None] | None
    out: list

    def done(self, i: int, error: str | None) -> None:
        self.out[i] = error
        if self.on_done is not None:
            self.on_done(i, error)

    def run_inline(self) -> None:
        self.out[:] = [None] * len(self.tasks)
        for i, fn in enumerate(self.tasks):
            try:
                fn()
            except Exception as e:  # noqa: BLE001 - reported, the caller decides
                self.done(i, f"{type(e).__name__}: {e}")
            else:
                self.done(i, None)

    def submit(self, pool_backend: _PoolBackend) -> None:
        self.out[:] = [None] * len(self.tasks)
        for i, fn in enumerate(self.tasks):
            fut = pool_backend.pool.submit(beside_task, fn)
            pool_backend.beside.append(fut)
            fut.add_done_callback(lambda f, i=i: self.done(i, _error_of(f)))

    def wait(self, pool_backend: _PoolBackend) -> None:
        wait(pool_backend.beside)


def _error_of(fut) -> str | None:
    if fut.cancelled():
        return "cancelled"
    e = fut.exception()
    return None if e is None else f"{type(e).__name__}: {e}"


def _run_jobs(to_run, dec, results, finish, *, store, hook, by_key, jobs, threads_per_job,
              keep_going, backend, flag, beside: _Beside) -> None:
    """Run the jobs ``to_run`` where :func:`execute` was asked to: on ``backend`` when there is
    one (and something to run), inline for ``jobs=1`` or a single job, else on this machine's
    process pool of ``min(jobs, len(to_run))`` workers (``threads_per_job`` defaulting to
    ``cpu_count // jobs``); ``beside`` tasks in that pool, queued first (then it has ``jobs``
    workers, whatever the graph's size), or one after another here."""
    if beside.tasks and (backend is not None or jobs <= 1):
        beside.run_inline()
    elif beside.tasks:
        if threads_per_job is None:
            threads_per_job = max(1, (os.cpu_count() or 1) // jobs)
        with _PoolBackend(store, hook, by_key, jobs, threads_per_job) as b:
            beside.submit(b)
            try:
                if to_run:
                    _run_graph(to_run, dec, results, finish, b, flag, keep_going)
                beside.wait(b)
            except BaseException:  # a user error, an interrupt: stop the tasks, do not wait
                b.stop([], flag)
                raise
        return
    if backend is not None and to_run:
        with backend(store, hook, by_key, threads_per_job) as b:
            _run_graph(to_run, dec, results, finish, b, flag, keep_going)
    elif jobs <= 1 or len(to_run) <= 1:
        _run_inline(to_run, dec, results, store, finish, hook, threads_per_job, keep_going)
    else:
        if threads_per_job is None:
            threads_per_job = max(1, (os.cpu_count() or 1) // jobs)
        with _PoolBackend(store, hook, by_key, min(jobs, len(to_run)), threads_per_job) as b:
            _run_graph(to_run, dec, results, finish, b, flag, keep_going)


def _stopped(report: ExecutionReport, to_run, order, results, finish) -> None:
    """When the graph stopped early: record every job of ``to_run`` that has no result yet as
    CANCELLED and put every job's result in ``report``, in graph order."""
    for j in to_run:
        if j.key() not in results:
            finish(JobResult(j, j.key(), CANCELLED))
    report.results = [results[j.key()] for j in order]


def _annotate(e: BaseException, job: Job, key: str) -> None:
    if hasattr(e, "add_note"):
        e.add_note(f"while running job {job.name} ({job.impl}, key {key[:12]})")


def _inputs(job: Job, results: dict[str, JobResult]) -> tuple[StoredObject, ...]:
    objs = []
    for j in job.inputs:
        r = results.get(j.key())
        if r is None or r.object is None:
            raise RuntimeError(f"input {j.name} of {job.name} is not available")  # a bug
        objs.append(r.object)
    return tuple(objs)


def _failed(job: Job, key: str, t0: float, e: BaseException, finish, keep_going: bool) -> bool:
    """Record ``job`` as FAILED with ``e``; True when the graph goes on without it (only with
    ``keep_going``, and never for a user error), False when ``e`` must stop the graph."""
    finish(JobResult(job, key, FAILED, time.perf_counter() - t0, error=f"{type(e).__name__}: {e}"))
    _annotate(e, job, key)
    tolerated = keep_going and isinstance(e, Exception) and not isinstance(e, ReproError)
    if tolerated:
        log.info("job %s failed (%s: %s); its dependents are cancelled",
                 job.name, type(e).__name__, e)
    return tolerated


def _blocked(job: Job, results: dict[str, JobResult]) -> JobResult | None:
    """The CANCELLED result of ``job`` when one of its inputs failed or was cancelled."""
    for i in job.inputs:
        r = results.get(i.key())
        if r is not None and r.status in (FAILED, CANCELLED):
            why = r.error if r.status == CANCELLED else f"input {i.name} failed"
            return JobResult(job, job.key(), CANCELLED, error=why)
    return None


def _run_inline(to_run, dec, results, store, finish, hook, threads, keep_going=False) -> None:
    for job in to_run:
        k = job.key()
        blocked = _blocked(job, results)
        if blocked is not None:
            finish(blocked)
            continue
        inputs = _inputs(job, results)
        hook.job_started(job, k)
        t0 = time.perf_counter()

        def progress(done, total=None, message=None, _job=job, _k=k):
            hook.job_progress(_job, _k, done, total, message)

        try:
            status, obj = run_job(job, k, inputs, store, force=dec[k].forced, threads=threads,
                                  progress=progress)
        except KeyboardInterrupt:
            finish(JobResult(job, k, INTERRUPTED, time.perf_counter() - t0))
            raise
        except BaseException as e:
            if _failed(job, k, t0, e, finish, keep_going):
                continue
            raise
        finish(JobResult(job, k, status, time.perf_counter() - t0, obj))


class Backend:
    """Where :func:`_run_graph` runs jobs: this machine's process pool (:class:`_PoolBackend`)
    or a Ray cluster (:mod:`repro.engine.ray_executor`).  A *handle* is whatever
    :meth:`submit` returns (hashable).  The scheduling (dependency order, failure isolation,
    interrupt bookkeeping) is :func:`_run_graph`'s, the same for every back end."""

    def submit(self, job: Job, key: str, inputs: tuple[StoredObject, ...], force: bool) -> Any:
        """Start ``job`` (its inputs are published) and return its handle."""
        raise NotImplementedError

    def wait(self, handles: list) -> Iterable:
        """Block until at least one of ``handles`` has finished; return the finished ones."""
        raise NotImplementedError

    def outcome(self, handle) -> tuple[str, StoredObject, float]:
        """``(status, object, seconds)`` of a finished job; raises the job's exception."""
        raise NotImplementedError

    def stop(self, handles: list, flag: dict) -> None:
        """On an interrupt: cancel the queued jobs and interrupt the running ones (``flag``
        says whether it came as SIGTERM)."""
        raise NotImplementedError

    def settled(self, handle) -> tuple[str, StoredObject | None]:
        """After :meth:`stop`: the job's status (INTERRUPTED, CANCELLED, or what it finished
        with) and its object, if any."""
        raise NotImplementedError


def _run_graph(to_run, dec, results, finish, backend: Backend, flag, keep_going=False) -> None:
    """Run ``to_run`` on ``backend``, each job once its inputs are published."""
    run_keys = {j.key() for j in to_run}
    waiting = {j.key(): {i.key() for i in j.inputs if i.key() in run_keys} for j in to_run}
    dependents: dict[str, list[Job]] = {}
    for j in to_run:
        for i in waiting[j.key()]:
            dependents.setdefault(i, []).append(j)
    ready = [j for j in to_run if not waiting[j.key()]]
    running: dict[Any, tuple[Job, float]] = {}
    failure: BaseException | None = None
    try:
        while ready or running:
            while ready and failure is None:
                job = ready.pop(0)
                k = job.key()
                handle = backend.submit(job, k, _inputs(job, results), dec[k].forced)
                running[handle] = (job, time.perf_counter())
            if not running:
                break
            for handle in backend.wait(list(running)):
                job, t0 = running.pop(handle)
                k = job.key()
                try:
                    status, obj, seconds = backend.outcome(handle)
                except KeyboardInterrupt:
                    finish(JobResult(job, k, INTERRUPTED, time.perf_counter() - t0))
                    raise
                except BaseException as e:
                    if _failed(job, k, t0, e, finish, keep_going):
                        _cancel_dependents(k, dependents, results, finish)
                    else:
                        failure = failure or e
                    continue
                finish(JobResult(job, k, status, seconds, obj))
                for d in dependents.get(k, []):
                    waiting[d.key()].discard(k)
                    if not waiting[d.key()]:
                        ready.append(d)
            if failure is not None:
                ready.clear()
        if failure is not None:
            raise failure
    except KeyboardInterrupt:
        backend.stop(list(running), flag)
        for handle, (job, t0) in running.items():
            if job.key() in results:
                continue
            status, obj = backend.settled(handle)
            finish(JobResult(job, job.key(), status, time.perf_counter() - t0, obj))
        raise


def _cancel_dependents(key: str, dependents: dict[str, list[Job]], results, finish) -> None:
    """Record every job downstream of the failed ``key`` as CANCELLED (they never become ready)."""
    stack = list(dependents.get(key, []))
    while stack:
        d = stack.pop()
        if d.key() in results:
            continue
        blocked = _blocked(d, results)
        finish(blocked or JobResult(d, d.key(), CANCELLED, error="an input failed"))
        stack.extend(dependents.get(d.key(), []))


def _signal_all(pids: Iterable[int], sig: int) -> None:
    for pid in list(pids):
        try:
            os.kill(pid, sig)
        except (ProcessLookupError, PermissionError):
            pass


class _PoolBackend(Backend):
    """This machine's back end: a ``spawn`` process pool of ``workers`` processes (module
    docstring); the workers report their pids, starts and progress through a queue that a
    thread drains into the hook."""

    def __init__(self, store: Store, hook: ProgressHook, by_key: dict[str, Job], workers: int,
                 threads: int | None):
        self.store, self.hook, self.by_key = store, hook, by_key
        self.threads = threads
        ctx = multiprocessing.get_context("spawn")
        self.q = ctx.Queue()
        self.stop_workers = ctx.Event()
        self.pids: set[int] = set()
        self._done = threading.Event()
        self.drainer = threading.Thread(target=self._drain, name="repro-progress", daemon=True)
        self.pool = ProcessPoolExecutor(max_workers=workers, mp_context=ctx,
                                        initializer=worker_init,
                                        initargs=(self.q, self.stop_workers, threads))
        self.beside: list = []  # futures of execute's ``beside`` tasks (stopped with the jobs)

    def __enter__(self) -> _PoolBackend:
        self.drainer.start()
        return self

    def __exit__(self, *exc) -> None:
        self.pool.shutdown(wait=True, cancel_futures=True)
        self._done.set()
        self.drainer.join(timeout=2.0)
        self.q.close()

    def _drain(self) -> None:
        while True:
            try:
                msg = self.q.get(timeout=0.1)
            except queue.Empty:
                if self._done.is_set():
                    return
                continue
            except (EOFError, OSError, ValueError):
                return
            if msg[0] == "pid":
                self.pids.add(msg[1])
            else:
                dispatch_progress(msg, self.hook, self.by_key)

    def submit(self, job, key, inputs, force):
        return self.pool.submit(worker_task, job, key, inputs, str(self.store.root), force,
                                self.threads)

    def wait(self, handles):
        done, _ = wait(handles, return_when=FIRST_COMPLETED)
        return done

    def outcome(self, handle):
        return handle.result()

    def stop(self, handles, flag) -> None:
        """Cancel queued jobs; interrupt running ones (SIGINT, then SIGKILL after a grace
        period)."""
        self.stop_workers.set()
        handles = list(handles) + [f for f in self.beside if not f.done()]
        for fut in handles:
            fut.cancel()  # those still waiting in the executor's queue
        pending = {f for f in handles if not f.cancelled()}
        if pending and not flag.get("sigterm"):
            # Ctrl-C in a terminal reaches the workers too: give them a moment to stop cleanly.
            _, pending = wait(pending, timeout=2.0)
        if pending:
            _signal_all(self.pids, signal.SIGINT)
            _, pending = wait(pending, timeout=10.0)
        if pending:
            _signal_all(self.pids, signal.SIGKILL)
        self.pool.shutdown(wait=False, cancel_futures=True)

    def settled(self, handle):
        if handle.cancelled():
            return CANCELLED, None
        if handle.done():
            try:
                status, obj, _ = handle.result()
                return status, obj
            except BaseException:
                pass
        return INTERRUPTED, None
