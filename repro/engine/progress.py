"""A :mod:`rich` progress display for :func:`repro.engine.executor.execute`.

One bar for the graph (jobs to run), one line per running job fed by ``ctx.progress``, and a
log line per finished job (status, seconds).  Use as a context manager::

    with RichProgressHook() as hook:
        execute(targets, hook=hook)
"""

from __future__ import annotations

import threading

from repro.engine.executor import ProgressHook
from repro.engine.job_run import COMPUTED, HIT

_MARK = {HIT: "[green]hit[/]", COMPUTED: "[cyan]computed[/]", "failed": "[red]failed[/]",
         "interrupted": "[yellow]interrupted[/]", "uncached": "[magenta]uncached[/]"}


class RichProgressHook(ProgressHook):
    def __init__(self, console=None, *, transient: bool = True):
        from rich.console import Console
        from rich.progress import (BarColumn, MofNCompleteColumn, Progress, SpinnerColumn,
                                   TextColumn, TimeElapsedColumn)

        self.console = console or Console(stderr=True)
        self.progress = Progress(SpinnerColumn(), TextColumn("{task.description}"), BarColumn(),
                                 MofNCompleteColumn(), TimeElapsedColumn(),
                                 console=self.console, transient=transient)
        self._overall = None
        self._tasks: dict[str, int] = {}
        self._lock = threading.Lock()

    def __enter__(self) -> RichProgressHook:
        self.progress.start()
        return self

    def __exit__(self, *exc) -> None:
        self.progress.stop()

    def graph_started(self, entries) -> None:
        n_run = sum(1 for _, _, a in entries if a == "run")
        n_hit = sum(1 for _, _, a in entries if a == "hit")
        self.console.log(f"{len(entries)} jobs: {n_hit} cached, {n_run} to run")
        self._overall = self.progress.add_task("jobs", total=max(n_run, 1) if n_run else 0)

    def job_started(self, job, key) -> None:
        with self._lock:
            if key not in self._tasks:
                self._tasks[key] = self.progress.add_task(f"  {job.name}", total=None)

    def job_progress(self, job, key, done, total, message) -> None:
        self.job_started(job, key)
        desc = f"  {job.name}" + (f" [dim]{message}[/]" if message else "")
        self.progress.update(self._tasks[key], completed=done, total=total, description=desc)

    def job_finished(self, result) -> None:
        with self._lock:
            tid = self._tasks.pop(result.key, None)
        if tid is not None:
            self.progress.remove_task(tid)
            if self._overall is not None:
                self.progress.advance(self._overall)
        if result.status not in ("skipped", "cancelled") and (tid is not None
                                                              or result.status != HIT):
            self.console.log(f"{result.job.name}: {_MARK.get(result.status, result.status)} "
                             f"({result.seconds:.1f} s)")


class LineProgressHook(ProgressHook):
    """Plain progress lines on stderr for a run whose output is not a terminal (a log file, a
    pipe, CI without ``--quiet``; issue 28: a redirected run printed nothing for 9 minutes):
    one line per finished job (kind, row, replicate or seed, its own seconds, elapsed time
    since the run started, jobs done of jobs to run), and :meth:`note` lines for the steps
    outside the graph (each evaluator, the real rows, the gate).  Hits found before the graph
    ran are counted in the first line, not listed one by one."""

    def __init__(self, stream=None, t0: float | None = None):
        import sys
        import time

        self.stream = stream if stream is not None else sys.stderr
        self.t0 = time.monotonic() if t0 is None else t0
        self._lock = threading.Lock()
        self._started: set[str] = set()
        self._done = 0
        self._to_run = 0

    def note(self, text: str) -> None:
        """One line: ``repro: [elapsed] text``."""
        import time

        with self._lock:
            print(f"repro: [{_elapsed(time.monotonic() - self.t0)}] {text}", file=self.stream,
                  flush=True)

    def graph_started(self, entries) -> None:
        with self._lock:  # a run may execute two graphs (trainings beside the evaluators)
            self._done = 0
            self._started.clear()
        self._to_run = sum(1 for _, _, a in entries if a == "run")
        n_hit = sum(1 for _, _, a in entries if a == "hit")
        self.note(f"{len(entries)} jobs: {n_hit} cached, {self._to_run} to run")

    def job_started(self, job, key) -> None:
        with self._lock:
            self._started.add(key)

    def job_finished(self, result) -> None:
        with self._lock:
            started = result.key in self._started
            self._started.discard(result.key)
            if started:
                self._done += 1
            done = self._done
        if result.status in ("skipped", "cancelled") or not (started or result.status != HIT):
            return
        error = f": {result.error}" if result.error else ""
        self.note(f"{result.status} {job_words(result.job)} in {result.seconds:.1f} s "
                  f"({done}/{self._to_run}){error}")

    def graph_finished(self, report) -> None:
        counts = ", ".join(f"{n} {s}" for s, n in sorted(report.counts.items()))
        self.note(f"jobs finished: {counts or 'none'}")


def job_words(job) -> str:
    """``train marionet (seed 0)`` / ``measure row real, replicate 2``: a job's kind, its row
    (or method) and replicate, from its label (``row/kind/rN``, ``method/train[/sN]``)."""
    parts = (job.label or "").split("/")
    row = parts[0] if parts and parts[0] else "-"
    rep = next((p[1:] for p in parts[1:] if p[:1] == "r" and p[1:].isdigit()), None)
    where = f"replicate {rep}" if rep is not None else (
        f"seed {job.seed}" if job.seed is not None else "")
    return f"{job.kind} {row}" + (f" ({where})" if where else "")


def _elapsed(seconds: float) -> str:
    """``   12.3 s`` under a minute, ``  4m05s`` under an hour, else ``1h02m``."""
    s = max(0.0, float(seconds))
    if s < 60:
        return f"{s:6.1f} s"
    if s < 3600:
        return f"{int(s // 60):3d}m{int(s % 60):02d}s"
    return f"{int(s // 3600)}h{int(s % 3600 // 60):02d}m"
