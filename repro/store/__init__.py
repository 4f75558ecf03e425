"""Content-addressed store (``objects``) and run records (``runs`` writes them, ``run_files``
reads them back, ``index`` indexes them).

See ``docs/store.md``.  The names below are loaded lazily (PEP 562) so that importing one
submodule does not pull in the others (this keeps the source hash of job implementations that
use one of them small; see ``repro.engine.source_hash``).
"""

from __future__ import annotations

from repro.lazy_exports import lazy_getattr

_EXPORTS = {
    "Store": "objects", "StoredObject": "object_files", "ObjectInfo": "object_files",
    "CorruptObject": "object_files", "VerifyReport": "object_files", "GcReport": "object_files",
    "RunRecorder": "runs", "collect_garbage": "runs", "RunRecord": "run_files",
    "load_run": "run_files", "resolve_run": "run_files", "QUEUED": "run_files",
    "RUNNING": "run_files", "FINISHED": "run_files", "FAILED": "run_files",
    "INTERRUPTED": "run_files", "RunIndex": "index",
}
__all__ = sorted(_EXPORTS)
__getattr__ = lazy_getattr(__name__, _EXPORTS)
