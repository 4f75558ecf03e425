"""Before any training: does each protocol's split give every class the clips it needs?
(issue 28)

A table's protocols split the data set their own way (docs/datasets.md, "Which split each
table uses"): Neural Marionette's tables by its per-class rule (``min(cap, round(f·n))`` test
clips per class, :func:`repro.data.splits.marionette_split`, unless the protocol's ``split =
"dataset"``), MultiAct's and ODMO's by the data set's stored split.  The evaluator trains on
that split and the Real rows and the scored test items read it, so a class without a training
clip, or without a test clip where the table reads the test side, used to surface only after
the evaluator had trained (about 9 minutes on a small set: "the test split lacks classes [10,
11, ...]").  :func:`check_protocol_splits` makes the same splits from the labels alone
(:func:`repro.engine.steps.evaluator_split`, the split ``build_plan`` already derived) and
refuses with the classes by name, their clip counts and the fix; ``repro plan`` and ``repro
run`` call it right after the plan is built.
"""

from __future__ import annotations

import numpy as np

from repro.errors import DataError


def split_rule(proto) -> tuple[str, str, int | None]:
    """(how ``proto`` splits the clips, the fix for a class short of test clips, the fewest
    clips a class needs for a test clip under the rule, or None: the data set's own)."""
    from repro.data.dataset_clips import min_clips_for_test

    src = proto.item_source() if hasattr(proto, "item_source") else None
    if getattr(src, "split", None) == "marionette":
        f, cap = float(src.test_fraction), int(src.test_cap_per_class)
        need = min_clips_for_test(f)
        return (f"Neural Marionette's per-class split (min({cap}, round({f:g} × n)) of a "
                f"class's n clips go to test, so a class needs at least {need} clips)",
                "drop the class (list only the others in [labels] classes of the data set's "
                f"spec) or give it at least {need} clips", need)
    return ("the data set's own split ([split] of its spec, as prepared)",
            "change the data set's [split] (e.g. by = \"style\" or \"subject\" with stratify = "
            "\"action\": whole groups, every action on both sides), or drop the class ([labels] "
            "classes), then `repro data prepare` it again", None)


def needs_test_side(proto, plan) -> bool:
    """Whether the table reads the test side of ``proto``'s split: a Real row, or a protocol
    that scores test items (ODMO's reads it only when ``fid_references`` names "test")."""
    if any(getattr(rp, "method", None) == "real" for rp in plan.rows):
        return True
    refs = getattr(getattr(proto, "params", None), "fid_references", None)
    return refs is None or "test" in refs


def split_shortfalls(labels, split, names, *, test: bool = True) -> dict[str, list[int]]:
    """{"test": [...], "train": [...]}: the class ids without a clip on that side (the test
    side only when ``test``)."""
    from repro.data.clipset import TEST, TRAIN

    labels, split = np.asarray(labels), np.asarray(split)
    sides = (("train", TRAIN),) + ((("test", TEST),) if test else ())
    return {side: [c for c in range(len(names)) if not ((labels == c) & (split == v)).any()]
            for side, v in sides}


def check_protocol_splits(plan) -> None:
    """DataError (before anything is computed) when a band's protocol split leaves a class
    of ``plan``'s data set without a training clip, or without a test clip where the table
    reads one (module docstring); nothing when the data set is not prepared (its rows say
    so)."""
    if plan.data_fingerprint is None or plan.data_missing is not None:
        return
    from repro.engine.steps import clipset, evaluator_split
    from repro.eval.protocols import get_protocol

    clips, problems, seen = None, [], set()
    for b in plan.bands:
        if not b.implemented:
            continue
        proto = get_protocol(b.protocol, b.params)
        clips = clips or clipset(plan.dataset)
        split = evaluator_split(proto, clips)
        rule, fix, _ = split_rule(proto)
        test = needs_test_side(proto, plan)
        if (rule, split.fingerprint, test) in seen:
            continue
        seen.add((rule, split.fingerprint, test))
        counts = np.bincount(np.asarray(split.labels), minlength=split.n_classes)
        for side, missing in split_shortfalls(split.labels, split.split, split.label_names,
                                              test=test).items():
            if missing:
                names = ", ".join(f"{split.label_names[c]!r} ({int(counts[c])} clip"
                                  f"{'' if counts[c] == 1 else 's'})" for c in missing)
                problems.append(f"protocol {b.protocol}: {rule} leaves {names} without a "
                                f"{'training' if side == 'train' else 'test'} clip; fix: {fix}")
    if problems:
        raise DataError(f"{plan.spec.id} on data set {plan.dataset!r}: " + "; ".join(problems))
