"""Kernel pinning (issue 25, repro/kernels.py): importing repro pins the kernel paths, the pin
is measured before a job computes, job keys and run records name it, the op battery gives the
same bytes whatever the ambient settings under the pin (and not without it: the control), and
``verify`` knows hosts: it refuses an unpinned run against a pinned baseline and compares with
``--tolerance`` by the spread of training seeds."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from repro import kernels
from repro.engine import baselines as bl
from repro.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]
BATTERY = ROOT / "benchmarks" / "kernel_ops.py"
AMBIENT = ("ATEN_CPU_CAPABILITY", "MKL_CBWR", "ONEDNN_MAX_CPU_ISA", "DNNL_MAX_CPU_ISA",
           "OPENBLAS_CORETYPE", "OPENBLAS_NUM_THREADS", "NPY_DISABLE_CPU_FEATURES",
           "MKL_DYNAMIC", "OMP_DYNAMIC",
           kernels.FAST_ENV)


def _env(**extra) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in AMBIENT}
    env.update(extra)
    return env


def _py(code: str, **extra) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], env=_env(**extra), capture_output=True,
                          text=True, timeout=300, cwd=ROOT)


def _battery(**extra) -> dict:
    r = subprocess.run([sys.executable, str(BATTERY)], env=_env(**extra), capture_output=True,
                       text=True, timeout=300, cwd=ROOT)
    assert r.returncode == 0, r.stderr[-2000:]
    return json.loads(r.stdout)


def test_this_process_is_pinned():
    st = kernels.check()
    assert kernels.pinned_in_force(st) == []
    assert st["aten"] == "AVX2" and st["mkl_cbwr"] == "COMPATIBLE"  # read back from MKL
    assert st["onednn"] is False and st["nnpack"] is False
    assert st["deterministic_algorithms"] is True


def test_import_overrides_ambient_settings():
    code = ("import json, repro; from repro.kernels import check; "
            "print(json.dumps(check()))")
    r = _py(code, ATEN_CPU_CAPABILITY="default", MKL_CBWR="AUTO",
            NPY_DISABLE_CPU_FEATURES="")
    assert r.returncode == 0, r.stderr
    st = json.loads(r.stdout)
    assert st["aten"] == "AVX2" and kernels.pinned_in_force(st) == []


def test_fast_kernels_keep_the_hosts_paths_and_say_so():
    code = ("import json, repro; from repro import kernels; "
            "print(json.dumps([kernels.check(), kernels.key(), kernels.record()]))")
    r = _py(code, REPRO_FAST_KERNELS="1", ATEN_CPU_CAPABILITY="default")
    assert r.returncode == 0, r.stderr
    st, key, rec = json.loads(r.stdout)
    assert st["aten"] == "DEFAULT" and st["onednn"] is True  # nothing pinned
    assert key["mode"] == "fast" and key["isa"] and rec["mode"] == "fast"
    assert "fast" in kernels.describe(rec)
    # the ambient setting that chose those paths is in the key: the same host with nothing set
    # computes other bytes (the op battery: 40 of 50 differ) and must not share the key
    assert key["ambient"] == {"ATEN_CPU_CAPABILITY": "default"}
    r2 = _py(code, REPRO_FAST_KERNELS="1")
    assert r2.returncode == 0, r2.stderr
    assert "ambient" not in json.loads(r2.stdout)[1]


def test_numeric_libraries_loaded_before_repro_are_refused():
    code = ("import torch; (torch.ones(4, 4) @ torch.ones(4, 4)).exp(); import repro; "
            "from repro.kernels import check\n"
            "try:\n    check()\nexcept Exception as e:\n    print(type(e).__name__, e)")
    r = _py(code, ATEN_CPU_CAPABILITY="default")
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith("ConfigError") and "ATen capability DEFAULT" in r.stdout
    assert "--fast-kernels" in r.stdout


def test_job_keys_name_the_kernel_paths(monkeypatch):
    from repro.engine.job import Job

    j = Job("train", "repro.engine.job:topo_order", {"a": 1}, seed=0)
    pinned, key = j.key_parts()["kernels"], j.key()
    assert pinned == kernels.key() and pinned["mode"] == "pinned"
    monkeypatch.setenv(kernels.FAST_ENV, "1")
    j2 = Job("train", "repro.engine.job:topo_order", {"a": 1}, seed=0)
    assert j2.key_parts()["kernels"]["mode"] == "fast" and j2.key() != key


def test_run_records_name_the_pin(tmp_path):
    from repro.store.runs import RunRecorder

    rec = RunRecorder(table="t/x", scale="quick", dataset="d")
    k = rec.data["env"]["kernels"]
    assert k["mode"] == "pinned" and k["settings"] == kernels.PINNED_ENV
    assert k["host"]["isa"] in ("AVX2", "AVX512", "AMX", "below AVX2", "unknown")


def _ops(b: dict) -> dict:
    return {k: v for k, v in b.items() if not k.startswith("_")}


def test_op_battery_under_the_pin_matches_the_committed_hashes():
    """The pinned battery gives the bytes committed in tests/golden/kernel_ops.json, which were
    made on another CPU (an AMD EPYC, AVX2): on any x86-64 host with AVX2 this is the fast
    cross-host check of the pin (the quick baselines are the slow one).  A mismatch names the
    ops whose kernels the pin does not cover on this host."""
    import numpy
    import torch

    golden = json.loads((ROOT / "tests" / "golden" / "kernel_ops.json").read_text())
    if torch.__version__.split("+")[0] != "2.13.0" or numpy.__version__ != "2.4.6":
        pytest.skip("golden hashes are for torch 2.13.0 / numpy 2.4.6 (the pinned install)")
    got = _ops(_battery())
    differ = sorted(k for k in golden["ops"] if got.get(k) != golden["ops"][k])
    assert not differ, (f"pinned ops with other bytes than on the golden host: {differ} "
                        f"(this host: {kernels.host_paths()})")


def test_op_battery_ignores_ambient_settings_under_the_pin_and_tells_paths_apart_without():
    """Pinned, ambient settings naming other paths (ATen default, MKL AUTO) change no byte;
    unpinned, ATen's default path gives other bytes (the control: the battery can tell two
    kernel paths apart)."""
    pinned = [_ops(_battery(ATEN_CPU_CAPABILITY=a, MKL_CBWR=m))
              for a, m in (("default", "AUTO"), ("avx2", ""))]
    assert pinned[0] == pinned[1]
    fast = [_battery(REPRO_FAST_KERNELS="1", ATEN_CPU_CAPABILITY=a) for a in ("default", "avx2")]
    assert fast[0]["_state"]["aten"] == "DEFAULT" and fast[1]["_state"]["aten"] == "AVX2"
    assert fast[0]["_state"]["onednn"] and fast[0]["_state"]["nnpack"] is not None
    differ = [k for k in pinned[0] if _ops(fast[0])[k] != _ops(fast[1])[k]]
    assert differ, "unpinned ATen default and AVX2 paths gave the same bytes everywhere"


def test_the_library_avoids_the_host_dependent_torch_ops():
    """torch's sqrt / acos / cdist (MKL's vector maths) and its non-fused optimisers give
    host-dependent bits (repro/kernels.py): no library module calls them."""
    import re

    bad = re.compile(r"torch\.(sqrt|acos|cdist)\(|\.(sqrt|acos)\(\)|torch\.optim\.(Adam|AdamW|"
                     r"RMSprop|SGD|Adagrad)\(|\*\* *0?\.5\b|\.pow\(0?\.5\)")
    hits = []
    for path in sorted((ROOT / "repro").rglob("*.py")):
        if path.name == "kernels.py":
            continue
        for n, line in enumerate(path.read_text().splitlines(), 1):
            code = line.split("#", 1)[0]
            if bad.search(code) and not re.search(r"\b(np|numpy|math|scipy)\.", code):
                hits.append(f"{path.relative_to(ROOT)}:{n}: {line.strip()}")
    assert not hits, hits


def test_sqrt_is_within_one_ulp_and_exact_at_zero():
    import numpy as np
    import torch

    x = torch.rand(10_000, generator=torch.Generator().manual_seed(0)) * 100
    ref = np.sqrt(x.numpy().astype(np.float64)).astype(np.float32)
    got = kernels.sqrt(x).numpy()
    assert np.all(np.abs(got.view(np.int32) - ref.view(np.int32)) <= 1)
    assert kernels.sqrt(x).dtype == torch.float32 and kernels.sqrt(x.double()).dtype == torch.float64
    assert kernels.sqrt(torch.zeros(3)).tolist() == [0.0, 0.0, 0.0]
    y = x.clone().requires_grad_(True)
    kernels.sqrt(y).sum().backward()
    assert torch.allclose(y.grad, 0.5 / torch.sqrt(x), rtol=1e-5)


def test_optimisers_are_fused_on_the_cpu():
    import torch

    lin = torch.nn.Linear(3, 2)
    assert kernels.adam(lin.parameters(), lr=1e-3).defaults["fused"] is True
    opt = kernels.adamw([{"params": [lin.weight]}, {"params": [lin.bias]}], lr=1e-3)
    assert opt.defaults["fused"] is True


# ------------------------------------------------------------------ verify knows hosts
def _summary(mean=1.0, lo=0.9, hi=1.1, verdict="supported"):
    return {"table": "t/x", "cells": {"r": {"c": {"mean": mean, "n": 3,
                                                   "bootstrap_percentile": [lo, hi]}}},
            "claims": [{"id": "c1", "verdict": verdict}]}


def _kern(mode="pinned", vendor="AuthenticAMD", isa="AVX2", model="AMD EPYC"):
    rec = {"mode": mode, "host": {"vendor": vendor, "model": model, "isa": isa}}
    if mode == "pinned":
        rec.update(pin=kernels.PIN_NAME, version=kernels.PIN_VERSION)
    return rec


def test_verify_refuses_an_unpinned_run_against_a_pinned_baseline():
    base = bl.make_baseline(_summary(), scale="quick", dataset="d", run_id="r", kernels=_kern())
    why = bl.refusal(base, _kern("fast"))
    assert why and "--fast-kernels" in why and "\n" not in why
    assert "before kernel pinning" in bl.refusal(base, None)
    assert bl.refusal(base, _kern()) is None
    lines = bl.host_lines(base, _kern("fast", "GenuineIntel", "AVX512", "Intel Xeon"))
    assert "pinned" in lines[0] and "AMD EPYC" in lines[0] and "Intel Xeon" in lines[1]


def test_verify_refuses_another_pin_version():
    base = bl.make_baseline(_summary(), scale="quick", dataset="d", run_id="r", kernels=_kern())
    other = {**_kern(), "version": kernels.PIN_VERSION + 1}
    assert "remake the baselines" in bl.refusal(base, other)


def test_verify_says_when_the_host_differs():
    base = bl.make_baseline(_summary(), scale="quick", dataset="d", run_id="r", kernels=_kern())
    assert bl.host_note(base, _kern()) is None
    note = bl.host_note(base, _kern(vendor="GenuineIntel", isa="AVX512", model="Intel Xeon"))
    assert "host differs" in note and "both pinned" in note
    note = bl.host_note(base, _kern("fast", "GenuineIntel", "AVX512", "Intel Xeon"))
    assert "kernel paths differ" in note
    quiet = bl.host_note(base, _kern(vendor="GenuineIntel", isa="AVX512"), drift=False)
    assert "host differs" in quiet and "matches" in quiet


def test_tolerance_compares_by_the_spread():
    base = bl.make_baseline(_summary(), scale="quick", dataset="d", run_id="r", kernels=_kern())
    drifted = _summary(mean=1.25, lo=1.0, hi=1.5, verdict="inconclusive")
    assert len(bl.compare(base, drifted)) == 2  # the cell and the verdict
    # K x the current (--retrain) run's half-width 0.25: passes at K = 1, not at K = 0.5
    notes = []
    assert bl.compare(base, drifted, tolerance=1.0, retrain=True, notes=notes) == []
    assert any("within the tolerance" in n for n in notes) and any("one step" in n for n in notes)
    assert len(bl.compare(base, drifted, tolerance=0.5, retrain=True)) == 1
    # a verdict two steps away fails even under tolerance
    flipped = _summary(mean=1.0, verdict="contradicted")
    assert len(bl.compare(base, flipped, tolerance=3.0)) == 1


def test_baseline_kernels_do_not_enter_the_checksum():
    a = bl.make_baseline(_summary(), scale="quick", dataset="d", run_id="r", kernels=_kern())
    b = bl.make_baseline(_summary(), scale="quick", dataset="d", run_id="r", kernels=None)
    assert a["checksum"] == b["checksum"] and a["kernels"]["mode"] == "pinned"
    assert bl.compare(a, _summary()) == []


def test_verify_cli_tolerance_option_is_checked():
    from cli.main import main

    with pytest.raises(SystemExit) as e:
        main(["verify", "marionette/table1", "--baseline", "x", "--tolerance", "-1"])
    assert e.value.code == 2


def _recorded_run(monkeypatch, *, fast: bool, summary: dict) -> str:
    from repro.store.runs import RunRecorder

    if fast:
        monkeypatch.setenv(kernels.FAST_ENV, "1")
    rec = RunRecorder(table="marionette/table1", scale="quick", dataset="bandai2-mini",
                      config={})
    monkeypatch.delenv(kernels.FAST_ENV, raising=False)
    rec.start()
    rec.write_summary({**summary, "table": "marionette/table1"})
    rec.finish()
    return rec.run_id


def test_verify_table_refuses_a_fast_run_and_update_refuses_to_write_it(monkeypatch, tmp_path):
    from cli.main import main
    from repro.engine.runner import verify_table

    s = _summary()
    base = bl.make_baseline({**s, "table": "marionette/table1"}, scale="quick",
                            dataset="bandai2-mini", run_id="r", kernels=_kern())
    (tmp_path / "marionette").mkdir()
    (tmp_path / "marionette" / "table1.json").write_text(json.dumps(base))
    _recorded_run(monkeypatch, fast=True, summary=s)
    with pytest.raises(ConfigError, match="--fast-kernels"):
        verify_table("marionette/table1", tmp_path)
    problems, notes = verify_table("marionette/table1", tmp_path, tolerance=2.0)
    assert problems == [] and any("compared under --tolerance" in n for n in notes)
    out = tmp_path / "new"
    assert main(["verify", "marionette/table1", "--baseline", str(out), "--update"]) == 2
    assert not out.exists()
    # a pinned run is compared, matches, and --update writes its kernels into the baseline
    _recorded_run(monkeypatch, fast=False, summary=s)
    problems, notes = verify_table("marionette/table1", tmp_path)
    assert problems == [] and notes[0].startswith("baseline: pinned")
    assert main(["verify", "marionette/table1", "--baseline", str(out), "--update"]) == 0
    written = json.loads((out / "marionette" / "table1.json").read_text())
    assert written["kernels"]["mode"] == "pinned" and written["kernels"]["settings"]


def test_ray_tasks_get_the_pin():
    from repro.engine.ray_executor import _forwarded_env

    env = _forwarded_env()
    assert all(env[k] == v for k, v in kernels.PINNED_ENV.items())
    assert env[kernels.FAST_ENV] == "0"


def test_evaluator_keys_name_the_kernel_paths(monkeypatch):
    from repro.eval.provider import evaluator_key
    from repro.eval.settings import resolve_settings

    settings = resolve_settings("quick")
    a = evaluator_key("transformer", settings, "fp", 0)
    monkeypatch.setenv(kernels.FAST_ENV, "1")
    assert evaluator_key("transformer", settings, "fp", 0) != a


def test_fast_kernels_in_a_pinned_process_is_refused(capsys):
    """In-process, after torch and numpy loaded pinned, --fast-kernels would key and record
    the jobs as fast while they compute pinned: refused, one line, exit 2."""
    import torch  # noqa: F401
    from cli.main import main

    assert main(["run", "marionette/table1", "--fast-kernels"]) == 2
    err = capsys.readouterr().err
    assert "must be given when the process starts" in err and err.count("\n") == 1
    assert os.environ.get(kernels.FAST_ENV) is None


def test_fast_kernels_flag_reaches_keys_and_records_in_a_fresh_process():
    code = ("import sys; sys.argv = ['repro', 'spec', 'check', '--fast-kernels']\n"
            "import cli.main, json; from repro import kernels\n"
            "print(json.dumps([kernels.key(), kernels.record()['mode']]))")
    r = _py(code)
    assert r.returncode == 0, r.stderr
    key, mode = json.loads(r.stdout)
    assert key["mode"] == "fast" and mode == "fast"
