"""One recipe for content keys: sha256 of canonical JSON (DVC-style).

Canonical means: keys sorted, no insignificant whitespace, tuples as lists, numpy scalars and
arrays as plain numbers/lists, floats written by ``repr`` (round-trip exact), NaN/inf refused.
Nothing that varies between identical computations (paths, timestamps, argument order) may be
part of what is hashed; callers pass only what can change a result.
"""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path
from typing import Any


def _normalise(obj: Any) -> Any:
    if isinstance(obj, dict):
        out = {}
        for k, v in obj.items():
            if not isinstance(k, str):
                raise TypeError(f"canonical JSON needs string keys, got {type(k).__name__}")
            out[k] = _normalise(v)
        return out
    if isinstance(obj, (list, tuple)):
        return [_normalise(v) for v in obj]
    if isinstance(obj, (set, frozenset)):
        return sorted(_normalise(v) for v in obj)
    if isinstance(obj, bool) or obj is None or isinstance(obj, str):
        return obj
    if isinstance(obj, int):
        return int(obj)
    if isinstance(obj, float):
        if not math.isfinite(obj):
            raise ValueError("canonical JSON refuses NaN and infinities")
        return obj
    # numpy scalars / arrays without importing numpy eagerly
    tolist = getattr(obj, "tolist", None)
    if callable(tolist):
        return _normalise(tolist())
    if hasattr(obj, "model_dump"):  # pydantic models
        return _normalise(obj.model_dump(mode="json"))
    if isinstance(obj, Path):
        raise TypeError("paths are not content; hash the file's bytes instead")
    raise TypeError(f"cannot canonicalise {type(obj).__name__}")


def canonical_json(obj: Any) -> bytes:
    """The canonical UTF-8 JSON encoding of ``obj`` (see module docstring)."""
    return json.dumps(
        _normalise(obj), sort_keys=True, separators=(",", ":"), ensure_ascii=False, allow_nan=False
    ).encode("utf-8")


def content_key(obj: Any) -> str:
    """sha256 hex digest of :func:`canonical_json` of ``obj``."""
    return hashlib.sha256(canonical_json(obj)).hexdigest()


def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def sha256_file(path: str | Path, chunk: int = 1 << 20) -> str:
    """sha256 hex digest of a file's bytes, read in chunks."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while True:
            b = f.read(chunk)
            if not b:
                break
            h.update(b)
    return h.hexdigest()
