"""A table's job graph (:func:`build_plan`): bands of columns that share a protocol, and per row
its train, generate and measure jobs; the data flow, job keys and replicates are described in
:mod:`repro.engine.tables`, which aggregates the run.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from repro.engine.job import Job
from repro.report.view import DATA_UNAVAILABLE, NOT_IMPLEMENTED, OK

STEPS = "repro.engine.steps"


# ---------------------------------------------------------------------------------------------
# planning


@dataclass
class Band:
    """Columns of one table that share a protocol and its parameters."""

    protocol: str
    params: dict[str, Any]
    columns: list[str]
    metrics: dict[str, str]  # column id -> metric id
    implemented: bool = False
    reason: str | None = None
    evaluator: dict[str, Any] | None = None  # {dataset, kind, scale, seed}
    evaluator_key: str | None = None
    version: int | None = None  # the protocol implementation's version
    module: str | None = None   # the protocol implementation's module (a plug-in of its jobs)
    item_source: dict | None = None  # how training items are made (ItemSource.describe())
    generation_uses_evaluator: bool = False  # generate jobs read the evaluator (multi-action)

    def step_config(self, dataset: str, *, with_evaluator: bool = False) -> dict[str, Any]:
        """What every step of this band reads: data set and protocol (+ the evaluator for the
        steps that measure; train/generate keys must not depend on the evaluator)."""
        cfg = {"dataset": dataset, "protocol": self.protocol, "protocol_params": self.params,
               "protocol_version": self.version}
        if with_evaluator:
            cfg["evaluator"] = self.evaluator
        return cfg


@dataclass
class RowPlan:
    row_id: str
    method: str
    status: str = OK
    reason: str | None = None
    train: dict[int, list[Job]] = field(default_factory=dict)    # band index -> train job(s)
    measures: dict[int, list[Job]] = field(default_factory=dict)  # band index -> per replicate


@dataclass
class TablePlan:
    spec: Any
    scale: Any
    dataset: str
    data_fingerprint: str | None
    data_missing: str | None
    seeds: tuple[int, ...]
    bands: list[Band]
    rows: list[RowPlan]
    retrain: bool = False  # one training per replicate (build_plan)
    budget: float = 1.0    # epochs × this factor (repro sweep --budget; 1 = the profile's)
    evaluator_seed: int = 0  # the evaluators' training seed (repro sweep --evaluator-seeds)

    def jobs(self) -> list[Job]:
        out: list[Job] = []
        for r in self.rows:
            for js in r.measures.values():
                out.extend(js)
        return out

    @property
    def config(self) -> dict:
        """The resolved configuration recorded in run.json."""
        return {"scale": self.scale.to_dict(), "dataset": self.dataset, "seeds": list(self.seeds),
                "retrain": self.retrain, "budget": self.budget,
                "evaluator_seed": self.evaluator_seed,
                "data_fingerprint": self.data_fingerprint,
                "bands": [{"protocol": b.protocol, "params": b.params, "columns": b.columns,
                           "implemented": b.implemented, "evaluator": b.evaluator,
                           "evaluator_key": b.evaluator_key} for b in self.bands]}


def _bands(spec, scale) -> list[Band]:
    bands: list[Band] = []
    for col in spec.columns:
        pid = spec.protocol_for(col.id)
        params = {**spec.protocol_params_for(col.id),
                  **{k: v for k, v in scale.protocol_config(pid).items() if k != "replicates"}}
        for b in bands:
            if b.protocol == pid and b.params == params:
                b.columns.append(col.id)
                b.metrics[col.id] = col.metric
                break
        else:
            bands.append(Band(pid, params, [col.id], {col.id: col.metric}))
    return bands


def _data_status(dataset: str) -> tuple[str | None, str | None]:
    from repro.data.registry import get_entry

    st = get_entry(dataset).status()
    if not st.prepared:
        return None, st.missing or f"data set {dataset!r} is not prepared"
    return st.fingerprint, None


def _method_config(method: str, scale, overrides: dict) -> tuple[dict | None, str | None]:
    """The fully resolved config of ``method`` (paper defaults < scale < row overrides), or
    (None, reason) when the method is not built."""
    from repro.errors import ConfigError
    from repro.models.base import GENERATOR_MODULES, method_card

    if method not in GENERATOR_MODULES:
        return None, f"method {method!r} is not implemented yet"
    try:
        card = method_card(method)  # its Config without its network: no torch
    except ConfigError as e:
        return None, str(e)
    base = card.trains_as  # its training method's scale settings come first
    scaled = {**(scale.method_config(base) if base else {}), **scale.method_config(method)}
    try:
        cfg = card.Config.resolve({**scaled, **overrides}, where=method)
    except ConfigError as e:  # a variant the spec names but the method does not offer (yet)
        return None, f"variant not implemented: {e}"
    return cfg.model_dump(mode="json"), None


#: at most this many replicate seeds in one ``--seeds`` (a typo must not allocate billions)
MAX_SEEDS = 10_000


def parse_seeds(text: str) -> tuple[int, ...]:
    """``"0-4"`` → (0, 1, 2, 3, 4); ``"0,3,7"`` → (0, 3, 7) (``--seeds``; at most
    :data:`MAX_SEEDS` of them)."""
    from repro.errors import ConfigError

    shown = text if len(text) <= 40 else text[:37] + "..."
    try:
        out: list[int] = []
        for part in text.split(","):
            a, sep, b = part.strip().partition("-")
            lo, hi = (int(a), int(b)) if sep else (int(a), int(a))
            if hi - lo + 1 + len(out) > MAX_SEEDS:
                raise ConfigError(f"--seeds {shown!r}: more than {MAX_SEEDS} seeds")
            out.extend(range(lo, hi + 1))
    except ValueError:
        raise ConfigError(f"--seeds {shown!r}: give seeds as '0-4' or '0,3,7'") from None
    if not out or len(set(out)) != len(out) or min(out) < 0:
        raise ConfigError(f"--seeds {shown!r}: seeds must be distinct non-negative integers")
    return tuple(out)


def _resolve_bands(bands: list[Band], dataset: str, fp: str | None, scale,
                   evaluator_seed: int) -> dict[int, Any]:
    """Resolve each implemented band's protocol, its evaluator and (when the data set is
    prepared) the evaluator's store key; a band whose protocol is not built gets its reason.
    Returns band index -> protocol instance."""
    from repro.eval.protocols import get_protocol, is_implemented
    from repro.eval.provider import evaluator_key
    from repro.eval.settings import resolve_settings

    settings = resolve_settings(scale.name)
    clips = None
    protos: dict[int, Any] = {}
    for bi, b in enumerate(bands):
        if not is_implemented(b.protocol):
            b.reason = f"protocol {b.protocol!r} is not implemented yet"
            continue
        proto = protos[bi] = get_protocol(b.protocol, b.params)
        over, heading = _describe_band(b, proto, dataset, scale, evaluator_seed)
        if fp is not None:
            from repro.engine.steps import clipset, evaluator_split

            clips = clips or clipset(dataset)
            ev_over = {**over, **({} if heading is None else {"heading": heading})}
            ev_settings = resolve_settings(scale.name, ev_over) if ev_over else settings
            b.evaluator_key = evaluator_key(proto.evaluator_kind, ev_settings,
                                            evaluator_split(proto, clips).fingerprint,
                                            int(evaluator_seed))
    return protos


def _describe_band(b: Band, proto, dataset: str, scale,
                   evaluator_seed: int) -> tuple[dict, str | None]:
    """Fill ``b`` from its protocol: resolved parameters, version, module, evaluator, item
    source.  Returns the protocol's evaluator setting overrides and its heading (or None)."""
    b.implemented = True
    b.params = proto.params.describe()  # resolved defaults, as the steps get them back
    b.version = proto.version
    b.module = type(proto).__module__
    b.evaluator = {"dataset": dataset, "kind": proto.evaluator_kind, "scale": scale.name,
                   "seed": int(evaluator_seed)}
    heading = getattr(proto, "evaluator_heading", None)
    if heading is not None:  # a protocol that changes headings asks for a heading-free one
        b.evaluator["heading"] = heading
    over = dict(proto.evaluator_overrides()) if hasattr(proto, "evaluator_overrides") else {}
    if over:  # e.g. ODMO's window per paper data set
        b.evaluator["settings"] = over
    b.item_source = proto.item_source().describe() if hasattr(proto, "item_source") else None
    b.generation_uses_evaluator = bool(getattr(proto, "generation_uses_evaluator", False))
    return over, heading


@dataclass
class _Planner:
    """What every job of one plan shares (:func:`build_plan`)."""

    scale: Any
    dataset: str
    fp: str | None
    seeds: tuple[int, ...]
    retrain: bool
    budget: float
    # held-out share of the training actions for the learning curve (repro.train.validation)
    validation: dict[str, Any]

    def job(self, *args, **kwargs) -> Job:
        """A job that computes with the profile's thread count."""
        return Job(*args, threads=self.scale.threads, **kwargs)

    def device_of(self, method: str) -> str | None:
        """The profile's device (--device) for a method that ``uses_device``, else None: only
        train and generate compute with a network; measuring runs on the CPU, so its keys
        never name a device and Ray gives it no GPU."""
        from repro.models.base import method_card

        device = getattr(self.scale, "device", "cpu")
        return device if method_card(method).uses_device else None


@dataclass
class _RowMethod:
    """A generative row's method, resolved for planning (:func:`_row_method`)."""

    method: str
    config: dict          # fully resolved, epochs scaled by the budget
    module: str
    train_method: str     # the method whose training job it shares (``trains_as``)
    train_config: dict    # ``config`` less the inference-time fields
    train_module: str
    inference: tuple[str, ...]
    # a composite's components: name -> (method, scaled config); empty for any other method
    component_configs: dict[str, tuple[str, dict]]


def _scaled_configs(what: str, methods, scale,
                    budget: float) -> tuple[dict[str, tuple[str, dict]] | None, str | None]:
    """``(name, method)`` pairs resolved to name -> (method, its profile config with epochs
    scaled by ``budget``), or (None, reason) naming the first ``what`` that is not built."""
    from repro.engine.evidence import scale_epochs

    out: dict[str, tuple[str, dict]] = {}
    for name, m in methods:
        c, why = _method_config(m, scale, {})
        if c is None:
            return None, f"{what} {name!r}: {why}"
        out[name] = (m, scale_epochs(c, budget))
    return out, None


def _row_method(row, scale, budget: float) -> tuple[_RowMethod | None, str | None]:
    """Resolve a generative row's method, its training method and a composite's components,
    or (None, reason) when any of them is not built."""
    from repro.engine.evidence import scale_epochs
    from repro.models.base import method_card

    mcfg, why = _method_config(row.method, scale, dict(row.overrides))
    if mcfg is None:
        return None, why
    mcfg = scale_epochs(mcfg, budget)
    card = method_card(row.method)
    # a method that trains as another (NEURAL MARIONETTE = MarioNet's weights plus
    # inference-time schemes) shares that method's training job
    train_method = card.trains_as or row.method
    inference = tuple(card.inference_fields)
    train_cfg = {k: v for k, v in mcfg.items() if k not in inference}
    train_module = method_card(train_method).module
    # a composite (ACTOR + SSMCT, ACTOR + interpolation) trains nothing of its own: its
    # components are trained as those methods are for any other row (shared jobs)
    comp_cfgs, why = _scaled_configs("component", card.components.items(), scale, budget)
    if comp_cfgs is None:
        return None, why
    return _RowMethod(row.method, mcfg, card.module, train_method, train_cfg, train_module,
                      inference, comp_cfgs), None


def _band_reasons(bands: list[Band]) -> str:
    """The bands' reasons for not being implemented, joined."""
    return "; ".join(sorted({b.reason for b in bands if b.reason}))


def _real_measures(pl: _Planner, row, b: Band, proto) -> list[Job]:
    """The "Real" row's ``measure_real`` job per replicate."""
    # a protocol whose Real rows differ by an option (MultiAct's Real-train /
    # Real-test: ``split``) names the overrides it reads; others ignore them
    opts = {k: v for k, v in row.overrides.items() if k in getattr(proto, "real_row_options", ())}
    real = {"real": opts} if opts else {}
    return [pl.job("measure_real", f"{STEPS}:measure_real",
                   {**b.step_config(pl.dataset), "replicate": r, "evaluator": b.evaluator, **real},
                   seed=s, fingerprints={"dataset": pl.fp, "evaluator": b.evaluator_key},
                   label=f"{row.id}/real/r{r}", plugins=(b.module,))
            for r, s in enumerate(pl.seeds)]


def _train_job(pl: _Planner, b: Band, seed: int, method: str, method_cfg: dict,
               module: str) -> Job:
    """One training of ``method`` for band ``b``: keyed by how the training items are made,
    not by the protocol, so a model serves every table whose protocols make items the same
    way."""
    per_method = getattr(pl.scale, "schedule_for", None)  # until a plateau (issue 32)
    schedule = per_method(method) if per_method is not None else getattr(pl.scale, "schedule",
                                                                           None)
    return pl.job("train", f"{STEPS}:train_method",
                  {"dataset": pl.dataset, "items": b.item_source, "method": method,
                   "method_config": method_cfg, "validation": pl.validation,
                   **({"schedule": schedule} if schedule else {})},
                  seed=seed, fingerprints={"dataset": pl.fp}, device=pl.device_of(method),
                  label=f"{method}/train" + ("" if seed == pl.seeds[0] else f"/s{seed}"),
                  plugins=(module,))


def _needed_models(proto, takes_models: bool, rm: _RowMethod, scale,
                   budget: float) -> tuple[dict[str, tuple[str, dict]] | None, str | None]:
    """Extra trained models the protocol needs for this row (MultiAct: ACTOR's previous
    motions and first step), then a composite's components: name -> (method, config); or
    (None, reason) when one is not built."""
    needed: dict[str, tuple[str, dict]] = {}
    if takes_models and hasattr(proto, "extra_models"):
        needed, why = _scaled_configs("model", sorted(proto.extra_models(rm.method, rm.config)
                                                      .items()), scale, budget)
        if needed is None:
            return None, why
    needed.update(rm.component_configs)
    return needed, None


def _train_jobs(pl: _Planner, b: Band, rm: _RowMethod, needed: dict, seed: int) -> list[Job]:
    """The training jobs one generation reads: the row's own model (none for a composite),
    then the needed models."""
    from repro.models.base import method_card

    own = [] if rm.component_configs else [_train_job(pl, b, seed, rm.train_method, rm.train_config,
                                               rm.train_module)]
    return own + [_train_job(pl, b, seed, m, c, method_card(m).module)
                  for _, (m, c) in needed.items()]


def _generate_and_measure(pl: _Planner, row, rm: _RowMethod, b: Band, needed: dict,
                          takes_models: bool, per_seed: list[list[Job]]) -> list[Job]:
    """Per replicate: a ``generate`` job reading its trained models, then its ``measure``."""
    base = b.step_config(pl.dataset)
    fps = {"dataset": pl.fp}
    ms = []
    for r, s in enumerate(pl.seeds):
        gcfg = {**base, "replicate": r, "need": sorted(set(b.metrics.values()))}
        gfps = fps
        if (rm.train_method != rm.method or rm.component_configs
                or (takes_models and rm.inference)):
            gcfg.update(method=rm.method, method_config=rm.config)
        if needed:
            gcfg["models"] = list(needed)
        if b.generation_uses_evaluator:  # test set (and AR) depend on the evaluator
            gcfg["evaluator"] = b.evaluator
            gfps = {**fps, "evaluator": b.evaluator_key}
        gen = pl.job("generate", f"{STEPS}:generate", gcfg,
                     inputs=tuple(per_seed[r if pl.retrain else 0]), seed=s, fingerprints=gfps,
                     device=pl.device_of(rm.method),
                     label=f"{row.id if rm.train_method != rm.method else rm.method}"
                           f"/generate/r{r}",
                     plugins=tuple(dict.fromkeys((rm.module, rm.train_module, b.module))))
        ms.append(pl.job("measure", f"{STEPS}:measure", {**base, "evaluator": b.evaluator},
                         inputs=(gen,), seed=s,
                         fingerprints={**fps, "evaluator": b.evaluator_key},
                         label=f"{row.id}/measure/r{r}", plugins=(b.module,)))
    return ms


def _plan_band(pl: _Planner, rp: RowPlan, row, rm: _RowMethod, bi: int, b: Band,
               proto) -> bool:
    """A generative row's jobs in band ``bi``: its trainings, then per replicate generate and
    measure.  False (with ``rp``'s status and reason set) when a needed model is not built."""
    takes_models = bool(getattr(proto, "takes_models", False))
    needed, why = _needed_models(proto, takes_models, rm, pl.scale, pl.budget)
    if needed is None:
        rp.status, rp.reason = NOT_IMPLEMENTED, why
        return False
    # one model per row (its seed = the first replicate seed), or with ``retrain`` one
    # per replicate (seed = the replicate's): the first is the same job either way
    per_seed = [_train_jobs(pl, b, rm, needed, s)
                for s in (pl.seeds if pl.retrain else pl.seeds[:1])]
    rp.train[bi] = [j for js in per_seed for j in js]
    rp.measures[bi] = _generate_and_measure(pl, row, rm, b, needed, takes_models, per_seed)
    return True


def _plan_row(pl: _Planner, row, bands: list[Band], protos: dict[int, Any],
              missing: str | None) -> RowPlan:
    """One row's plan: its status and, per implemented band, its jobs."""
    rp = RowPlan(row.id, row.method)
    if missing is not None:
        rp.status, rp.reason = DATA_UNAVAILABLE, missing
        return rp
    if not any(b.implemented for b in bands):
        rp.status, rp.reason = NOT_IMPLEMENTED, _band_reasons(bands)
        return rp
    rm = None
    if row.method != "real":
        rm, why = _row_method(row, pl.scale, pl.budget)
        if rm is None:
            rp.status, rp.reason = NOT_IMPLEMENTED, why
            return rp
    for bi, b in enumerate(bands):
        if not b.implemented:
            continue
        if rm is None:
            rp.measures[bi] = _real_measures(pl, row, b, protos[bi])
        elif not _plan_band(pl, rp, row, rm, bi, b, protos[bi]):
            break
    if not rp.measures and rp.status == OK:
        rp.status, rp.reason = NOT_IMPLEMENTED, _band_reasons(bands)
    return rp


def build_plan(spec, scale, dataset: str | None = None, seeds: tuple[int, ...] | None = None,
               retrain: bool = False, budget: float = 1.0, evaluator_seed: int = 0) -> TablePlan:
    """Everything a run of ``spec`` at ``scale`` would do (no training; the data set is only
    opened, memory-mapped, for the fingerprint of the evaluator's training split).

    A replicate is a sampling pass of one trained model per row; with ``retrain`` each
    replicate also trains its own model (training seed = the replicate's seed), so the
    intervals include training-seed variance, at R times the training cost.  ``budget``
    multiplies every method's epoch counts (:func:`repro.engine.evidence.scale_epochs`; 1 keeps
    the profile's, so its jobs are the plain run's); ``evaluator_seed`` trains the evaluators
    with another seed (evaluator sensitivity, :mod:`repro.engine.sweep`)."""
    dataset = dataset or scale.dataset_for(spec)
    fp, missing = _data_status(dataset)
    seeds = tuple(seeds) if seeds else scale.seeds_for(spec.protocol)
    bands = _bands(spec, scale)
    protos = _resolve_bands(bands, dataset, fp, scale, evaluator_seed)
    plan = TablePlan(spec, scale, dataset, fp, missing, seeds, bands, [], retrain=bool(retrain),
                     budget=float(budget), evaluator_seed=int(evaluator_seed))
    validation = {"fraction": float(getattr(scale, "validation_fraction", 0.0) or 0.0), "seed": 0}
    pl = _Planner(scale, dataset, fp, seeds, retrain, budget, validation)
    plan.rows.extend(_plan_row(pl, row, bands, protos, missing) for row in spec.rows)
    return plan
