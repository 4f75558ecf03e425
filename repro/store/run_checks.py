"""Shape checks of a run folder's files as read back (:func:`repro.store.run_files.read_run_json`,
:func:`~repro.store.run_files.read_values`).

A run folder is plain files anyone can edit, and one damaged record must not break the
commands about every other run (``repro runs ls`` indexes them all).  So what the readers
hand on is checked here, field by field, against what :class:`~repro.store.runs.RunRecorder`
writes: a field of the wrong type (a ``status`` that is a list, a ``replicate`` of 2^70, a
``value`` that is a dict, a lone surrogate anywhere) is one :class:`~repro.errors.DataError`
naming the file, the line when there is one, and the field.  Fields no reader depends on are
left as they are.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from repro.errors import DataError

#: every status a run record can hold
STATUSES = frozenset({"QUEUED", "RUNNING", "FINISHED", "FAILED", "INTERRUPTED"})
#: SQLite's INTEGER range (the index stores replicates and pids as such)
INT64 = 1 << 63
#: the largest process id Linux hands out (PID_MAX_LIMIT)
MAX_PID = 1 << 22

_STR_FIELDS = ("run_id", "table", "scale", "dataset", "created", "started", "ended", "error",
               "note")
_DICT_FIELDS = ("spec", "git", "env", "config", "extra", "packages", "keys")
_SUB_STR = {"spec": ("hash",), "git": ("commit", "diff_sha256"),
            "env": ("host", "device", "dtype", "platform", "pid_start")}


#: bytes read from one run folder's JSON record (``run.json``, ``summary.json``,
#: ``trainings.json``): real ones are kilobytes; a larger one is refused, not read
JSON_CAP = 16 << 20
#: bytes read from a run folder's ``values.jsonl`` (a real one is a few MiB at most)
VALUES_CAP = 256 << 20


def read_regular(f: Path, cap: int = JSON_CAP) -> bytes:
    """The bytes of ``f``, which must be a regular file of at most ``cap`` bytes
    (:func:`repro.data.sources.read_regular`: a FIFO planted at ``run.json`` would block every
    ``repro runs ls``; a sparse 3 GB ``values.jsonl`` would be read whole).  A missing file
    is FileNotFoundError (callers say what its absence means); anything else a DataError."""
    from repro.data.sources import read_regular as _read

    if not os.path.lexists(f):
        raise FileNotFoundError(f)
    return _read(Path(f), cap, Path(f).name)


def check_number(cfg: dict, key: str, f: Path, *, integer: bool = False) -> None:
    """``cfg[key]`` (a field of ``run.json``'s ``config``), when present, is a finite number
    (an integer with ``integer``): readers compare it as such (``repro show`` picks the run
    at the profile's budget and default evaluator seed)."""
    import math

    x = cfg.get(key)
    if x is None:
        return
    if isinstance(x, bool) or not isinstance(x, (int, float)) or \
            (integer and not isinstance(x, int)) or \
            (isinstance(x, float) and not math.isfinite(x)):
        raise DataError(f"field 'config.{key}' must be {'an integer' if integer else 'a finite number'}, "
                        f"not {_kind(x)}", file=f)
    if integer and not -INT64 <= x < INT64:
        raise DataError(f"field 'config.{key}' is beyond 2^63", file=f)


def check_summary(data: Any, f: Path) -> dict[str, Any]:
    """``summary.json`` (loaded) if it has the shape :func:`repro.engine.runner._summary`
    writes: an object whose ``rows`` is an object of objects and ``footer`` a list."""
    if not isinstance(data, dict):
        raise DataError(f"must be a JSON object, not {_kind(data)}", file=f)
    rows = data.get("rows")
    if rows is not None and (not isinstance(rows, dict) or
                             not all(isinstance(r, dict) for r in rows.values())):
        raise _bad(f, "rows", "an object of objects", rows)
    if data.get("footer") is not None and not isinstance(data["footer"], list):
        raise _bad(f, "footer", "a list", data["footer"])
    claims = data.get("claims")
    if claims is not None and (not isinstance(claims, list) or
                               not all(isinstance(c, dict) for c in claims)):
        raise _bad(f, "claims", "a list of objects", claims)
    _valid_unicode(data, f)
    return data


def _kind(x: Any) -> str:
    return {dict: "an object", list: "a list", str: "a string", bool: "a boolean",
            type(None): "null"}.get(type(x), "a number")


def _bad(f: Path, field: str, want: str, got: Any, line: int | None = None) -> DataError:
    return DataError(f"field {field!r} must be {want}, not {_kind(got)}", file=f, line=line)


def _valid_unicode(obj: Any, f: Path, line: int | None = None) -> None:
    """JSON ``\\ud800`` escapes load as lone surrogates, which cannot be printed or stored."""
    try:
        json.dumps(obj, ensure_ascii=False).encode("utf-8")
    except UnicodeEncodeError:
        raise DataError("holds a lone surrogate (\\ud800-\\udfff): not valid Unicode", file=f,
                        line=line) from None
    except (ValueError, RecursionError):
        raise DataError("nested too deeply", file=f, line=line) from None


def check_run_json(data: Any, f: Path, schema: int) -> dict[str, Any]:
    """``data`` (``run.json`` as loaded) if it has the shape a run record has, else a
    DataError naming ``f`` and the first field that is wrong."""
    if not isinstance(data, dict) or data.get("schema") != schema or "status" not in data:
        raise DataError(f"not a run record of schema {schema}", file=f)
    st = data["status"]
    if not isinstance(st, str) or st not in STATUSES:
        got = repr(st) if isinstance(st, str) and len(st) < 40 else _kind(st)
        raise DataError(f"field 'status' must be one of {', '.join(sorted(STATUSES))}, not "
                        f"{got}", file=f)
    _valid_unicode(data, f)
    for k in _STR_FIELDS:
        if data.get(k) is not None and not isinstance(data[k], str):
            raise _bad(f, k, "a string or null", data[k])
    for k in _DICT_FIELDS:
        if data.get(k) is not None and not isinstance(data[k], dict):
            raise _bad(f, k, "an object or null", data[k])
    cfg = data.get("config") or {}
    check_number(cfg, "budget", f)
    check_number(cfg, "evaluator_seed", f, integer=True)
    for k, subs in _SUB_STR.items():
        for s in subs:
            v = (data.get(k) or {}).get(s)
            if v is not None and not isinstance(v, str):
                raise _bad(f, f"{k}.{s}", "a string or null", v)
    pid = (data.get("env") or {}).get("pid")
    if pid is not None and (isinstance(pid, bool) or not isinstance(pid, int)
                            or not 0 <= pid < MAX_PID):
        raise DataError(f"field 'env.pid' must be a process id (0 to {MAX_PID - 1})", file=f)
    for k in ("jobs", "command", "status_history"):
        if data.get(k) is not None and not isinstance(data[k], list):
            raise _bad(f, k, "a list or null", data[k])
    for j in data.get("jobs") or []:
        if not isinstance(j, dict):
            raise _bad(f, "jobs[]", "an object", j)
        for s in ("key", "status", "kind"):
            if j.get(s) is not None and not isinstance(j[s], str):
                raise _bad(f, f"jobs[].{s}", "a string or null", j[s])
    for c in data.get("command") or []:
        if not isinstance(c, str):
            raise _bad(f, "command[]", "a string", c)
    for mode in ("read", "written"):
        ks = (data.get("keys") or {}).get(mode)
        if ks is not None and (not isinstance(ks, list) or
                               not all(isinstance(k, str) for k in ks)):
            raise _bad(f, f"keys.{mode}", "a list of strings", ks)
    return data


def check_value_line(v: Any, f: Path, line: int) -> dict[str, Any]:
    """One ``values.jsonl`` line (loaded) if it is a value row :func:`repro.store.runs.
    _value_line` could have written; ``value`` comes back as a float (or None)."""
    if not isinstance(v, dict) or not {"row", "column", "replicate", "value"} <= set(v):
        raise DataError("value line lacks row/column/replicate/value", file=f, line=line)
    for k in ("row", "column"):
        if not isinstance(v[k], str):
            raise _bad(f, k, "a string", v[k], line)
    rep = v["replicate"]
    if isinstance(rep, bool) or not isinstance(rep, int):
        raise _bad(f, "replicate", "an integer", rep, line)
    if not -INT64 <= rep < INT64:
        raise DataError("field 'replicate' is beyond 2^63", file=f, line=line)
    x = v["value"]
    if x is not None:
        if isinstance(x, bool) or not isinstance(x, (int, float)):
            raise _bad(f, "value", "a number or null", x, line)
        try:
            x = float(x)
        except OverflowError:
            raise DataError("field 'value' is beyond the float range", file=f,
                            line=line) from None
        v = {**v, "value": x}
    _valid_unicode(v, f, line)
    return v


_WARNED: set[str] = set()


def warn_bad_run(d: Path, e: Exception) -> None:
    """Say once per process that the damaged run folder ``d`` is skipped (``e`` why): a
    table's run is looked up often (:func:`repro.engine.runner.latest_run`)."""
    import sys

    if str(d) not in _WARNED:
        _WARNED.add(str(d))
        print(f"repro: warning: skipping run {d.name}: {e}", file=sys.stderr)
