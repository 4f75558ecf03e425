"""Issue 17 item 1: the training-throughput changes compute bitwise what the code before them
computed.  Each changed path is compared with the same path as it was at the commit before the
change (``bench_train_throughput.ISSUE17``, imported from git history by
``benchmarks/_before.py``): same seed, same data, then the per-epoch history compared with
``==`` and every weight with ``torch.equal``.  Without that history (a source tarball, a
shallow clone) the comparisons skip, saying so."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest
import torch
from model_fixtures import clips, items, one_torch_thread  # noqa: F401 (fixtures)

from repro.data.registry import load_clipset
from repro.models.a2m import A2M
from repro.train.loop import _float_sum, train

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"


def _load_benchmark(name: str):
    """benchmarks/NAME.py as a module (the path entries it adds removed again once imported)."""
    spec = importlib.util.spec_from_file_location(name, BENCH / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    try:
        spec.loader.exec_module(mod)
    finally:
        for p in (str(BENCH), str(BENCH.parent)):
            while p in sys.path:
                sys.path.remove(p)
    return mod


@pytest.fixture(scope="module")
def bench():
    """benchmarks/bench_train_throughput.py."""
    return _load_benchmark("bench_train_throughput")


@pytest.fixture(scope="module")
def ref(bench):
    """The training paths before issue 17: ``ref.paths()`` swaps them in, ``ref.train`` is the
    old loop (skips without the git history holding the commit)."""
    import types

    from repro import kernels

    kernels.check()  # the pin's matrix products (repro/gemm.py) for the old paths too
    before = sys.modules["_before"]
    try:
        bench.issue17_paths()
        old_loop = before.import_before(bench.ISSUE17, "repro/train/loop.py")
    except before.BeforeUnavailable as e:
        pytest.skip(f"no 'before' code to compare with: {e}")
    return types.SimpleNamespace(paths=bench.issue17_paths, train=old_loop.train)


def _weights(module) -> list[torch.Tensor]:
    return [t.detach().clone() for t in module.state_dict().values()]


def _same(a: list[torch.Tensor], b: list[torch.Tensor]) -> bool:
    return len(a) == len(b) and all(torch.equal(x, y) for x, y in zip(a, b))


def _assert_fits_alike(ref, make, train_items, seed: int, library=None) -> None:
    """``make()``'s generator fitted on ``train_items`` through the pre-issue-17 paths and through
    the library's (or the paths ``library()`` swaps in): the same history (``==``) and the same
    weights (``torch.equal``)."""
    import contextlib

    runs = []
    for ctx in (ref.paths(), (library or contextlib.nullcontext)()):
        gen = make()
        with ctx:
            res = gen.fit(train_items, seed=seed)
        runs.append((res.history, _weights(gen.network)))
    assert runs[1][0] == runs[0][0]
    assert _same(runs[1][1], runs[0][1])


def _toy():
    torch.manual_seed(5)
    model = torch.nn.Sequential(torch.nn.Linear(4, 16), torch.nn.Dropout(0.3),
                                torch.nn.Linear(16, 1))
    opt = torch.optim.Adam(model.parameters(), lr=1e-2)
    X = torch.linspace(-1, 1, 48 * 4).reshape(48, 4)
    y = X.sin().sum(1, keepdim=True)

    def batches(epoch, gen):
        perm = torch.randperm(48, generator=gen)
        for i in range(0, 48, 10):  # a short last batch
            yield X[perm[i:i + 10]], y[perm[i:i + 10]]

    def step(m, batch, epoch):
        xb, yb = batch
        loss = torch.nn.functional.mse_loss(m(xb), yb)
        # every kind of logged scalar: float32, float64, int tensors, Python numbers, and a
        # view of a parameter that the optimiser step changes in place afterwards
        return {"loss": loss, "f64": loss.detach().double() / 3, "count": torch.tensor(len(xb)),
                "epoch_f": float(epoch) / 7, "n": len(xb), "bias0": m[2].bias.detach()[0]}

    return model, opt, batches, step


def test_loop_history_and_weights_equal_the_pre_issue17_loop(ref, tmp_path):
    """The loop's logged scalars are converted once per epoch instead of after every step:
    the history (with validation) and the weights are bitwise the old loop's."""
    runs = []
    for fn, sub in ((ref.train, "old"), (train, "new")):
        model, opt, batches, step = _toy()
        res = fn(model, opt, batches=batches, step=step, epochs=3, seed=4, config={"toy": 1},
                 ckpt_dir=tmp_path / sub,
                 validate=lambda m, e: {"loss": m(torch.ones(3, 4)).mean()})
        runs.append((res.history, _weights(model)))
    (h_old, w_old), (h_new, w_new) = runs
    assert h_new == h_old and list(h_new[0]) == list(h_old[0])  # values and key order
    assert _same(w_new, w_old)


def test_float_sum_is_the_stepwise_python_sum():
    vals = [torch.tensor(0.1), torch.tensor(1e-8), torch.tensor(3.3), torch.tensor(2.0),
            torch.tensor(1e8)]
    stepwise = 0.0
    for v in vals:
        stepwise += float(v)
    assert _float_sum(vals) == stepwise
    mixed = [torch.tensor(0.1), 2, torch.tensor(0.2, dtype=torch.float64), 0.5,
             torch.tensor(7)]
    assert _float_sum(mixed) == ((((0.0 + float(mixed[0])) + 2) + float(mixed[2])) + 0.5) + 7
    assert _float_sum([]) == 0.0


@pytest.mark.parametrize("time_counter", [True, False])
def test_a2m_conditions_equal_the_per_frame_condition(clips, time_counter):  # noqa: F811
    net = A2M({"dim_z": 4, "hidden": 8, "time_counter": time_counter}, clips.skeleton,
              clips.n_classes, clips.fps).network
    lengths = torch.tensor([1, 2, 17, 60, 121, 33])
    onehot = torch.nn.functional.one_hot(torch.arange(6) % clips.n_classes,
                                         clips.n_classes).float()
    T = int(lengths.max())
    per_frame = torch.stack([net.condition(onehot, t, lengths) for t in range(T)], 1)
    assert torch.equal(net.conditions(onehot, T, lengths), per_frame)


@pytest.mark.parametrize("over", [{}, {"time_counter": False, "self_feed_ratio": 1.0}])
def test_a2m_training_equals_the_pre_issue17_step(ref, bench, clips, items, over):  # noqa: F811
    """Action2Motion's step with its conditions built once per batch: same history, same
    weights as the per-frame condition of the old step (through the old loop).  Issue 31 has
    since replaced the step (the posterior over the whole sequence: other numbers, its test in
    tests/test_baselines.py), so the step compared is the one issue 17 left, at
    ``bench_train_throughput.BEFORE``."""
    before = sys.modules["_before"]
    issue17_step = vars(before.import_before(bench.BEFORE, "repro/models/a2m.py").A2M)[
        "training_step"]
    cfg = {"dim_z": 4, "hidden": 16, "batch_size": 8, "epochs": 2, "lr": 3e-3, **over}
    _assert_fits_alike(ref, lambda: A2M(cfg, clips.skeleton, clips.n_classes, clips.fps),
                       items, seed=2,
                       library=lambda: before.swapped((A2M, "training_step", issue17_step)))


def test_before_paths_are_the_old_code_and_restore_the_library(ref):
    """Within the block the two paths are the old commit's (its loop has no ``device``
    argument yet, its A2M step no per-batch conditions); after it, the library's again; the
    generator registry still holds today's A2M.  (ODMO's old decoder is no longer swapped in:
    issue 27 rebuilt the network it ran on.)"""
    import inspect

    from repro.models.base import generator_class
    from repro.train import loop

    saved = (loop.train, A2M.training_step)
    with ref.paths():
        now = (loop.train, A2M.training_step)
        assert all(x is not y for x, y in zip(now, saved))
        assert loop.train is ref.train and "device" not in inspect.signature(loop.train).parameters
        assert "conditions(" not in inspect.getsource(A2M.training_step)
    assert (loop.train, A2M.training_step) == saved
    assert generator_class("a2m") is A2M


def test_throughput_benchmark_runs_and_writes_its_json(bench, ref, capsys, tmp_path):
    """benchmarks/bench_train_throughput.py on the quick profile (bundled data), one step:
    the before/after row is printed and ``--json`` holds the issue's fields (the speed goals are
    not checked at this size; issue 31's paths change numbers, so "same numbers" is no)."""
    import json

    out_json = tmp_path / "bt.json"
    rc = bench.main(["--scale", "quick", "--methods", "a2m", "--steps", "1", "--repeats", "1",
                     "--json", str(out_json)])
    out = capsys.readouterr().out
    row = [line for line in out.splitlines() if line.startswith("| a2m |")]
    assert rc == 0 and len(row) == 1
    got = json.loads(out_json.read_text())
    assert got["before"] == bench.BEFORE and got["scale"] == "quick"
    m = got["methods"]["a2m"]
    assert {"samples_per_cpu_s_before", "samples_per_cpu_s_after", "ratio"} <= set(m)
    assert m["ratio"] > 0 and m["samples_per_cpu_s_after"] > 0


def test_issue31_before_paths_swap_the_old_kernels_and_layers_and_restore_them(bench, ref):
    """Issue 31's "before": torch's own matrix products (repro.gemm uninstalled, the check
    not reinstalling it), ``nn.Dropout``'s masks, ``nn.Conv1d``'s kernel and the old attention
    (SDPA with dropout_p) inside the block; the library's paths after it."""
    import inspect

    from repro import gemm, kernels
    from repro.models import layers

    saved = (kernels.check, layers.Dropout.forward, layers.Conv1d.forward,
             layers.MultiHeadAttention.attend)
    with bench.before_paths():
        kernels.check()
        assert not gemm.installed()
        assert "dropout_p=drop" in inspect.getsource(layers.MultiHeadAttention.attend)
        x = torch.ones(1000)
        layer = layers.Dropout(0.5)
        torch.manual_seed(0)
        a = layer(x)
        torch.manual_seed(0)
        assert torch.equal(a, torch.nn.functional.dropout(x, 0.5, True))
        conv = layers.Conv1d(2, 3, 3)
        assert layers.Conv1d.forward is torch.nn.Conv1d.forward
        assert conv(torch.ones(1, 2, 5)).shape == (1, 3, 3)
    assert gemm.installed()
    assert (kernels.check, layers.Dropout.forward, layers.Conv1d.forward,
            layers.MultiHeadAttention.attend) == saved


def test_curves_statement_reads_the_seed_spread():
    """benchmarks/train_curves.py's equivalence statement: a difference of means within the
    pooled seed standard deviation is "within", a shift past it is not, per epoch; the table
    stops at the shorter run's epochs."""
    mod = _load_benchmark("train_curves")
    before = [[1.0, 0.50], [1.2, 0.52], [1.1, 0.48]]        # epoch sds 0.1 and 0.02
    after = [[1.05, 0.60, 0.3], [1.15, 0.62, 0.3], [1.1, 0.58, 0.3]]
    rows = mod.summarise(before, after)
    assert [r["epoch"] for r in rows] == [0, 1]
    assert rows[0]["within"] and rows[0]["diff"] == pytest.approx(0.0)
    assert not rows[1]["within"] and rows[1]["diff"] == pytest.approx(0.10)
    assert rows[1]["pooled_sd"] == pytest.approx(0.02)
    ex = mod.exceedance(rows, 3)
    assert (ex["outside"], ex["after_lower"], ex["before_lower"]) == (1, 0, 1)
    assert ex["expected_share_if_equivalent"] == pytest.approx(0.2879, abs=1e-3)
    assert mod.exceedance(rows, 6)["expected_share_if_equivalent"] == pytest.approx(0.1139, abs=1e-3)


def test_curves_combine_pools_the_seeds_of_earlier_runs(tmp_path):
    """``train_curves.py --combine``: one statement over the seeds of several runs (same before
    commit, scale and curve); a repeated seed or another before commit is refused."""
    import json

    mod = _load_benchmark("train_curves")

    def run(name, seeds, before, after, commit="a681c37"):
        p = tmp_path / name
        p.write_text(json.dumps({"before": commit, "after": "x", "scale": "medium",
                                 "curve": "val_loss", "seeds": seeds, "methods": {"m": {
                                     "raw": {"before": before, "after": after},
                                     "seconds": {"before": [1.0] * len(seeds),
                                                 "after": [1.0] * len(seeds)}}}}))
        return str(p)

    a = run("a.json", [0, 1], [[1.0, 0.5], [1.2, 0.7]], [[1.1, 0.6], [1.3, 0.8]])
    b = run("b.json", [2, 3], [[1.1, 0.6], [0.9, 0.4]], [[1.0, 0.5], [1.2, 0.7]])
    out = mod.combine([a, b], ["m"])
    assert out["seeds"] == [0, 1, 2, 3]
    rows = out["methods"]["m"]["epochs"]
    assert rows[0]["before_mean"] == pytest.approx(1.05) and rows[0]["after_mean"] == pytest.approx(1.15)
    assert out["methods"]["m"]["exceedance"]["expected_share_if_equivalent"] == pytest.approx(
        mod.exceedance(rows, 4)["expected_share_if_equivalent"])
    with pytest.raises(ValueError):
        mod.combine([a, a], ["m"])
    with pytest.raises(ValueError):
        mod.combine([a, run("c.json", [5, 6], [[1, 1], [1, 1]], [[1, 1], [1, 1]], "other")], ["m"])
