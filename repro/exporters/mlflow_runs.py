"""``repro runs export RUN... --mlflow URI``: run records into an MLflow tracking store.

A run record (:mod:`repro.store.runs`) stays the truth; the export is a copy that MLflow's UI
and API can read beside other experiments.  Each repro run becomes one MLflow run, found again
by its tag ``repro.run_id``, so exporting a run twice updates the MLflow run it made the first
time instead of adding one:

- **params** (immutable in MLflow, like the record): table, scale, data set, spec version and
  hash, the resolved config flattened (scale profile, seeds, retrain, budget, evaluator seed,
  data fingerprint, every band's protocol parameters, evaluator and evaluator key), each
  trained row's method config (``method.<row>.<field>``, from ``trainings.json``), the code
  (``git.commit``, ``git.dirty``, ``git.diff_sha256``) and ``fingerprints.data`` /
  ``fingerprints.evaluators`` / ``fingerprints.spec``;
- **metrics**: ``value/<row>/<column>`` holds every replicate value of a cell, one history
  entry per replicate with ``step`` = the replicate index; ``mean/<row>/<column>`` the
  summary's mean (step 0); ``claim/<claim>/probability``; ``curve/<row>/s<seed>/<term>`` each
  training's learning curve (step = epoch).  A non-finite value goes in as NaN / ±inf; a
  missing one (``null`` in ``values.jsonl``) is not logged and is listed in ``keys.json``.
  Every entry carries the run's end time as its timestamp, so an export is the same every time;
- **tags**: ``repro.*`` (run id, table, status, scale, data set), ``claim.<id>.verdict`` /
  ``.probability`` / ``.posterior_verdict`` / ``.evidence`` / ``.reason``, ``row.<id>.status``
  (and ``.reason``), the environment (``env.*``, ``packages.*``, ``command``, times), MLflow's
  ``mlflow.runName``, ``mlflow.source.git.commit`` and ``mlflow.note.content`` (the table as
  Markdown, shown as the run's description);
- **artifacts**: ``record/`` (the run folder's files as they are), ``table/`` (the rendered
  table in every format of :mod:`repro.report.render`), ``keys.json`` (which MLflow key holds
  which row, column, claim or config field) and ``report/`` (the table's report page with its
  plots and, when the run's samples are still in the store, its strips:
  :func:`repro.report.html_report.table_page`).

Keys.  MLflow allows letters, digits, ``_ - . /``, space and (not on Windows) ``:`` in keys,
and a key must not resolve to another as a path.  A name made of ``[A-Za-z0-9_.-]`` only (and
not ``.`` or ``..``) is used as it is; any other name has its other characters replaced by
``_`` and gets ``-`` plus the first 8 hex digits of the sha256 of the original name appended
(:func:`key_part`), so the mapping is deterministic and two names never share a key.  In param
and tag paths ``.`` separates the parts, so a part that holds a ``.`` is mapped the same way.

Idempotence.  Params are written only when absent (a different value already there is an
error: the record is immutable); a metric entry only when its (key, step) is absent, with the
same check; tags and artifacts are written again with the same content.  A second export of a
run therefore changes nothing.

The note.  ``mlflow.note.content`` is the table as Markdown, which MLflow's UI renders: its
``<`` and ``>`` are written as ``&lt;`` / ``&gt;`` (:func:`note_text`), so a label in a spec
shows as text and never becomes HTML there (issue 29, item 11).

MLflow is an optional extra (``pip install 'repro[mlflow]'``: mlflow-skinny), imported only
here and only when an export runs.  mlflow-skinny opens file stores (a folder, ``file:``) and
tracking servers (``http(s)://``); a ``sqlite:`` or other SQL store needs the full ``mlflow``
package.  The store is opened and checked (an existing folder that is no store, a server that
does not answer within seconds, the variables MLflow is given) by
:mod:`repro.exporters.mlflow_store`.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
import shutil
import tempfile
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from repro.errors import ConfigError, DataError, ReproError
from repro.exporters.mlflow_store import (  # noqa: F401 (also this module's names, as before)
    INSTALL_HINT,
    RUN_ID_TAG,
    SQL_SCHEMES,
    Store,
    is_file_store,
    tracking_uri,
)

KEYS_JSON = "keys.json"
#: MLflow's limits (mlflow.utils.validation) on one value and on one log_batch call
MAX_PARAM_VALUE, MAX_TAG_VALUE = 6000, 8000
MAX_PARAMS_TAGS_PER_BATCH, MAX_METRICS_PER_BATCH = 100, 1000
#: a record's status -> the MLflow run status it ends with
STATUS = {"FINISHED": "FINISHED", "FAILED": "FAILED", "INTERRUPTED": "KILLED"}
_SAFE = re.compile(r"[A-Za-z0-9_.\-]+")
_SAFE_NO_DOT = re.compile(r"[A-Za-z0-9_\-]+")


# ---------------------------------------------------------------------- keys
def key_part(name: Any, *, dots: bool = True) -> str:
    """``name`` as one part of an MLflow key (module docstring): unchanged when it is made of
    ``[A-Za-z0-9_.-]`` (``dots=False``: without ``.``) and is not ``.``/``..``; otherwise its
    other characters become ``_`` and ``-`` + 8 hex digits of its sha256 are appended."""
    text = str(name)
    safe = _SAFE if dots else _SAFE_NO_DOT
    if safe.fullmatch(text) and text not in (".", ".."):
        return text
    cleaned = re.sub(r"[^A-Za-z0-9_\-]" if not dots else r"[^A-Za-z0-9_.\-]", "_", text)
    return f"{cleaned}-{hashlib.sha256(text.encode('utf-8')).hexdigest()[:8]}"


def _flat(prefix: str, obj: Any, out: dict[str, tuple[Any, list]], path: list) -> None:
    """Flatten dicts and lists into ``prefix.part.part`` keys (parts through :func:`key_part`
    without dots), keeping the original path of each leaf."""
    items: Iterable[tuple[Any, Any]] = ()
    if isinstance(obj, Mapping) and obj:
        items = sorted(obj.items(), key=lambda kv: str(kv[0]))
    elif isinstance(obj, list) and obj and any(isinstance(x, (dict, list)) for x in obj):
        items = enumerate(obj)
    else:
        out[prefix] = (obj, path)
        return
    for k, v in items:
        _flat(f"{prefix}.{key_part(k, dots=False)}", v, out, [*path, k])


def _text(v: Any) -> str:
    return v if isinstance(v, str) else json.dumps(v, sort_keys=True)


def _fit(text: str, limit: int, where: str) -> str:
    """``text`` cut to MLflow's ``limit`` with a note saying where the whole of it is."""
    if len(text) <= limit:
        return text
    note = f" … [cut at {limit} characters; whole in {where}]"
    return text[:limit - len(note)] + note


def _ms(stamp: str | None) -> int | None:
    """An ISO time of the record (``...Z``) in milliseconds since the epoch."""
    if not stamp:
        return None
    try:
        t = datetime.fromisoformat(stamp)  # "...Z" is UTC; the record writes no other zone
    except ValueError:
        return None
    return int((t if t.tzinfo else t.replace(tzinfo=UTC)).timestamp() * 1000)


def _value(v: Mapping[str, Any]) -> float | None:
    """A ``values.jsonl`` line's value as a float (NaN / ±inf from ``nonfinite``; None when
    missing)."""
    if v.get("value") is not None:
        return float(v["value"])
    return {"nan": math.nan, "inf": math.inf, "-inf": -math.inf}.get(v.get("nonfinite"))


def _same(a: float, b: float) -> bool:
    return a == b or (math.isnan(a) and math.isnan(b))


# ---------------------------------------------------------------------- what is exported
@dataclass
class Export:
    """Everything one run record turns into (no MLflow involved): built by :func:`build`."""

    run_id: str
    experiment: str
    run_name: str
    status: str
    start_ms: int | None
    end_ms: int | None
    params: dict[str, str] = field(default_factory=dict)
    tags: dict[str, str] = field(default_factory=dict)
    #: key -> {step: value}
    metrics: dict[str, dict[int, float]] = field(default_factory=dict)
    #: what keys.json holds: which MLflow key stands for what in the record
    keys: dict[str, Any] = field(default_factory=dict)


def _add(target: dict, paths: dict, key: str, value: str, path: list) -> None:
    """Set ``target[key]``, noting in ``paths`` (keys.json) the record path it comes from; two
    paths whose mapped keys collide are an error, never a merge."""
    if paths.setdefault(key, path) != path:
        raise DataError(f"the MLflow key {key!r} would hold both {paths[key]} and {path}")
    target[key] = value


def build(rec, trainings: list[dict] | None = None, *, experiment: str | None = None) -> Export:
    """The params, tags and metrics of run record ``rec`` (:class:`repro.store.runs.RunRecord`)
    and ``trainings`` (its ``trainings.json``), as the module docstring lays them out."""
    run = rec.run
    table = run.get("table")
    ex = Export(run_id=rec.run_id, experiment=experiment or table or "repro",
                run_name=" ".join(str(x) for x in (table, run.get("scale"), rec.run_id) if x),
                status=STATUS.get(run.get("status"), "FAILED"),
                start_ms=_ms(run.get("started") or run.get("created")),
                end_ms=_ms(run.get("ended")))
    keys: dict[str, Any] = {"schema": 1, "run_id": rec.run_id, "params": {}, "tags": {},
                            "metrics": {}, "missing_values": []}
    _build_params(ex, keys, run, trainings)
    _build_tags(ex, keys, rec)
    _build_metrics(ex, keys, rec, trainings)
    ex.keys = keys
    return ex


def _build_params(ex: Export, keys: dict, run: Mapping[str, Any],
                  trainings: list[dict] | None) -> None:
    """:func:`build`'s params: the run's fields and resolved config flattened, the
    fingerprints, and each trained row's method config (one per seed where they differ)."""
    cfg = run.get("config") or {}
    evaluators = sorted({b.get("evaluator_key") for b in cfg.get("bands") or []
                         if b.get("evaluator_key")})
    top = {"table": run.get("table"), "scale": run.get("scale"), "dataset": run.get("dataset"),
           "spec": run.get("spec") or {}, "config": cfg, "git": run.get("git") or {},
           "fingerprints": {"data": cfg.get("data_fingerprint"), "evaluators": evaluators,
                            "spec": (run.get("spec") or {}).get("hash")}}
    flat: dict[str, tuple[Any, list]] = {}
    for name, obj in top.items():
        _flat(name, obj, flat, [name])
    by_row: dict[str, list[dict]] = {}
    for t in trainings or []:
        by_row.setdefault(str(t.get("row")), []).append(t)
    for row, ts in sorted(by_row.items()):
        configs = {json.dumps(t.get("method_config"), sort_keys=True) for t in ts}
        if len(configs) == 1:  # one config per row (several seeds under --retrain share it)
            _flat(f"method.{key_part(row, dots=False)}", ts[0].get("method_config"), flat,
                  ["method", row])
        else:
            for t in ts:
                _flat(f"method.{key_part(row, dots=False)}.s{t.get('seed')}",
                      t.get("method_config"), flat, ["method", row, t.get("seed")])
    for k, (v, path) in flat.items():
        _add(ex.params, keys["params"], k,
             _fit(_text(v), MAX_PARAM_VALUE, f"record/{_record_file(path)}"), path)


def _build_tags(ex: Export, keys: dict, rec) -> None:
    """:func:`build`'s tags: the run's ``repro.*`` fields, MLflow's run name and commit, the
    environment and packages, then each claim's (with its probability as a metric) and each
    row's status."""
    run, summary = rec.run, rec.summary or {}

    def tag(key: str, v: Any, path: list, where: str = "record/run.json") -> None:
        if v is None:
            return
        _add(ex.tags, keys["tags"], key, _fit(_text(v), MAX_TAG_VALUE, where), path)

    tag(RUN_ID_TAG, rec.run_id, ["run_id"])
    for f in ("table", "status", "scale", "dataset"):
        tag(f"repro.{f}", run.get(f), [f])
    tag("mlflow.runName", ex.run_name, ["table", "scale", "run_id"])
    tag("mlflow.source.git.commit", (run.get("git") or {}).get("commit"), ["git", "commit"])
    for f in ("created", "started", "ended", "error", "note"):
        tag(f"repro.{f}", run.get(f), [f])
    tag("repro.command", " ".join(run.get("command") or []) or None, ["command"])
    env = {k: v for k, v in (run.get("env") or {}).items() if k not in ("pid", "pid_start")}
    envflat: dict[str, tuple[Any, list]] = {}
    _flat("env", env, envflat, ["env"])
    _flat("packages", run.get("packages") or {}, envflat, ["packages"])
    for k, (v, path) in envflat.items():
        tag(k, v, path)
    for c in summary.get("claims") or []:
        base = f"claim.{key_part(c.get('id'), dots=False)}"
        for f in ("verdict", "probability", "posterior_verdict", "reason", "kind"):
            tag(f"{base}.{f}", c.get(f), ["summary", "claims", c.get("id"), f],
                "record/summary.json")
        tag(f"{base}.evidence", (c.get("evidence") or {}).get("text"),
            ["summary", "claims", c.get("id"), "evidence", "text"], "record/summary.json")
        if isinstance(c.get("probability"), (int, float)) and not isinstance(
                c.get("probability"), bool):
            mk = f"claim/{key_part(c.get('id'))}/probability"
            ex.metrics[mk] = {0: float(c["probability"])}
            _meaning(keys, mk, {"claim": c.get("id"), "field": "probability"})
    for row, st in sorted((summary.get("rows") or {}).items()):
        base = f"row.{key_part(row, dots=False)}"
        tag(f"{base}.status", (st or {}).get("status"), ["summary", "rows", row, "status"],
            "record/summary.json")
        tag(f"{base}.reason", (st or {}).get("reason"), ["summary", "rows", row, "reason"],
            "record/summary.json")


def _build_metrics(ex: Export, keys: dict, rec, trainings: list[dict] | None) -> None:
    """:func:`build`'s metrics: every replicate value (a missing one noted in ``keys``), the
    summary's means, the learning curves."""
    summary = rec.summary or {}
    for v in rec.values:
        row, col, rep = str(v["row"]), str(v["column"]), int(v["replicate"])
        mk = f"value/{key_part(row)}/{key_part(col)}"
        _meaning(keys, mk, {"row": row, "column": col, "step": "replicate"})
        x = _value(v)
        if x is None:
            keys["missing_values"].append({"row": row, "column": col, "replicate": rep})
            continue
        steps = ex.metrics.setdefault(mk, {})
        if rep in steps and not _same(steps[rep], x):
            raise DataError(f"two values for row {row!r}, column {col!r}, replicate {rep}",
                            file=rec.path / "values.jsonl")
        steps[rep] = x
    for row, cols in sorted((summary.get("cells") or {}).items()):
        for col, cell in sorted(cols.items()):
            mean = (cell or {}).get("mean")
            if isinstance(mean, (int, float)) and not isinstance(mean, bool):
                mk = f"mean/{key_part(row)}/{key_part(col)}"
                ex.metrics[mk] = {0: float(mean)}
                _meaning(keys, mk, {"row": row, "column": col, "field": "mean"})
    for t in trainings or []:
        hist = ((t.get("training") or {}).get("history")) or []
        for i, h in enumerate(hist):
            if not isinstance(h, dict):
                continue
            step = int(h["epoch"]) if isinstance(h.get("epoch"), int) else i
            for term, x in h.items():
                if term == "epoch" or isinstance(x, bool) or not isinstance(x, (int, float)):
                    continue
                mk = f"curve/{key_part(t.get('row'))}/s{t.get('seed')}/{key_part(term)}"
                ex.metrics.setdefault(mk, {})[step] = float(x)
                _meaning(keys, mk, {"row": t.get("row"), "seed": t.get("seed"), "term": term,
                                    "step": "epoch"})


def _meaning(keys: dict, key: str, meaning: dict) -> None:
    """Note in ``keys.json`` what metric ``key`` holds; two meanings for one key (two names
    whose mapped keys collide) are an error, never a merge."""
    had = keys["metrics"].setdefault(key, meaning)
    if had != meaning:
        raise DataError(f"the MLflow key {key!r} would hold both {had} and {meaning}")


def note_text(markdown: str) -> str:
    """The run's description (module docstring, "The note"): ``markdown`` with no HTML tag
    left, ``<`` and ``>`` as entities (an ``&lt;`` already there stays as it is)."""
    return markdown.replace("<", "&lt;").replace(">", "&gt;")


def _record_file(path: list) -> str:
    return "trainings.json" if path and path[0] == "method" else "run.json"


# ---------------------------------------------------------------------- artifacts
def write_artifacts(rec, out: Path, keys: dict, *, pictures: bool = True) -> list[str]:
    """Fill ``out`` with the run's artifacts (module docstring); returns notes on what could
    not be drawn.  The table and the report page need the run's table spec and its summary."""
    notes: list[str] = []
    (out / "record").mkdir(parents=True)
    for p in sorted(rec.path.iterdir()):
        if p.is_file():
            shutil.copyfile(p, out / "record" / p.name)
    (out / KEYS_JSON).write_text(json.dumps(keys, indent=1, sort_keys=True) + "\n",
                                 encoding="utf-8")
    table = rec.run.get("table")
    if not table or rec.summary is None:
        notes.append("no table: the run names no table or has no summary")
        return notes
    from repro.engine.runner import table_view
    from repro.report.render import FORMATS, render

    try:
        view = table_view(table, run=str(rec.path))
    except ReproError as e:
        notes.append(f"no table: {e}")
        return notes
    suffix = {"term": "txt", "latex": "tex"}
    (out / "table").mkdir()
    for fmt in FORMATS:
        (out / "table" / f"table.{suffix.get(fmt, fmt)}").write_text(render(view, fmt),
                                                                     encoding="utf-8")
    if pictures:
        from repro.report.html_report import table_page

        (out / "report").mkdir()  # table_page writes into a folder that exists
        try:
            page = table_page(table, out / "report", run=str(rec.path))
        except ReproError as e:
            notes.append(f"no pictures: {e}")
        else:
            strips = out / "report" / page["page"][:-len(".html")] / "strips.json"
            if strips.is_file():
                notes += [f"no strip: {n}" for n in json.loads(strips.read_text())["notes"]]
    return notes


# ---------------------------------------------------------------------- MLflow
def _mlflow_run(store: Store, rec, ex: Export, experiment: str | None):
    """The MLflow run of repro run ``rec``: the one tagged with its id, else a new one in
    ``ex.experiment``.  Returns (MLflow run, experiment name, created)."""
    found = store.find(rec.run_id)
    if len(found) > 1:
        raise DataError(f"{len(found)} MLflow runs carry {RUN_ID_TAG}={rec.run_id} "
                        f"({', '.join(r.info.run_id for r in found)}); delete all but one",
                        file=store.uri)
    client = store.client
    if found:
        mrun = found[0]
        name = store.call(lambda: client.get_experiment(mrun.info.experiment_id).name)
        if experiment is not None and name != experiment:
            raise ConfigError(f"run {rec.run_id} is already exported to experiment "
                              f"{name!r} of {store.uri} (MLflow run {mrun.info.run_id}); "
                              f"export it there (--experiment {name!r}) or delete that run")
        return mrun, name, False
    exp_id = store.experiment_id(ex.experiment)
    mrun = store.call(lambda: client.create_run(exp_id, start_time=ex.start_ms,
                                                 tags={RUN_ID_TAG: rec.run_id},
                                                 run_name=ex.run_name))
    return mrun, ex.experiment, True


def _missing(store: Store, rec, ex: Export, mrun, created: bool):
    """The params and metric entries ``mrun`` lacks (module docstring, "Idempotence"); one
    already there with another value is an error."""
    from mlflow.entities import Metric, Param

    mid, old = mrun.info.run_id, dict(mrun.data.params)
    for k, v in ex.params.items():
        if k in old and old[k] != v:
            raise DataError(f"MLflow run {mid} holds param {k}={old[k]!r}, the record says "
                            f"{v!r}; delete that MLflow run to export again",
                            file=rec.path / "run.json")
    params = [Param(k, v) for k, v in ex.params.items() if k not in old]
    stamp = ex.end_ms or ex.start_ms or 0
    metrics = []
    for k, steps in ex.metrics.items():
        have = {} if created else {m.step: m.value for m in store.call(
            lambda k=k: store.client.get_metric_history(mid, k))}
        for step, x in sorted(steps.items()):
            if step not in have:
                metrics.append(Metric(k, x, stamp, step))
            elif not _same(float(have[step]), x):
                raise DataError(f"MLflow run {mid} holds {k} step {step} = {have[step]!r}, the "
                                f"record says {x!r}; delete that MLflow run to export again",
                                file=rec.path / "values.jsonl")
    return params, metrics


def export_run(store: Store, ref: str | Path, *, experiment: str | None = None,
               pictures: bool = True) -> dict[str, Any]:
    """Export one run (an id, prefix, ``latest`` or a run folder) into ``store``; returns what
    was written: the MLflow run and experiment, counts of params / metric entries / tags
    (``new_*``: written by this call) and artifact files, and notes on what was not drawn."""
    from mlflow.entities import RunTag

    from repro.store.runs import (
        TERMINAL,
        load_run,
        read_trainings,
        reconcile_stale,
        resolve_run,
    )

    path = ref if isinstance(ref, Path) else resolve_run(str(ref))
    reconcile_stale(path)
    rec = load_run(path)
    if rec.status not in TERMINAL:
        raise ConfigError(f"run {rec.run_id} is {rec.status}: export it once it has ended")
    ex = build(rec, read_trainings(path), experiment=experiment)
    client = store.client
    with tempfile.TemporaryDirectory(prefix="repro-mlflow-") as tmp:
        notes = write_artifacts(rec, Path(tmp), ex.keys, pictures=pictures)  # before any write
        md = Path(tmp) / "table" / "table.md"  # shown by MLflow as the run's description
        if md.is_file():
            ex.tags["mlflow.note.content"] = _fit(note_text(md.read_text(encoding="utf-8")),
                                                  MAX_TAG_VALUE, "table/table.md")
        mrun, exp_name, created = _mlflow_run(store, rec, ex, experiment)
        mid = mrun.info.run_id
        params, metrics = _missing(store, rec, ex, mrun, created)
        tags = [RunTag(k, v) for k, v in ex.tags.items()]
        for batch, size, field_ in ((params, MAX_PARAMS_TAGS_PER_BATCH, "params"),
                                    (tags, MAX_PARAMS_TAGS_PER_BATCH, "tags"),
                                    (metrics, MAX_METRICS_PER_BATCH, "metrics")):
            for i in range(0, len(batch), size):
                chunk = {field_: batch[i:i + size]}
                store.call(lambda chunk=chunk: client.log_batch(mid, **chunk))
        n_files = sum(1 for p in Path(tmp).rglob("*") if p.is_file())
        store.call(lambda: client.log_artifacts(mid, tmp))
    store.call(lambda: client.set_terminated(mid, status=ex.status, end_time=ex.end_ms))
    return {"run": rec.run_id, "mlflow_run": mid, "experiment": exp_name,
            "experiment_id": mrun.info.experiment_id, "uri": store.uri, "created": created,
            "params": len(ex.params), "new_params": len(params),
            "metric_values": sum(len(s) for s in ex.metrics.values()),
            "new_metric_values": len(metrics), "tags": len(ex.tags), "artifacts": n_files,
            "notes": notes}


def export_runs(refs: list[str | Path], uri: str, *, experiment: str | None = None,
                pictures: bool = True) -> list[dict[str, Any]]:
    """Export every run ``refs`` names into the MLflow store at ``uri`` (each ref resolved
    first, so a typo stops before anything is written)."""
    from repro.store.runs import resolve_run

    if experiment is not None and not experiment.strip():
        raise ConfigError("--experiment: give a name")
    paths = [r if isinstance(r, Path) else resolve_run(str(r)) for r in refs]
    paths = list(dict.fromkeys(paths))
    store = Store(uri)
    return [export_run(store, p, experiment=experiment, pictures=pictures) for p in paths]
