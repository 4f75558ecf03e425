"""Content-addressed store (``objects``) and run records (``runs``, indexed by ``index``).

See ``docs/store.md``.  The names below are loaded lazily (PEP 562) so that importing one
submodule does not pull in the others (this keeps the source hash of job implementations that
use one of them small; see ``repro.engine.source_hash``).
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    "Store": "objects", "StoredObject": "objects", "ObjectInfo": "objects",
    "CorruptObject": "objects", "VerifyReport": "objects", "GcReport": "objects",
    "RunRecorder": "runs", "RunRecord": "runs", "load_run": "runs", "resolve_run": "runs",
    "collect_garbage": "runs", "QUEUED": "runs", "RUNNING": "runs", "FINISHED": "runs",
    "FAILED": "runs", "INTERRUPTED": "runs", "RunIndex": "index",
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(importlib.import_module(f"{__name__}.{_EXPORTS[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
