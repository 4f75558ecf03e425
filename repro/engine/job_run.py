"""Running one job (issue 4, item 3; back ends: issue 15, item 1): a job's statuses,
:func:`run_job` (its thread count, its log file, its payload through :meth:`Store.compute`, or an
ephemeral folder when it is not cacheable) and the worker side of a back end
(:func:`run_in_worker`, which every back end runs a job through, and the process pool's
:func:`worker_init` and :func:`worker_task`).  The graph, its scheduling and the back ends are
:mod:`repro.engine.executor`'s.
"""

from __future__ import annotations

import logging
import os
import signal
import sys
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from repro.engine.job import Job, JobContext
from repro.store.object_files import StoredObject
from repro.store.objects import Store

HIT = "hit"              # found in the store (or computed meanwhile by another process)
COMPUTED = "computed"    # computed and published by this call
UNCACHED = "uncached"    # run, but not cacheable: output is ephemeral
SKIPPED = "skipped"      # not needed (downstream cached) and not in the store
FAILED = "failed"
INTERRUPTED = "interrupted"
CANCELLED = "cancelled"  # not started because another job failed or the run was interrupted


# ---------------------------------------------------------------------- running one job
def _thread_env(n: int) -> None:
    """``n`` threads for torch, MKL and OpenMP not imported yet (they read these at import)."""
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = str(n)


@contextmanager
def _thread_count(threads: int | None):
    """Compute with ``threads`` torch and BLAS/OpenMP threads for the duration (nothing when
    None), then restore the previous counts.  Before torch is imported (a fresh worker) the
    count goes through ``OMP_NUM_THREADS``/``MKL_NUM_THREADS``, which torch reads at import."""
    if not threads:
        yield
        return
    from threadpoolctl import threadpool_limits

    n = int(threads)
    torch = sys.modules.get("torch")
    before = torch.get_num_threads() if torch is not None else None
    if torch is not None:
        torch.set_num_threads(n)
    else:
        _thread_env(n)
    try:
        with threadpool_limits(limits=n):
            yield
    finally:
        if before is not None:
            torch.set_num_threads(before)


def _meta(job: Job) -> dict[str, Any]:
    return {"label": job.label, "impl": job.impl, "seed": job.seed, "key_parts": job.key_parts()}


def _job_logger(store: Store, job: Job, key: str) -> tuple[logging.Logger, logging.Handler]:
    logger = logging.getLogger(f"repro.job.{job.kind}")
    if logger.level == logging.NOTSET:
        logger.setLevel(logging.INFO)
    path = store.log_path(key)
    path.parent.mkdir(parents=True, exist_ok=True)
    handler = logging.FileHandler(path, encoding="utf-8")
    handler.setFormatter(logging.Formatter(f"%(asctime)s %(levelname)s [{job.name}] %(message)s"))
    logger.addHandler(handler)
    return logger, handler


def run_job(job: Job, key: str, inputs: tuple[StoredObject, ...], store: Store, *,
            force: bool = False, threads: int | None = None, progress=None
            ) -> tuple[str, StoredObject]:
    """Run one job (inputs already resolved) and return ``(status, object)``, computing with
    the job's own ``threads`` when it declares them, else with ``threads`` (the executor's)."""
    from repro.kernels import check as check_kernels

    fn = job.resolve()
    threads = job.threads or threads
    check_kernels()  # the pin (or --fast-kernels) the job's key names is really in force
    logger, handler = _job_logger(store, job, key)
    try:
        with _thread_count(threads):
            return _run_payload(fn, job, key, inputs, store, logger, force, threads, progress)
    finally:
        logger.removeHandler(handler)
        handler.close()


def _run_payload(fn, job: Job, key: str, inputs, store: Store, logger, force: bool,
                 threads: int | None, progress) -> tuple[str, StoredObject]:
    from repro.keys import sha256_file
    from repro.store.atomic import utc_now
    from repro.store.object_files import payload_files

    if job.cacheable:
        def payload(out: Path) -> None:
            scratch = store.scratch(key)
            logger.info("start %s key %s (scratch %s, %s threads)", job.impl, key[:12], scratch,
                        threads or "default")
            fn(JobContext(job, key, inputs, out, scratch, logger, threads, progress))

        obj = store.compute(key, job.kind, payload, meta=_meta(job), force=force)
        logger.info("%s", "found in the store" if obj.hit else "published")
        return (HIT if obj.hit else COMPUTED), obj
    root = store.ephemeral_dir()
    out, scratch = root / "out", root / "scratch"
    out.mkdir()
    scratch.mkdir()
    fn(JobContext(job, key, inputs, out, scratch, logger, threads, progress))
    files = {rel: {"sha256": sha256_file(p), "size": p.stat().st_size}
             for rel, p in payload_files(out)}
    return UNCACHED, StoredObject(key, job.kind, out, files, utc_now(), _meta(job),
                                  hit=False, ephemeral=True)


# ---------------------------------------------------------------------- worker processes
_QUEUE = None
_STOP = None


def _put(msg) -> None:
    try:
        if _QUEUE is not None:
            _QUEUE.put(msg)
    except (OSError, ValueError, EOFError):  # parent gone or queue closed
        pass


def worker_init(q, stop, threads: int | None) -> None:
    """A pool worker's initializer: its message queue and stop event, Ctrl-C ignored while
    idle, and ``threads`` for the libraries it has yet to import; it reports its pid."""
    global _QUEUE, _STOP
    _QUEUE, _STOP = q, stop
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # idle workers ignore Ctrl-C
    if threads:
        _thread_env(int(threads))
    _put(("pid", os.getpid()))


def run_in_worker(job: Job, key: str, inputs, root: str, force: bool, threads: int | None,
                  put) -> tuple[str, StoredObject, float]:
    """Run one job in a worker (a pool process or a Ray worker) against the store at ``root``
    and return ``(status, object, seconds)``; ``put`` carries its "start" and "progress"
    messages to the driver.  Every back end runs a job through here, so a job computes the
    same way (thread settings, store protocol) whatever runs it."""
    put(("start", key))
    t0 = time.perf_counter()

    def progress(done, total=None, message=None):
        put(("progress", key, done, total, message))

    status, obj = run_job(job, key, inputs, Store(root), force=force, threads=threads,
                          progress=progress)
    return status, obj, time.perf_counter() - t0


def worker_task(job: Job, key: str, inputs, root: str, force: bool, threads: int | None):
    """A pool worker's task: :func:`run_in_worker`, interruptible by Ctrl-C while it runs, not
    started at all once the driver has asked the workers to stop."""
    signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        if _STOP is not None and _STOP.is_set():  # queued before the interrupt: do not start
            raise KeyboardInterrupt
        return run_in_worker(job, key, inputs, root, force, threads, _put)
    finally:
        signal.signal(signal.SIGINT, signal.SIG_IGN)


def beside_task(fn):
    """A pool worker's task that is not a job (``execute(beside=...)``: a run's evaluator):
    ``fn()``, interruptible by Ctrl-C while it runs, as :func:`worker_task`."""
    signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        if _STOP is not None and _STOP.is_set():
            raise KeyboardInterrupt
        return fn()
    finally:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
