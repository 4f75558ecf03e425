"""A :mod:`rich` progress display for :func:`repro.engine.executor.execute`.

One bar for the graph (jobs to run), one line per running job fed by ``ctx.progress``, and a
log line per finished job (status, seconds).  Use as a context manager::

    with RichProgressHook() as hook:
        execute(targets, hook=hook)
"""

from __future__ import annotations

import threading

from repro.engine.executor import COMPUTED, HIT, ProgressHook

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
