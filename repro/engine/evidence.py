"""What decided a claim (issue 11): the variance inside the intervals, the training budget
against the paper's, and the evaluator; and the verdict that evidence allows.

**Training budget.** A row's budget is its optimisation steps over the steps the paper's
stated settings (the ``paper`` scale profile: epochs and batch size of the method, or of the
method it trains as) would take *on the same training set*:

    budget = epochs · ⌈S / b⌉  /  (E_paper · ⌈S / b_paper⌉),

with S the training samples per epoch (items, from the training record's ``n_train``; MANN,
which drops the last partial batch: frame pairs, ``batches × b``) or, for a record without
them, the same ratio with S cancelled, ``(epochs / b) / (E_paper / b_paper)``.  The paper's own
data set is not here (the stand-in is), so "the paper's budget" means the paper's schedule
applied to the data at hand; a method without epochs (the retrieval reference) has no budget.
Only MarioNet's schedule is stated by Neural Marionette (supp. Sec. 3); its baselines' are the
harness's assumptions from their own papers and code (:data:`SCHEDULES`), and Action2Motion's
is stated in iterations (50,000), so its paper budget is that many steps.

**Verdict.**  A posterior verdict of "contradicted" is only printed as such when the run can
refute the claim: every trained row involved at (at least) the paper's budget, with the
paper's model (the ``paper`` scale profile, not a smaller width at more epochs), *and* the
intervals holding training-seed variance (``--retrain``).  Otherwise it reads, by the first
condition that fails,

- ``not reproduced at this budget`` when some involved row trained for less than the paper's
  budget (the claim may still hold with the paper's optimisation);
- ``not reproduced (paper budget unknown)`` when the paper states no schedule for a row;
- ``not reproduced (reduced model)`` at a scale other than ``paper``;
- ``not reproduced (sampling variance only)`` without ``--retrain`` (one training per row: a
  different training seed could reverse the ordering).

"supported" and "inconclusive" are kept as they are; every verdict carries its evidence line.

**Convergence** (issue 32).  Where every training of every trained row a claim involves was
trained until the convergence rule fired (a profile with ``until = "plateau"``, e.g.
``converged``; :mod:`repro.train.plateau`), the budget and model-size conditions above no longer
decide: the comparison is between models that stopped improving on this data.  "supported" and
"contradicted" then read "supported at convergence on the stand-in" (or "on <name> (own
data)"), with "(sampling variance only)" appended when the intervals hold one training per row
(no ``--retrain``).  A fixed-epoch training records whether the rule fired in its
``training.json`` (``repro runs show``) but never counts as converged here, so the verdicts of
the fixed-budget profiles (and their regression baselines) keep their meaning.  The evidence's
``converged`` is None for a claim without a trained row.
"""

from __future__ import annotations

import math
from functools import lru_cache

from repro.train.epochs import config_epochs

NOT_REPRODUCED_BUDGET = "not reproduced at this budget"
NOT_REPRODUCED_UNKNOWN = "not reproduced (paper budget unknown)"
NOT_REPRODUCED_REDUCED = "not reproduced (reduced model)"
NOT_REPRODUCED_SAMPLING = "not reproduced (sampling variance only)"
CONTRADICTED = "contradicted"
SUPPORTED = "supported"
#: the words a verdict gains when every training it compares reached its plateau (issue 32)
AT_CONVERGENCE = "at convergence"
PAPER_SCALE = "paper"

#: where each method's "paper schedule" comes from (the ``paper`` profile, tables/scales.toml);
#: ``steps``: a schedule stated in optimisation steps rather than epochs
SCHEDULES: dict[str, dict] = {
    "marionet": {"source": "stated: Neural Marionette supp. Sec. 3 (1,000 epochs, batch 30)"},
    "mann": {"source": "assumed: MANN's own settings (150 epochs, batch 32); NM states none",
             "assumed": True},
    "a2m": {"source": "assumed: Action2Motion's 50,000 iterations; NM states none",
            "assumed": True, "steps": 50_000},
    "actor": {"source": "assumed: ACTOR's UESTC command (1,000 epochs, batch 20; its HumanAct12 "
              "command trains 5,000); neither NM nor MultiAct states one", "assumed": True},
    "macvae": {"source": "stated: MultiAct supp. 'Implementation details' (1,300 epochs, batch "
               "16; the released code trains 1,200)"},
    "ssmct": {"source": "assumed: the harness's paper-scale SSMCT schedule; MultiAct states none",
              "assumed": True},
    "odmo": {"source": "the reference code: 100,000 epochs of 2,048 pairs in batches of 512 "
             "(protocols.md §3.9); the paper states none", "steps": 400_000},
    "dlow_gen": {"source": "stated: ODMO supp. §2.4 (5,000 VAE and 600 DLow epochs; epochs of "
                 "2,048 windows in DLow's batches of 64 are our reading)", "steps": 179_200},
    "act_mocogan": {"source": "assumed: MoCoGAN's 100,000 iterations; ODMO states none",
                    "assumed": True, "steps": 100_000},
}

#: the method-config fields that count epochs; a budget factor scales all of them together,
#: so a schedule keeps its shape (MarioNet's scheduled sampling, MANN's warm restarts)
EPOCH_FIELDS = ("epochs", "ss_activate_epoch", "ss_accomplish_epoch", "restart_period",
                "vae_epochs", "dlow_epochs", "tf_decay_epochs")
@lru_cache(maxsize=None)
def _paper_scale():
    from repro.specs.scales import resolve_scale

    return resolve_scale("paper")


def paper_method_config(method: str) -> dict:
    """The paper scale profile's settings of ``method`` (empty when it states none)."""
    try:
        return dict(_paper_scale().method_config(method))
    except Exception:  # an unknown method or a missing profile: no paper budget to compare
        return {}


def scale_epochs(config: dict, factor: float) -> dict:
    """``config`` with every epoch count (:data:`EPOCH_FIELDS`) multiplied by ``factor``
    (rounded half up; at least one epoch; a restart period of at least one, and equal to the
    epochs when it was, so a one-cycle schedule stays one cycle; MarioNet's scheduled sampling
    kept inside the training, its warm-up at least one epoch when it had one).
    ``factor == 1`` returns ``config`` unchanged, so the ×1 point of a budget sweep is the
    plain run's jobs."""
    if factor == 1:
        return dict(config)
    out = dict(config)
    for k in EPOCH_FIELDS:
        v = out.get(k)
        if isinstance(v, int) and not isinstance(v, bool):
            out[k] = int(math.floor(v * factor + 0.5))
    if "epochs" in out and isinstance(out["epochs"], int):
        out["epochs"] = max(1, out["epochs"])
        if out.get("restart_period") is not None:
            out["restart_period"] = (out["epochs"] if config.get("restart_period") ==
                                     config.get("epochs") else max(1, out["restart_period"]))
        if "ss_activate_epoch" in out and "ss_accomplish_epoch" in out:
            a = min(max(1 if config["ss_activate_epoch"] >= 1 else 0,
                        out["ss_activate_epoch"]), out["epochs"])
            out["ss_activate_epoch"] = a
            out["ss_accomplish_epoch"] = min(max(a, out["ss_accomplish_epoch"]), out["epochs"])
    return out


def training_budget(train_method: str, method_config: dict, training: dict | None) -> dict | None:
    """A row's budget against the paper's (module docstring), or None for a method that does
    not train by epochs.  Keys: ``fraction`` (None when the paper states no schedule),
    ``epochs``, ``paper_epochs``, ``steps``, ``paper_steps`` (None when S is unknown)."""
    epochs, batch = config_epochs(method_config), method_config.get("batch_size")
    if not epochs:
        return None
    paper = paper_method_config(train_method)
    pe, pb = config_epochs(paper), paper.get("batch_size")
    sched = SCHEDULES.get(train_method, {})
    out = {"method": train_method, "epochs": int(epochs), "paper_epochs": pe, "steps": None,
           "paper_steps": None, "fraction": None, "schedule": sched.get("source"),
           "assumed": bool(sched.get("assumed"))}
    if sched.get("steps") and not training:  # no record yet: the planned steps
        wpe = method_config.get("windows_per_epoch")
        if wpe:
            steps = int(epochs) * math.ceil(int(wpe) / int(batch))
            out.update(steps=steps, paper_steps=int(sched["steps"]),
                       fraction=steps / int(sched["steps"]))
            return out
    if not pe or not pb or not batch:
        return out
    training = training or {}
    hist = training.get("history") or []
    first = hist[0].get("batches") if hist and isinstance(hist[0], dict) else None
    if first:
        n = training.get("n_train")
        # items when every item is in a batch (ceil); else (MANN: frame pairs, the last
        # partial batch dropped) the samples the batches hold
        samples = int(n) if n and int(first) == math.ceil(int(n) / int(batch)) \
            else int(first) * int(batch)
        steps = sum(int(h.get("batches", first)) for h in hist if isinstance(h, dict))
        paper_steps = int(sched["steps"]) if sched.get("steps") else \
            int(pe) * math.ceil(samples / int(pb))
        out.update(steps=steps, paper_steps=paper_steps, fraction=steps / paper_steps)
    else:
        out["fraction"] = (int(epochs) / int(batch)) / (int(pe) / int(pb))
    return out


def _pct(f: float) -> str:
    p = 100.0 * f
    if 99.5 <= p < 100.0:  # below the budget must never read as 100 %
        return "<100%"
    return f"{p:.2g}%" if p < 10 else f"{p:.0f}%"


def budget_text(b: dict, short: bool = False) -> str:
    """``marionet 2% (140 of 7,000 steps)``; ``short``: ``marionet 2%``."""
    if b.get("fraction") is None:
        return f"{b['method']} {b['epochs']} epochs (the paper states no schedule)"
    s = f"{b['method']} {_pct(b['fraction'])}" + ("*" if b.get("assumed") else "")
    if short:
        return s
    if b.get("steps") is not None:
        s += f" ({b['steps']:,} of {b['paper_steps']:,} steps)"
    else:
        s += f" ({b['epochs']} of {b['paper_epochs']} epochs)"
    return s


def budgets_text(budgets, short: bool = False) -> str:
    """One :func:`budget_text` per method (the first row of each; rows that train as the same
    method share its budget), comma-separated; ``budgets``: budget dicts or None (skipped)."""
    seen: dict[str, str] = {}
    for b in budgets:
        if b is not None:
            seen.setdefault(b["method"], budget_text(b, short=short))
    return ", ".join(seen.values())


def claim_evidence(*, rows: list[str], budgets: dict[str, dict | None], retrain: bool,
                   replicates: int, evaluators: list[str], scale: str | None = None,
                   convergence: dict[str, dict] | None = None, dataset: str | None = None
                   ) -> dict:
    """The evidence of a claim over ``rows``: variance, budgets of the trained rows involved
    (``budgets``: row id -> :func:`training_budget` or None), whether their trainings reached
    their plateau (``convergence``: :func:`repro.engine.tables.row_convergence`), evaluators;
    with its text.  ``converged``: None without a trained row, else whether every training of
    every trained row involved was trained until the convergence rule fired (issue 32)."""
    trained = {r: budgets[r] for r in rows if budgets.get(r) is not None}
    conv = {r: (convergence or {}).get(r) for r in sorted(trained)}
    converged = (None if not trained else all(
        c is not None and c["trainings"] > 0 and c["converged"] == c["trainings"]
        for c in conv.values()))
    fractions = [b["fraction"] for b in trained.values() if b.get("fraction") is not None]
    unknown = sorted(r for r, b in trained.items() if b.get("fraction") is None)
    if retrain:
        variance = f"{replicates} independent trainings per row (training-seed variance)"
    else:
        variance = (f"{replicates} sampling passes of one trained model per row "
                    "(no training-seed variance)")
    parts = [f"variance: {variance}"]
    if trained:
        assumed = any(b.get("assumed") for b in trained.values())
        parts.append("budget vs the paper's schedule on this data: "
                     + budgets_text(trained.values(), short=True)
                     + (" (*: schedule assumed, the paper states none)" if assumed else ""))
    else:
        parts.append("budget: no trained row involved")
    if trained:
        text = convergence_text(conv, scale)
        if converged and evaluators:
            text += ("; the evaluators below are trained for their profile's fixed number of "
                     "epochs, not by the rule")
        parts.append(text)
    if evaluators:
        parts.append("evaluator: " + "; ".join(evaluators))
    return {"variance": "training" if retrain else "sampling", "replicates": replicates,
            "budgets": {r: b for r, b in trained.items()},
            "min_budget": min(fractions) if fractions else None, "unknown_budget": unknown,
            "scale": scale, "converged": converged, "convergence": conv,
            "where": _where(dataset),
            "trained_rows": sorted(trained), "evaluators": evaluators,
            "text": "; ".join(parts)}


def convergence_text(conv: dict[str, dict | None], scale: str | None = None) -> str:
    """``convergence: every training at its plateau (marionet 34 epochs, ...; rule: ...)``, or
    which rows were not trained to their plateau and why: a fixed number of epochs (a profile
    without ``until = "plateau"``), the epoch cap or the time cap.  Below the ``paper`` scale a
    converged comparison names whose widths converged: the profile's, not the papers' (a
    verdict "at convergence" is about these models, which tables/scales.toml compares with the
    papers')."""
    done = {r: c for r, c in conv.items()
            if c is not None and c["trainings"] and c["converged"] == c["trainings"]}
    if conv and len(done) == len(conv):
        crit = next((c["criterion"] for c in done.values() if c.get("criterion")), None)
        runs = ", ".join(f"{r} {'/'.join(str(e) for e in c['epochs'])} epochs"
                         for r, c in done.items())
        widths = ("" if scale in (None, PAPER_SCALE) else
                  f"; at the {scale} profile's widths, smaller than the papers' "
                  "(tables/scales.toml)")
        return f"convergence: every training at its plateau ({runs}; rule: {crit}){widths}"
    words = {"epochs": "the epoch cap", "time": "the time cap"}
    why = []
    for r, c in conv.items():
        if r in done:
            continue
        if c is None:
            why.append(f"{r} (no training record)")
        elif not c.get("plateau_runs"):
            why.append(f"{r} (a fixed number of epochs)")
        else:
            stops = sorted({words.get(x, str(x)) for x in c["stopped_by"] if x != "plateau"})
            by = ", ".join(stops) or "nothing recorded"
            why.append(f"{r} (stopped by {by}, not at its plateau)" if c["trainings"] == 1
                       else f"{r} ({c['converged']} of {c['trainings']} at the plateau; "
                            f"the others stopped by {by})")
    return "convergence: not every training reached its plateau: " + "; ".join(why)


def _where(dataset: str | None) -> str:
    """"the stand-in", "<name> (own data)" or a paper data set's name (as evaluators say)."""
    from repro.specs import names

    if dataset is None:
        return "the stand-in"
    kind = names.dataset_kind(dataset)
    return {names.STANDIN: "the stand-in", names.OWN: f"{dataset} (own data)"}.get(kind, dataset)


def qualified_verdict(verdict: str, evidence: dict) -> str:
    """The verdict the evidence allows (module docstring): a posterior "contradicted" below
    the paper's budget, or without training-seed variance, is "not reproduced", qualified;
    where every training involved reached its plateau, "supported"/"contradicted" read "at
    convergence on the stand-in" (issue 32).  Convergence answers the budget, not the seed: a
    contradiction from one training per row (no ``--retrain``) is still "not reproduced", as
    another training seed could reverse the ordering — "not reproduced at convergence on the
    stand-in (sampling variance only)"; a supported claim says "(sampling variance only)"."""
    if evidence.get("converged") and verdict in (SUPPORTED, CONTRADICTED):
        where = evidence.get("where") or "the stand-in"
        seeds = evidence.get("variance") == "training"
        if verdict == CONTRADICTED and not seeds:
            return f"not reproduced {AT_CONVERGENCE} on {where} (sampling variance only)"
        tail = "" if seeds else " (sampling variance only)"
        return f"{verdict} {AT_CONVERGENCE} on {where}{tail}"
    if verdict != CONTRADICTED or not evidence.get("trained_rows"):
        return verdict  # (a claim among untrained rows is decided by the data alone)
    mb = evidence.get("min_budget")
    if mb is not None and mb < 1.0 - 1e-9:
        return NOT_REPRODUCED_BUDGET
    if evidence.get("unknown_budget"):
        return NOT_REPRODUCED_UNKNOWN
    if evidence.get("scale") != PAPER_SCALE:
        return NOT_REPRODUCED_REDUCED
    if evidence.get("variance") != "training":
        return NOT_REPRODUCED_SAMPLING
    return CONTRADICTED


def evaluator_text(ev: dict | None, dataset: str | None = None) -> str | None:
    """The evaluator in a claim's evidence; it was trained on the run's data set: "the
    stand-in" for a built-in stand-in (or when none is named), "<name> (own data)" for one a
    data-set spec declares (issue 28: own data is never called a stand-in), the paper data
    set's name for a paper's."""
    from repro.specs import names

    if not ev:
        return None
    s = f"{ev.get('kind')} seed {ev.get('seed', 0)}"
    if ev.get("heading"):
        s += f", heading {ev['heading']}"
    for k, v in sorted((ev.get("settings") or {}).items()):
        s += f", {k} {v}"
    kind = names.STANDIN if dataset is None else names.dataset_kind(dataset)
    where = {names.STANDIN: "the stand-in", names.OWN: f"{dataset} (own data)"}.get(kind, dataset)
    return s + f" (trained by the harness on {where})"
