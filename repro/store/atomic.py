"""Atomic file writes: temp file in the same folder, fsync, ``os.replace``.

A reader never sees half a file: either the old bytes or the new ones.  Used for every file
the store and the run records persist (manifests, ``run.json``, ``values.jsonl``, ...).
"""

from __future__ import annotations

import json
import math
import os
import secrets
from datetime import datetime, timezone
from pathlib import Path
from typing import Any


def utc_now() -> str:
    """The current UTC time as ISO 8601 with microseconds and a ``Z`` suffix."""
    return datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def fsync_dir(path: Path) -> None:
    """Make a rename inside ``path`` durable (no-op where directories cannot be opened)."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def atomic_write_bytes(path: str | Path, data: bytes, *, mode: int | None = None) -> None:
    """Write ``data`` to ``path`` atomically (temp file beside it, fsync, rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.parent / f".{path.name}.tmp-{os.getpid()}-{secrets.token_hex(4)}"
    try:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        if mode is not None:
            os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    fsync_dir(path.parent)


def jsonable(obj: Any) -> Any:
    """Plain-JSON form of ``obj``: numpy scalars/arrays to numbers/lists, tuples to lists,
    non-finite floats to ``None`` (JSON has no NaN), paths to strings."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, (set, frozenset)):
        return sorted(jsonable(v) for v in obj)
    if isinstance(obj, bool) or obj is None or isinstance(obj, (str, int)):
        return obj
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, Path):
        return str(obj)
    tolist = getattr(obj, "tolist", None)
    if callable(tolist):
        return jsonable(tolist())
    if hasattr(obj, "model_dump"):
        return jsonable(obj.model_dump(mode="json"))
    raise TypeError(f"cannot write {type(obj).__name__} as JSON")


def dumps(obj: Any, *, indent: int | None = 2) -> str:
    """JSON text of :func:`jsonable` ``obj`` with sorted keys (stable, diff-friendly)."""
    return json.dumps(jsonable(obj), indent=indent, sort_keys=True, ensure_ascii=False, allow_nan=False)


def atomic_write_json(path: str | Path, obj: Any, *, mode: int | None = None) -> None:
    atomic_write_bytes(path, (dumps(obj) + "\n").encode("utf-8"), mode=mode)
