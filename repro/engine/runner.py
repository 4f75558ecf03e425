"""``repro run / show / plan / rescore / verify``: a table from spec to recorded run to report.

A run: resolve the spec, the scale profile and the data set → build the plan
(:func:`repro.engine.table_plan.build_plan`) → train or load each band's evaluator → the real-data
gate (:mod:`repro.eval.gate`; a failing gate stops the run before any method is scored, with
the reason) → execute the job graph (cached jobs are hits) → record every raw replicate value,
the summary and the environment in a run folder → render the table.

``show`` renders the newest finished run of a table (for a scale and data set) without
computing anything; ``rescore`` recomputes only the ``measure`` jobs from stored samples.
"""

from __future__ import annotations

import contextlib
import contextvars
import json
import sys
from pathlib import Path
from typing import Any

from repro.engine.evaluator_step import evaluators as _evaluators
from repro.engine.evaluator_step import evaluators_to_train, train_evaluators_side_by_side, \
    train_one_evaluator
from repro.engine.footer import table_footer as _footer
from repro.engine.gate_step import check_gate, stored_by
from repro.engine.table_facts import test_sets_stored
from repro.errors import ConfigError, ReproError


#: whether a spec file outside ``tables/`` may take a registered table's id (``--claim-id``)
_CLAIM_IDS: contextvars.ContextVar[bool] = contextvars.ContextVar("claim_ids", default=False)


@contextlib.contextmanager
def claiming_ids(allow: bool):
    """Within the block, a spec file given by path may use the id of a table under
    ``tables/`` when ``allow`` (its runs then count as that table's: ``repro show`` of the id
    shows them)."""
    token = _CLAIM_IDS.set(bool(allow))
    try:
        yield
    finally:
        _CLAIM_IDS.reset(token)


def table_spec(name: str):
    """The spec ``name`` names; a spec file outside ``tables/`` may not claim the id of a
    registered table (its runs would become that table's newest run) unless
    :func:`claiming_ids` allows it."""
    from repro.specs.load import find_spec

    spec = find_spec(name)
    p = Path(name)
    if p.suffix == ".toml" and p.is_file() and not _CLAIM_IDS.get():
        from repro.paths import tables_root

        own = tables_root() / f"{spec.id}.toml"
        if own.is_file() and own.resolve() != p.resolve():
            raise ConfigError(f"{name}: spec file claims the id {spec.id!r} of "
                              f"tables/{spec.id}.toml; give it an id of its own (or pass "
                              "--claim-id to let its runs count as that table's)")
    return spec


def table_scale(name: str, dataset: str | None):
    """The scale profile ``name`` resolved for ``dataset`` (``--dataset``; None: the
    profile's own), :func:`repro.specs.scales.resolve_scale`."""
    from repro.specs.scales import resolve_scale

    return resolve_scale(name, dataset)


def _measurements_stored(plans, force) -> bool:
    """Whether every measurement the plans ask for is already in the store and nothing is
    forced: then no job will score, so the evaluators' weights need not be read (their
    records name them) and the gate reads its stored real rows.  A measurement that turns
    out corrupt when the executor verifies it is recomputed by its job, which loads the
    evaluator itself (:func:`repro.engine.steps.measure`)."""
    if force:
        return False
    from repro.store.objects import Store

    store = Store()
    return all(store.has(j.key()) for p in plans for rp in p.rows for j in _row_targets(rp))


def run_table(name: str, *, scale: str = "quick", dataset: str | None = None, jobs: int = 1,
              force: Any = None, progress: bool = True,
              seeds: tuple[int, ...] | None = None, retrain: bool = False,
              budget: float = 1.0, evaluator_seed: int = 0, backend: Any = None,
              lines: bool = False, gate_margin: float | None = None, no_gate: bool = False
              ) -> tuple[Any, dict, str]:
    """Run one table; returns (plan, summary, run_id).  ``seeds`` replaces the profile's
    replicate seeds (the first one is also the training seed); ``retrain`` trains one model
    per replicate; ``budget`` scales every method's epochs; ``evaluator_seed`` trains the
    evaluators with another seed (:func:`repro.engine.table_plan.build_plan`); ``backend`` runs
    the graph elsewhere (:func:`repro.engine.executor.execute`, e.g. on Ray); ``lines``,
    ``gate_margin``, ``no_gate``: :func:`run_tables`."""
    return run_tables([name], scale=scale, dataset=dataset, jobs=jobs, force=force,
                      progress=progress, seeds=seeds, retrain=retrain, budget=budget,
                      evaluator_seed=evaluator_seed, backend=backend, lines=lines,
                      gate_margin=gate_margin, no_gate=no_gate)[0]


def run_tables(names: list[str], *, scale: str = "quick", dataset: str | None = None,
               jobs: int = 1, force: Any = None, progress: bool = True,
               seeds: tuple[int, ...] | None = None, retrain: bool = False,
               budget: float = 1.0, evaluator_seed: int = 0,
               backend: Any = None, lines: bool = False, gate_margin: float | None = None,
               no_gate: bool = False) -> list[tuple[Any, dict, str]]:
    """Run several tables as one job graph; one (plan, summary, run_id) per distinct name.

    Every spec is resolved first (a typo stops before anything is computed); each table gets
    its own run record, evaluators and gate; then the jobs of all tables run as one graph, so
    ``--jobs N`` overlaps them (Tables 1, 2 and 4 share MarioNet's training and their other
    trainings run side by side instead of one table after another).  With a ``backend`` (Ray)
    the graph's jobs run there; the evaluators and the gate still run here.

    ``progress``: rich bars (a terminal); ``lines``: plain progress lines on stderr instead
    (:class:`repro.engine.progress.LineProgressHook`, output that is not a terminal).
    ``gate_margin`` / ``no_gate``: the real-data gate (:func:`repro.eval.gate.resolve_gate`;
    the command line over the data-set spec's ``[gate]`` over the profile), recorded in each
    run's record, summary and footer."""
    from contextlib import ExitStack

    from repro.kernels import check as check_kernels

    check_kernels()  # the evaluators and the gate compute in this process (repro/kernels.py)

    from repro.engine.table_plan import build_plan
    from repro.eval.gate import resolve_gate
    from repro.store.runs import RunRecorder

    hook = None
    if lines:
        from repro.engine.progress import LineProgressHook

        hook, progress = LineProgressHook(), False
    sc = table_scale(scale, dataset)
    specs = list({s.id: s for s in (table_spec(n) for n in names)}.values())
    plans = [build_plan(spec, sc, dataset, seeds, retrain, budget, evaluator_seed)
             for spec in specs]
    from repro.engine.split_check import check_protocol_splits

    for p in plans:  # a class short of clips under a protocol's split: said before training
        check_protocol_splits(p)
    gates = [resolve_gate(p.dataset, margin=gate_margin, no_gate=no_gate) for p in plans]
    from repro.engine.plan import check_force

    check_force(force, [j for p in plans for rp in p.rows for j in _row_targets(rp)])
    log = None if hook is None else hook.note
    out = []
    with ExitStack() as stack:
        recs = [stack.enter_context(RunRecorder(
            table=p.spec.id, spec_version=p.spec.version, spec_hash=p.spec.spec_hash,
            config=p.config, scale=sc.name, dataset=p.dataset,
            device=getattr(sc, "device", "cpu"))) for p in plans]
        stored = _measurements_stored(plans, force)  # decide hits first: no scoring, no weights
        trained: frozenset = frozenset()
        early: dict[str, dict] = {}
        failed_early: dict = {}
        if jobs > 1 and not stored:
            trained, early, failed_early = _evaluators_beside_trainings(
                plans, recs, jobs=jobs, force=force, progress=progress, backend=backend,
                hook=hook, log=log)
        evaluators = [_evaluators(p, train=bool(p.jobs()), progress=progress, weights=not stored,
                                  rec=rec, trained=trained, log=log)
                      for p, rec in zip(plans, recs)]
        gate_records = []
        for p, rec, setting in zip(plans, recs, gates):
            gate_records.append(check_gate(p, setting, rec, log, check=bool(p.jobs())))
        executed = _execute_plans(plans, recs, jobs=jobs, force=force, progress=progress,
                                  backend=backend, hook=hook, early=early,
                                  failed=failed_early)
        for p, rec, ev, gate, (reports, counts) in zip(plans, recs, evaluators, gate_records,
                                                        executed):
            out.append((p, _finish_run(p, rec, ev, gate, reports, counts), rec.run_id))
    return out


def _finish_run(plan, rec, evaluators: dict, gate: dict, reports: dict, counts: dict) -> dict:
    """End one table's run once its graph has run: its raw values and training records written
    to the run record ``rec``, its summary (with the evaluators, the gate, the footer, the job
    counts and the stored test sets) written, the run marked finished; returns the summary."""
    from repro.engine.tables import collect_trainings, collect_values

    values = collect_values(plan, reports)
    rec.add_values(values)
    trainings = collect_trainings(plan, reports)
    rec.write_trainings(trainings)
    summary = _summary(plan, values, trainings, stored_by(rec))
    summary["evaluators"] = evaluators
    summary["gate"] = gate
    summary["footer"] = _footer(plan, evaluators, rec.run_id, summary.get("budgets"), trainings,
                                kernels=(rec.data.get("env") or {}).get("kernels"), gate=gate)
    summary["counts"] = counts
    test_sets = test_sets_stored(plan, stored_by(rec))
    if test_sets:
        summary["test_sets"] = test_sets
    rec.write_summary(summary)
    rec.finish()
    return summary


def _summary(plan, values: list[dict], trainings: list[dict], stored=None) -> dict:
    """:func:`repro.engine.tables.summarise` of a run, stored under a key made of everything
    it reads: the spec's hash, the resolved configuration, every row's status and every job's
    key (which cover the method configs the budgets read), the raw values, the training
    records and the source of ``repro.engine.tables`` (with the statistics it imports).  A
    rerun whose values are all cache hits reads the summary instead of bootstrapping every
    cell and sampling every claim's posterior again (docs/engine.md, "Fixed costs")."""
    from repro.engine.source_hash import source_hash
    from repro.engine.tables import summarise
    from repro.keys import content_key, sha256_bytes
    from repro.store.atomic import jsonable
    from repro.store.objects import Store

    jobs = [j.key() for rp in plan.rows for js in (*rp.train.values(), *rp.measures.values())
            for j in js]
    inputs = json.dumps({"spec": plan.spec.spec_hash, "config": plan.config, "jobs": jobs,
                         "rows": [[rp.row_id, rp.status, rp.reason] for rp in plan.rows],
                         "bands": [b.reason for b in plan.bands], "values": values,
                         "trainings": trainings}, sort_keys=True)  # NaN allowed, unlike keys
    key = content_key({"schema": 1, "object": "summary",
                       "inputs": sha256_bytes(inputs.encode()),
                       "source": source_hash("repro.engine.tables")})

    def compute(out: Path) -> None:  # the run record's JSON form, in summarise's key order
        (out / "summary.json").write_text(json.dumps(jsonable(summarise(plan, values,
                                                                        trainings))))

    obj = Store().compute(key, "summary", compute)
    if stored is not None:
        stored(key, bool(obj.hit))
    return obj.read_json("summary.json")


class _FanOut:
    """The executor's recorder for a graph that serves several tables: each job line goes to
    the run record of every table whose graph contains the job; an interrupt or a failure
    that stops the graph ends every table's run.  ``early``: jobs this run computed before the
    graph (its trainings, beside the evaluators): the graph finds them stored, and their
    "computed" lines stay."""

    status = "RUNNING"

    def __init__(self, recorders: list, keys: list[set[str]], early: dict | None = None):
        self._pairs = list(zip(recorders, keys))
        self._early = early or {}

    def record_job(self, rec) -> None:
        if rec.get("status") == "hit" and rec.get("key") in self._early:
            return
        for recorder, keys in self._pairs:
            if rec.get("key") in keys:
                recorder.record_job(rec)

    def interrupt(self, note: str = "interrupted") -> None:
        for recorder, _ in self._pairs:
            recorder.interrupt(note)

    def fail(self, error: str) -> None:
        for recorder, _ in self._pairs:
            recorder.fail(error)


def _row_targets(rp) -> list:
    return [j for js in rp.measures.values() for j in js]


def _plan_targets(plans: list) -> tuple[dict[str, Any], list[set[str]]]:
    """Every row target of the plans by key, and per plan the keys of the graph reaching its
    targets."""
    from repro.engine.job import topo_order

    targets: dict[str, Any] = {}
    keys: list[set[str]] = []
    for p in plans:
        mine = [j for rp in p.rows for j in _row_targets(rp)]
        for j in mine:
            targets.setdefault(j.key(), j)
        keys.append({j.key() for j in topo_order(mine)} if mine else set())
    return targets, keys


def _run_graph(targets: list, fan: _FanOut, *, jobs: int, force: Any, progress: bool,
               backend: Any, hook: Any, beside=(), on_beside=None, failed=None):
    """:func:`repro.engine.executor.execute` over ``targets`` with the run's progress display
    (``hook``, else rich bars when ``progress``)."""
    from repro.engine.executor import execute

    if hook is None and progress:
        from repro.engine.progress import RichProgressHook

        hook = RichProgressHook()
    with hook if isinstance(hook, contextlib.AbstractContextManager) else contextlib.nullcontext():
        return execute(targets, jobs=jobs, force=force, hook=hook, recorder=fan,
                       keep_going=True, backend=backend, beside=beside, on_beside=on_beside,
                       failed=failed)


def _evaluators_beside_trainings(plans: list, recorders: list, *, jobs: int, force: Any,
                                 progress: bool, backend: Any, hook: Any, log
                                 ) -> tuple[frozenset, dict[str, dict], dict]:
    """With ``--jobs N > 1``: train the evaluators the run lacks in the same pool of N worker
    processes as the graph's jobs that need none (the trainings; samples of protocols that do
    not read the evaluator), queued first, so no worker idles while either has work: an
    evaluator alone used to hold one core for its whole training while the trainings waited
    (issue 32's converged runs).  The real-data gate and the scoring still wait for the
    evaluators; a failing gate stops the run with those jobs stored.  Returns (store keys of
    the evaluators trained, key -> record of each job computed here, key -> result of each
    that failed here).  With nothing to overlap (or with ``--force`` or another back end)
    the evaluators train side by side before the graph, as before this change."""
    from functools import partial

    from repro.engine.job import topo_order

    todo = evaluators_to_train(plans)
    if not todo:
        return frozenset(), {}, {}
    targets, keys = _plan_targets(plans)
    if force or backend is not None:
        return train_evaluators_side_by_side(plans, jobs, progress, log), {}, {}
    from repro.engine import plan as planmod
    from repro.store.objects import Store

    order = topo_order(list(targets.values()))
    dec = planmod.decide(order, Store(), None, verify=False, targets=list(targets))
    needs: dict[str, bool] = {}  # the job or one it reads is keyed by an evaluator
    for j in order:
        needs[j.key()] = "evaluator" in j.fingerprints or any(needs[i.key()] for i in j.inputs)
    early_jobs = [j for j in order if not needs[j.key()] and dec[j.key()].action == planmod.RUN]
    if not early_jobs:
        return train_evaluators_side_by_side(plans, jobs, progress, log), {}, {}
    keys_todo = list(todo)
    n_train = sum(j.kind == "train" for j in early_jobs)
    msg = (f"{len(todo)} evaluator(s), {n_train} training(s) and {len(early_jobs) - n_train} "
           f"other job(s) that need no evaluator, on {jobs} worker(s)")
    if log is not None:
        log(msg)
    elif progress:
        print(f"repro: {msg}…", file=sys.stderr)

    def ended(i: int, error: str | None) -> None:
        if log is not None:
            log(f"evaluator trained [{keys_todo[i][:12]}]" if error is None else
                f"evaluator [{keys_todo[i][:12]}] failed beside the trainings ({error}); it is "
                "trained again once they end, to report the error")

    report = _run_graph(early_jobs, _FanOut(recorders, keys), jobs=jobs, force=None,
                        progress=progress, backend=None, hook=hook,
                        beside=[partial(train_one_evaluator, todo[k]) for k in keys_todo],
                        on_beside=ended)
    trained = frozenset(k for k, err in zip(keys_todo, report.beside) if err is None)
    # a job that failed here is not run again by the graph (a worker killed under it is)
    failed = {r.key: r for r in report.results
              if r.status == "failed" and "BrokenProcessPool" not in (r.error or "")}
    return (trained, {r.key: r.as_record() for r in report.results if r.status == "computed"},
            failed)


def _execute_plans(plans: list, recorders: list, *, jobs: int, force: Any,
                   progress: bool, backend: Any = None, hook: Any = None,
                   early: dict[str, dict] | None = None, failed: dict | None = None
                   ) -> list[tuple[dict[str, Any], dict[str, int]]]:
    """Execute every row of every plan as one graph, so ``--jobs N`` overlaps rows and tables
    (five trainings of a table run N at a time, not one after another).  A job that fails
    cancels only what depends on it (``keep_going``): each row it reaches is marked FAILED
    with the error and the other rows go on; a user error (:class:`ReproError`) and Ctrl-C
    still stop the run.  Returns, per plan, (row id -> the graph's report, job counts by
    status over that table's jobs).  ``hook``: a progress hook to use instead of the rich one
    ``progress`` makes (:class:`repro.engine.progress.LineProgressHook`).  ``early``: the
    trainings computed beside the evaluators (:func:`_evaluators_beside_trainings`), counted
    as computed, not as the hits the graph finds them; ``failed``: those that failed there,
    recorded as failed without a second try."""
    from repro.report.view import FAILED

    early = early or {}
    targets, keys = _plan_targets(plans)
    if not targets:
        return [({}, {}) for _ in plans]
    report = _run_graph(list(targets.values()), _FanOut(recorders, keys, early), jobs=jobs,
                        force=force, progress=progress, backend=backend, hook=hook,
                        failed=failed)
    out = []
    for p, mine in zip(plans, keys):
        reports: dict[str, Any] = {}
        for rp in p.rows:
            row_targets = _row_targets(rp)
            if not row_targets:
                continue
            failed = report.failure_of(row_targets)
            if failed is not None:  # a bug or a numerical failure in one method: say it, go on
                rp.status, rp.reason = FAILED, f"{failed.job.name}: {failed.error}"
                rp.measures = {}
                print(f"repro: {p.spec.id}: row {rp.row_id} failed: {rp.reason}",
                      file=sys.stderr)
                continue
            reports[rp.row_id] = report
        counts: dict[str, int] = {}
        for r in report.results:
            if r.key in mine:
                status = "computed" if r.status == "hit" and r.key in early else r.status
                counts[status] = counts.get(status, 0) + 1
        out.append((reports, counts))
    return out


def latest_run(table: str, scale: str | None = None, dataset: str | None = None,
               retrain: bool | None = None, plain: bool = True) -> Path | None:
    """The newest FINISHED run folder of ``table`` (optionally for a scale / data set, and
    made with or without ``--retrain``); with ``plain`` (the default) only runs at the
    profile's budget with the default evaluator seed (a sweep's other points are not "the"
    run of a table).  A run whose ``run.json`` or ``summary.json`` is damaged is skipped with
    one warning naming it (the next newest good run is used)."""
    from repro.store.run_checks import warn_bad_run as _warn_bad_run
    from repro.store.runs import FINISHED, read_run_json, read_summary, run_dirs

    for d in reversed(run_dirs()):
        try:
            rj = read_run_json(d)
        except ReproError as e:
            _warn_bad_run(d, e)
            continue
        if rj.get("table") != table or rj.get("status") != FINISHED:
            continue
        if scale is not None and rj.get("scale") != scale:
            continue
        if dataset is not None and rj.get("dataset") != dataset:
            continue
        cfg = rj.get("config") or {}
        if retrain is not None and bool(cfg.get("retrain")) != retrain:
            continue
        if plain and (cfg.get("budget", 1.0) != 1.0 or cfg.get("evaluator_seed", 0)):
            continue  # both checked as numbers by read_run_json
        try:
            read_summary(d, required=True)
        except ReproError as e:
            _warn_bad_run(d, e)
            continue
        return d
    return None


def table_run(spec, scale: str = "quick", dataset: str | None = None,
              run: str | Path | None = None) -> Path | None:
    """The run folder of a table: ``run`` (an id, a prefix or a folder) or the newest finished
    plain run at ``scale`` on ``dataset`` (the profile's or the spec's), None when there is none."""
    from repro.store.runs import resolve_run

    if run is not None:
        return Path(run) if isinstance(run, Path) or Path(str(run)).is_dir() else \
            resolve_run(str(run))
    sc = table_scale(scale, dataset)
    return latest_run(spec.id, sc.name, dataset or sc.dataset_for(spec))


def table_view(name: str, *, scale: str = "quick", dataset: str | None = None, run: str | None = None):
    """The view of a table: from a run (the newest finished one by default) or, when there is
    none, the paper's values beside "not run" cells."""
    from repro.engine.table_view import make_view
    from repro.engine.table_plan import build_plan
    from repro.engine.tables import unbuilt_columns

    from repro.engine.footer import failure_line, gate_mark

    spec = table_spec(name)
    sc = table_scale(scale, dataset)
    path = table_run(spec, scale, dataset, run or None)
    # the newest run, when it did not finish, is said (issue 28: "not run yet" after two
    # FAILED runs); a run asked for by id is shown as asked
    failed = None if run else newest_failure(spec.id, sc.name, dataset or sc.dataset_for(spec),
                                             after=path)
    if path is not None:
        from repro.store.runs import read_run_json, read_summary

        summary = read_summary(path, required=True)
        rj = read_run_json(path)
        view = make_view(spec, summary.get("rows", {}), summary, summary.get("footer", []),
                         rj.get("dataset"))
        mark = gate_mark(summary.get("gate"))
        if mark:
            view.marks.append(mark)
    else:
        plan = build_plan(spec, sc, dataset)
        rows = {rp.row_id: {"status": _before_run(rp.status), "reason": rp.reason}
                for rp in plan.rows}
        view = make_view(spec, rows, None,
                         _footer(plan, _evaluators(plan, train=False, progress=False), None),
                         plan.dataset, unbuilt_columns(plan))
    if failed is not None:
        view.failed_run = {k: failed.get(k) for k in ("run_id", "status", "ended", "error",
                                                      "note")}
        view.marks.append(f"NEWEST RUN {failed.get('status')}")
        view.footer = [failure_line(failed, path.name if path else None), *view.footer]
    return view


def newest_failure(table: str, scale: str, dataset: str, after: Path | None = None
                   ) -> dict | None:
    """The ``run.json`` of the newest FAILED or INTERRUPTED plain run of ``table`` at
    ``scale`` on ``dataset`` that is newer than the run folder ``after`` (the finished run
    shown; None: any), else None.  Run ids sort by start time."""
    from repro.store.run_checks import warn_bad_run as _warn_bad_run
    from repro.store.runs import FAILED, INTERRUPTED, read_run_json, run_dirs

    for d in reversed(run_dirs()):
        if after is not None and d.name <= Path(after).name:
            return None
        try:
            rj = read_run_json(d)
        except ReproError as e:
            _warn_bad_run(d, e)
            continue
        if (rj.get("table"), rj.get("scale"), rj.get("dataset")) != (table, scale, dataset):
            continue
        cfg = rj.get("config") or {}
        if cfg.get("budget", 1.0) != 1.0 or cfg.get("evaluator_seed", 0):
            continue  # a sweep's other points are not the table's run
        if rj.get("status") in (FAILED, INTERRUPTED):
            return rj
        if rj.get("status") not in ("RUNNING", "QUEUED"):
            return None  # a finished run newer than ``after``: nothing failed after it
    return None


def _before_run(status: str) -> str:
    """A row that could run but has not: "not run"; other statuses say why it cannot."""
    from repro.report.view import NOT_RUN, OK

    return NOT_RUN if status == OK else status


def plan_table(name: str, *, scale: str = "quick", dataset: str | None = None, why: bool = False,
               force: Any = None, seeds: tuple[int, ...] | None = None,
               retrain: bool = False) -> list[dict]:
    """What a run would do: each job with its key, cached or not, and (``why``) what changed."""
    from repro.engine.plan import plan as plan_jobs
    from repro.engine.table_plan import build_plan

    spec = table_spec(name)
    plan = build_plan(spec, table_scale(scale, dataset), dataset, seeds, retrain)
    from repro.engine.split_check import check_protocol_splits

    check_protocol_splits(plan)
    from repro.engine.plan import check_force

    check_force(force, plan.jobs())
    entries = plan_jobs(plan.jobs(), force=force, why=why)
    out = [{"job": e.job.name if hasattr(e.job, "name") else e.job.label, "kind": e.job.kind,
            "key": e.key[:12], "cached": e.cached, "why": getattr(e, "why", None)} for e in entries]
    for rp in plan.rows:
        if rp.status != "ok":
            out.append({"job": f"{rp.row_id}", "kind": "row", "key": "", "cached": False,
                        "why": f"{rp.status}: {rp.reason}"})
    return out


def verify_table(name: str, baseline_dir: str | Path, *, scale: str = "quick",
                 dataset: str | None = None, tolerance: float | None = None
                 ) -> tuple[list[str], list[str]]:
    """Compare the newest run of ``name`` with a committed baseline; returns ``(problems,
    notes)``: the notes name both hosts and kernel paths and, when cells drift on another host,
    say so (:mod:`repro.engine.baselines`).  Baselines are made from runs without
    ``--retrain``, so only those are compared, except under ``tolerance``, where the newest run
    with or without ``--retrain`` is compared (a ``--retrain`` run's intervals hold the spread
    of training seeds; such a run is preferred).  A run made unpinned (or under another pin
    version) against a pinned baseline is a ConfigError, and a note under ``tolerance``."""
    from repro.engine.baselines import (compare, gate_check, host_lines, host_note,
                                        load_baseline, refusal)
    from repro.store.runs import read_run_json, read_summary

    spec = table_spec(name)
    sc = table_scale(scale, dataset)
    ds = dataset or sc.dataset_for(spec)
    path = latest_run(spec.id, sc.name, ds, retrain=False)
    if tolerance is not None:  # the spread of training seeds: a --retrain run when there is one
        path = latest_run(spec.id, sc.name, ds, retrain=True) or path
    if path is None:
        from repro.engine.footer import no_run_message

        raise ConfigError(no_run_message(spec.id, sc.name, dataset,
                                         newest_failure(spec.id, sc.name, ds)))
    base = load_baseline(Path(baseline_dir), spec.id)
    rj = read_run_json(path)
    kernels = (rj.get("env") or {}).get("kernels")
    notes = host_lines(base, kernels)
    why = refusal(base, kernels)
    if why is not None and tolerance is None:
        raise ConfigError(f"{spec.id}: run {path.name}: {why}")
    if why is not None:
        notes.append(f"compared under --tolerance although {why.split(':')[0]}")
    summary = read_summary(path, required=True)
    retrain = bool((rj.get("config") or {}).get("retrain"))
    if tolerance is not None:
        notes.append(f"run {path.name}; tolerance {tolerance:g} x the "
                     + ("training-seed spread (run made with --retrain)" if retrain else
                        "sampling spread (no --retrain run: training seeds are not in the "
                        "intervals, so this is narrower than the training-seed spread)"))
    problems = compare(base, summary, tolerance=tolerance, retrain=retrain, notes=notes)
    gate_note, gate_problem = gate_check(base, summary.get("gate"))
    if gate_note:
        notes.append(gate_note)
    if gate_problem:
        problems.append(gate_problem)
    note = host_note(base, kernels, drift=bool(problems))
    if note:
        notes.append(note)
    return problems, notes
