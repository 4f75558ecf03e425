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

This module writes a run (:class:`RunRecorder`, which keeps the index of
:mod:`repro.store.index` up to date) and collects garbage; the files' names, the statuses and
reading a run folder back live in :mod:`repro.store.run_files`, under the index.
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
import subprocess
import sys
from collections.abc import Iterable, Mapping
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from repro.errors import DataError
from repro.kernels import cpu_description, record as kernel_record
from repro.store.atomic import atomic_write_bytes, atomic_write_json, jsonable, utc_now
# the run folder's files and reading them back (below the index this recorder updates); their
# names stay importable from here
from repro.store.run_files import (FAILED, FINISHED, INTERRUPTED, QUEUED,  # noqa: F401
                                   READ_ONLY, RUN_JSON, RUN_SCHEMA, RUNNING, SUMMARY_JSON,
                                   SUMMARY_SCHEMA, TERMINAL, TRAININGS_JSON, VALUES_JSONL,
                                   VALUES_SCHEMA, RunRecord, load_run, process_alive,
                                   process_start, read_run_json, read_summary, read_trainings,
                                   read_values, reconcile_stale, resolve_run, run_dirs)

_NEXT = {QUEUED: {RUNNING, FAILED, INTERRUPTED}, RUNNING: {FINISHED, FAILED, INTERRUPTED}}
PACKAGES = ("torch", "numpy", "scipy", "scikit-learn", "roma", "pydantic", "repro")

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
                    "pid": pid, "pid_start": process_start(pid),
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
                os.chmod(p, READ_ONLY)
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
