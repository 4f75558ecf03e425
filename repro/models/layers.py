"""Transformer pieces shared by the generators, with key/value caching for decoding.

The layers follow Vaswani et al. (2017) as PyTorch's ``nn.Transformer*Layer`` do by default
(post-norm: ``x = norm(x + sublayer(x))``), written on top of
:func:`torch.nn.functional.scaled_dot_product_attention` so that a decoder can run

- **in parallel** over a whole sequence with a causal mask (training, teacher forcing), or
- **one step at a time** with a :class:`DecoderCache` holding, per layer, the self-attention
  keys/values of the steps already taken and the cross-attention keys/values of the memory
  (computed once).  Step ``t`` then costs one token instead of ``t`` tokens.

Both paths compute the same function: the parallel causal output at position ``t`` equals the
``t``-th cached step (tested to 1e-5).

Tensors are batch-first: ``(B, L, d)``.  Boolean ``key_padding_mask``: ``True`` marks a padded
key that must not be attended to (PyTorch's convention).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch
import torch.nn.functional as F
from torch import nn

_ACTIVATIONS = {"relu": F.relu, "gelu": F.gelu}


def activation_fn(name: str):
    """``relu`` or ``gelu`` (the two activations of Neural Marionette supp. Table 2)."""
    try:
        return _ACTIVATIONS[name]
    except KeyError:
        raise ValueError(f"unknown activation {name!r}; expected one of {sorted(_ACTIVATIONS)}") from None


def sinusoidal_encoding(positions: torch.Tensor, d: int) -> torch.Tensor:
    """Sinusoidal encodings (Vaswani et al. 2017, Sec. 3.5) of arbitrary (even fractional or
    per-item) positions: ``positions`` (...,) -> (..., d), float32 unless ``positions`` is
    floating.  Channel ``2i`` is ``sin(p / 10000^(2i/d))``, channel ``2i+1`` the cosine."""
    dtype = positions.dtype if positions.is_floating_point() else torch.float32
    p = positions.to(dtype).unsqueeze(-1)
    i = torch.arange(0, d, 2, dtype=dtype, device=positions.device)
    freq = torch.exp(-math.log(10000.0) * i / d)
    out = torch.zeros(*positions.shape, d, dtype=dtype, device=positions.device)
    out[..., 0::2] = torch.sin(p * freq)
    out[..., 1::2] = torch.cos(p * freq)[..., : d // 2]
    return out


def _padding_to_additive(mask: torch.Tensor | None, dtype) -> torch.Tensor | None:
    """(B, Lk) bool padding mask -> (B, 1, 1, Lk) additive float mask (``-inf`` where padded)."""
    if mask is None:
        return None
    add = torch.zeros(mask.shape, dtype=dtype, device=mask.device)
    add = add.masked_fill(mask, float("-inf"))
    return add[:, None, None, :]


class MultiHeadAttention(nn.Module):
    """Multi-head attention with separate q/k/v/out projections (Vaswani et al. 2017, Sec. 3.2).

    ``forward(q_in, kv_in)`` projects both; ``attend(q_in, k, v)`` takes already projected and
    head-split keys/values (B, H, Lk, dh), which is what a cache stores.
    """

    def __init__(self, d_model: int, n_heads: int, dropout: float = 0.0):
        super().__init__()
        if d_model % n_heads:
            raise ValueError(f"d_model {d_model} is not divisible by n_heads {n_heads}")
        self.d_model, self.n_heads, self.dropout = d_model, n_heads, dropout
        self.q = nn.Linear(d_model, d_model)
        self.k = nn.Linear(d_model, d_model)
        self.v = nn.Linear(d_model, d_model)
        self.out = nn.Linear(d_model, d_model)

    def _split(self, x: torch.Tensor) -> torch.Tensor:
        B, L, _ = x.shape
        return x.view(B, L, self.n_heads, self.d_model // self.n_heads).transpose(1, 2)

    def project_kv(self, kv_in: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self._split(self.k(kv_in)), self._split(self.v(kv_in))

    def attend(self, q_in, k, v, *, causal: bool = False, key_padding_mask=None) -> torch.Tensor:
        q = self._split(self.q(q_in))
        mask = _padding_to_additive(key_padding_mask, q.dtype)
        if causal:
            Lq, Lk = q.shape[-2], k.shape[-2]
            c = torch.ones(Lq, Lk, dtype=torch.bool, device=q.device).tril(Lk - Lq)
            cm = torch.zeros(Lq, Lk, dtype=q.dtype, device=q.device).masked_fill(~c, float("-inf"))
            mask = cm if mask is None else mask + cm
        drop = self.dropout if self.training else 0.0
        o = F.scaled_dot_product_attention(q, k, v, attn_mask=mask, dropout_p=drop)
        B, H, L, dh = o.shape
        return self.out(o.transpose(1, 2).reshape(B, L, H * dh))

    def forward(self, q_in, kv_in, *, causal: bool = False, key_padding_mask=None):
        k, v = self.project_kv(kv_in)
        return self.attend(q_in, k, v, causal=causal, key_padding_mask=key_padding_mask)


class FeedForward(nn.Module):
    def __init__(self, d_model: int, d_ff: int, dropout: float, activation: str):
        super().__init__()
        self.lin1 = nn.Linear(d_model, d_ff)
        self.lin2 = nn.Linear(d_ff, d_model)
        self.drop = nn.Dropout(dropout)
        self.act = activation_fn(activation)

    def forward(self, x):
        return self.lin2(self.drop(self.act(self.lin1(x))))


class EncoderLayer(nn.Module):
    """Post-norm transformer encoder layer: self-attention, then feed-forward."""

    def __init__(self, d_model: int, n_heads: int, d_ff: int, dropout: float, activation: str):
        super().__init__()
        self.attn = MultiHeadAttention(d_model, n_heads, dropout)
        self.ff = FeedForward(d_model, d_ff, dropout, activation)
        self.norm1, self.norm2 = nn.LayerNorm(d_model), nn.LayerNorm(d_model)
        self.drop1, self.drop2 = nn.Dropout(dropout), nn.Dropout(dropout)

    def forward(self, x, key_padding_mask=None):
        x = self.norm1(x + self.drop1(self.attn(x, x, key_padding_mask=key_padding_mask)))
        return self.norm2(x + self.drop2(self.ff(x)))


class TransformerEncoder(nn.Module):
    def __init__(self, n_layers: int, d_model: int, n_heads: int, d_ff: int, dropout: float,
                 activation: str):
        super().__init__()
        self.layers = nn.ModuleList(
            EncoderLayer(d_model, n_heads, d_ff, dropout, activation) for _ in range(n_layers))

    def forward(self, x, key_padding_mask=None):
        for layer in self.layers:
            x = layer(x, key_padding_mask)
        return x


@dataclass
class DecoderCache:
    """Per-layer keys/values for incremental decoding.

    ``self_k[i]``/``self_v[i]``: (B, H, t, dh) self-attention keys/values of the ``t`` steps
    taken so far (grown by :meth:`TransformerDecoder.step`); ``mem_k[i]``/``mem_v[i]``: the
    cross-attention keys/values of the memory, computed once; ``mem_mask``: its padding mask.
    """

    mem_k: list
    mem_v: list
    mem_mask: torch.Tensor | None
    self_k: list = field(default_factory=list)
    self_v: list = field(default_factory=list)

    @property
    def length(self) -> int:
        return 0 if not self.self_k or self.self_k[0] is None else int(self.self_k[0].shape[-2])


class DecoderLayer(nn.Module):
    """Post-norm transformer decoder layer: (causal) self-attention, cross-attention to a
    memory, feed-forward."""

    def __init__(self, d_model: int, n_heads: int, d_ff: int, dropout: float, activation: str):
        super().__init__()
        self.self_attn = MultiHeadAttention(d_model, n_heads, dropout)
        self.cross_attn = MultiHeadAttention(d_model, n_heads, dropout)
        self.ff = FeedForward(d_model, d_ff, dropout, activation)
        self.norm1, self.norm2, self.norm3 = (nn.LayerNorm(d_model) for _ in range(3))
        self.drop1, self.drop2, self.drop3 = (nn.Dropout(dropout) for _ in range(3))

    def _tail(self, x, mem_k, mem_v, mem_mask):
        x = self.norm2(x + self.drop2(self.cross_attn.attend(x, mem_k, mem_v,
                                                             key_padding_mask=mem_mask)))
        return self.norm3(x + self.drop3(self.ff(x)))

    def forward(self, x, memory, *, causal: bool, self_padding_mask=None, mem_padding_mask=None):
        sa = self.self_attn(x, x, causal=causal, key_padding_mask=self_padding_mask)
        x = self.norm1(x + self.drop1(sa))
        mk, mv = self.cross_attn.project_kv(memory)
        return self._tail(x, mk, mv, mem_padding_mask)

    def step(self, x, cache: DecoderCache, i: int):
        """One new position ``x`` (B, 1, d) attending to the cached past and itself."""
        k, v = self.self_attn.project_kv(x)
        if cache.self_k[i] is not None:
            k = torch.cat([cache.self_k[i], k], dim=-2)
            v = torch.cat([cache.self_v[i], v], dim=-2)
        cache.self_k[i], cache.self_v[i] = k, v
        x = self.norm1(x + self.drop1(self.self_attn.attend(x, k, v)))
        return self._tail(x, cache.mem_k[i], cache.mem_v[i], cache.mem_mask)


class TransformerDecoder(nn.Module):
    """A stack of :class:`DecoderLayer` with a parallel path and a key/value-cached step path."""

    def __init__(self, n_layers: int, d_model: int, n_heads: int, d_ff: int, dropout: float,
                 activation: str):
        super().__init__()
        self.layers = nn.ModuleList(
            DecoderLayer(d_model, n_heads, d_ff, dropout, activation) for _ in range(n_layers))

    def forward(self, x, memory, *, causal: bool = False, self_padding_mask=None,
                mem_padding_mask=None):
        for layer in self.layers:
            x = layer(x, memory, causal=causal, self_padding_mask=self_padding_mask,
                      mem_padding_mask=mem_padding_mask)
        return x

    def init_cache(self, memory: torch.Tensor, mem_padding_mask=None) -> DecoderCache:
        """Project the memory's cross-attention keys/values once per layer."""
        ks, vs = [], []
        for layer in self.layers:
            k, v = layer.cross_attn.project_kv(memory)
            ks.append(k)
            vs.append(v)
        n = len(self.layers)
        return DecoderCache(ks, vs, mem_padding_mask, [None] * n, [None] * n)

    def step(self, x: torch.Tensor, cache: DecoderCache) -> torch.Tensor:
        """Decode one position ``x`` (B, 1, d); appends its keys/values to ``cache``."""
        for i, layer in enumerate(self.layers):
            x = layer.step(x, cache, i)
        return x
