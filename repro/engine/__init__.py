"""Jobs, content keys, plans and the local executor (see ``docs/store.md``).

A table's graph is built from :class:`Job` objects; :func:`plan` says what would run and why,
:func:`execute` runs it through the content-addressed store.  Names are loaded lazily (PEP 562)
so that a job implementation importing ``repro.engine.job`` does not have the executor's source
in its key.
"""

from __future__ import annotations

from repro.lazy_exports import lazy_getattr

_EXPORTS = {
    "Job": "job", "JobContext": "job", "topo_order": "job",
    "execute": "executor", "ExecutionReport": "executor", "JobResult": "executor",
    "ProgressHook": "executor", "plan": "plan", "PlanEntry": "plan", "explain": "plan",
    "source_hash": "source_hash", "source_manifest": "source_hash",
    "clear_source_cache": "source_hash", "RichProgressHook": "progress",
}
__all__ = sorted(_EXPORTS)
__getattr__ = lazy_getattr(__name__, _EXPORTS)
