"""A run folder's files, and reading them back: the layer under the SQLite index.

``runs_root()/<run_id>/`` holds ``run.json``, ``values.jsonl``, ``summary.json`` and
``trainings.json`` (their content: :mod:`repro.store.runs`, which writes them through its
:class:`~repro.store.runs.RunRecorder`).  This module names the files, the statuses and the
schemas, reads a folder back with every file checked (:func:`load_run`, :func:`read_run_json`,
:func:`read_values`, :func:`read_summary`, :func:`read_trainings`), lists and resolves run
folders (:func:`run_dirs`, :func:`resolve_run`) and marks a run whose process died INTERRUPTED
(:func:`reconcile_stale`).  The index (:mod:`repro.store.index`) is built from these; the
recorder, above both, updates the index after each write.  Every name here stays importable
from :mod:`repro.store.runs`.
"""

from __future__ import annotations

import json
import os
import socket
import stat
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from repro.errors import ConfigError, DataError
from repro.store.atomic import atomic_write_json, utc_now

RUN_SCHEMA = 1
VALUES_SCHEMA = 1
SUMMARY_SCHEMA = 1
QUEUED, RUNNING, FINISHED, FAILED, INTERRUPTED = (
    "QUEUED", "RUNNING", "FINISHED", "FAILED", "INTERRUPTED")
TERMINAL = frozenset({FINISHED, FAILED, INTERRUPTED})

RUN_JSON, VALUES_JSONL, SUMMARY_JSON = "run.json", "values.jsonl", "summary.json"
TRAININGS_JSON = "trainings.json"
#: the mode of a finished run's files (read-only for everyone)
READ_ONLY = stat.S_IRUSR | stat.S_IRGRP | stat.S_IROTH


def _stat_fields(pid: int) -> list[str] | None:
    """The fields of ``/proc/<pid>/stat`` after the command name (Linux), or None."""
    try:
        raw = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    return raw[raw.rfind(")") + 2:].split()


def process_start(pid: int) -> str | None:
    """The process start time in clock ticks since boot (Linux), to tell a reused pid apart
    (a run records its own as ``env.pid_start``)."""
    fields = _stat_fields(pid)
    return fields[19] if fields is not None and len(fields) > 19 else None


def _proc_state(pid: int) -> str | None:
    fields = _stat_fields(pid)
    return fields[0] if fields else None


def process_alive(pid: int | None, start: str | None = None) -> bool:
    """Whether ``pid`` runs (and, when known, is the same process that started at ``start``)."""
    if not pid:
        return False
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass
    if _proc_state(int(pid)) in ("Z", "X"):
        return False
    if start is not None:
        now = process_start(int(pid))
        if now is not None and now != start:
            return False
    return True


# ---------------------------------------------------------------------- reading
@dataclass
class RunRecord:
    path: Path
    run: dict[str, Any]
    values: list[dict[str, Any]]
    summary: dict[str, Any] | None

    @property
    def run_id(self) -> str:
        return self.run["run_id"]

    @property
    def status(self) -> str:
        return self.run["status"]


def read_run_json(path: Path) -> dict[str, Any]:
    """``run.json`` of the run folder ``path``, its fields checked
    (:func:`repro.store.run_checks.check_run_json`)."""
    from repro.store.run_checks import check_run_json, read_regular

    f = Path(path) / RUN_JSON
    try:
        data = json.loads(read_regular(f).decode("utf-8"))
    except FileNotFoundError:
        raise DataError("run record has no run.json", file=f) from None
    except (OSError, ValueError) as e:
        raise DataError(f"run.json is not valid JSON ({e})", file=f) from None
    except RecursionError:
        raise DataError("run.json is nested too deeply", file=f) from None
    return check_run_json(data, f, RUN_SCHEMA)


def read_trainings(path: Path) -> list[dict[str, Any]]:
    """The ``trainings`` a run folder's ``trainings.json`` holds (:meth:`RunRecorder.
    write_trainings`; empty when the run has none or the file is unreadable)."""
    f = Path(path) / TRAININGS_JSON
    if not f.is_file():
        return []
    from repro.store.run_checks import read_regular

    try:
        got = json.loads(read_regular(f).decode("utf-8")).get("trainings") or []
    except (OSError, ValueError, AttributeError, RecursionError, DataError):
        return []
    return [t for t in got if isinstance(t, dict)] if isinstance(got, list) else []


def read_values(path: Path) -> list[dict[str, Any]]:
    f = Path(path) / VALUES_JSONL
    if not f.exists():
        return []
    from repro.store.run_checks import VALUES_CAP, check_value_line, read_regular

    out = []
    try:
        lines = read_regular(f, VALUES_CAP).decode("utf-8").splitlines()
    except (OSError, ValueError) as e:
        raise DataError(f"cannot read the values ({e})", file=f) from None
    for i, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            v = json.loads(line)
        except ValueError as e:
            raise DataError(f"not a JSON line ({e})", file=f, line=i) from None
        except RecursionError:
            raise DataError("nested too deeply", file=f, line=i) from None
        out.append(check_value_line(v, f, i))
    return out


def read_summary(path: Path, required: bool = False) -> dict[str, Any] | None:
    """``summary.json`` of the run folder ``path``, capped and its shape checked
    (:func:`repro.store.run_checks.check_summary`); None when there is none, unless
    ``required`` (a FINISHED run always has one), where its absence is a DataError."""
    from repro.store.run_checks import check_summary, read_regular

    sf = Path(path) / SUMMARY_JSON
    try:
        data = json.loads(read_regular(sf).decode("utf-8"))
    except FileNotFoundError:
        if required:
            raise DataError("the run has no summary.json", file=sf) from None
        return None
    except (OSError, ValueError) as e:
        raise DataError(f"summary.json is not valid JSON ({e})", file=sf) from None
    except RecursionError:
        raise DataError("summary.json is nested too deeply", file=sf) from None
    return check_summary(data, sf)


def load_run(path: str | Path) -> RunRecord:
    """The whole record of the run folder ``path`` (``run.json``, the values, the summary),
    every file checked: a damaged one is a DataError naming it."""
    path = Path(path)
    summary = read_summary(path)
    return RunRecord(path, read_run_json(path), read_values(path), summary)


def run_dirs(runs_dir: str | Path | None = None) -> list[Path]:
    """Run folders, oldest first."""
    from repro.paths import runs_root

    root = Path(runs_dir) if runs_dir is not None else runs_root()
    if not root.is_dir():
        return []
    return sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith("."))


def resolve_run(ref: str, runs_dir: str | Path | None = None) -> Path:
    """The folder of run ``ref``: a run id, a unique prefix of one, or ``latest``."""
    if not str(ref).strip():
        raise ConfigError("the run id is empty (give a run id, a unique prefix of one, or "
                          "'latest'; `repro runs ls` lists them)")
    dirs = run_dirs(runs_dir)
    if ref in ("latest", "last"):
        if not dirs:
            raise ConfigError("no runs recorded yet")
        return dirs[-1]
    exact = [d for d in dirs if d.name == ref]
    if exact:
        return exact[0]
    matches = [d for d in dirs if d.name.startswith(ref)]
    if len(matches) == 1:
        return matches[0]
    if not matches:
        raise ConfigError(f"no run {ref!r} (see `repro runs ls`)")
    raise ConfigError(f"run {ref!r} is ambiguous: {', '.join(d.name for d in matches[:5])}")


def reconcile_stale(path: str | Path) -> bool:
    """Mark a QUEUED/RUNNING run INTERRUPTED if its process (on this host) has died.

    Returns whether ``run.json`` was changed.
    """
    path = Path(path)
    try:
        data = read_run_json(path)
    except DataError:
        return False
    if data["status"] in TERMINAL:
        return False
    env = data.get("env") or {}
    if env.get("host") != socket.gethostname():
        return False
    if process_alive(env.get("pid"), env.get("pid_start")):
        return False
    now = utc_now()
    data["status"] = INTERRUPTED
    data["status_history"] = [*(data.get("status_history") or []),
                              {"status": INTERRUPTED, "at": now}]
    data["ended"] = now
    data["note"] = f"process {env.get('pid')} ended without closing the run (killed?)"
    atomic_write_json(path / RUN_JSON, data)
    for p in path.iterdir():
        if p.is_file():
            os.chmod(p, READ_ONLY)
    return True
