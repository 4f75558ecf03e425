"""The sequence views ``bandai2-seq`` and ``bandai2-seq-mini``: the default composition
(:mod:`repro.data.sequences`) of a stand-in clip set under Neural Marionette's test split, named
so that a reader can prepare, fingerprint and inspect it (``repro data prepare|info``;
``docs/data.md``, "Views, files and CLI")."""

from __future__ import annotations

import difflib
import io
import json

import numpy as np

from repro.data.builtin_sets import SEQUENCE_VIEWS  # name → source data set (docs/data.md)
from repro.data.clipset import ClipSet
from repro.data.sequence_card import card_of
from repro.data.sequences import (CARD_SCHEMA, COMPOSE_VERSION, ComposeConfig, SequenceSet,
                                  sequences_for)
from repro.errors import ConfigError

__all__ = ["SEQUENCE_VIEWS", "load_view", "view_dir", "prepare_view", "view_card",
           "view_status"]

_POINTER = "current.json"


def _check_view(name: str) -> str:
    if name not in SEQUENCE_VIEWS:
        near = difflib.get_close_matches(name, list(SEQUENCE_VIEWS), n=1)
        hint = f"; did you mean {near[0]!r}?" if near else ""
        raise ConfigError(f"unknown sequence view {name!r}{hint} "
                          f"(known: {', '.join(SEQUENCE_VIEWS)})")
    return SEQUENCE_VIEWS[name]


def _view_source(name: str) -> ClipSet:
    from repro.data.registry import load_clipset
    from repro.data.splits import marionette_clipset

    return marionette_clipset(load_clipset(_check_view(name)))


def load_view(name: str) -> SequenceSet:
    """The sequence view ``name``: its source ClipSet (registry) with Neural Marionette's test
    split (:func:`repro.data.splits.marionette_clipset`, seed 0, 20 % capped at 100 per class),
    composed with the default :class:`ComposeConfig`.  A missing source raises the registry's
    MissingDataError (naming ``repro data prepare bandai2``)."""
    return sequences_for(_view_source(name), ComposeConfig(), name=name)


def view_dir(name: str):
    """Folder of a prepared view: ``datasets_root()/<name>/``."""
    from repro.data.cache import dataset_dir

    _check_view(name)
    return dataset_dir(name)


def _npz_bytes(arrays: dict) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **{k: np.ascontiguousarray(v) for k, v in arrays.items()})
    return buf.getvalue()


def prepare_view(name: str) -> dict:
    """Compose view ``name`` and write ``<view_dir>/<fingerprint>/{sequences.npz, card.json}``
    (index arrays and card, each atomically) and the ``current.json`` pointer.  Returns
    ``{"path", "fingerprint", "reused", "seconds", "card"}``."""
    import time

    from repro.store.atomic import atomic_write_bytes, atomic_write_json

    t0 = time.perf_counter()
    seqs = load_view(name)
    card = card_of(seqs)
    root = view_dir(name)
    folder = root / seqs.fingerprint
    reused = False
    try:
        reused = json.loads((folder / "card.json").read_text()) == card \
            and (folder / "sequences.npz").is_file()
    except (OSError, ValueError):
        reused = False
    if not reused:
        meta = {"schema": np.array(CARD_SCHEMA), "fingerprint": np.array(seqs.fingerprint)}
        atomic_write_bytes(folder / "sequences.npz", _npz_bytes({**seqs.index_arrays(), **meta}))
        atomic_write_json(folder / "card.json", card)
    atomic_write_json(root / _POINTER, {"fingerprint": seqs.fingerprint})
    return {"path": str(folder), "fingerprint": seqs.fingerprint, "reused": reused,
            "seconds": round(time.perf_counter() - t0, 3), "card": card}


def _stored_card(name: str) -> dict | None:
    root = view_dir(name)
    try:
        fp = json.loads((root / _POINTER).read_text())["fingerprint"]
        card = json.loads((root / str(fp) / "card.json").read_text())
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return card if isinstance(card, dict) and card.get("schema") == CARD_SCHEMA else None


def view_card(name: str) -> dict:
    """The card of view ``name``: the prepared one when it still matches the source, the
    compose version and the default config; otherwise composed now."""
    src = _view_source(name)
    card = _stored_card(name)
    if (card is not None and card.get("compose_version") == COMPOSE_VERSION
            and card.get("source", {}).get("fingerprint") == src.fingerprint
            and card.get("config") == ComposeConfig().model_dump(mode="json")):
        return card
    return card_of(sequences_for(src, ComposeConfig(), name=name))


def view_status(name: str):
    """A :class:`repro.data.registry.DatasetStatus` for a view: ready when its source is;
    ``fingerprint`` is the prepared view's (``None`` if not prepared)."""
    from repro.data.registry import DatasetStatus, get_entry

    st = get_entry(_check_view(name)).status()
    card = _stored_card(name)
    return DatasetStatus(st.prepared, str(view_dir(name)),
                         card.get("fingerprint") if card else None,
                         None if st.prepared else f"source {SEQUENCE_VIEWS[name]} is not ready: "
                         f"{st.missing}")
