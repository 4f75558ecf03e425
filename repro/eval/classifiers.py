"""The recognition networks behind every Acc / FID / Diversity / Multimodality column.

- :class:`GRURecogniser`: Action2Motion's MotionDiscriminator (protocols.md §2.1; ODMO supp.
  Tables S3/S4): per-frame flattened joint xyz → ``layers`` GRU layers of ``hidden`` units →
  the top layer's output at the last time step (``readout = "last_step"``, A2M/ODMO) or at the
  last valid frame (``"last_valid"``, ACTOR's copy) → Linear(hidden → 30) → tanh (the 30-d
  feature for FID, diversity, multimodality) → Linear(30 → C) (the logits).
  ``a2m_gru`` = 2 × 128, ``uestc_gru`` = 3 × 256, ``multiact_gru`` = 4 × 256 (MultiAct's BABEL
  recogniser, protocols.md §2.3; how its protocols feed variable-length segments:
  :mod:`repro.eval.protocols.multiact_common`).
- :class:`TransformerRecogniser`: Neural Marionette §5.1.2's "Transformer-based action
  recognition network N" (the paper gives no architecture; our choice, docs/evaluators.md):
  Linear(J·3 → d) + sinusoidal positions, a learned class token, a pre-norm transformer
  encoder (GELU) with padding masked, the class token's output → LayerNorm → Linear(d → 30)
  → tanh → Linear(30 → C).

Initial GRU state (protocols.md §1.5): the reference classifiers draw ``randn`` for every
forward pass; here ``hidden_init`` is ``"zero"`` (default, deterministic), ``"learned"`` (a
trained parameter) or ``"random"`` (fidelity: the caller passes a standard-normal ``h0``).
"""

from __future__ import annotations

import math
from contextlib import contextmanager

import torch
from torch import nn


@contextmanager
def torch_threads(n: int):
    """Run with ``n`` torch CPU threads, restoring the previous count afterwards.  Small GRUs
    gain little from more threads and lose badly when the cores are shared (spin-waiting)."""
    before = torch.get_num_threads()
    torch.set_num_threads(int(n))
    try:
        yield
    finally:
        torch.set_num_threads(before)


class GRURecogniser(nn.Module):
    def __init__(self, input_dim: int, n_classes: int, *, hidden: int, layers: int,
                 feature_dim: int = 30, hidden_init: str = "zero", readout: str = "last_step"):
        super().__init__()
        if hidden_init not in ("zero", "learned", "random"):
            raise ValueError(f"hidden_init {hidden_init!r}")
        if readout not in ("last_step", "last_valid"):
            raise ValueError(f"readout {readout!r}")
        self.hidden, self.layers = hidden, layers
        self.hidden_init, self.readout = hidden_init, readout
        self.gru = nn.GRU(input_dim, hidden, layers, batch_first=True)
        self.feature = nn.Linear(hidden, feature_dim)
        self.classify = nn.Linear(feature_dim, n_classes)
        if hidden_init == "learned":
            self.h0 = nn.Parameter(torch.zeros(layers, 1, hidden))

    def initial_state(self, n: int, generator: torch.Generator | None = None) -> torch.Tensor | None:
        """h0 for ``n`` sequences: zeros (None), the learned state, or standard normal noise
        (from ``generator``, else the global torch RNG; protocols.md §1.5)."""
        if self.hidden_init == "zero":
            return None
        if self.hidden_init == "learned":
            return self.h0.expand(-1, n, -1).contiguous()
        w = self.feature.weight
        return torch.randn(self.layers, n, self.hidden, generator=generator, dtype=w.dtype)

    def forward(self, x: torch.Tensor, lengths: torch.Tensor | None = None,
                h0: torch.Tensor | None = None, generator: torch.Generator | None = None):
        """``x`` (N, T, D) → (features (N, 30), logits (N, C))."""
        if h0 is None:
            h0 = self.initial_state(x.shape[0], generator)
        out, _ = self.gru(x, h0)
        if self.readout == "last_valid" and lengths is not None:
            idx = (lengths.to(torch.long) - 1).clamp(min=0)
            last = out[torch.arange(out.shape[0]), idx]
        else:
            last = out[:, -1]
        feat = torch.tanh(self.feature(last))
        return feat, self.classify(feat)


def sinusoidal_positions(n: int, d: int) -> torch.Tensor:
    """(n, d) fixed sinusoidal position codes (Vaswani et al. 2017, Sec. 3.5)."""
    pos = torch.arange(n, dtype=torch.float32)[:, None]
    i = torch.arange(0, d, 2, dtype=torch.float32)
    div = torch.exp(-math.log(10000.0) * i / d)
    pe = torch.zeros(n, d)
    pe[:, 0::2] = torch.sin(pos * div)
    pe[:, 1::2] = torch.cos(pos * div[: d // 2])
    return pe


class TransformerRecogniser(nn.Module):
    def __init__(self, input_dim: int, n_classes: int, *, d_model: int, heads: int, layers: int,
                 ff: int, dropout: float = 0.1, feature_dim: int = 30, max_len: int = 1024):
        super().__init__()
        if d_model % heads:
            raise ValueError("d_model must be divisible by heads")
        self.embed = nn.Linear(input_dim, d_model)
        self.cls = nn.Parameter(torch.zeros(1, 1, d_model))
        nn.init.normal_(self.cls, std=0.02)
        self.register_buffer("pos", sinusoidal_positions(max_len + 1, d_model), persistent=False)
        layer = nn.TransformerEncoderLayer(d_model, heads, ff, dropout, activation="gelu",
                                           batch_first=True, norm_first=True)
        self.encoder = nn.TransformerEncoder(layer, layers, enable_nested_tensor=False)
        self.norm = nn.LayerNorm(d_model)
        self.feature = nn.Linear(d_model, feature_dim)
        self.classify = nn.Linear(feature_dim, n_classes)

    def forward(self, x: torch.Tensor, lengths: torch.Tensor | None = None, h0=None, generator=None):
        """``x`` (N, T, D) → (features (N, 30), logits (N, C)); frames ≥ lengths are masked."""
        n, t, _ = x.shape
        if t + 1 > self.pos.shape[0]:
            raise ValueError(f"sequence of {t} frames exceeds the recogniser's {self.pos.shape[0] - 1}")
        h = self.embed(x)
        h = torch.cat([self.cls.expand(n, -1, -1), h], dim=1) + self.pos[: t + 1]
        mask = None
        if lengths is not None:
            valid = torch.arange(t)[None, :] < lengths.to(torch.long)[:, None]
            mask = torch.cat([torch.zeros(n, 1, dtype=torch.bool), ~valid], dim=1)
        h = self.encoder(h, src_key_padding_mask=mask)
        feat = torch.tanh(self.feature(self.norm(h[:, 0])))
        return feat, self.classify(feat)


def build_module(kind: str, input_dim: int, n_classes: int, settings) -> nn.Module:
    """The network of ``kind`` for ``settings`` (:class:`repro.eval.settings.EvaluatorSettings`)."""
    from repro.eval.settings import GRU_SHAPES

    if kind in GRU_SHAPES:
        shape = GRU_SHAPES[kind]
        return GRURecogniser(input_dim, n_classes, hidden=shape["hidden"], layers=shape["layers"],
                             feature_dim=settings.feature_dim, hidden_init=settings.hidden_init,
                             readout=settings.readout)
    if kind == "transformer":
        s = settings.transformer
        return TransformerRecogniser(input_dim, n_classes, d_model=s.d_model, heads=s.heads,
                                     layers=s.layers, ff=s.ff, dropout=s.dropout,
                                     feature_dim=settings.feature_dim,
                                     max_len=max(1024, settings.window))
    raise ValueError(f"unknown evaluator kind {kind!r}")
