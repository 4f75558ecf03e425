"""Facts a table run records beside its job graph, stored by content so a rerun reads them
back: the real rows the real-data gate reads (:func:`real_rows_stored`) and what each
multi-action test set holds (:func:`test_sets_stored`, issue 26; Neural Marionette supp. §4.2).
Neither is a job: they depend on the data, the band's protocol and its evaluator, never on a
generator, so no job key changes with them."""

from __future__ import annotations

import json
from pathlib import Path

__all__ = ["real_rows_stored", "test_sets_stored"]


def real_rows_stored(e: dict, evaluator_key: str, ev, clips, load=None, stored=None) -> dict:
    """:func:`repro.eval.real_rows` of one evaluator, stored under a key made of everything
    they depend on: the evaluator's store key, the clips, the evaluator settings (sample
    counts), the profile's bootstrap resamples and the source of ``repro.eval.real``.
    ``ev`` may be a record without weights; ``load()`` then gives the scoring one, called
    only when the rows are not stored.  ``stored(key, hit)`` hears the object's key and whether
    it was found (a run record counts what it read and wrote)."""
    from repro.engine.source_hash import source_hash
    from repro.eval import real_rows
    from repro.eval.real import bootstrap_resamples
    from repro.keys import content_key
    from repro.store.objects import Store

    key = content_key({"schema": 1, "object": "real_rows", "evaluator": evaluator_key,
                       "clips": clips.fingerprint, "kind": e["kind"], "dataset": e["dataset"],
                       "scale": e["scale"], "settings": ev.settings.model_dump(mode="json"),
                       "bootstrap_resamples": bootstrap_resamples(e["scale"]),
                       "source": source_hash("repro.eval.real")})

    def compute(out: Path) -> None:
        scorer = ev if ev.module is not None or load is None else load()
        rows = real_rows(e["dataset"], e["scale"], seed=0, kind=e["kind"], evaluator=scorer,
                         clipset=clips)
        (out / "real_rows.json").write_text(json.dumps(rows, sort_keys=True))

    obj = Store().compute(key, "real_rows", compute)
    if stored is not None:
        stored(key, bool(obj.hit))
    return obj.read_json("real_rows.json")


def test_sets_stored(plan, stored=None) -> dict:
    """What each multi-action test set of the run holds (issue 26, supp. §4.2): the
    ``test_set_record`` of every band whose protocol draws test chains (``multi_action``,
    ``ss_ar``), merged by set name (``overall``, ``sufficient``).  A record depends on the
    data, the band's protocol parameters and version and its evaluator only (no job, no
    generator), and is stored by content like the real rows, so a rerun reads it back; the
    evaluator's weights are read only to compute it.  ``stored(key, hit)``: as for
    :func:`real_rows_stored`."""
    from repro.engine.source_hash import source_hash
    from repro.engine.steps import clipset, evaluator_for
    from repro.eval.protocols import get_protocol
    from repro.keys import content_key
    from repro.store.objects import Store

    out: dict = {}
    if plan.data_fingerprint is None:
        return out
    for b in plan.bands:
        if not b.implemented or b.evaluator_key is None:
            continue
        proto = get_protocol(b.protocol, b.params)
        if not hasattr(proto, "test_set_record"):
            continue
        key = content_key({"schema": 1, "object": "test_sets", "protocol": b.protocol,
                           "params": b.params, "version": b.version,
                           "evaluator": b.evaluator_key, "data": plan.data_fingerprint,
                           "source": source_hash(b.module, "repro.data.tag_chains")})

        def compute(path: Path, proto=proto, b=b) -> None:
            cfg = b.step_config(plan.dataset, with_evaluator=True)
            rec = proto.test_set_record(clipset(plan.dataset), evaluator_for(cfg))
            (path / "test_sets.json").write_text(json.dumps(rec, sort_keys=True))

        obj = Store().compute(key, "test_sets", compute)
        if stored is not None:
            stored(key, bool(obj.hit))
        rec = obj.read_json("test_sets.json")
        for name, stats in sorted(rec.items()):
            out.setdefault(name, stats)
    return out
