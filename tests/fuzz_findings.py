"""What the fuzz modules (``tests/test_fuzz.py``, ``tests/test_fuzz_outputs.py``) share: the
guarded call and what it counts, and the findings kept in ``REPRO_FUZZ_LOG`` mode instead of
failing at the first one (docs/fuzzing.md).  Each module holds one :class:`Findings`."""

from __future__ import annotations

import json
import os
import sys
import time
import traceback
from collections import Counter
from pathlib import Path

from repro.errors import ReproError

REFUSED = object()   # the call raised a ReproError
FOREIGN = object()   # the call raised something else (only returned in LOG mode)
REPO = str(Path(__file__).resolve().parents[1])


def shown_text(x) -> str:
    r = repr(x)
    return r if len(r) <= 4000 else r[:4000] + f"... ({len(r)} characters)"


class Findings:
    """Inputs tried (``counts``) and read without an error (``accepted``) per target, seconds
    per test (``times``), and, with a ``log`` path, the foreign exceptions and broken
    properties found (``found``, one entry per target, kind and place, with its shortest
    input).  ``chained_where``: a finding's place also names the entry point and the innermost
    frame (``a.py:1 -> b.py:2 -> lib.py:3``), not only the last frame in ``repro``."""

    def __init__(self, log: str | None, *, chained_where: bool):
        self.log = log
        self.chained_where = chained_where
        self.counts: Counter = Counter()
        self.accepted: Counter = Counter()
        self.times: dict[str, float] = {}
        self.found: dict[tuple, dict] = {}

    def record(self, target: str, kind: str, where: str, message: str, tb: str, shown) -> None:
        key = (target, kind, where)
        text = shown_text(shown)
        f = self.found.get(key)
        if f is None:
            self.found[key] = {"target": target, "exception": kind, "where": where, "count": 1,
                               "message": message[:300], "input": text, "traceback": tb}
        else:
            f["count"] += 1
            if len(text) < len(f["input"]):
                f.update(input=text, message=message[:300], traceback=tb)

    def where(self, e: BaseException) -> str:
        """The place a foreign exception was raised (see the class docstring)."""
        frames = traceback.extract_tb(e.__traceback__)
        ours = [f for f in frames if f.filename.startswith(REPO) and "/tests/" not in f.filename]
        last = ours[-1] if ours else frames[-1]
        where = f"{os.path.relpath(last.filename, REPO)}:{last.lineno}"
        if not self.chained_where:
            return where
        if len(ours) > 1:  # the entry point too: resolve_scale -> keys.canonical_json
            where = f"{os.path.relpath(ours[0].filename, REPO)}:{ours[0].lineno} -> {where}"
        inner = frames[-1]
        if inner is not last:
            where += f" -> {inner.filename.rsplit('/', 1)[-1]}:{inner.lineno}"
        return where

    def call(self, target: str, fn, *args, shown, **kwargs):
        """``fn(*args, **kwargs)``; :data:`REFUSED` on a ReproError.  Any other exception fails
        the test (or, with a log, is recorded and :data:`FOREIGN` returned)."""
        self.counts[target] += 1
        try:
            out = fn(*args, **kwargs)
            self.accepted[target] += 1
            return out
        except ReproError:
            return REFUSED
        except Exception as e:
            if self.log is None:
                raise
            self.record(target, type(e).__name__, self.where(e), str(e),
                        "".join(traceback.format_exception(e, limit=-12)), shown)
            return FOREIGN

    def fail(self, target: str, problem: str, shown) -> None:
        """A broken property other than an exception: assertion, or a record in LOG mode."""
        if self.log is None:
            raise AssertionError(f"{problem}\ninput: {shown_text(shown)}")
        self.record(target, "PropertyViolated", problem.split(":", 1)[0], problem, "", shown)

    def write_log(self, head: dict, t0: float) -> None:
        """With a log: the module's summary line (``head``'s fields first, then the counts,
        times and number of findings; ``t0`` its start) and a line per finding, appended."""
        if self.log is None:
            return
        with open(self.log, "a", encoding="utf-8") as fh:
            fh.write(json.dumps({
                **head, "inputs": dict(self.counts), "inputs_total": sum(self.counts.values()),
                "accepted": dict(self.accepted), "test_seconds": self.times,
                "seconds": round(time.perf_counter() - t0, 1), "foreign": len(self.found),
                "python": sys.version.split()[0]}) + "\n")
            fh.writelines(json.dumps(f) + "\n" for f in self.found.values())
