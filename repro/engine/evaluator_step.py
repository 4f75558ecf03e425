"""Each band's evaluator as a step of a table run (split from :mod:`repro.engine.runner`,
issue 30): trained, or loaded from the store, before the real-data gate
(:mod:`repro.engine.gate_step`) and the job graph; several a run needs and the store lacks are
trained side by side in worker processes; each is described for the run's summary and footer
and its store key counted in the run record."""

from __future__ import annotations

import sys

from repro.engine.gate_step import stored_by


def evaluators(plan, *, train: bool, progress: bool, weights: bool = True, rec=None,
               trained: frozenset = frozenset(), log=None) -> dict[str, str]:
    """Describe (and, with ``train``, train or load) every band's evaluator; without
    ``weights`` a stored evaluator is described from its record (no weights read: nothing
    will be scored, as the runner decides from the stored measurements), one not stored yet
    is still trained.  With a run record ``rec`` each evaluator's store key is recorded as
    read, or written when this run trained it (here, or side by side: ``trained``); ``log(line)`` hears when each
    one is ready (progress lines, :mod:`repro.engine.progress`)."""
    from repro.engine.steps import evaluator_for

    out: dict[str, str] = {}
    for b in plan.bands:
        if b.evaluator is None or b.evaluator_key is None or b.evaluator_key in out:
            continue
        e = b.evaluator
        if not train:
            out[b.evaluator_key] = f"{e['kind']} on {e['dataset']} (store key {b.evaluator_key[:12]})"
            continue
        if progress:
            print(f"repro: evaluator {e['kind']} on {e['dataset']} ({e['scale']})…", file=sys.stderr)
        if log is not None:  # training one can take minutes: say it started
            log(f"evaluator {e['kind']} on {e['dataset']}: training or loading…")
        ev = evaluator_for(b.step_config(plan.dataset, with_evaluator=True), weights=weights)
        out[b.evaluator_key] = ev.describe()
        key = ev.meta.get("store_key") or b.evaluator_key
        hit = bool(ev.meta.get("store_hit", True)) and key not in trained
        if rec is not None:
            stored_by(rec)(key, hit)
        if log is not None:
            log(f"evaluator {e['kind']} on {e['dataset']} "
                f"{'loaded' if hit else 'trained'} [{key[:12]}]")
    return out


def train_one_evaluator(cfg: dict) -> str:
    """Train (or load) one evaluator in a worker process and describe it: the task of
    :func:`train_evaluators_side_by_side` and of a run's evaluators beside its trainings (a
    top-level function: picklable)."""
    from repro.engine.steps import evaluator_for

    return evaluator_for(cfg).describe()


def evaluators_to_train(plans) -> dict[str, dict]:
    """The evaluators the plans need (those with jobs to run) and the store lacks: store key ->
    the band's step config that trains it (:func:`repro.engine.steps.evaluator_for`)."""
    from repro.store.objects import Store

    store, todo = Store(), {}
    for p in plans:
        if not p.jobs():
            continue
        for b in p.bands:
            if b.evaluator is None or b.evaluator_key is None or b.evaluator_key in todo:
                continue
            if store.get(b.evaluator_key) is None:
                todo[b.evaluator_key] = b.step_config(p.dataset, with_evaluator=True)
    return todo


def train_evaluators_side_by_side(plans, jobs: int, progress: bool, log=None) -> frozenset:
    """Train the evaluators the plans need and the store lacks, up to ``jobs`` at a time in
    worker processes (each trains with its settings' fixed thread count, so the weights are the
    same as one after another); :func:`evaluators` then loads them.  A failure is left for
    the sequential pass to raise in the parent, with its usual message.  Returns the store
    keys of those trained here (the run records count them as written); with fewer than two
    to train, nothing (the sequential pass trains it).  A run with trainings to do trains its
    evaluators beside them instead (:func:`repro.engine.runner.run_tables`)."""
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    todo = evaluators_to_train(plans)
    if len(todo) < 2:
        return frozenset()
    if progress:
        print(f"repro: training {len(todo)} evaluators, {min(jobs, len(todo))} at a time…",
              file=sys.stderr)
    done = set()
    with ProcessPoolExecutor(max_workers=min(jobs, len(todo)),
                             mp_context=mp.get_context("spawn")) as pool:
        futures = {key: pool.submit(train_one_evaluator, cfg) for key, cfg in todo.items()}
        for key, f in futures.items():
            try:
                f.result()
            except Exception:  # noqa: BLE001 - re-raised by the sequential pass
                continue
            done.add(key)
            if log is not None:
                log(f"evaluator trained [{key[:12]}]")
    return frozenset(done)
