"""Ray executor (issue 15, item 1): a graph run through Ray on a local two-CPU cluster started
here gives the keys, statuses and stored bytes of the same graph run locally; a job whose
worker is killed fails (its dependent is cancelled, the rest completes) and the rerun completes
with identical results; a worker that cannot see the store stops the run with a clear error;
the CLI options refuse bad combinations with exit 2 and ``repro --help`` never imports Ray."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from repro.engine.executor import ProgressHook, execute
from repro.engine.job import Job, topo_order
from repro.engine.job_run import CANCELLED, COMPUTED, FAILED, HIT
from repro.errors import ConfigError
from repro.store.objects import Store
from repro.store.runs import RunRecorder, load_run

MOD = "repro_rayjobs"

# prepare (numpy data) -> train (a small torch MLP per seed, one thread, as a table's jobs)
# -> measure (its loss).  The module imports nothing from repro, so its source hash (which the
# Ray workers check against the driver's) covers this file only, not modules that may be
# edited while the tests run.  REPRO_TEST_CALLS collects "label pid start end" per training;
# REPRO_TEST_DIE_LABEL names a training that kills its own process halfway through, once
# (REPRO_TEST_DIE_MARKER).
JOBS_SOURCE = '''
"""Job implementations used by tests/test_ray_executor.py."""
import json
import os
import signal
import time

import numpy as np


def prepare(ctx):
    rng = np.random.default_rng(ctx.config["data_seed"])
    np.save(ctx.out / "x.npy", rng.standard_normal((256, 8)).astype(np.float32))


def _weights(model):
    return np.concatenate([p.detach().numpy().ravel() for p in model.parameters()])


def train(ctx):
    import torch

    ctx.seed_globals()
    t0 = time.time()
    barrier = os.environ.get("REPRO_TEST_BARRIER")
    if barrier:  # wait (at most 60 s) until a second process has started a training
        with open(barrier, "a") as f:
            f.write(f"{os.getpid()}\\n")
        while time.time() < t0 + 60 and len(set(open(barrier).read().split())) < 2:
            time.sleep(0.05)
    x = torch.from_numpy(np.load(ctx.input("prepare").file("x.npy")))
    y = torch.sin(x.sum(1, keepdim=True))
    model = torch.nn.Sequential(torch.nn.Linear(8, 64), torch.nn.Tanh(), torch.nn.Linear(64, 1))
    opt = torch.optim.SGD(model.parameters(), lr=0.05)
    steps = ctx.config["steps"]
    marker = os.environ.get("REPRO_TEST_DIE_MARKER")
    for step in range(steps):
        opt.zero_grad()
        loss = ((model(x) - y) ** 2).mean()
        loss.backward()
        opt.step()
        ctx.progress(step + 1, steps)
        if (step == steps // 2 and ctx.job.label == os.environ.get("REPRO_TEST_DIE_LABEL")
                and marker and not os.path.exists(marker)):
            open(marker, "w").close()
            os.kill(os.getpid(), signal.SIGKILL)
    (ctx.out / "weights.bin").write_bytes(_weights(model).astype(np.float32).tobytes())
    calls = os.environ.get("REPRO_TEST_CALLS")
    if calls:
        with open(calls, "a") as f:
            f.write(f"{ctx.job.label} {os.getpid()} {t0} {time.time()}\\n")


def measure(ctx):
    import torch

    w = torch.from_numpy(np.frombuffer(ctx.inputs[0].read_bytes("weights.bin"), np.float32).copy())
    x = torch.from_numpy(np.load(ctx.input("prepare").file("x.npy")))
    w1, b1 = w[:512].reshape(64, 8), w[512:576]
    w2, b2 = w[576:640].reshape(1, 64), w[640:641]
    pred = torch.tanh(x @ w1.T + b1) @ w2.T + b2
    loss = float(((pred - torch.sin(x.sum(1, keepdim=True))) ** 2).mean())
    (ctx.out / "score.json").write_text(json.dumps({"loss": loss}))
'''


@pytest.fixture(scope="module")
def ray_cluster(tmp_path_factory):
    """A local Ray instance of two CPUs (two worker processes run side by side), started once
    for the module with the test jobs' module on the workers' PYTHONPATH."""
    ray = pytest.importorskip("ray", reason="the Ray executor's tests need `pip install "
                              "'repro[ray]'` (part of the dev extra)")
    pkg = tmp_path_factory.mktemp("rayjobs")
    (pkg / f"{MOD}.py").write_text(JOBS_SOURCE)
    old_path = os.environ.get("PYTHONPATH")
    os.environ["PYTHONPATH"] = os.pathsep.join(p for p in (str(pkg), old_path) if p)
    sys.path.insert(0, str(pkg))
    ray.init(num_cpus=2, include_dashboard=False, object_store_memory=80 << 20,
             log_to_driver=False, _temp_dir=str(tmp_path_factory.mktemp("ray")))
    try:
        yield pkg
    finally:
        ray.shutdown()
        sys.path.remove(str(pkg))
        sys.modules.pop(MOD, None)
        if old_path is None:
            os.environ.pop("PYTHONPATH", None)
        else:
            os.environ["PYTHONPATH"] = old_path


def _graph(seeds=(0, 1, 2), steps=40) -> list[Job]:
    """prep -> train/s<seed> -> measure/s<seed> (every job with one thread, as a table's)."""
    prep = Job("prepare", f"{MOD}:prepare", {"data_seed": 7}, deterministic=True, label="prep",
               threads=1)
    out = []
    for s in seeds:
        tr = Job("train", f"{MOD}:train", {"steps": steps}, (prep,), seed=s,
                 label=f"train/s{s}", threads=1)
        out.append(Job("measure", f"{MOD}:measure", {}, (tr, prep), seed=s,
                       label=f"measure/s{s}", threads=1))
    return out


def _payloads(store: Store, report) -> dict[str, dict]:
    """key -> the manifest's files (sha256 and size of every payload file)."""
    return {r.key: store.get(r.key).files for r in report.results}


def _scores(report) -> dict[str, bytes]:
    return {r.job.label: r.object.read_bytes("score.json") for r in report.results
            if r.job.kind == "measure"}


def _statuses(report) -> dict[str, str]:
    return {r.job.label: r.status for r in report.results}


class RecordingHook(ProgressHook):
    """Remembers the order of job_started / job_finished events."""

    def __init__(self):
        self.events: list[tuple[str, str]] = []

    def job_started(self, job, key):
        self.events.append(("start", key))

    def job_finished(self, result):
        self.events.append((result.status, result.key))


def _run(targets, store, backend=None, hook=None):
    """Execute with a run record (as a table run does: ``keep_going``); the report and the
    record's run.json."""
    with RunRecorder(table="toy/ray") as rec:
        report = execute(targets, store=store, recorder=rec, keep_going=True, backend=backend,
                         hook=hook)
    return report, load_run(rec.path).run


def _job_lines(run) -> list[tuple]:
    """A run record's job lines without their timings, in key order (jobs finish in another
    order when they run side by side)."""
    return sorted((j["key"], j["kind"], j["label"], j["seed"], j["status"], j["error"])
                  for j in run["jobs"])


def test_ray_run_equals_local_run_bitwise(ray_cluster, tmp_path, monkeypatch):
    from repro.engine.ray_executor import RayBackend

    calls = tmp_path / "calls.txt"
    monkeypatch.setenv("REPRO_TEST_CALLS", str(calls))
    local_store, ray_store = Store(tmp_path / "local"), Store(tmp_path / "ray")
    local, local_run = _run(_graph(), local_store)
    local_pids = {line.split()[1] for line in calls.read_text().splitlines()}
    calls.unlink()
    hook = RecordingHook()
    # the trainings wait for each other (at most a minute): a worker that finished its first
    # training before Ray started a second worker must not make "side by side" a race
    monkeypatch.setenv("REPRO_TEST_BARRIER", str(tmp_path / "barrier.txt"))
    remote, remote_run = _run(_graph(), ray_store, backend=RayBackend(), hook=hook)
    monkeypatch.delenv("REPRO_TEST_BARRIER")

    assert set(_statuses(remote).values()) == {COMPUTED}
    assert [r.key for r in remote.results] == [r.key for r in local.results]
    assert _payloads(ray_store, remote) == _payloads(local_store, local)  # every byte
    assert _scores(remote) == _scores(local)
    assert _job_lines(remote_run) == _job_lines(local_run)  # the run records' job lines
    # the trainings ran in Ray's worker processes, two of them side by side, never more than
    # the cluster's two CPUs (a task asks for its job's one thread)
    lines = [line.split() for line in calls.read_text().splitlines()]
    ray_pids = {pid for _, pid, _, _ in lines}
    assert str(os.getpid()) not in ray_pids and not ray_pids & local_pids
    assert len(ray_pids) >= 2
    spans = [(float(a), float(b)) for _, _, a, b in lines]
    assert max(sum(a <= t < b for a, b in spans) for t, _ in spans) <= 2
    # the progress hook saw every job start (through Ray's queue), once, before it finished
    for r in remote.results:
        assert [e for e in hook.events if e[1] == r.key] == [("start", r.key), (COMPUTED, r.key)]
    # a second Ray run finds everything in the store and computes nothing
    again, _ = _run(_graph(), ray_store, backend=RayBackend())
    assert set(_statuses(again).values()) == {HIT}


def test_killed_worker_fails_its_job_and_the_rerun_completes(ray_cluster, tmp_path,
                                                              monkeypatch):
    from repro.engine.ray_executor import RayBackend

    store = Store(tmp_path / "ray")
    monkeypatch.setenv("REPRO_TEST_DIE_LABEL", "train/s1")
    monkeypatch.setenv("REPRO_TEST_DIE_MARKER", str(tmp_path / "died-once"))
    first, first_run = _run(_graph(), store, backend=RayBackend())
    st = _statuses(first)
    assert (tmp_path / "died-once").exists()
    assert st["train/s1"] == FAILED and st["measure/s1"] == CANCELLED  # only its dependent
    assert {st[k] for k in ("prep", "train/s0", "train/s2", "measure/s0", "measure/s2")} \
        == {COMPUTED}
    failed = first.result(next(j for j in topo_order(_graph()) if j.label == "train/s1"))
    assert "WorkerCrashedError" in failed.error
    assert first_run["status"] == "FINISHED"

    rerun, _ = _run(_graph(), store, backend=RayBackend())
    st = _statuses(rerun)
    assert st["train/s1"] == COMPUTED and st["measure/s1"] == COMPUTED
    assert {st[k] for k in ("prep", "train/s0", "train/s2", "measure/s0", "measure/s2")} == {HIT}

    monkeypatch.delenv("REPRO_TEST_DIE_LABEL")
    local_store = Store(tmp_path / "local")
    local, _ = _run(_graph(), local_store)
    assert _scores(rerun) == _scores(local)
    assert _payloads(store, rerun) == _payloads(local_store, local)


def test_worker_that_cannot_reach_the_store_stops_the_run(ray_cluster, tmp_path):
    from repro.engine.ray_executor import RayBackend, _RaySession

    class ProbeLost(_RaySession):
        """A session whose probe file is gone before any task runs: what a node without the
        shared store sees."""

        def _open(self):
            super()._open()
            self.probe.unlink()

    class Backend(RayBackend):
        def __call__(self, store, hook, by_key, threads):
            return ProbeLost(self, store, hook, by_key, threads)

    store = Store(tmp_path / "store")
    with pytest.raises(ConfigError) as e:
        execute(_graph(), store=store, backend=Backend(), keep_going=True)
    msg = str(e.value)
    assert type(e.value) is ConfigError  # the worker's own error, not Ray's wrapper
    assert "cannot reach the store" in msg and str(store.root) in msg
    assert not list(store.objects_dir.glob("*/*"))  # nothing published


def test_worker_refuses_a_job_keyed_with_other_code(ray_cluster, tmp_path):
    from repro.engine.ray_executor import RayBackend

    mod = ray_cluster / "repro_rayjobs_edited.py"
    mod.write_text(JOBS_SOURCE)
    job = Job("prepare", "repro_rayjobs_edited:prepare", {"data_seed": 2}, deterministic=True,
              label="edited", threads=1)
    job.key()  # keyed with the code as it is now ...
    mod.write_text(JOBS_SOURCE + "\n# ... then the code changes before a worker runs it\n")
    with pytest.raises(ConfigError, match="runs other code than the driver for job edited"):
        execute([job], store=Store(tmp_path / "store"), backend=RayBackend(), keep_going=True)


def test_job_with_more_threads_than_any_node_is_refused_not_left_pending(ray_cluster, tmp_path):
    from repro.engine.ray_executor import RayBackend

    job = Job("prepare", f"{MOD}:prepare", {"data_seed": 1}, deterministic=True, label="wide",
              threads=3)
    with pytest.raises(ConfigError, match="computes with 3 threads but the largest node"):
        execute([job], store=Store(tmp_path / "store"), backend=RayBackend(), keep_going=True)


def _cli(argv, monkeypatch, capsys, hide_ray=False):
    from cli.main import main

    if hide_ray:
        monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` raises ImportError
    rc = main(argv)
    return rc, capsys.readouterr().err


def test_cli_refuses_address_without_ray_and_names_the_extra(monkeypatch, capsys):
    rc, err = _cli(["run", "marionette/table1", "--address", "127.0.0.1:6379", "--quiet"],
                   monkeypatch, capsys)
    assert rc == 2 and "--address" in err and "--executor ray" in err
    assert "Traceback" not in err
    rc, err = _cli(["run", "marionette/table1", "--executor", "ray", "--quiet"], monkeypatch,
                   capsys, hide_ray=True)
    assert rc == 2 and "pip install 'repro[ray]'" in err
    assert len(err.strip().splitlines()) == 1


def test_cli_unreachable_address_is_one_clear_error(monkeypatch, capsys):
    pytest.importorskip("ray")
    from repro.engine.ray_executor import _check_address

    with pytest.raises(ConfigError, match="no Ray cluster answers there"):
        _check_address("127.0.0.1:1")


def test_help_does_not_import_ray():
    out = subprocess.run([sys.executable, "-c", "import cli.main, sys; "
                          "cli.main.build_parser().parse_args(['run', 'x', '--executor', 'ray']); "
                          "print('ray' in sys.modules)"], capture_output=True, text=True)
    assert out.stdout.strip() == "False", out.stderr


# -- review fixes: SIGTERM, the address, GPUs, the driver's device check, Ray = local ----------

SIGTERM_DRIVER = '''
"""A driver that runs a slow training through Ray (starting its own local Ray, so ray.init runs
inside the executor's SIGTERM guard) and writes the run record's path and each start."""
import sys
from pathlib import Path

from repro.engine.executor import ProgressHook, execute
from repro.engine.job import Job
from repro.engine.ray_executor import RayBackend
from repro.store.objects import Store
from repro.store.runs import RunRecorder

store, started, runs = sys.argv[1:4]


class Hook(ProgressHook):
    def job_started(self, job, key):
        with open(started, "a") as f:
            f.write(job.label + "\\n")


prep = Job("prepare", "repro_rayjobs:prepare", {"data_seed": 5}, deterministic=True,
           label="prep", threads=1)
train = Job("train", "repro_rayjobs:train", {"steps": 10 ** 8}, (prep,), seed=0,
            label="train/slow", threads=1)
measure = Job("measure", "repro_rayjobs:measure", {}, (train, prep), seed=0,
              label="measure/slow", threads=1)
with RunRecorder(table="toy/ray-sigterm", runs_dir=runs) as rec:
    Path(started).with_suffix(".run").write_text(str(rec.path))
    try:
        execute([measure], store=Store(store), recorder=rec, keep_going=True,
                backend=RayBackend(), hook=Hook())
    except KeyboardInterrupt:
        sys.exit(130)
'''


def test_sigterm_to_a_ray_driver_records_the_run_interrupted(ray_cluster, tmp_path):
    """ray.init replaces the executor's SIGTERM handler with one that exits: without putting
    ours back, SIGTERM ends the run FAILED (SystemExit) instead of INTERRUPTED."""
    import signal
    import time

    script = tmp_path / "driver.py"
    script.write_text(SIGTERM_DRIVER)
    started = tmp_path / "started.txt"
    env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}
    env["REPRO_HOME"] = str(tmp_path / "home")
    proc = subprocess.Popen([sys.executable, str(script), str(tmp_path / "store"), str(started),
                             str(tmp_path / "runs")], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + 240
        while not (started.exists() and "train/slow" in started.read_text()):
            assert proc.poll() is None, proc.communicate()[0]
            assert time.monotonic() < deadline, "the slow training never started"
            time.sleep(0.5)
        time.sleep(1.0)  # the training is under way in a Ray worker
        proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130, out
    run = load_run(started.with_suffix(".run").read_text()).run
    assert run["status"] == "INTERRUPTED", (run["status"], run["error"], out)
    assert run["note"] == "interrupted (SIGTERM)"
    st = {j["label"]: j["status"] for j in run["jobs"]}
    assert st == {"prep": COMPUTED, "train/slow": "interrupted", "measure/slow": CANCELLED}


def test_cli_unreachable_address_is_refused_before_any_work(monkeypatch, capsys, tmp_path):
    """A bad --address ends the command in seconds, exit 2, one line, and leaves no run record
    (it used to be noticed after the evaluators trained, leaving a FAILED run)."""
    import time

    pytest.importorskip("ray")
    from repro.store.runs import run_dirs

    monkeypatch.setenv("REPRO_HOME", str(tmp_path))
    before = len(run_dirs())
    t0 = time.monotonic()
    rc, err = _cli(["run", "marionette/table1", "--executor", "ray", "--address", "127.0.0.1:1",
                    "--quiet"], monkeypatch, capsys)
    assert rc == 2 and "--address 127.0.0.1:1: no Ray cluster answers there" in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert time.monotonic() - t0 < 30
    assert len(run_dirs()) == before == 0
    assert not (tmp_path / "store").exists()


def test_cuda_job_on_a_cluster_without_gpus_is_refused_not_left_pending(ray_cluster, tmp_path):
    from repro.engine.ray_executor import RayBackend

    prep = Job("prepare", f"{MOD}:prepare", {"data_seed": 3}, deterministic=True, label="prep",
               threads=1)
    train = Job("train", f"{MOD}:train", {"steps": 5}, (prep,), seed=0, label="train/gpu",
                threads=1, device="cuda")
    with pytest.raises(ConfigError, match="train/gpu computes on cuda but the Ray cluster has "
                       "no GPU"):
        execute([train], store=Store(tmp_path / "store"), backend=RayBackend(), keep_going=True)


def test_ray_executor_skips_the_drivers_device_check(ray_cluster, monkeypatch):
    """--executor ray --device cuda on a driver without a GPU: the cluster's GPUs count (checked
    by the backend), so the driver-side check is skipped; the local executor still refuses."""
    import torch

    from cli.commands.tables import executor_backend
    from cli.main import build_parser
    from repro.engine.ray_executor import RayBackend

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    parser = build_parser()
    args = parser.parse_args(["run", "marionette/table1", "--executor", "ray", "--device", "cuda"])
    assert isinstance(executor_backend(args), RayBackend)
    args = parser.parse_args(["run", "marionette/table1", "--device", "cuda"])
    with pytest.raises(ConfigError, match=r"\(--device\)"):
        executor_backend(args)


@pytest.mark.slow
def test_quick_table1_through_ray_has_the_local_runs_values(ray_cluster, tmp_path, monkeypatch):
    """Quick Table 1 run locally and through the two-CPU Ray (separate homes: data, evaluators
    and every job computed twice) gives the same raw replicate values, bit for bit."""
    from repro.engine.ray_executor import RayBackend
    from repro.engine.runner import run_table
    from repro.paths import runs_root

    def values(home, **kw):
        monkeypatch.setenv("REPRO_HOME", str(tmp_path / home))
        _, _, run_id = run_table("marionette/table1", progress=False, **kw)
        rec = load_run(runs_root() / run_id)
        assert rec.run["status"] == "FINISHED"
        return sorted((v["row"], v["column"], v["replicate"], v["job"], repr(v["value"]))
                      for v in rec.values)

    local = values("local", jobs=2)
    remote = values("ray", backend=RayBackend())
    assert len(local) > 100 and remote == local
