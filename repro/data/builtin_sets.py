"""The data sets the harness itself knows, by name: the stand-ins, their sequence views and the
papers' data sets, and the command that prepares a stand-in.

These are the names a user's data-set spec may not take (:func:`builtin_names`, checked by
:func:`repro.data.dataset_spec.load_dataset_spec`).  The registry (:mod:`repro.data.registry`)
registers the stand-ins and the papers' entries (:func:`upstream_entries`); the views are
composed by :mod:`repro.data.sequence_views`.  Nothing here imports those modules, so the spec
loader and the cache readers below the registry can use it.
"""

from __future__ import annotations

#: The stand-ins :mod:`repro.data.registry` registers (its built-in entries).
STANDINS = ("bandai2", "bandai2-mini")
#: Sequence views: name → source data set (not registered data sets; see docs/data.md).
SEQUENCE_VIEWS = {"bandai2-seq": "bandai2", "bandai2-seq-mini": "bandai2-mini"}


def upstream_entries() -> list:
    """The :class:`~repro.data.dataset_entry.DatasetEntry` of each paper data set that
    :mod:`repro.data.upstream` lists (``ENTRIES``), when that module is present."""
    import importlib

    try:
        mod = importlib.import_module("repro.data.upstream")
    except ModuleNotFoundError as e:
        if e.name == "repro.data.upstream":
            return []
        raise
    if getattr(mod, "__file__", None) is None:  # a bare folder (namespace package): no entries
        return []
    return list(mod.ENTRIES)


def builtin_names() -> set[str]:
    """Names a user's data-set spec may not take: the stand-ins, their sequence views and the
    papers' data sets."""
    from repro.specs.names import DATASETS as KNOWN

    return ({*STANDINS} | {e.name for e in upstream_entries()} | set(SEQUENCE_VIEWS)
            | set(KNOWN))


def standin_prepare_command(name: str = "bandai2") -> str:
    """The exact command that prepares the stand-in ``name`` from the Bandai-Namco archive (for
    error messages; :func:`repro.data.dataset_registration.prepare_command` names a declared
    data set's instead)."""
    from repro.paths import BANDAI_ARCHIVE_NAME, find_bandai_archive, shared_data_dir

    src = find_bandai_archive() or (shared_data_dir() / BANDAI_ARCHIVE_NAME)
    return f"repro data prepare {name} --source {src}"
