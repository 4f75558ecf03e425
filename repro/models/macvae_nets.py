"""The networks of MACVAE (MultiAct, AAAI'23; see :mod:`repro.models.macvae` for the method).

:class:`MACVAENet` holds every learned piece; tensors are batch-first, pose vectors are the
``6J + 3`` vectors of :mod:`repro.models.baseline_io` (the paper's 315-d ``p`` for SMPL-H),
``d = cfg.d_model``, ``P`` the pose length, ``C`` the number of action classes.  Where the paper
("Architecture") and the released code (``models/modules/transformer.py``) differ, the code is
the default and the paper a config field (docs/multiact.md, "Paper and released code"):

- **Encoder** (paper "Encoder"): per frame an embedding of the pose and its label (``a_p`` on
  S_p frames, ``a_c`` on S_c frames, the extra row ``C`` ("transition") on T frames):
  ``encoder_embedding = "joint"`` (code ``pre_coding``: ``Linear(P + d → d)`` of ``[p, E_d(a)]``)
  or ``"split"`` (paper: ``[Linear(P → d/2)(p), E_{d/2}(a)]``); positional encodings
  (``pos_encoding``, :func:`positional_encoding`); the backbone over the frames (padding
  masked); temporal convolutions of kernel ``temporal_kernel`` (code: 5, Conv2d (5, d); paper
  silent) with replicate padding; the posterior heads ``posterior_head``: ``"per_frame"``
  (code ``CVAETransformerEncoder``: for μ and for log σ² its own convolution, then one shared
  BatchNorm (statistics over valid frames here), ReLU and a Linear per frame, the same heads for
  ``z_p`` and ``z_c``, pooled afterwards) or ``"pooled"`` (paper: one convolution, the pooled
  vector into four separate Linear heads); the pooling ``posterior_pooling``: ``"per_part"``
  (code: ``subaction_mean_mask`` of ``data/datasets/BABEL.py``, the encoder's ``mean[:, 1:]``)
  pools ``z_p``'s posterior over the T frames and ``z_c``'s over the S_c frames (one latent:
  over ``[T, S_c]``); ``"global"`` (paper: "take a mean along time dimension") one mean over all
  valid frames for every latent.
- **CurrNet**: two tables ``μ(a), log σ²(a)`` of ``C + 1`` rows of ``d``; row ``C`` is the
  learnable "transition" token PrevNet adds (protocols.md §4.2: the *same* table).
- **PrevNet**: the last ``k`` canonical S_p frames flattened, two ``Linear(k·P → d)`` (μ and
  log σ²), each plus the transition token.
- **Decoder**: memory ``[z_p × l_t, z_c × l_c]``; queries the sinusoidal encodings of the
  frames: with ``transition_pos_enc`` (code: ``LayeredPositionalEncoding``, ``layered_pos_enc =
  True``) the first ``d/2`` channels encode the frame index ``t`` and the last ``d/2`` the index
  from the current segment's start (``t`` on T frames, ``t − l_t`` on S_c frames), otherwise
  (paper) ``t`` in every channel; with ``decoder_causal`` (code: ``subsequent_mask``) the
  self-attention sees no later frame and the temporal convolution is causal (code: replicate
  padding of ``kernel − 1`` frames in front), otherwise (paper) unmasked and centred;
  ``decoder_head = "conv"`` (code ``post_conv``: that convolution maps ``d → P`` directly) or
  ``"conv_linear"`` (paper: a ``d → d`` convolution, then ``Linear(d → P)``).
- **Postprocessor**: a temporal convolution of kernel 5 over all ``P`` pose channels of
  ``[S_p, T̃, S̃_c]`` with replicate padding 2; :meth:`MACVAENet.postprocess` keeps the
  ``[T̂, Ŝ_c]`` part, :meth:`MACVAENet.postprocess_whole` all of it (``loss_frames = "whole"``).

Backbones (supp. Table B, "similar network specifications": same ``d`` and ``layers``):
``transformer`` (post-norm layers of :mod:`repro.models.layers`, sinusoidal positions with
dropout), ``lstm``/``gru`` (encoder bidirectional, ``d/2`` per direction, packed so padding is
never read; decoder unidirectional ``d`` wide, unrolled over ``l_t + l_c`` steps fed with
memory token + positional encoding), ``mlp`` (``layers`` × [Linear(d → d), activation, dropout]
per frame on token + positional encoding; the encoder's pooling is the shared pooling).  The
temporal convolutions, heads, priors and postprocessor are the same for every backbone.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from repro import kernels
from repro.models.baseline_io import length_mask
from repro.models.layers import (Conv1d, Dropout, TransformerDecoder, TransformerEncoder,
                                 activation_fn, sinusoidal_encoding)

#: Default kernel of the encoder's and decoder's temporal convolutions (the released code's
#: Conv2d kernels (5, d); the paper is silent): ``MACVAEConfig.temporal_kernel``.
TEMPORAL_KERNEL = 5
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
    """Conv1d over time of width ``d`` and kernel ``k`` with replicate padding (the released
    code's ``nn.functional.pad(..., mode="replicate")``): centred (``(k−1)/2`` copies of each
    item's first and last valid frame; ``k`` odd) or ``causal`` (``k − 1`` copies of the first
    frame in front, so output ``t`` reads frames ``t−k+1 .. t`` only).  Padded frames (past
    an item's valid length) are never read and come out zero, so an item's output does not
    depend on its batch."""

    def __init__(self, d: int, kernel: int = TEMPORAL_KERNEL, causal: bool = False,
                 d_out: int | None = None):
        super().__init__()
        if kernel < 1 or (not causal and kernel % 2 == 0):
            raise ValueError("a centred temporal kernel must be odd and >= 1")
        self.kernel, self.causal = int(kernel), bool(causal)
        self.conv = Conv1d(d, d if d_out is None else d_out, self.kernel)

    def forward(self, x: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
        T, k = x.shape[1], self.kernel
        n = valid.sum(1).to(torch.long)
        before, after = (k - 1, 0) if self.causal else ((k - 1) // 2, (k - 1) // 2)
        # frames 0 .. n-1 of each item, its last valid frame held for `after` more frames
        body = hold_frames(x, torch.zeros_like(n), n, T + after)
        xp = torch.cat([x[:, :1].expand(-1, before, -1), body], dim=1)
        out = self.conv(xp.transpose(1, 2)).transpose(1, 2)
        return out * valid[..., None].to(out.dtype)


class FrameMLP(nn.Module):
    """``layers`` × [Linear(d → d), activation, dropout], applied to every frame alone."""

    def __init__(self, d: int, layers: int, dropout: float, activation: str):
        super().__init__()
        self.lins = nn.ModuleList(nn.Linear(d, d) for _ in range(layers))
        self.drop = Dropout(dropout)
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
        self.pe_kind = cfg.pos_encoding
        self.pos_drop = Dropout(cfg.dropout)
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
        pe = positional_encoding(torch.arange(x.shape[1], device=x.device), x.shape[-1],
                                 self.pe_kind)
        x = self.pos_drop(x + pe.to(x.dtype))
        if self.kind == "transformer":
            return self.net(x, key_padding_mask=~valid)
        return self.net(x)


#: the released code's ``max_input_len``: the base of its transposed sinusoid (below)
CODE_PE_BASE = 120


def positional_encoding(positions: torch.Tensor, d: int, kind: str) -> torch.Tensor:
    """Encodings (..., d) of frame indices ``positions`` (...,).  ``"standard"`` (the paper's
    "sinusoidal positional encoding", Vaswani et al.): channel ``2i`` is ``sin(t/10000^(2i/d))``.
    ``"transposed"`` (the released code's ``PositionalEncoding(max_input_len)`` added to a
    (B, L, d) tensor: its table is built with the frame and channel axes swapped): frame ``t``
    is the sinusoid over the channel index ``c`` with the frequency ``10000^(−2⌊t/2⌋/120)``,
    ``sin`` for even ``t`` and ``cos`` for odd ``t`` (base :data:`CODE_PE_BASE`)."""
    if kind == "standard":
        return sinusoidal_encoding(positions, d)
    if kind != "transposed":
        raise ValueError(f"unknown positional encoding {kind!r}")
    t = positions.to(torch.float32)
    freq = torch.exp(-math.log(10000.0) * (2 * torch.div(t, 2, rounding_mode="floor"))
                     / CODE_PE_BASE)
    c = torch.arange(d, dtype=torch.float32, device=positions.device)
    ang = freq[..., None] * c
    odd = (torch.remainder(positions, 2) == 1)[..., None]
    return torch.where(odd, torch.cos(ang), torch.sin(ang))


def decoder_positions(T: int, d: int, l_t: torch.Tensor | None, device=None,
                      kind: str = "standard") -> torch.Tensor:
    """Decoder queries' sinusoidal encodings (B or 1, T, d): of the frame index ``t``, or with
    ``l_t`` (B,) given (the code's transition-length encoding, module docstring) the first
    ``d/2`` channels of ``t`` and the last ``d/2`` of ``t`` on transition frames (``t < l_t``)
    and ``t − l_t`` on current-action frames."""
    t = torch.arange(T, device=device)
    pe = positional_encoding(t, d, kind)[None]
    if l_t is None:
        return pe
    rel = torch.where(t[None] < l_t[:, None], t[None], t[None] - l_t[:, None])
    pe_rel = positional_encoding(rel, d, kind)
    h = d // 2
    return torch.cat([pe[..., :h].expand(rel.shape[0], T, h), pe_rel[..., h:]], dim=-1)


class DecoderBackbone(nn.Module):
    """Memory (B, T, d) (the expanded latents), validity (B, T) and ``l_t`` (B,) → (B, T, d);
    ``cfg.decoder_causal`` masks later frames in the transformer's self-attention,
    ``cfg.transition_pos_enc`` picks the positional encoding (:func:`decoder_positions`)."""

    def __init__(self, cfg):
        super().__init__()
        self.kind, d = cfg.backbone, cfg.d_model
        self.causal = bool(cfg.decoder_causal)
        self.layered = bool(cfg.transition_pos_enc)
        self.pe_kind = cfg.pos_encoding
        self.pos_drop = Dropout(cfg.dropout)
        if self.kind == "transformer":
            self.net = TransformerDecoder(cfg.layers, d, cfg.heads, cfg.ff_size, cfg.dropout,
                                          cfg.activation)
        elif self.kind in ("lstm", "gru"):
            self.net = _rnn(self.kind, d, d, cfg.layers, cfg.dropout, bidirectional=False)
        else:
            self.net = FrameMLP(d, cfg.layers, cfg.dropout, cfg.activation)

    def forward(self, memory: torch.Tensor, valid: torch.Tensor,
                l_t: torch.Tensor | None = None) -> torch.Tensor:
        B, T, d = memory.shape
        pe = decoder_positions(T, d, l_t if self.layered else None, device=memory.device,
                               kind=self.pe_kind).to(memory.dtype)
        if self.kind == "transformer":
            queries = self.pos_drop(pe.expand(B, T, d))
            return self.net(queries, memory, causal=self.causal, self_padding_mask=~valid,
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
        if cfg.encoder_embedding == "joint":      # code: pre_coding(cat(p, E(a)))
            self.action_embed = nn.Embedding(n_classes + 1, d)
            self.pose_embed = nn.Linear(P + d, d)
        else:                                      # paper: [Linear(p), E(a)], d/2 each
            self.pose_embed = nn.Linear(P, d // 2)
            self.action_embed = nn.Embedding(n_classes + 1, d // 2)
        self.encoder = EncoderBackbone(cfg)
        self.enc_conv = TemporalConv(d, cfg.temporal_kernel)
        heads = 1 if cfg.posterior_head == "per_frame" else self.n_latents
        if cfg.posterior_head == "per_frame":      # code: conv -> BN -> ReLU -> FC, per frame
            self.enc_conv_logvar = TemporalConv(d, cfg.temporal_kernel)
            self.enc_bn = nn.BatchNorm1d(d)        # one BN for both branches, as the code
        self.post_mu = nn.ModuleList(nn.Linear(d, d) for _ in range(heads))
        self.post_logvar = nn.ModuleList(nn.Linear(d, d) for _ in range(heads))
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
        if cfg.decoder_head == "conv":             # code: post_conv (5, d) -> P, no Linear
            self.dec_conv = TemporalConv(d, cfg.temporal_kernel, causal=cfg.decoder_causal,
                                         d_out=P)
            self.final = None
        else:                                      # paper: temporal conv, then Linear(d -> P)
            self.dec_conv = TemporalConv(d, cfg.temporal_kernel, causal=cfg.decoder_causal)
            self.final = nn.Linear(d, P)
        # postprocessor: the reference's Conv2d(1, P, kernel (5, P)) over the (L, P) image is
        # exactly this Conv1d(P, P, 5) over time
        self.postprocessor = Conv1d(P, P, POST_KERNEL) if cfg.postprocessor else None

    # -- encoder -------------------------------------------------------------------------------
    def pooling_weights(self, l_p, l_t, l_c, L: int) -> list[torch.Tensor]:
        """Per latent, the (B, L) weights of the encoder's pooling (each row sums to 1;
        module docstring, ``posterior_pooling``)."""
        t = torch.arange(L, device=l_p.device)[None]
        total = (l_p + l_t + l_c)[:, None]
        if self.cfg.posterior_pooling == "global":
            masks = [t < total] * self.n_latents
        elif self.n_latents == 2:
            p_end = (l_p + l_t)[:, None]
            masks = [(t >= l_p[:, None]) & (t < p_end), (t >= p_end) & (t < total)]
        else:
            masks = [(t >= l_p[:, None]) & (t < total)]
        return [m.float() / m.sum(1, keepdim=True).clamp(min=1).float() for m in masks]

    def encode(self, seq, seg_labels, l_p, l_t, l_c) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """Posteriors ``[(μ_p, log σ²_p), (μ_c, log σ²_c)]`` (one pair without a separate
        latent) of ``[S_p, T, S_c]`` poses (B, L, P) with per-frame labels (B, L) (``C`` on
        transition frames) and part lengths ``l_p``, ``l_t``, ``l_c`` (B,)."""
        valid = length_mask(l_p + l_t + l_c, seq.shape[1])
        if self.cfg.encoder_embedding == "joint":
            x = self.pose_embed(torch.cat([seq, self.action_embed(seg_labels)], dim=-1))
        else:
            x = torch.cat([self.pose_embed(seq), self.action_embed(seg_labels)], dim=-1)
        e = self.encoder(x, valid)
        weights = self.pooling_weights(l_p, l_t, l_c, seq.shape[1])
        if self.cfg.posterior_head == "per_frame":
            mu_f = self.post_mu[0](self._bn_relu(self.enc_conv(e, valid), valid))
            lv_f = self.post_logvar[0](self._bn_relu(self.enc_conv_logvar(e, valid), valid))
            return [(torch.einsum("bl,bld->bd", w.to(mu_f.dtype), mu_f),
                     torch.einsum("bl,bld->bd", w.to(lv_f.dtype), lv_f)) for w in weights]
        h = self.enc_conv(e, valid)
        out = []
        for w, mu, lv in zip(weights, self.post_mu, self.post_logvar):
            pooled = torch.einsum("bl,bld->bd", w.to(h.dtype), h)
            out.append((mu(pooled), lv(pooled)))
        return out

    def _bn_relu(self, h: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
        """The code's BatchNorm + ReLU per frame, statistics over the valid frames only (the
        code's also count the padded frames of its 120-frame window)."""
        bn, m = self.enc_bn, valid[..., None].to(h.dtype)
        if self.training:
            cnt = m.sum()
            mean = (h * m).sum((0, 1)) / cnt
            var = (((h - mean) ** 2) * m).sum((0, 1)) / cnt
            with torch.no_grad():              # nn.BatchNorm1d's running statistics
                bn.num_batches_tracked += 1
                unbiased = var * cnt / (cnt - 1).clamp(min=1)
                bn.running_mean.mul_(1 - bn.momentum).add_(bn.momentum * mean)
                bn.running_var.mul_(1 - bn.momentum).add_(bn.momentum * unbiased)
        else:
            mean, var = bn.running_mean, bn.running_var
        y = (h - mean) / kernels.sqrt(var + bn.eps) * bn.weight + bn.bias  # host-independent bits
        return torch.relu(y) * m

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
        h = self.dec_conv(self.decoder(memory, valid, l_t), valid)
        if self.final is not None:
            h = self.final(h)
        return h * valid[..., None].to(h.dtype)

    def postprocess_whole(self, seq, l_p, raw, n) -> torch.Tensor:
        """The postprocessor over the whole ``[S_p, T̃, S̃_c]`` (B, max(l_p + n), P): the given
        ``S_p`` frames of ``seq`` then the ``n`` generated ones, replicate-padded by 2 at both
        ends (an item's last frame held), as the released code convolves its 120-frame window.
        Frames ``l_p ..`` equal :meth:`postprocess`'s; padded frames are zero.  Without a
        postprocessor, ``S_p``'s frames are copied (the code's ``postprocessor = "none"``)."""
        m = l_p + n
        L = int(m.max())
        t = torch.arange(L, device=seq.device)[None]
        given = hold_frames(seq, torch.zeros_like(l_p), l_p, L)
        idx = (t - l_p[:, None]).clamp(min=0)
        idx = torch.minimum(idx, (n - 1).clamp(min=0)[:, None])
        gen = raw[torch.arange(raw.shape[0], device=raw.device)[:, None], idx]
        x = torch.where((t < l_p[:, None])[..., None], given, gen)
        if self.postprocessor is not None:
            ext = torch.cat([x[:, :1].expand(-1, POST_PAD, -1), x,
                             x[:, -1:].expand(-1, POST_PAD, -1)], dim=1)
            x = self.postprocessor(ext.transpose(1, 2)).transpose(1, 2)
        return x * length_mask(m, L)[..., None].to(x.dtype)

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
