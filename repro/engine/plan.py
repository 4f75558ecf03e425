"""Plan-only mode: which jobs of a graph are cached, which would run, and why (``--why``).

:func:`plan` walks the graph like the executor does, without running or verifying anything
(:meth:`Store.has` only): a job *runs* when it is needed (a target, or an input of a job that
runs) and is not stored, is forced, or is not cacheable; a stored job is a *hit*; a job that is
neither stored nor needed (everything downstream of it is stored) is *skipped*.

For ``why``, the executor keeps, per job identity (``kind`` + ``label``), the key parts and the
per-module source digests of the last time the job was run or found
(``store/plans/<sha256(identity)>.json``).  :func:`explain` compares them with the job's
current parts and names what changed, e.g. ``source of repro.models.marionet changed``,
``config.lr 0.0001 -> 0.0002``, ``dataset fingerprint changed``, ``seed 0 -> 1``.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from repro.engine.job import Job, topo_order
from repro.keys import content_key

PLAN_SCHEMA = 1
HIT, RUN, SKIP = "hit", "run", "skip"


@dataclass(frozen=True)
class PlanEntry:
    """One job of a plan.  ``action`` is ``hit``, ``run`` or ``skip``; ``cached`` whether its
    object is in the store; ``why`` a short human reason."""

    job: Job
    key: str
    action: str
    cached: bool
    why: str
    forced: bool = False


def force_matcher(force: bool | str | Iterable[str] | None):
    """``force``: ``True`` (everything), a kind, or kinds/labels; returns ``job -> bool``."""
    if force is True:
        return lambda job: True
    if not force:
        return lambda job: False
    names = {force} if isinstance(force, str) else set(force)
    return lambda job: job.kind in names or (job.label and job.label in names)


def check_force(force, jobs: Iterable[Job]) -> None:
    """A ``--force`` name that names no kind or label of the graph reaching ``jobs`` is a
    typo (``--force trian`` would force nothing and retrain nothing): ConfigError listing the
    graph's kinds.  Called before anything is computed."""
    if force is None or isinstance(force, bool):
        return
    from repro.errors import ConfigError

    order = topo_order(list(jobs))
    names = {force} if isinstance(force, str) else set(force)
    kinds = {j.kind for j in order}
    unknown = sorted(names - kinds - {j.label for j in order if j.label})
    if unknown:
        raise ConfigError(f"--force {', '.join(unknown)}: no job of this run has that kind or "
                          f"label (kinds: {', '.join(sorted(kinds))})")


@dataclass
class Decision:
    action: str
    obj: Any = None  # the StoredObject of a verified hit (executor)
    forced: bool = False


def decide(order: list[Job], store, force=None, *, verify: bool,
           targets: Iterable[str] | None = None) -> dict[str, Decision]:
    """The action of every job of ``order`` (topological).  ``targets``: keys that must be
    produced (default: the jobs nothing in ``order`` consumes).  With ``verify`` (executor)
    needed jobs are read with :meth:`Store.get` (so a corrupt object becomes a run);
    otherwise :meth:`Store.has` is enough (plan)."""
    forced = force_matcher(force)
    if targets is None:
        consumed = {j.key() for job in order for j in job.inputs}
        targets = [job.key() for job in order if job.key() not in consumed]
    needed = set(targets)
    out: dict[str, Decision] = {}
    for job in reversed(order):
        k = job.key()
        f = bool(forced(job))
        if k not in needed and not f:
            present = job.cacheable and store.has(k)
            out[k] = Decision(HIT if present else SKIP)
            continue
        if not job.cacheable or f:
            out[k] = Decision(RUN, forced=f)
            needed.update(j.key() for j in job.inputs)
            continue
        obj = store.get(k) if verify else (True if store.has(k) else None)
        if obj is not None:
            out[k] = Decision(HIT, obj if verify else None)
        else:
            out[k] = Decision(RUN)
            needed.update(j.key() for j in job.inputs)
    return out


def plan(targets: Iterable[Job], *, store=None, force=None, why: bool = True) -> list[PlanEntry]:
    """The plan of the graph reaching ``targets`` (inputs first); nothing is run or written."""
    from repro.store.objects import Store

    store = store or Store()
    targets = list(targets)
    order = topo_order(targets)
    dec = decide(order, store, force, verify=False, targets=[t.key() for t in targets])
    entries = []
    for job in order:
        k = job.key()
        d = dec[k]
        cached = job.cacheable and store.has(k)
        if d.action == HIT:
            reason = "cached"
        elif d.action == SKIP:
            reason = "not needed: everything downstream is cached"
        elif d.forced:
            reason = "forced"
        elif not job.cacheable:
            reason = "not cacheable (unseeded, not declared deterministic)"
        else:
            reason = explain(job, store) if why else "not in the store"
        entries.append(PlanEntry(job, k, d.action, cached, reason, d.forced))
    return entries


# ---------------------------------------------------------------------- records for --why
def _record_path(store, job: Job):
    return store.plans_dir / f"{content_key({'kind': job.kind, 'label': job.label})}.json"


def load_record(store, job: Job) -> dict | None:
    try:
        rec = json.loads(_record_path(store, job).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return rec if isinstance(rec, dict) and rec.get("schema") == PLAN_SCHEMA else None


def record(store, job: Job) -> None:
    """Remember ``job``'s key parts under its identity (called by the executor)."""
    from repro.engine.source_hash import joined_manifest
    from repro.store.atomic import atomic_write_json, utc_now

    old = load_record(store, job)
    if old is not None and old.get("key") == job.key():
        return
    atomic_write_json(_record_path(store, job), {
        "schema": PLAN_SCHEMA, "kind": job.kind, "label": job.label, "key": job.key(),
        "key_parts": job.key_parts(), "sources": joined_manifest(job.module, *job.plugins),
        "input_names": [j.name for j in job.inputs], "recorded": utc_now(),
    })


def _fmt(v: Any, limit: int = 40) -> str:
    s = json.dumps(v, sort_keys=True, separators=(",", ":"))
    return s if len(s) <= limit else s[: limit - 3] + "..."


def _dict_changes(prefix: str, old: Any, new: Any, out: list[str]) -> None:
    if isinstance(old, dict) and isinstance(new, dict):
        for k in sorted(set(old) | set(new)):
            p = f"{prefix}.{k}"
            if k not in old:
                out.append(f"{p} added (= {_fmt(new[k])})")
            elif k not in new:
                out.append(f"{p} removed (was {_fmt(old[k])})")
            else:
                _dict_changes(p, old[k], new[k], out)
    elif old != new:
        out.append(f"{prefix} {_fmt(old)} -> {_fmt(new)}")


def describe_changes(old: dict, job: Job, limit: int = 6) -> list[str]:
    """What differs between a stored record ``old`` and ``job`` now (human phrases)."""
    from repro.engine.source_hash import joined_manifest

    a, b = old.get("key_parts", {}), job.key_parts()
    out: list[str] = []
    if a.get("schema") != b["schema"]:
        out.append(f"key schema {a.get('schema')} -> {b['schema']}")
    if a.get("impl") != b["impl"]:
        out.append(f"implementation {a.get('impl')} -> {b['impl']}")
    if a.get("source") != b["source"]:
        olds, news = old.get("sources", {}), joined_manifest(job.module, *job.plugins)
        changed = sorted(m for m in set(olds) & set(news) if olds[m] != news[m])
        added = sorted(set(news) - set(olds))
        removed = sorted(set(olds) - set(news))
        if changed:
            out.append(f"source of {', '.join(changed)} changed")
        if added:
            out.append(f"now imports {', '.join(added)}")
        if removed:
            out.append(f"no longer imports {', '.join(removed)}")
        if not (changed or added or removed):
            out.append("source changed")
    _dict_changes("config", a.get("config", {}), b["config"], out)
    ia, ib = a.get("inputs", []), b["inputs"]
    if len(ia) != len(ib):
        out.append(f"inputs changed ({len(ia)} -> {len(ib)})")
    else:
        for i, (x, y) in enumerate(zip(ia, ib)):
            if x != y:
                out.append(f"input {job.inputs[i].name} changed")
    fa, fb = a.get("fingerprints", {}), b["fingerprints"]
    for name in sorted(set(fa) | set(fb)):
        if name not in fa:
            out.append(f"{name} fingerprint added")
        elif name not in fb:
            out.append(f"{name} fingerprint removed")
        elif fa[name] != fb[name]:
            out.append(f"{name} fingerprint changed")
    if a.get("seed") != b["seed"]:
        out.append(f"seed {a.get('seed')} -> {b['seed']}")
    if a.get("threads") != b["threads"]:
        out.append(f"threads {a.get('threads')} -> {b['threads']}")
    if len(out) > limit:
        out = out[:limit] + [f"and {len(out) - limit} more"]
    return out


def explain(job: Job, store) -> str:
    """Why ``job`` is not in the store, compared with the last recorded run of its identity."""
    rec = load_record(store, job)
    if rec is None:
        return f"new: no earlier run of {job.identity}"
    if rec.get("key") == job.key():
        return "unchanged since it last ran, but its object is gone (gc, corruption, interrupt)"
    changes = describe_changes(rec, job)
    return "; ".join(changes) if changes else "key changed"
