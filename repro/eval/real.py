"""The "Real" rows every table has: the metrics of real motions, with intervals.

For each replicate ``r`` (seeded by ``(seed, r)``), following ODMO's real reference sets
(protocols.md §3.2: a class-balanced draw of ``per_class`` windows per class, with
replacement, random starts) and the A2M metric core (§1):

- ``fid_train``: FID between the features of a real *test* set and of a real *train* set
  (the FID_train of real data: the floor a perfect generator reaches against the training
  reference);
- ``fid_test``: FID between two independent real test sets (MultiAct's "Real_test_sampled");
- ``accuracy`` / ``accuracy_top5``: recogniser accuracy on the real test set;
- ``diversity`` (200 pairs) and ``multimodality`` (20 pairs per class) of the real test set;
- ``n_apd``: n-APD of the real test set against itself, 100 by construction (ODMO's real
  row, §3.6: real file i is paired with real file i).

Each metric keeps its per-replicate values, the mean, the paper-style ± (convention
``real.ci_method``, :mod:`repro.stats.intervals`) and a bootstrap interval over replicates
(``real.bootstrap``).  Units: FID in squared feature units, diversity/multimodality in feature
units, accuracy as a fraction, n-APD in %.
"""

from __future__ import annotations

import math

import numpy as np

from repro.data.clipset import TEST, TRAIN
from repro.errors import DataError
from repro.eval.sampling import per_class_windows
from repro.seeding import derive_seed, numpy_rng

METRICS = ("fid_train", "fid_test", "accuracy", "accuracy_top5", "diversity", "multimodality", "n_apd")


def _summary(values: list[float], method: str, bootstrap: str, n_boot: int, seed: int) -> dict:
    from repro.stats.bootstrap import bootstrap_ci
    from repro.stats.intervals import paper_halfwidth

    v = np.asarray(values, dtype=np.float64)
    pm = paper_halfwidth(v, method)
    lo, hi = bootstrap_ci(v, method=bootstrap, n_boot=n_boot, seed=seed)
    return {"values": [float(x) for x in v], "mean": float(v.mean()),
            "sd": float(v.std(ddof=1)) if v.size > 1 else 0.0,
            "pm": None if pm is None else float(pm), "pm_method": method,
            "ci": [float(lo), float(hi)], "ci_method": bootstrap}


def bootstrap_resamples(scale: str) -> int:
    """The profile's ``bootstrap_resamples`` (1,000 when there is no scales.toml)."""
    from repro.specs.scales import resolve_scale, scales_path

    if scale and scales_path().is_file():
        return int(resolve_scale(scale).bootstrap_resamples)
    return 1000


def real_replicate(evaluator, clipset, per_class: int, seed: int, r: int) -> dict[str, float]:
    """The metrics of one replicate (see the module docstring)."""
    from repro.metrics.accuracy import accuracy
    from repro.metrics.apd import n_apd
    from repro.metrics.diversity import diversity, multimodality
    from repro.metrics.fid import fid

    st = evaluator.settings
    rng = numpy_rng(seed, "real-rows", r)
    test_pool, train_pool = clipset.indices(split=TEST), clipset.indices(split=TRAIN)
    te = per_class_windows(clipset, test_pool, per_class, st.window, rng, include_last=st.include_last)
    te2 = per_class_windows(clipset, test_pool, per_class, st.window, rng, include_last=st.include_last)
    tr = per_class_windows(clipset, train_pool, per_class, st.window, rng, include_last=st.include_last)
    h = derive_seed(seed, "real-rows-h0", r)
    f_te, lg_te = evaluator.encode(te[0], te[1], seed=h)
    f_te2 = evaluator.features(te2[0], te2[1], seed=derive_seed(h, "second test set"))
    f_tr = evaluator.features(tr[0], tr[1], seed=derive_seed(h, "train set"))
    y = te[2]
    c = evaluator.n_classes
    return {
        "fid_train": fid(f_te, f_tr).value,
        "fid_test": fid(f_te, f_te2).value,
        "accuracy": accuracy(lg_te, y, top_k=1).value,
        "accuracy_top5": accuracy(lg_te, y, top_k=min(5, c)).value,
        "diversity": diversity(f_te, seed=derive_seed(seed, "diversity", r)),
        "multimodality": multimodality(f_te, y, c, seed=derive_seed(seed, "multimodality", r)),
        "n_apd": n_apd(te[0], y, te[0], y, c),
    }


def real_rows(dataset: str, scale: str = "medium", replicates: int | None = None, seed: int = 0, *,
              kind: str = "a2m_gru", heading: str | None = None, evaluator=None, clipset=None,
              settings=None, evaluator_seed: int = 0) -> dict:
    """The real rows of ``dataset`` (module docstring) as a JSON-able dict.

    ``evaluator``/``clipset``/``settings`` may be given (tests, the engine); otherwise they
    come from :func:`repro.eval.provider.get_evaluator` (training seed ``evaluator_seed``),
    the data-set registry and the scale profile.
    """
    from repro.eval.provider import check_kind, get_evaluator, load_dataset
    from repro.eval.settings import resolve_settings

    if settings is None:
        settings = evaluator.settings if evaluator is not None else \
            resolve_settings(scale, {"heading": heading} if heading else None)
    rs = settings.real
    reps = int(replicates or rs.replicates)
    if reps < 2:
        raise DataError(f"real rows need at least 2 replicates for an interval, got {reps}")
    if clipset is None:
        clipset = load_dataset(dataset)
    if evaluator is None:
        evaluator = get_evaluator(dataset, check_kind(kind), scale, seed=evaluator_seed,
                                  clipset=clipset, settings=settings)
    for split, name in ((TEST, "test"), (TRAIN, "train")):
        present = np.unique(clipset.labels[clipset.indices(split=split)])
        if present.size != clipset.n_classes:
            missing = sorted(set(range(clipset.n_classes)) - set(present.tolist()))
            raise DataError(f"data set {dataset!r}: the {name} split lacks "
                            f"{'class' if len(missing) == 1 else 'classes'} "
                            f"{', '.join(clipset.label_names[c] for c in missing)} (by index "
                            f"{missing}); drop them ([labels] classes in the data set's spec) "
                            "or give them more clips")
    per_rep = [real_replicate(evaluator, clipset, rs.per_class, seed, r) for r in range(reps)]
    n_boot = bootstrap_resamples(scale)
    metrics = {m: _summary([p[m] for p in per_rep], rs.ci_method, rs.bootstrap, n_boot,
                           derive_seed(seed, "bootstrap", m))
               for m in METRICS}
    bad = [m for m, s in metrics.items() if not all(math.isfinite(x) for x in s["values"])]
    test = dict(evaluator.meta.get("test", {}))
    return {
        "dataset": dataset,
        "scale": scale,
        "seed": int(seed),
        "replicates": reps,
        "per_class": rs.per_class,
        "n_classes": clipset.n_classes,
        "window": settings.window,
        "data_fingerprint": clipset.fingerprint,
        "evaluator": {
            "fingerprint": evaluator.fingerprint,
            "kind": evaluator.kind,
            "describe": evaluator.describe(),
            "hidden_init": settings.hidden_init if evaluator.kind != "transformer" else None,
            "heading": settings.heading,
            "test_top1": test.get("top1"),
            "test_top5": test.get("top5"),
            "test_windows": test.get("n_windows"),
        },
        "intervals": {"pm": rs.ci_method, "bootstrap": rs.bootstrap, "resamples": n_boot},
        "gate": {"margin": rs.gate_margin, "max_fid": rs.max_fid},
        "nonfinite": bad,
        "rows": {"real": metrics},
    }
