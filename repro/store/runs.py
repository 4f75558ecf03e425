"""Run records: one folder of plain files per run, the truth the SQLite index is built from.

``runs_root()/<run_id>/`` (``run_id`` = UTC time to the millisecond + 6 random hex digits, so
folder names sort by start time) holds

- ``run.json``: ``schema``, ``run_id``, ``status`` (QUEUED -> RUNNING -> FINISHED | FAILED |
  INTERRUPTED, with ``status_history``), ``table``, ``spec`` {version, hash}, resolved
  ``config``, ``scale``, ``dataset``, ``git`` {commit, diff_sha256 of ``git diff HEAD
  --binary`` (null when clean), dirty} (null outside a checkout), ``packages`` (python, torch,
  numpy, scipy, scikit-learn, roma, pydantic, repro), ``env`` {device, dtype, threads, host,
  platform, cpu, ``kernels`` (pinned or fast, the pin's settings, the host's vendor and widest
  ISA: :func:`repro.kernels.record`), pid; on a CUDA device also ``gpu`` {name, cuda, cudnn},
  :func:`gpu_info`},
  ``created``/``started``/``ended`` (UTC), ``keys`` {read, written}, ``jobs``
  (kind, label, key, status, seconds per job), ``error``/``note``, ``command``, ``extra``;
- ``values.jsonl``: one JSON object per line ``{schema, row, column, replicate, value, ...}``
  with every raw replicate value (non-finite values are written as ``null`` with
  ``"nonfinite": "nan" | "inf" | "-inf"``);
- ``summary.json``: whatever the aggregation computes (means, paper-style ±, bootstrap
  intervals, verdicts), with ``schema``.

Every write replaces the whole file atomically.  Parameters (table, spec, config, scale,
dataset, environment) are fixed when the recorder is created.  When the run reaches a terminal
status (FINISHED, FAILED or INTERRUPTED) its files are made read-only and no further write is
accepted.  A RUNNING run whose process has died (kill -9, power loss) is marked INTERRUPTED the
next time runs are listed (:func:`reconcile_stale`).
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import os
import platform
import secrets
import socket
import stat
import subprocess
import sys
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from repro.errors import ConfigError, DataError
from repro.kernels import cpu_description, record as kernel_record
from repro.store.atomic import atomic_write_bytes, atomic_write_json, jsonable, utc_now

RUN_SCHEMA = 1
VALUES_SCHEMA = 1
SUMMARY_SCHEMA = 1
QUEUED, RUNNING, FINISHED, FAILED, INTERRUPTED = (
    "QUEUED", "RUNNING", "FINISHED", "FAILED", "INTERRUPTED")
TERMINAL = frozenset({FINISHED, FAILED, INTERRUPTED})
_NEXT = {QUEUED: {RUNNING, FAILED, INTERRUPTED}, RUNNING: {FINISHED, FAILED, INTERRUPTED}}
PACKAGES = ("torch", "numpy", "scipy", "scikit-learn", "roma", "pydantic", "repro")
RUN_JSON, VALUES_JSONL, SUMMARY_JSON = "run.json", "values.jsonl", "summary.json"
TRAININGS_JSON = "trainings.json"
_READ_ONLY = stat.S_IRUSR | stat.S_IRGRP | stat.S_IROTH

log = logging.getLogger("repro.runs")


def new_run_id() -> str:
    """``YYYYMMDDTHHMMSS.mmmZ-xxxxxx``: sortable by start time, unique by the random suffix."""
    now = datetime.now(timezone.utc)
    return f"{now:%Y%m%dT%H%M%S}.{now.microsecond // 1000:03d}Z-{secrets.token_hex(3)}"


def git_state(root: str | Path | None = None) -> dict[str, Any] | None:
    """Commit and a sha256 of uncommitted changes of the checkout holding ``repro`` (or None)."""
    from repro.paths import repo_root

    root = Path(root) if root is not None else repo_root()
    if not (root / ".git").exists():
        return None
    try:
        head = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True,
                              timeout=30, check=True).stdout.decode().strip()
        diff = subprocess.run(["git", "-C", str(root), "diff", "HEAD", "--binary"],
                              capture_output=True, timeout=60, check=True).stdout
    except (OSError, subprocess.SubprocessError):
        return None
    return {"commit": head or None,
            "diff_sha256": hashlib.sha256(diff).hexdigest() if diff else None,
            "dirty": bool(diff)}


def package_versions() -> dict[str, str | None]:
    """Installed versions (from package metadata; nothing is imported)."""
    from importlib.metadata import PackageNotFoundError, version

    out: dict[str, str | None] = {"python": platform.python_version()}
    for name in PACKAGES:
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            out[name] = None
    return out


# CPU features that decide which float kernels BLAS / oneDNN pick (and so the last bits of a
# training): a run is bitwise reproducible only on a CPU with the same ones.
_ISA_FLAGS = ("avx512f", "avx512_bf16", "avx512_vnni", "amx_tile", "avx2", "fma", "avx", "sse4_2")


def cpu_info() -> dict[str, Any]:
    """The CPU a run used: model name, logical CPUs and the float-relevant ISA flags (from
    ``/proc/cpuinfo`` where there is one)."""
    _, model, flags = cpu_description()
    model = model or platform.processor() or platform.machine()
    return {"model": model, "cpus": os.cpu_count(), "isa": [f for f in _ISA_FLAGS if f in flags]}


def gpu_info(device: str | None) -> dict[str, Any] | None:
    """The GPU a CUDA run computes on, as this process sees it: the card's name, the CUDA
    version torch was built with and cuDNN's (a CUDA result can depend on all three); None on
    the CPU.  A driver without a GPU (``--executor ray``: the cards are the workers') records
    ``name`` None, as torch cannot name a card it does not see."""
    from repro.seeding import device_type

    if device_type(device) != "cuda":
        return None
    torch = sys.modules.get("torch")
    if torch is None:
        import torch
    visible = torch.cuda.is_available()
    cudnn = torch.backends.cudnn.version() if torch.backends.cudnn.is_available() else None
    return {"name": torch.cuda.get_device_name(torch.device(device)) if visible else None,
            "cuda": torch.version.cuda, "cudnn": cudnn}


def _proc_start(pid: int) -> str | None:
    """The process start time in clock ticks since boot (Linux), to tell a reused pid apart."""
    try:
        raw = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = raw[raw.rfind(")") + 2:].split()
    return fields[19] if len(fields) > 19 else None


def _proc_state(pid: int) -> str | None:
    try:
        raw = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = raw[raw.rfind(")") + 2:].split()
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
        now = _proc_start(int(pid))
        if now is not None and now != start:
            return False
    return True


def _value_line(row: Mapping[str, Any]) -> dict[str, Any]:
    if not isinstance(row, Mapping):
        raise ValueError(f"a value row must be a mapping, got {type(row).__name__}")
    for f in ("row", "column", "replicate", "value"):
        if f not in row:
            raise ValueError(f"a value row needs {f!r}: {dict(row)!r}")
    out = {k: jsonable(v) for k, v in row.items() if k not in ("value",)}
    if not isinstance(out["row"], str) or not isinstance(out["column"], str):
        raise ValueError("value rows need string 'row' and 'column'")
    rep = row["replicate"]
    if isinstance(rep, bool) or not isinstance(jsonable(rep), int):
        raise ValueError(f"'replicate' must be an int, got {rep!r}")
    v = row["value"]
    if v is None:
        out["value"] = None
    else:
        fv = float(v)
        if math.isfinite(fv):
            out["value"] = fv
        else:
            out["value"] = None
            out["nonfinite"] = "nan" if math.isnan(fv) else ("inf" if fv > 0 else "-inf")
    out["schema"] = VALUES_SCHEMA
    return out


class RunRecorder:
    """Creates and writes one run folder (see the module docstring).

    Use as a context manager: entering starts the run (RUNNING); leaving normally finishes it
    (FINISHED) unless it already ended; ``KeyboardInterrupt`` marks it INTERRUPTED and any
    other exception FAILED (the exception propagates).
    """

    def __init__(self, *, table: str | None = None, spec_version: str | int | None = None,
                 spec_hash: str | None = None, config: Mapping[str, Any] | None = None,
                 scale: str | None = None, dataset: str | None = None, device: str = "cpu",
                 dtype: str = "float32", threads: int | None = None,
                 command: list[str] | None = None, extra: Mapping[str, Any] | None = None,
                 runs_dir: str | Path | None = None, index: bool = True):
        from repro.paths import runs_root

        self.runs_dir = Path(runs_dir) if runs_dir is not None else runs_root()
        self.runs_dir.mkdir(parents=True, exist_ok=True)
        while True:
            self.run_id = new_run_id()
            self.path = self.runs_dir / self.run_id
            try:
                self.path.mkdir()
                break
            except FileExistsError:  # pragma: no cover - 24 random bits in the same ms
                continue
        if threads is None and "torch" in sys.modules:
            threads = int(sys.modules["torch"].get_num_threads())
        pid = os.getpid()
        now = utc_now()
        gpu = gpu_info(device)
        self._index = index
        self._values: list[dict[str, Any]] = []
        self._data: dict[str, Any] = {
            "schema": RUN_SCHEMA, "run_id": self.run_id, "status": QUEUED,
            "status_history": [{"status": QUEUED, "at": now}],
            "table": table, "spec": {"version": spec_version, "hash": spec_hash},
            "config": jsonable(dict(config or {})), "scale": scale, "dataset": dataset,
            "git": git_state(), "packages": package_versions(),
            "env": {"device": device, "dtype": dtype, "threads": threads,
                    "host": socket.gethostname(), "platform": platform.platform(),
                    "cpu": cpu_info(), "kernels": kernel_record(),
                    "pid": pid, "pid_start": _proc_start(pid),
                    **({} if gpu is None else {"gpu": gpu})},
            "command": list(command) if command is not None else list(sys.argv),
            "created": now, "started": None, "ended": None,
            "keys": {"read": [], "written": []}, "jobs": [], "error": None, "note": None,
            "extra": jsonable(dict(extra or {})),
        }
        self._write_run()

    # ------------------------------------------------------------------ state
    @property
    def status(self) -> str:
        return self._data["status"]

    @property
    def data(self) -> dict[str, Any]:
        """A copy of what ``run.json`` holds."""
        return json.loads(json.dumps(self._data))

    def _check_open(self) -> None:
        if self.status in TERMINAL:
            raise RuntimeError(f"run {self.run_id} is {self.status}; its record is read-only")

    def _transition(self, new: str) -> None:
        cur = self.status
        if new not in _NEXT.get(cur, set()):
            raise RuntimeError(f"run {self.run_id}: cannot go from {cur} to {new}")
        now = utc_now()
        self._data["status"] = new
        self._data["status_history"].append({"status": new, "at": now})
        if new == RUNNING:
            self._data["started"] = now
        if new in TERMINAL:
            self._data["ended"] = now

    # ------------------------------------------------------------------ writing
    def _write_run(self) -> None:
        atomic_write_json(self.path / RUN_JSON, self._data)
        self._reindex()

    def _reindex(self) -> None:
        if not self._index:
            return
        try:
            from repro.store.index import RunIndex

            RunIndex(runs_dir=self.runs_dir).update(self.path)
        except Exception as e:  # the index is derived; never lose a run over it
            log.warning("run index not updated for %s: %s", self.run_id, e)

    def start(self) -> None:
        self._transition(RUNNING)
        self._write_run()

    def record_job(self, rec: Mapping[str, Any]) -> None:
        """Add or replace (by key) a job line; hits go to ``keys.read``, computed to
        ``keys.written``."""
        self._check_open()
        rec = jsonable(dict(rec))
        jobs = [j for j in self._data["jobs"] if j.get("key") != rec.get("key")]
        jobs.append(rec)
        self._data["jobs"] = jobs
        status, key = rec.get("status"), rec.get("key")
        if key and status == "hit":
            self._add_keys(read=[key])
        elif key and status == "computed":
            self._add_keys(written=[key])
        self._write_run()

    def _add_keys(self, read: Iterable[str] = (), written: Iterable[str] = ()) -> None:
        keys = self._data["keys"]
        keys["read"] = sorted(set(keys["read"]) | set(read))
        keys["written"] = sorted(set(keys["written"]) | set(written))

    def add_keys(self, read: Iterable[str] = (), written: Iterable[str] = ()) -> None:
        """Record store keys this run read or wrote outside the executor."""
        self._check_open()
        self._add_keys(read, written)
        self._write_run()

    def add_extra(self, name: str, value: Any) -> None:
        """Set ``extra[name]`` (e.g. the real-data gate the run used, :mod:`repro.eval.gate`),
        written at once so a run that fails later still records it."""
        self._check_open()
        self._data["extra"][str(name)] = jsonable(value)
        self._write_run()

    def add_values(self, rows: Iterable[Mapping[str, Any]]) -> None:
        """Append value lines ``{row, column, replicate, value, ...}`` (file rewritten atomically)."""
        self._check_open()
        lines = [_value_line(r) for r in rows]
        self._values.extend(lines)
        body = "".join(json.dumps(v, sort_keys=True, ensure_ascii=False, allow_nan=False) + "\n"
                       for v in self._values)
        atomic_write_bytes(self.path / VALUES_JSONL, body.encode("utf-8"))
        self._reindex()

    def write_summary(self, summary: Mapping[str, Any]) -> None:
        self._check_open()
        atomic_write_json(self.path / SUMMARY_JSON, {**jsonable(dict(summary)),
                                                      "schema": SUMMARY_SCHEMA})
        self._reindex()

    def write_trainings(self, trainings: list) -> None:
        """``trainings.json``: every training of the run with its learning curve (per-epoch
        loss terms, validation error, steps), as :func:`repro.engine.tables.collect_trainings`
        returns them."""
        self._check_open()
        atomic_write_json(self.path / TRAININGS_JSON, {"schema": 1,
                                                        "trainings": jsonable(list(trainings))})

    def _close(self, status: str, *, error: str | None = None, note: str | None = None) -> None:
        self._transition(status)
        if error is not None:
            self._data["error"] = error
        if note is not None:
            self._data["note"] = note
        atomic_write_json(self.path / RUN_JSON, self._data)
        for p in self.path.iterdir():
            if p.is_file():
                os.chmod(p, _READ_ONLY)
        self._reindex()

    def finish(self) -> None:
        """RUNNING -> FINISHED; the folder's files become read-only."""
        self._close(FINISHED)

    def fail(self, error: str) -> None:
        """-> FAILED with ``error`` (no-op if the run already ended)."""
        if self.status not in TERMINAL:
            self._close(FAILED, error=str(error))

    def interrupt(self, note: str = "interrupted") -> None:
        """-> INTERRUPTED (no-op if the run already ended)."""
        if self.status not in TERMINAL:
            self._close(INTERRUPTED, note=note)

    def __enter__(self) -> RunRecorder:
        if self.status == QUEUED:
            self.start()
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            if self.status == RUNNING:
                self.finish()
        elif issubclass(exc_type, KeyboardInterrupt):
            self.interrupt()
        else:
            self.fail(f"{exc_type.__name__}: {exc}")


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
            os.chmod(p, _READ_ONLY)
    return True


def referenced_keys(runs_dir: str | Path | None = None) -> set[str]:
    """Every store key any run record read or wrote (what ``repro cache gc`` keeps)."""
    keys: set[str] = set()
    for d in run_dirs(runs_dir):
        try:
            data = read_run_json(d)
        except DataError as e:
            log.warning("skipping %s: %s", d, e)
            continue
        k = data.get("keys") or {}
        keys.update(k.get("read") or [])
        keys.update(k.get("written") or [])
        for j in data.get("jobs") or []:
            if j.get("key") and j.get("status") in ("hit", "computed"):
                keys.add(j["key"])
    return keys


def earliest_live_start(runs_dir: str | Path | None = None) -> str | None:
    """The creation time of the oldest run still in progress (its objects may not be recorded
    yet, so gc keeps everything created since)."""
    out = None
    for d in run_dirs(runs_dir):
        try:
            data = read_run_json(d)
        except DataError:
            continue
        if data["status"] in TERMINAL or reconcile_stale(d):
            continue
        t = data.get("created")
        if t and (out is None or t < out):
            out = t
    return out


def collect_garbage(store=None, *, dry_run: bool = False, include_scratch: bool = False,
                    runs_dir: str | Path | None = None):
    """``repro cache gc``: drop store objects no run record references (see
    :meth:`repro.store.objects.Store.gc`)."""
    from repro.store.objects import Store

    store = store or Store()
    return store.gc(referenced_keys(runs_dir), dry_run=dry_run,
                    keep_created_after=earliest_live_start(runs_dir),
                    include_scratch=include_scratch)
