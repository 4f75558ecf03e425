"""Training the evaluation classifiers on the real train split, and their test accuracy.

Recipe (ODMO ``train_classifiers_a2m.py``, protocols.md §2.2): cross-entropy on the logits,
Adam (lr 1e-3 at every scale by default), each epoch one class-balanced draw of
``windows_per_epoch`` windows (cut as in :mod:`repro.eval.sampling`) split into batches of
``batch_size``.  Training goes through the one loop, :func:`repro.train.train` (seeded
epochs, atomic checkpoints, exact resume).  The final weights are kept: no model selection
on held-out data (ODMO's released checkpoint choice is unrecorded; selecting on the test
split would bias the reported test accuracy).

With ``heading = "yaw_augment"`` every training window is rotated by a uniform random yaw;
with ``hidden_init = "random"`` every training forward pass starts from a standard-normal GRU
state, as the reference classifiers do (protocols.md §1.5).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from repro.data.clipset import TEST, TRAIN, ClipSet
from repro.errors import DataError
from repro.eval.classifiers import build_module, torch_threads
from repro.eval.evaluator import Evaluator, fingerprint_of, input_representation, weights_sha256
from repro.eval.features import facing_joint_indices, random_yaw, to_model_input
from repro.eval.sampling import random_windows, tiling_windows
from repro.eval.settings import EvaluatorSettings, architecture
from repro.seeding import derive_seed, numpy_rng
from repro import kernels


def _check_clipset(clipset: ClipSet) -> tuple[np.ndarray, np.ndarray]:
    train_pool = clipset.indices(split=TRAIN)
    test_pool = clipset.indices(split=TEST)
    if train_pool.size == 0:
        raise DataError(f"data set {clipset.name!r} has no training clips")
    present = np.unique(clipset.labels[train_pool])
    if present.size < 2:
        raise DataError(f"data set {clipset.name!r}: the train split holds fewer than two classes")
    missing = sorted(set(range(clipset.n_classes)) - set(present.tolist()))
    if missing:
        names = ", ".join(clipset.label_names[i] for i in missing)
        raise DataError(f"data set {clipset.name!r}: classes without training clips: {names}")
    return train_pool, test_pool


def train_evaluator(clipset: ClipSet, kind: str, settings: EvaluatorSettings, seed: int = 0, *,
                    ckpt_dir: str | Path | None = None,
                    on_epoch: Callable[[int, dict], None] | None = None) -> Evaluator:
    """Train a recogniser of ``kind`` on ``clipset``'s train split; returns the Evaluator
    (its ``meta`` holds the training record; test accuracy is added by the caller)."""
    import torch

    from repro.train import train

    train_pool, _ = _check_clipset(clipset)
    names = list(clipset.skeleton.names)
    facing = None
    facing_names = None
    if settings.heading == "remove":
        facing = facing_joint_indices(clipset.skeleton, settings.facing_joints)
        facing_names = [names[i] for i in facing]
    t, ts = settings.train, settings
    input_dim = 3 * len(names)
    with torch.random.fork_rng():
        torch.manual_seed(derive_seed(seed, "evaluator-init", kind))
        module = build_module(kind, input_dim, clipset.n_classes, settings)
    optimizer = kernels.adam(module.parameters(), lr=t.lr, weight_decay=t.weight_decay)

    def batches(epoch: int, gen):
        sub = int(torch.randint(0, 2**62, (1,), generator=gen))
        rng = numpy_rng(sub, "evaluator-windows")
        joints, lengths, labels = random_windows(clipset, train_pool, t.windows_per_epoch, ts.window,
                                                 rng, class_balanced=t.class_balanced,
                                                 include_last=ts.include_last)
        if ts.min_window is not None and ts.min_window < ts.window:
            # valid lengths as short as the actions scored (padded by to_model_input)
            lengths = np.minimum(lengths, rng.integers(ts.min_window, ts.window + 1,
                                                       size=lengths.shape[0]))
        x = torch.from_numpy(to_model_input(joints, lengths, heading=ts.heading, facing=facing))
        if ts.heading == "yaw_augment":
            x = random_yaw(x, gen)
        lens = torch.from_numpy(lengths)
        y = torch.from_numpy(labels)
        for s in range(0, x.shape[0], t.batch_size):
            yield x[s:s + t.batch_size], lens[s:s + t.batch_size], y[s:s + t.batch_size]

    def step(model, batch, epoch):
        x, lens, y = batch
        _, logits = model(x, lens)  # random h0 (if chosen) comes from the loop-seeded global RNG
        loss = torch.nn.functional.cross_entropy(logits, y)
        acc = (logits.detach().argmax(1) == y).float().mean()
        return {"loss": loss, "acc": acc}

    arch = architecture(kind, settings)
    config = {
        "job": "train_evaluator", "kind": kind, "architecture": arch,
        "input": input_representation(settings, facing_names),
        "train": t.model_dump(mode="json"), "data": clipset.fingerprint, "seed": seed,
    }
    with torch_threads(t.threads):
        result = train(module, optimizer, batches=batches, step=step, epochs=t.epochs, seed=seed,
                       config=config, ckpt_dir=ckpt_dir, checkpoint_every=t.checkpoint_every,
                       grad_clip=t.grad_clip, on_epoch=on_epoch)
    module.eval()
    sha = weights_sha256(module.state_dict())
    rep = input_representation(settings, facing_names)
    fp = fingerprint_of(kind, arch, names, clipset.label_names, rep, clipset.fingerprint, sha)
    last = result.history[-1] if result.history else {}
    meta = {
        "architecture": arch,
        "input": rep,
        "training": {
            "seed": seed, "epochs": result.epochs, "seconds": round(result.seconds, 3),
            "resumed_from": result.resumed_from,
            "final_loss": last.get("loss"), "final_train_acc": last.get("acc"),
            "loss_curve": [round(h["loss"], 5) for h in result.history],
            "recipe": t.model_dump(mode="json"),
        },
    }
    return Evaluator(kind=kind, settings=settings, module=module, joint_names=tuple(names),
                     label_names=tuple(clipset.label_names), dataset=clipset.name,
                     data_fingerprint=clipset.fingerprint, weights_sha256=sha, fingerprint=fp,
                     facing=facing, meta=meta)


@dataclass(frozen=True)
class TestAccuracy:
    """Accuracy of an evaluator on deterministic windows tiling the real test split."""

    top1: float
    top5: float
    top5_k: int
    correct: int
    n_windows: int
    n_clips: int
    confusion: np.ndarray
    label_names: tuple[str, ...]
    window: int
    stride: int

    def to_dict(self) -> dict:
        return {"top1": self.top1, "top5": self.top5, "top5_k": self.top5_k, "correct": self.correct,
                "n_windows": self.n_windows, "n_clips": self.n_clips,
                "confusion": self.confusion.tolist(), "label_names": list(self.label_names),
                "window": self.window, "stride": self.stride}


def test_accuracy(evaluator: Evaluator, clipset: ClipSet, seed: int = 0) -> TestAccuracy:
    """Top-1 / top-5 accuracy and the confusion matrix (row = label, column = prediction) on
    windows of length T evenly tiling every test clip (stride ``settings.stride()``)."""
    from repro.metrics.accuracy import accuracy, confusion_matrix

    if tuple(clipset.label_names) != tuple(evaluator.label_names):
        raise DataError(f"data set {clipset.name!r} has classes {clipset.label_names}, the evaluator "
                        f"{evaluator.label_names}")
    pool = clipset.indices(split=TEST)
    if pool.size == 0:
        raise DataError(f"data set {clipset.name!r} has no test clips")
    stride = evaluator.settings.stride()
    joints, lengths, labels, _ = tiling_windows(clipset, pool, evaluator.settings.window, stride)
    logits = evaluator.logits(joints, lengths, seed=seed)
    k = min(5, evaluator.n_classes)
    a1 = accuracy(logits, labels, top_k=1)
    a5 = accuracy(logits, labels, top_k=k)
    conf = confusion_matrix(logits, labels, evaluator.n_classes)
    return TestAccuracy(top1=float(a1.value), top5=float(a5.value), top5_k=k, correct=a1.correct,
                        n_windows=a1.n, n_clips=int(pool.size), confusion=conf,
                        label_names=tuple(evaluator.label_names), window=evaluator.settings.window,
                        stride=stride)


# Not pytest tests, despite their names (tests import them).
test_accuracy.__test__ = False  # type: ignore[attr-defined]
TestAccuracy.__test__ = False  # type: ignore[attr-defined]
