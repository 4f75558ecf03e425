"""``Evaluator``: a trained recogniser plus its input convention and its fingerprint.

An evaluator is identified everywhere by :attr:`Evaluator.fingerprint`, the content key
(:func:`repro.keys.content_key`) of

- the architecture (kind, layer shapes, feature layer, GRU initial state, read-out),
- the joint set (joint names in input order) and the class names,
- the input representation (window length, first-frame root at the origin, absolute xyz in
  metres, repeat-last padding, heading mode; the facing joints when heading is removed),
- the fingerprint of the training data (``ClipSet.fingerprint``),
- the sha256 of the trained weights (:func:`weights_sha256`).

It enters every downstream cache key and is printed under every table (:meth:`describe`).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from repro.errors import DataError
from repro.eval.settings import EvaluatorSettings
from repro.keys import content_key

WEIGHTS_FILE = "weights.pt"
META_FILE = "evaluator.json"


def weights_sha256(state_dict) -> str:
    """sha256 over (name, dtype, shape, raw bytes) of every tensor, names sorted."""
    h = hashlib.sha256()
    for name in sorted(state_dict):
        t = state_dict[name].detach().cpu().contiguous()
        h.update(name.encode())
        h.update(str(t.dtype).encode())
        h.update(repr(tuple(t.shape)).encode())
        h.update(t.numpy().tobytes())
    return h.hexdigest()


def input_representation(settings: EvaluatorSettings, facing_names: list[str] | None) -> dict:
    rep = {
        "window": settings.window,
        "coords": "world joint xyz, metres, flattened per frame",
        "origin": "root joint of the first frame",
        "padding": "repeat last valid frame",
        "heading": settings.heading,
    }
    if settings.heading == "remove":
        rep["facing_joints"] = facing_names
    return rep


def fingerprint_of(kind: str, architecture: dict, joint_names, label_names, input_rep: dict,
                   data_fingerprint: str, weights_sha: str) -> str:
    return content_key({
        "kind": kind,
        "architecture": architecture,
        "joints": list(joint_names),
        "classes": list(label_names),
        "input": input_rep,
        "data": data_fingerprint,
        "weights": weights_sha,
    })


@dataclass(eq=False)
class Evaluator:
    """A trained recogniser.  ``features`` and ``logits`` take world joints (N, T, J, 3) in
    metres, in the joint order of :attr:`joint_names`, and apply the input convention of
    :mod:`repro.eval.features`.  ``lengths`` (N,) marks valid frames (the rest are padded by
    repeating the last valid one).  With ``hidden_init = "random"`` both take a ``seed``
    (protocols.md §1.5: features and logits use independent noise, as the reference's two
    network instances do); otherwise they are deterministic and ``seed`` is ignored."""

    kind: str
    settings: EvaluatorSettings
    module: Any = field(repr=False)
    joint_names: tuple[str, ...]
    label_names: tuple[str, ...]
    dataset: str
    data_fingerprint: str
    weights_sha256: str
    fingerprint: str
    facing: tuple[int, int] | None = None
    meta: dict = field(default_factory=dict, repr=False)
    path: Path | None = None

    @property
    def n_classes(self) -> int:
        return len(self.label_names)

    @property
    def random_hidden(self) -> bool:
        return self.kind != "transformer" and self.settings.hidden_init == "random"

    def describe(self) -> str:
        """One line for under a table."""
        arch = self.meta.get("architecture", {})
        if arch.get("net") == "gru":
            shape = f"GRU {arch['layers']}x{arch['hidden']}, h0={arch['hidden_init']}"
        else:
            shape = f"transformer d{arch.get('d_model')} L{arch.get('layers')} H{arch.get('heads')}"
        acc = self.meta.get("test", {}).get("top1")
        acc_s = f", test top-1 {acc:.3f}" if isinstance(acc, float) else ""
        return (f"evaluator {self.kind} [{self.fingerprint[:12]}]: {shape}, 30-d tanh features, "
                f"T={self.settings.window}, heading={self.settings.heading}, "
                f"trained on {self.dataset} train split ({self.data_fingerprint[:12]}){acc_s}")

    def identity(self) -> dict:
        """What downstream cache keys should include."""
        return {"evaluator": self.fingerprint, "kind": self.kind}

    # -- inference -------------------------------------------------------------------------
    def _inputs(self, joints, lengths):
        import torch

        j = np.asarray(joints)
        if j.ndim != 4 or j.shape[2] != len(self.joint_names) or j.shape[3] != 3:
            raise DataError(
                f"evaluator {self.kind} expects joints of shape (N, T, {len(self.joint_names)}, 3) "
                f"({self.dataset} joint order), got {tuple(j.shape)}")
        from repro.eval.features import to_model_input  # torch: only when scoring

        x = to_model_input(j, lengths, heading=self.settings.heading, facing=self.facing)
        n, t = x.shape[:2]
        lens = torch.full((n,), t, dtype=torch.long) if lengths is None else \
            torch.as_tensor(np.asarray(lengths, dtype=np.int64))
        return torch.from_numpy(x), lens

    def _run(self, joints, lengths, seed, stream: str, batch_size: int):
        import torch

        from repro.seeding import torch_generator

        if self.module is None:  # loaded with weights=False: a record, not a network
            raise RuntimeError(f"evaluator {self.fingerprint[:12]} was loaded without its "
                               "weights; load it with weights=True to score")
        x, lens = self._inputs(joints, lengths)
        n = x.shape[0]
        h0 = None
        if self.random_hidden:
            g = torch_generator(0 if seed is None else int(seed), "evaluator-h0", stream)
            h0 = self.module.initial_state(n, g)
        from repro.eval.classifiers import torch_threads

        feats, logits = [], []
        self.module.eval()
        with torch.no_grad(), torch_threads(self.settings.train.threads):
            for s in range(0, n, batch_size):
                e = min(n, s + batch_size)
                hb = None if h0 is None else h0[:, s:e].contiguous()
                f, lg = self.module(x[s:e], lens[s:e], h0=hb)
                feats.append(f)
                logits.append(lg)
        if not feats:
            d = self.settings.feature_dim
            return np.zeros((0, d), np.float32), np.zeros((0, self.n_classes), np.float32)
        return torch.cat(feats).numpy(), torch.cat(logits).numpy()

    def features(self, joints, lengths=None, seed: int | None = None, batch_size: int = 1024) -> np.ndarray:
        """(N, 30) float32 feature-layer outputs (FID, diversity, multimodality)."""
        return self._run(joints, lengths, seed, "features", batch_size)[0]

    def logits(self, joints, lengths=None, seed: int | None = None, batch_size: int = 1024) -> np.ndarray:
        """(N, C) float32 class logits (accuracy)."""
        return self._run(joints, lengths, seed, "logits", batch_size)[1]

    def encode(self, joints, lengths=None, seed: int | None = None, batch_size: int = 1024):
        """``(features, logits)`` in one call (one pass when the evaluator is deterministic)."""
        if self.random_hidden:
            return (self.features(joints, lengths, seed, batch_size),
                    self.logits(joints, lengths, seed, batch_size))
        return self._run(joints, lengths, seed, "both", batch_size)

    # -- persistence -----------------------------------------------------------------------
    def save(self, out_dir: str | Path) -> None:
        """Write ``weights.pt`` and ``evaluator.json`` into ``out_dir``."""
        import torch

        from repro.store.atomic import atomic_write_bytes

        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        tmp = out / f".{WEIGHTS_FILE}.tmp"
        torch.save(self.module.state_dict(), tmp)
        tmp.replace(out / WEIGHTS_FILE)
        meta = dict(self.meta)
        meta.update({
            "kind": self.kind,
            "settings": self.settings.model_dump(mode="json"),
            "joint_names": list(self.joint_names),
            "label_names": list(self.label_names),
            "dataset": self.dataset,
            "data_fingerprint": self.data_fingerprint,
            "weights_sha256": self.weights_sha256,
            "fingerprint": self.fingerprint,
            "facing": None if self.facing is None else list(self.facing),
        })
        atomic_write_bytes(out / META_FILE, json.dumps(meta, indent=2, sort_keys=True).encode())

    @classmethod
    def load(cls, path: str | Path, *, weights: bool = True) -> "Evaluator":
        """Load a stored evaluator; the weights are re-hashed and must match the record.

        With ``weights=False`` only ``evaluator.json`` is read (no torch, no weights file;
        :attr:`module` is None): enough for :meth:`describe`, :meth:`identity` and the
        recorded test statistics, which is all a run whose every measurement is already
        stored needs (docs/engine.md, "Fixed costs"); inference on it raises."""
        path = Path(path)
        meta_file = path / META_FILE
        try:
            meta = json.loads(meta_file.read_text())
        except (OSError, json.JSONDecodeError) as e:
            raise DataError(f"cannot read evaluator record: {e}", meta_file) from None
        settings = EvaluatorSettings.model_validate(meta["settings"])
        module, sha = None, meta["weights_sha256"]
        if weights:
            import torch

            from repro.eval.classifiers import build_module

            module = build_module(meta["kind"], 3 * len(meta["joint_names"]),
                                  len(meta["label_names"]), settings)
            state = torch.load(path / WEIGHTS_FILE, map_location="cpu", weights_only=True)
            sha = weights_sha256(state)
            if sha != meta["weights_sha256"]:
                raise DataError("stored weights do not match their recorded hash (corrupt store "
                                "object)", path / WEIGHTS_FILE)
            module.load_state_dict(state)
            module.eval()
        facing = meta.get("facing")
        return cls(kind=meta["kind"], settings=settings, module=module,
                   joint_names=tuple(meta["joint_names"]), label_names=tuple(meta["label_names"]),
                   dataset=meta["dataset"], data_fingerprint=meta["data_fingerprint"],
                   weights_sha256=sha, fingerprint=meta["fingerprint"],
                   facing=None if facing is None else tuple(facing), meta=meta, path=path)
