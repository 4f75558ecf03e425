"""Engine: content keys (order-invariant; sensitive to config, seed, inputs and source), plans
with --why, inline and process-pool execution, all-hits second run, concurrent runs of one
graph, corrupt objects rebuilt, and resume after Ctrl-C, SIGTERM and kill -9."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from repro import kernels
from repro.engine.executor import execute
from repro.engine.job import Job, topo_order
from repro.engine.job_run import COMPUTED, FAILED, HIT, SKIPPED, UNCACHED
from repro.engine.plan import plan
from repro.engine.source_hash import clear_source_cache, source_hash, source_manifest
from repro.paths import runs_root
from repro.store.objects import Store
from repro.store.runs import RunRecorder, load_run

MOD = "repro_testjobs"

# A small "table": prepare data -> train (per seed, checkpoints in scratch, resumable) ->
# evaluate.  Every call is appended to $REPRO_TEST_CALLS so tests can count computations.
JOBS_SOURCE = '''
"""Job implementations used by tests/test_engine.py."""
import json
import os
import time

from repro.engine.job import Job
from repro.keys import sha256_bytes


def _note(ctx, text=""):
    path = os.environ.get("REPRO_TEST_CALLS")
    if path:
        with open(path, "a") as f:
            f.write(f"{ctx.job.kind} {ctx.job.label} {os.getpid()} {text}\\n")


def prepare(ctx):
    _note(ctx)
    (ctx.out / "data.json").write_text(json.dumps(list(range(ctx.config["n"]))))


def train(ctx):
    data = json.loads(ctx.input("prepare").read_text("data.json"))
    steps = ctx.config["steps"]
    delay = float(os.environ.get("REPRO_TEST_DELAY", "0"))  # not part of the key
    stop_at = int(os.environ.get("REPRO_TEST_INTERRUPT_AT", "-1"))
    ckpt = ctx.scratch / "ckpt.json"
    step, w = 0, float(ctx.seed)
    if ckpt.exists():
        state = json.loads(ckpt.read_text())
        step, w = state["step"], state["w"]
    _note(ctx, f"resume={step}")
    while step < steps:
        if step == stop_at:
            raise KeyboardInterrupt
        w = 0.5 * w + ctx.config["lr"] * sum(data) / (step + 1)
        step += 1
        tmp = ckpt.with_suffix(".tmp")
        tmp.write_text(json.dumps({"step": step, "w": w}))
        os.replace(tmp, ckpt)
        ctx.progress(step, steps, "training")
        if delay:
            time.sleep(delay)
    (ctx.out / "model.json").write_text(json.dumps({"w": w, "steps": steps}))


def fail_user(ctx):
    from repro.errors import ConfigError

    raise ConfigError("a user error in a job")


def evaluate(ctx):
    _note(ctx)
    w = json.loads(ctx.inputs[0].read_text("model.json"))["w"]
    (ctx.out / "score.json").write_text(json.dumps({"score": round(w, 12)}))


def threads(ctx):
    import torch
    from threadpoolctl import threadpool_info

    blas = sorted({p["num_threads"] for p in threadpool_info()})
    (ctx.out / "threads.json").write_text(json.dumps(
        {"torch": torch.get_num_threads(), "pools": blas, "ctx": ctx.threads}))


def noise(ctx):
    _note(ctx)
    (ctx.out / "noise.bin").write_bytes(os.urandom(16))


def fail(ctx):
    raise ValueError("this job always fails")


def graph(n=10, steps=5, lr=0.01, seeds=(0,)):
    prep = Job("prepare", __name__ + ":prepare", {"n": n}, deterministic=True, label="prep",
               fingerprints={"dataset": "toy-" + str(n)})
    out = []
    for s in seeds:
        tr = Job("train", __name__ + ":train", {"steps": steps, "lr": lr},
                 (prep,), seed=s, label=f"train/s{s}")
        out.append(Job("evaluate", __name__ + ":evaluate", {}, (tr,), seed=s, label=f"eval/s{s}"))
    return out
'''


@pytest.fixture
def jobs_module(tmp_path, monkeypatch):
    """The test job module on sys.path (and PYTHONPATH for child processes)."""
    pkg = tmp_path / "pkgs"
    pkg.mkdir()
    (pkg / f"{MOD}.py").write_text(JOBS_SOURCE)
    monkeypatch.syspath_prepend(str(pkg))
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(pkg), os.environ.get("PYTHONPATH", "")]))
    calls = tmp_path / "calls.log"
    monkeypatch.setenv("REPRO_TEST_CALLS", str(calls))
    monkeypatch.delenv("REPRO_TEST_INTERRUPT_AT", raising=False)
    sys.modules.pop(MOD, None)
    clear_source_cache()
    import importlib

    mod = importlib.import_module(MOD)
    mod.calls_log = calls
    mod.path = pkg / f"{MOD}.py"
    yield mod
    sys.modules.pop(MOD, None)
    clear_source_cache()


def _calls(mod) -> list[list[str]]:
    if not mod.calls_log.exists():
        return []
    return [line.split() for line in mod.calls_log.read_text().splitlines()]


def _kinds(mod) -> list[str]:
    return sorted(c[0] for c in _calls(mod))


# ---------------------------------------------------------------------- keys
def test_key_is_order_invariant_and_sensitive_to_every_part(jobs_module):
    base = dict(kind="train", impl=f"{MOD}:train", config={"lr": 0.1, "opt": {"b": 1, "a": 2}},
                seed=0, fingerprints={"dataset": "d1", "evaluator": "e1"})
    prep = Job("prepare", f"{MOD}:prepare", {"n": 3}, deterministic=True)
    j = Job(inputs=(prep,), **base)
    same = Job(inputs=(prep,), **{**base, "config": {"opt": {"a": 2, "b": 1}, "lr": 0.1},
                                  "fingerprints": {"evaluator": "e1", "dataset": "d1"}},
               label="another label")
    assert j.key() == same.key() and j == same and len({j, same}) == 1
    variants = [
        Job(inputs=(prep,), **{**base, "config": {"lr": 0.2, "opt": {"b": 1, "a": 2}}}),
        Job(inputs=(prep,), **{**base, "config": {"lr": 0.1, "opt": {"b": 1, "a": 3}}}),
        Job(inputs=(prep,), **{**base, "seed": 1}),
        Job(inputs=(prep,), **{**base, "fingerprints": {"dataset": "d2", "evaluator": "e1"}}),
        Job(inputs=(Job("prepare", f"{MOD}:prepare", {"n": 4}, deterministic=True),), **base),
        Job(inputs=(prep,), **{**base, "kind": "train2"}),
        Job(inputs=(prep,), **{**base, "impl": f"{MOD}:evaluate"}),
        Job(inputs=(), **base),
        Job(inputs=(prep,), **base, threads=2),
    ]
    keys = {v.key() for v in variants} | {j.key()}
    assert len(keys) == len(variants) + 1
    parts = j.key_parts()
    assert set(parts) == {"schema", "kind", "impl", "source", "config", "inputs",
                          "fingerprints", "seed", "threads", "plugins", "kernels"}
    assert parts["kernels"] == {"mode": "pinned", "pin": "x86-64-avx2-portable",
                                "version": kernels.PIN_VERSION}
    assert parts["inputs"] == [prep.key()]
    # configs are copied: mutating the caller's dict changes nothing
    cfg = {"lr": 0.1}
    j2 = Job("train", f"{MOD}:train", cfg, seed=0)
    k2 = j2.key()
    cfg["lr"] = 0.5
    assert j2.key() == k2 == Job("train", f"{MOD}:train", {"lr": 0.1}, seed=0).key()


def test_invalid_jobs_are_refused(jobs_module):
    with pytest.raises(ValueError, match="package.module:function"):
        Job("train", "no_colon")
    with pytest.raises(ValueError, match="seed"):
        Job("train", f"{MOD}:train", seed=True)
    with pytest.raises(ValueError, match="canonical JSON"):
        Job("train", f"{MOD}:train", {"path": Path("/tmp")}, seed=0)
    with pytest.raises(ValueError, match="canonical JSON"):
        Job("train", f"{MOD}:train", {"lr": float("nan")}, seed=0)
    for bad in (0, True, 1.5):
        with pytest.raises(ValueError, match="threads"):
            Job("train", f"{MOD}:train", seed=0, threads=bad)
    for bad in ("repro.keys", ("not a module",), ("",)):
        with pytest.raises(ValueError, match="plugins"):
            Job("train", f"{MOD}:train", seed=0, plugins=bad)


def test_source_hash_follows_repro_imports_and_changes_with_the_code(jobs_module):
    names = [n for n, _ in source_manifest(MOD)]
    assert MOD in names and "repro.keys" in names and "repro.engine.job" in names
    assert "repro.engine.source_hash" in names  # imported lazily inside Job.key_parts
    assert not any(n.startswith(("json", "os")) for n in names)
    job = graph_job = jobs_module.graph()[0]
    old_key, old_src = graph_job.key(), source_hash(MOD)
    jobs_module.path.write_text(JOBS_SOURCE.replace("0.5 * w", "0.25 * w"))
    clear_source_cache()
    assert source_hash(MOD) != old_src
    fresh = Job(job.kind, job.impl, job.config, job.inputs, job.seed, job.fingerprints, job.label)
    assert fresh.key() != old_key
    # and a change in an imported repro module would change it as well
    assert dict(source_manifest("repro.engine.job"))["repro.keys"] == \
        dict(source_manifest(MOD))["repro.keys"]


def test_parsed_imports_are_kept_between_processes_by_file_digest(jobs_module, _repro_home,
                                                                    monkeypatch):
    """What each file imports is stored under REPRO_HOME keyed by its bytes' digest (issue 31):
    a later process hashes without parsing an unchanged file, and an edited one is parsed."""
    import ast

    from repro.engine.source_hash import IMPORTS_CACHE

    first = source_manifest(MOD)
    assert (_repro_home / IMPORTS_CACHE).is_file()
    clear_source_cache()  # as a new process: only the file is left
    parsed = []
    real_parse = ast.parse
    monkeypatch.setattr(ast, "parse", lambda src, *a, **k: parsed.append(k.get("filename"))
                        or real_parse(src, *a, **k))
    assert source_manifest(MOD) == first and parsed == []
    jobs_module.path.write_text(JOBS_SOURCE.replace("0.5 * w", "0.25 * w"))
    clear_source_cache()
    second = source_manifest(MOD)
    assert second != first and parsed == [str(jobs_module.path)]
    # a damaged entry, a file of another schema or of another reader: a miss, same hashes
    cache = _repro_home / IMPORTS_CACHE
    data = json.loads(cache.read_text())
    assert data["schema"] == 1 and len(data["reader"]) == 64
    data["entries"] = {k: (7 if MOD in k else v) for k, v in data["entries"].items()}
    cache.write_text(json.dumps(data))
    clear_source_cache()
    parsed.clear()
    assert source_manifest(MOD) == second and parsed == [str(jobs_module.path)]
    for damaged in ({**data, "reader": "0" * 64}, {**data, "schema": 0}, [1, 2], "{"):
        cache.write_text(damaged if isinstance(damaged, str) else json.dumps(damaged))
        clear_source_cache()
        parsed.clear()
        assert source_manifest(MOD) == second and str(jobs_module.path) in parsed


def test_a_plugin_loaded_by_name_is_part_of_the_key(jobs_module, tmp_path):
    """A module the job loads through a registry (no import statement leads to it) is hashed
    when the job names it in ``plugins``: editing it changes the key."""
    plug = jobs_module.path.parent / "repro_testplugin.py"
    plug.write_text("def method():\n    return 1\n")
    clear_source_cache()
    job = Job("train", f"{MOD}:train", {"lr": 0.1}, seed=0, plugins=("repro_testplugin",))
    bare = Job("train", f"{MOD}:train", {"lr": 0.1}, seed=0)
    assert job.key_parts()["plugins"] == ["repro_testplugin"] and job.key() != bare.key()
    assert Job("train", f"{MOD}:train", {"lr": 0.1}, seed=0,
               plugins=["repro_testplugin", "repro_testplugin"]).key() == job.key()
    old = job.key()
    plug.write_text("def method():\n    return 2\n")
    clear_source_cache()
    again = Job("train", f"{MOD}:train", {"lr": 0.1}, seed=0, plugins=("repro_testplugin",))
    assert again.key() != old
    assert bare.key_parts()["source"] == source_hash(MOD)


def test_topo_order_merges_shared_jobs(jobs_module):
    targets = jobs_module.graph(seeds=(0, 1))
    order = topo_order(targets + jobs_module.graph(seeds=(1,)))
    assert [j.kind for j in order] == ["prepare", "train", "evaluate", "train", "evaluate"]
    assert len({j.key() for j in order}) == 5


# ---------------------------------------------------------------------- execution
def test_second_run_is_all_hits_and_plan_says_why(jobs_module):
    targets = jobs_module.graph(seeds=(0, 1))
    entries = plan(targets)
    assert [e.action for e in entries] == ["run"] * 5
    assert entries[0].why == "new: no earlier run of prepare:prep"
    with RunRecorder(table="toy/table") as rec:
        report = execute(targets, recorder=rec)
    assert [r.status for r in report.results] == [COMPUTED] * 5
    assert _kinds(jobs_module) == ["evaluate", "evaluate", "prepare", "train", "train"]
    first = [report.object(t).read_bytes("score.json") for t in targets]
    run1 = load_run(rec.path).run
    assert run1["status"] == "FINISHED" and len(run1["keys"]["written"]) == 5
    assert [j["status"] for j in run1["jobs"]] == [COMPUTED] * 5

    jobs_module.calls_log.unlink()
    with RunRecorder(table="toy/table") as rec2:
        again = execute(jobs_module.graph(seeds=(0, 1)), recorder=rec2)
    assert again.all_hits and not jobs_module.calls_log.exists()
    # only the targets were needed; their inputs were not even read
    assert [r.status for r in again.results] == [HIT] * 5
    assert [again.object(t).read_bytes("score.json") for t in targets] == first
    run2 = load_run(rec2.path).run
    assert sorted(run2["keys"]["read"]) == sorted(run1["keys"]["written"])
    assert all(e.cached and e.action == "hit" for e in plan(targets))

    changed = jobs_module.graph(seeds=(0, 1), lr=0.02)
    why = {e.job.label: e for e in plan(changed)}
    assert why["prep"].action == "hit"
    assert why["train/s0"].why == "config.lr 0.01 -> 0.02"
    assert why["eval/s1"].why == "input train/s1 changed"
    reseeded = {e.job.label: e for e in plan(jobs_module.graph(seeds=(7,)))}
    assert reseeded["train/s7"].why.startswith("new: no earlier run")
    jobs_module.path.write_text(JOBS_SOURCE + "\n# a comment changes the source hash\n")
    clear_source_cache()
    fresh = jobs_module.graph(seeds=(0,))  # new Job objects: keys are computed afresh
    reasons = {e.job.label: e.why for e in plan(fresh)}
    assert reasons["train/s0"] == f"source of {MOD} changed; input prep changed"
    assert reasons["prep"] == f"source of {MOD} changed"


def test_force_kind_recomputes_only_that_kind_and_inputs_not_needed_are_skipped(jobs_module):
    targets = jobs_module.graph()
    execute(targets)
    jobs_module.calls_log.unlink()
    rep = execute(targets, force="evaluate")
    assert [r.status for r in rep.results] == [HIT, HIT, COMPUTED]
    assert _kinds(jobs_module) == ["evaluate"]
    # the train object disappears (gc): the evaluate target is still a hit; train not needed
    store = Store()
    import shutil

    train_key = rep.results[1].key
    shutil.rmtree(store.object_dir(train_key))
    rep2 = execute(targets)
    assert [r.status for r in rep2.results] == [HIT, SKIPPED, HIT] and rep2.all_hits
    entries = plan(targets)
    assert entries[1].action == "skip" and "downstream" in entries[1].why
    # forcing everything recomputes everything
    assert [r.status for r in execute(targets, force=True).results] == [COMPUTED] * 3


def test_corrupt_object_in_a_graph_is_reported_and_rebuilt(jobs_module, caplog):
    targets = jobs_module.graph()
    rep = execute(targets)
    store = Store()
    score = rep.object(targets[0]).file("score.json")
    os.chmod(score, 0o644)
    score.write_text('{"score": 999}')
    jobs_module.calls_log.unlink()
    with caplog.at_level("WARNING", logger="repro.store"):
        rep2 = execute(targets, store=store)
    assert [c.key for c in store.corrupt] == [targets[0].key()]
    assert any("corrupt store object" in r.getMessage() for r in caplog.records)
    # the corrupt evaluate object is rebuilt from its (verified) train input
    assert [r.status for r in rep2.results] == [HIT, HIT, COMPUTED]
    assert rep2.object(targets[0]).read_bytes("score.json") == \
        json.dumps({"score": json.loads(rep2.object(targets[0]).read_text("score.json"))
                    ["score"]}).encode()
    assert json.loads(rep2.object(targets[0]).read_text("score.json"))["score"] != 999


def test_unseeded_job_is_never_cached(jobs_module):
    noise = Job("noise", f"{MOD}:noise", {}, label="noise")
    down = Job("evaluate2", f"{MOD}:prepare", {"n": 2}, (noise,), seed=0)
    assert not noise.cacheable and not down.cacheable
    r1 = execute([down])
    r2 = execute([down])
    assert [r.status for r in r1.results] == [UNCACHED, UNCACHED] == \
        [r.status for r in r2.results]
    assert r1.object(noise).ephemeral and r1.object(noise).read_bytes("noise.bin") != \
        r2.object(noise).read_bytes("noise.bin")
    assert Store().keys() == []
    assert "not cacheable" in plan([down])[0].why


@pytest.mark.parametrize("jobs", [1, 2])
def test_failing_job_fails_the_run_and_keeps_finished_work(jobs_module, jobs):
    prep = jobs_module.graph()[0].inputs[0].inputs[0]
    bad = Job("broken", f"{MOD}:fail", {}, (prep,), seed=0, label="broken")
    after = Job("evaluate", f"{MOD}:evaluate", {}, (bad,), seed=0, label="after")
    with pytest.raises(ValueError, match="always fails") as ei:
        with RunRecorder(table="t") as rec:
            execute([after], recorder=rec, jobs=jobs)
    assert any("while running job broken" in n for n in getattr(ei.value, "__notes__", []))
    run = load_run(rec.path).run
    assert run["status"] == "FAILED" and "always fails" in run["error"]
    assert [j["status"] for j in run["jobs"]] == ["computed", "failed", "cancelled"]
    assert Store().has(prep.key()) and not Store().has(bad.key())


@pytest.mark.parametrize("jobs", [1, 2])
def test_keep_going_cancels_only_the_failed_jobs_dependents(jobs_module, jobs):
    good = jobs_module.graph(seeds=(0, 1))
    prep = good[0].inputs[0].inputs[0]
    bad = Job("broken", f"{MOD}:fail", {}, (prep,), seed=0, label="broken")
    after = Job("evaluate", f"{MOD}:evaluate", {}, (bad,), seed=0, label="after")
    report = execute([after, *good], jobs=jobs, keep_going=True)
    status = {r.job.label: r.status for r in report.results}
    assert status["broken"] == "failed" and status["after"] == "cancelled"
    assert {status[t.label] for t in good} == {COMPUTED}
    assert "always fails" in report.failure_of([after]).error
    assert report.failure_of(good) is None
    assert Store().has(good[1].key()) and not Store().has(bad.key())


def test_keep_going_still_stops_on_a_user_error(jobs_module, monkeypatch):
    from repro.errors import SpecError

    def user_error(ctx):
        raise SpecError("tables/x.toml: typo")

    monkeypatch.setattr(jobs_module, "fail", user_error)
    prep = jobs_module.graph()[0].inputs[0].inputs[0]
    bad = Job("broken", f"{MOD}:fail", {}, (prep,), seed=0, label="broken")
    with pytest.raises(SpecError):
        execute([bad, *jobs_module.graph(seeds=(3,))], keep_going=True)


def test_ctrl_c_keeps_checkpoint_marks_interrupted_and_next_run_resumes(jobs_module, monkeypatch):
    targets = jobs_module.graph(steps=6)
    monkeypatch.setenv("REPRO_TEST_INTERRUPT_AT", "3")
    with pytest.raises(KeyboardInterrupt):
        with RunRecorder(table="t") as rec:
            execute(targets, recorder=rec)
    run = load_run(rec.path).run
    assert run["status"] == "INTERRUPTED"
    assert [j["status"] for j in run["jobs"]] == ["computed", "interrupted", "cancelled"]
    train_key = targets[0].inputs[0].key()
    store = Store()
    assert json.loads((store.scratch(train_key) / "ckpt.json").read_text())["step"] == 3
    assert not list(store.objects_dir.glob("*/.tmp-*"))
    monkeypatch.delenv("REPRO_TEST_INTERRUPT_AT")
    rep = execute(targets)
    assert [r.status for r in rep.results] == [HIT, COMPUTED, COMPUTED]
    assert [c[3] for c in _calls(jobs_module) if c[0] == "train"] == ["resume=0", "resume=3"]
    assert not (store.root / "scratch" / train_key).exists()
    # the resumed result equals an uninterrupted computation
    uninterrupted = jobs_module.graph(steps=6)
    ref = Store(store.root.parent / "ref-store")
    assert execute(uninterrupted, store=ref).object(uninterrupted[0]).read_bytes("score.json") \
        == rep.object(targets[0]).read_bytes("score.json")


RUNNER = textwrap.dedent('''
    import json, sys
    import {mod} as m
    from repro.engine.executor import execute
    from repro.store.runs import RunRecorder
    kw = json.loads(sys.argv[1])
    jobs = kw.pop("jobs", 1)
    try:
        with RunRecorder(table="t") as rec:
            print(rec.run_id, flush=True)
            report = execute(m.graph(**kw), recorder=rec, jobs=jobs)
    except KeyboardInterrupt:
        sys.exit(130)
    print(json.dumps([r.status for r in report.results]), flush=True)
''').format(mod=MOD)


def _spawn_runner(kw: dict, delay: float) -> subprocess.Popen:
    env = {**os.environ, "REPRO_TEST_DELAY": str(delay)}
    return subprocess.Popen([sys.executable, "-c", RUNNER, json.dumps(kw)], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_for_step(path: Path, step: int, proc, timeout=60.0) -> None:
    deadline = time.time() + timeout
    while time.time() < deadline:
        try:
            if json.loads(path.read_text())["step"] >= step:
                return
        except (OSError, ValueError):
            pass
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.02)
    raise AssertionError("training never reached the step")


@pytest.mark.parametrize("sig,jobs", [(signal.SIGKILL, 1), (signal.SIGTERM, 1),
                                      (signal.SIGTERM, 2)])
def test_killed_run_resumes_training_from_its_checkpoint(jobs_module, sig, jobs):
    kw = {"steps": 40, "jobs": jobs}
    targets = jobs_module.graph(steps=40)
    train_key = targets[0].inputs[0].key()
    ckpt = Store().root / "scratch" / train_key / "ckpt.json"
    proc = _spawn_runner(kw, delay=0.05)
    _wait_for_step(ckpt, 3, proc)
    os.kill(proc.pid, sig)
    out, err = proc.communicate(timeout=60)
    killed_run = out.split()[0]
    reached = json.loads(ckpt.read_text())["step"]
    assert 3 <= reached < 40
    if sig == signal.SIGTERM:
        assert proc.returncode == 130, err
        assert load_run(runs_root() / killed_run).status == "INTERRUPTED"
    else:
        assert proc.returncode == -signal.SIGKILL
        assert load_run(runs_root() / killed_run).status == "RUNNING"  # until someone looks
    store = Store()
    assert store.has(targets[0].inputs[0].inputs[0].key())  # prepare finished before the kill
    rep = execute(jobs_module.graph(steps=40))
    assert [r.status for r in rep.results] == [HIT, COMPUTED, COMPUTED]
    resumes = [c[3] for c in _calls(jobs_module) if c[0] == "train"]
    assert resumes[0] == "resume=0" and int(resumes[-1].split("=")[1]) >= 3
    from repro.store.index import RunIndex

    assert {r["run_id"]: r["status"] for r in RunIndex().list()}[killed_run] == "INTERRUPTED"
    ref = Store(store.root.parent / "ref-store")
    clean = jobs_module.graph(steps=40)
    assert execute(clean, store=ref).object(clean[0]).read_bytes("score.json") == \
        rep.object(rep.results[-1].job).read_bytes("score.json")


def test_two_concurrent_runs_of_one_graph_compute_each_job_once(jobs_module):
    kw = {"seeds": [0, 1], "steps": 8}
    procs = [_spawn_runner(kw, delay=0.05) for _ in range(2)]
    outs = [p.communicate(timeout=120) for p in procs]
    for p, (out, err) in zip(procs, outs):
        assert p.returncode == 0, err
    statuses = [json.loads(out.splitlines()[-1]) for out, _ in outs]
    computed = [s.count("computed") for s in statuses]
    assert sum(computed) == 5  # each job computed by exactly one of the two runs
    assert sorted(c[0] for c in _calls(jobs_module)) == \
        ["evaluate", "evaluate", "prepare", "train", "train"]
    targets = jobs_module.graph(seeds=(0, 1), steps=8)
    store = Store()
    assert sorted(store.keys()) == sorted(j.key() for j in topo_order(targets))
    runs = [load_run(runs_root() / out.split()[0]).run for out, _ in outs]
    assert all(r["status"] == "FINISHED" for r in runs)
    assert set(runs[0]["keys"]["read"]) | set(runs[0]["keys"]["written"]) == \
        set(runs[1]["keys"]["read"]) | set(runs[1]["keys"]["written"]) == set(store.keys())


class _Events:
    def __init__(self):
        self.started, self.progress, self.finished = [], [], []

    def graph_started(self, entries):
        self.entries = entries

    def job_started(self, job, key):
        self.started.append(job.label)

    def job_progress(self, job, key, done, total, message):
        self.progress.append((job.label, done, total, message))

    def job_finished(self, result):
        self.finished.append((result.job.label, result.status))

    def graph_finished(self, report):
        self.report = report


def test_process_pool_gives_the_same_bytes_as_inline(jobs_module):
    targets = jobs_module.graph(seeds=(0, 1, 2), steps=4)
    inline_store = Store(Store().root.parent / "inline-store")
    inline = execute(targets, store=inline_store)
    jobs_module.calls_log.unlink()
    ev = _Events()
    pooled = execute(jobs_module.graph(seeds=(0, 1, 2), steps=4), jobs=2, hook=ev)
    assert [r.status for r in pooled.results] == [COMPUTED] * 7
    for t in targets:
        assert pooled.object(t).read_bytes("score.json") == \
            inline.object(t).read_bytes("score.json")
    assert str(os.getpid()) not in {c[2] for c in _calls(jobs_module)}  # ran in workers
    assert sorted(set(ev.started)) == sorted(j.label for j in topo_order(targets))
    assert ("train/s0", 4, 4, "training") in ev.progress
    assert len(ev.finished) == 7 and ev.report.counts == {COMPUTED: 7}
    assert execute(targets, jobs=2).all_hits


@pytest.mark.parametrize("jobs", [1, 2])
def test_a_job_computes_with_its_own_thread_count_whatever_jobs_says(jobs_module, jobs):
    """A table's bytes must not depend on --jobs: a job's declared ``threads`` (part of its
    key) is what torch and the BLAS/OpenMP pools use while it runs; the caller's count is
    restored afterwards; a job without one gets the executor's ``threads_per_job``."""
    import torch

    before = torch.get_num_threads()
    one = Job("probe", f"{MOD}:threads", {"n": 1}, seed=0, label="one", threads=1)
    two = Job("probe", f"{MOD}:threads", {"n": 2}, seed=0, label="two", threads=2)
    free = Job("probe", f"{MOD}:threads", {"n": 3}, seed=0, label="free")
    report = execute([one, two, free], jobs=jobs, threads_per_job=3)
    seen = {j.label: json.loads(report.object(j).read_text("threads.json")) for j in (one, two, free)}
    assert seen["one"] == {"torch": 1, "pools": [1], "ctx": 1}
    assert seen["two"] == {"torch": 2, "pools": [2], "ctx": 2}
    assert seen["free"]["torch"] == 3 and seen["free"]["ctx"] == 3
    assert torch.get_num_threads() == before
    assert len({one.key(), two.key(), Job("probe", f"{MOD}:threads", {"n": 1}, seed=0,
                                          threads=2).key()}) == 3


def test_rich_progress_hook_runs(jobs_module):
    from rich.console import Console

    from repro.engine.progress import RichProgressHook

    console = Console(record=True, width=100, force_terminal=False)
    with RichProgressHook(console) as hook:
        execute(jobs_module.graph(), hook=hook)
    text = console.export_text()
    assert "3 jobs: 0 cached, 3 to run" in text and "train/s0: computed" in text


@pytest.mark.parametrize("jobs", [1, 2])
def test_tasks_beside_the_graph_run_and_report_their_errors(jobs_module, jobs):
    """``execute(beside=...)``: a run's evaluators train in the graph's own pool, queued before
    its jobs (issue 32: an evaluator alone left a core idle); each task's outcome is reported
    (None, or its error) and ``on_beside`` hears each as it ends; the jobs are unaffected."""
    import functools

    targets = jobs_module.graph(seeds=(0, 1), steps=2)
    heard = []
    report = execute(targets, jobs=jobs, beside=[functools.partial(time.sleep, 0.2),
                                                 functools.partial(int, "x")],
                     on_beside=lambda i, err: heard.append((i, err)))
    assert report.beside[0] is None and report.beside[1].startswith("ValueError: ")
    assert sorted(heard) == [(0, None), (1, report.beside[1])]
    assert report.counts == {COMPUTED: len(report.results)}
    # nothing to run in the graph: the tasks still run (in a pool of ``jobs`` workers)
    again = execute(targets, jobs=jobs, beside=[functools.partial(int, "7")])
    assert again.all_hits and again.beside == [None]


def test_a_user_error_stops_the_tasks_beside_without_waiting_for_them(jobs_module):
    """A graph that stops (here a user error) stops ``beside`` tasks too, at once: before,
    the pool's exit waited for a running evaluator (up to its whole training)."""
    import functools

    from repro.errors import ConfigError

    t0 = time.perf_counter()
    with pytest.raises(ConfigError, match="a user error in a job"):
        execute([Job("fail", f"{MOD}:fail_user")], jobs=2, keep_going=True,
                beside=[functools.partial(time.sleep, 120)])
    assert time.perf_counter() - t0 < 60


def test_jobs_that_failed_earlier_are_recorded_failed_not_run_again(jobs_module):
    from repro.engine.executor import JobResult

    targets = jobs_module.graph(seeds=(0, 1), steps=2)
    train0 = next(j for j in topo_order(targets) if j.label == "train/s0")
    earlier = JobResult(train0, train0.key(), FAILED, 1.0, error="FloatingPointError: nan")
    report = execute(targets, keep_going=True, failed={train0.key(): earlier})
    assert report.result(train0).status == FAILED and report.result(train0).error == earlier.error
    assert report.failure_of([targets[0]]) is not None  # its dependents: cancelled
    assert "train/s0" not in {c[1] for c in _calls(jobs_module)}  # not run a second time
    assert any(c[1] == "train/s1" for c in _calls(jobs_module))
