"""The networks of MACVAE (MultiAct, AAAI'23; see :mod:`repro.models.macvae` for the method).

:class:`MACVAENet` holds every learned piece; tensors are batch-first, pose vectors are the
``6J + 3`` vectors of :mod:`repro.models.baseline_io` (the paper's 315-d ``p`` for SMPL-H),
``d = cfg.d_model``, ``P`` the pose length, ``C`` the number of action classes.

- **Encoder** (paper "Architecture", Encoder): per frame ``[Linear(P → d/2)(p), E_enc(label)]``
  (an action embedding of ``d/2``; the label is ``a_p`` on S_p frames, ``a_c`` on S_c frames,
  the extra row ``C`` ("transition") on T frames); the backbone over the frames (padding masked);
  a temporal convolution; the mean over valid frames; linear heads ``μ_p, log σ²_p, μ_c,
  log σ²_c`` (one pair when the latent is not separate).
- **CurrNet**: two tables ``μ(a), log σ²(a)`` of ``C + 1`` rows of ``d``; row ``C`` is the
  learnable "transition" token PrevNet adds (protocols.md §4.2: the *same* table).
- **PrevNet**: the last ``k`` canonical S_p frames flattened, two ``Linear(k·P → d)`` (μ and
  log σ²), each plus the transition token.
- **Decoder**: memory ``[z_p × l_t, z_c × l_c]``, queries the sinusoidal encodings of
  ``0 .. l_t + l_c − 1``; the backbone; a temporal convolution; ``Linear(d → P)``.
- **Postprocessor**: a temporal convolution of kernel 5 over all ``P`` pose channels of
  ``[S_p, T̃, S̃_c]`` with replicate padding 2; only the ``[T̂, Ŝ_c]`` part is kept.

Backbones (supp. Table B, "similar network specifications": same ``d`` and ``layers``):
``transformer`` (post-norm layers of :mod:`repro.models.layers`, sinusoidal positions with
dropout), ``lstm``/``gru`` (encoder bidirectional, ``d/2`` per direction, packed so padding is
never read; decoder unidirectional ``d`` wide, unrolled over ``l_t + l_c`` steps fed with
memory token + positional encoding), ``mlp`` (``layers`` × [Linear(d → d), activation, dropout]
per frame on token + positional encoding; the encoder's pooling is the shared mean).  The
temporal convolutions, heads, priors and postprocessor are the same for every backbone.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from repro.models.baseline_io import length_mask
from repro.models.layers import (TransformerDecoder, TransformerEncoder, activation_fn,
                                 sinusoidal_encoding)

#: Kernel of the encoder's and decoder's temporal convolutions (paper silent; our choice).
TEMPORAL_KERNEL = 3
#: Postprocessor kernel in frames and its replicate padding (protocols.md §4.2).
POST_KERNEL, POST_PAD = 5, 2


def take_frames(x: torch.Tensor, start: torch.Tensor, width: int) -> torch.Tensor:
    """``x[b, start[b] + t]`` for ``t < width``, indices clamped into ``[0, T − 1]``."""
    idx = (start[:, None] + torch.arange(width, device=x.device)[None]).clamp(0, x.shape[1] - 1)
    return x[torch.arange(x.shape[0], device=x.device)[:, None], idx]


def hold_frames(x: torch.Tensor, start: torch.Tensor, n: torch.Tensor, width: int) -> torch.Tensor:
    """Frames ``start .. start+n−1`` of each item left-aligned into ``width``; past ``n`` the
    last of them repeats."""
    t = torch.arange(width, device=x.device)[None]
    idx = (start[:, None] + torch.minimum(t, (n - 1).clamp(min=0)[:, None])).clamp(0, x.shape[1] - 1)
    return x[torch.arange(x.shape[0], device=x.device)[:, None], idx]


def kl_gaussians(mu1, lv1, mu2, lv2) -> torch.Tensor:
    """KL(N(μ1, e^lv1) ‖ N(μ2, e^lv2)) summed over the last dimension."""
    return 0.5 * (lv2 - lv1 + (lv1.exp() + (mu1 - mu2) ** 2) / lv2.exp() - 1.0).sum(-1)


class TemporalConv(nn.Module):
    """Conv1d over time of width ``d`` (kernel :data:`TEMPORAL_KERNEL`, zero padding); padded
    frames are zeroed before and after, so an item's output does not depend on its batch."""

    def __init__(self, d: int):
        super().__init__()
        self.conv = nn.Conv1d(d, d, TEMPORAL_KERNEL, padding=TEMPORAL_KERNEL // 2)

    def forward(self, x: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
        m = valid[..., None].to(x.dtype)
        return self.conv((x * m).transpose(1, 2)).transpose(1, 2) * m


class FrameMLP(nn.Module):
    """``layers`` × [Linear(d → d), activation, dropout], applied to every frame alone."""

    def __init__(self, d: int, layers: int, dropout: float, activation: str):
        super().__init__()
        self.lins = nn.ModuleList(nn.Linear(d, d) for _ in range(layers))
        self.drop = nn.Dropout(dropout)
        self.act = activation_fn(activation)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        for lin in self.lins:
            x = self.drop(self.act(lin(x)))
        return x


def _rnn(kind: str, d_in: int, hidden: int, layers: int, dropout: float, bidirectional: bool):
    cls = nn.LSTM if kind == "lstm" else nn.GRU
    return cls(d_in, hidden, num_layers=layers, batch_first=True, bidirectional=bidirectional,
               dropout=dropout if layers > 1 else 0.0)


class EncoderBackbone(nn.Module):
    """(B, L, d) frame tokens and their validity (B, L) → (B, L, d)."""

    def __init__(self, cfg):
        super().__init__()
        self.kind, d = cfg.backbone, cfg.d_model
        self.pos_drop = nn.Dropout(cfg.dropout)
        if self.kind == "transformer":
            self.net = TransformerEncoder(cfg.layers, d, cfg.heads, cfg.ff_size, cfg.dropout,
                                          cfg.activation)
        elif self.kind in ("lstm", "gru"):
            self.net = _rnn(self.kind, d, d // 2, cfg.layers, cfg.dropout, bidirectional=True)
        else:
            self.net = FrameMLP(d, cfg.layers, cfg.dropout, cfg.activation)

    def forward(self, x: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
        if self.kind in ("lstm", "gru"):   # order is the recurrence itself: no positions
            lengths = valid.sum(1).cpu()
            packed = nn.utils.rnn.pack_padded_sequence(x, lengths, batch_first=True,
                                                       enforce_sorted=False)
            out, _ = self.net(packed)
            return nn.utils.rnn.pad_packed_sequence(out, batch_first=True,
                                                    total_length=x.shape[1])[0]
        pe = sinusoidal_encoding(torch.arange(x.shape[1], device=x.device), x.shape[-1])
        x = self.pos_drop(x + pe.to(x.dtype))
        if self.kind == "transformer":
            return self.net(x, key_padding_mask=~valid)
        return self.net(x)


class DecoderBackbone(nn.Module):
    """Memory (B, T, d) (the expanded latents) and validity (B, T) → (B, T, d)."""

    def __init__(self, cfg):
        super().__init__()
        self.kind, d = cfg.backbone, cfg.d_model
        self.pos_drop = nn.Dropout(cfg.dropout)
        if self.kind == "transformer":
            self.net = TransformerDecoder(cfg.layers, d, cfg.heads, cfg.ff_size, cfg.dropout,
                                          cfg.activation)
        elif self.kind in ("lstm", "gru"):
            self.net = _rnn(self.kind, d, d, cfg.layers, cfg.dropout, bidirectional=False)
        else:
            self.net = FrameMLP(d, cfg.layers, cfg.dropout, cfg.activation)

    def forward(self, memory: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
        B, T, d = memory.shape
        pe = sinusoidal_encoding(torch.arange(T, device=memory.device), d).to(memory.dtype)
        if self.kind == "transformer":
            queries = self.pos_drop(pe.expand(B, T, d))
            return self.net(queries, memory, causal=False, self_padding_mask=~valid,
                            mem_padding_mask=~valid)
        x = self.pos_drop(memory + pe)
        if self.kind in ("lstm", "gru"):   # unidirectional: padded steps come last, unread
            return self.net(x)[0]
        return self.net(x)


class MACVAENet(nn.Module):
    """Encoder, CurrNet, PrevNet, decoder and postprocessor (module docstring)."""

    def __init__(self, cfg, n_joints: int, n_classes: int):
        super().__init__()
        self.cfg, self.n_classes = cfg, n_classes
        d, P = cfg.d_model, 6 * n_joints + 3
        self.pose_dim = P
        self.n_latents = 2 if cfg.separate_latent else 1
        # encoder
        self.pose_embed = nn.Linear(P, d // 2)
        self.action_embed = nn.Embedding(n_classes + 1, d // 2)
        self.encoder = EncoderBackbone(cfg)
        self.enc_conv = TemporalConv(d)
        self.post_mu = nn.ModuleList(nn.Linear(d, d) for _ in range(self.n_latents))
        self.post_logvar = nn.ModuleList(nn.Linear(d, d) for _ in range(self.n_latents))
        # CurrNet (row n_classes: the transition token PrevNet adds)
        self.prior_mu = nn.Embedding(n_classes + 1, d)
        self.prior_logvar = nn.Embedding(n_classes + 1, d)
        # PrevNet
        self.prev_frames = cfg.max_prev_frames if cfg.prevnet_frames == "all" else cfg.prevnet_frames
        prev_in = self.prev_frames * P + (n_classes if cfg.prevnet_action_label else 0)
        self.prev_mu = nn.Linear(prev_in, d)
        self.prev_logvar = nn.Linear(prev_in, d)
        # decoder
        self.decoder = DecoderBackbone(cfg)
        self.dec_conv = TemporalConv(d)
        self.final = nn.Linear(d, P)
        # postprocessor: the reference's Conv2d(1, P, kernel (5, P)) over the (L, P) image is
        # exactly this Conv1d(P, P, 5) over time
        self.postprocessor = nn.Conv1d(P, P, POST_KERNEL) if cfg.postprocessor else None

    # -- encoder -------------------------------------------------------------------------------
    def encode(self, seq, seg_labels, total) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """Posteriors ``[(μ_p, log σ²_p), (μ_c, log σ²_c)]`` (one pair without a separate
        latent) of ``[S_p, T, S_c]`` poses (B, L, P) with per-frame labels (B, L) (``C`` on
        transition frames) and valid lengths ``total`` (B,)."""
        valid = length_mask(total, seq.shape[1])
        x = torch.cat([self.pose_embed(seq), self.action_embed(seg_labels)], dim=-1)
        h = self.enc_conv(self.encoder(x, valid), valid)
        pooled = h.sum(1) / total[:, None].to(h.dtype)
        return [(mu(pooled), lv(pooled)) for mu, lv in zip(self.post_mu, self.post_logvar)]

    # -- priors ----------------------------------------------------------------------------------
    def prevnet_input(self, prev, l_p, labels) -> torch.Tensor:
        """PrevNet's input (B, k·P [+ C]): the last ``k`` frames of the canonical S_p (B, W, P)
        with ``l_p`` valid frames.  ``k`` frames: an S_p shorter than ``k`` repeats its first
        frame in front (as :func:`repro.data.pairs.last_frames`).  ``"all"``: the last
        ``max_prev_frames`` frames right-aligned, zeros in front of a shorter S_p (a longer one
        keeps its last ``max_prev_frames``).  With ``prevnet_action_label`` the one-hot of
        ``a_c`` is appended."""
        k = self.prev_frames
        start = l_p - k
        x = take_frames(prev, start, k)        # indices < 0 clamp to frame 0
        if self.cfg.prevnet_frames == "all":
            t = torch.arange(k, device=prev.device)[None]
            x = x * (start[:, None] + t >= 0)[..., None].to(x.dtype)
        x = x.reshape(x.shape[0], -1)
        if self.cfg.prevnet_action_label:
            x = torch.cat([x, F.one_hot(labels, self.n_classes).to(x.dtype)], dim=-1)
        return x

    def prior(self, prev_in, labels) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """Priors ``[(μ_p, log σ²_p) from PrevNet, (μ_c, log σ²_c) from CurrNet]``; without a
        separate latent one prior: PrevNet's linear output plus CurrNet's tokens of ``a_c``."""
        mu_x, lv_x = self.prev_mu(prev_in), self.prev_logvar(prev_in)
        if not self.cfg.separate_latent:
            return [(mu_x + self.prior_mu(labels), lv_x + self.prior_logvar(labels))]
        trans = torch.full_like(labels, self.n_classes)
        return [(mu_x + self.prior_mu(trans), lv_x + self.prior_logvar(trans)),
                (self.prior_mu(labels), self.prior_logvar(labels))]

    # -- decoder ---------------------------------------------------------------------------------
    def decode(self, zs: list[torch.Tensor], l_t, l_c) -> torch.Tensor:
        """``[T̃, S̃_c]`` (B, max(l_t + l_c), P) from the latents; padded frames are zero."""
        n = l_t + l_c
        T = int(n.max())
        valid = length_mask(n, T)
        if len(zs) == 2:
            before = (torch.arange(T, device=n.device)[None] < l_t[:, None])[..., None]
            memory = torch.where(before, zs[0][:, None], zs[1][:, None])
        else:
            memory = zs[0][:, None].expand(-1, T, -1)
        h = self.dec_conv(self.decoder(memory, valid), valid)
        return self.final(h) * valid[..., None].to(h.dtype)

    def postprocess(self, prev, l_p, raw, n) -> torch.Tensor:
        """``[T̂, Ŝ_c]`` (B, T, P): the kernel-5 convolution of ``[S_p, T̃, S̃_c]`` with
        replicate padding 2, S_p's part dropped.  Only S_p's last two frames reach the kept
        part, so the input is [those two (the first repeated when l_p = 1, which is what
        replicate padding gives), T̃ S̃_c held past their end for 2 frames] with no padding:
        identical per item to the whole-sequence convolution.  Padded frames are zero."""
        T = raw.shape[1]
        if self.postprocessor is None:
            return raw
        pre = take_frames(prev, l_p - POST_PAD, POST_PAD)   # index < 0 clamps to frame 0
        body = hold_frames(raw, torch.zeros_like(n), n, T + POST_PAD)
        x = torch.cat([pre, body], dim=1).transpose(1, 2)
        out = self.postprocessor(x).transpose(1, 2)
        return out * length_mask(n, T)[..., None].to(out.dtype)
