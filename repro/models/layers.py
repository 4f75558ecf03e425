"""Transformer pieces shared by the generators, with key/value caching for decoding.

The layers follow Vaswani et al. (2017) as PyTorch's ``nn.Transformer*Layer`` do by default
(post-norm: ``x = norm(x + sublayer(x))``), written on top of
:func:`torch.nn.functional.scaled_dot_product_attention` so that a decoder can run

- **in parallel** over a whole sequence with a causal mask (training, teacher forcing), or
- **one step at a time** with a :class:`DecoderCache` holding, per layer, the projected
  keys/values of the steps already taken and of the memory.  Step ``t`` then costs one token
  instead of ``t`` tokens.

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


#: the resolution of :func:`dropout`'s draw: 16 random bits per element
DROPOUT_LEVELS = 1 << 16


def dropout(x: torch.Tensor, p: float, training: bool = True) -> torch.Tensor:
    """Inverted dropout (Srivastava et al. 2014; ``nn.Dropout``'s function): each element is
    zeroed with probability ``p`` and the rest scaled by ``1 / (1 − p)``, during training only.

    The mask comes from 16 random bits per element, four elements per 64-bit draw of torch's
    generator (``random_`` over the whole int64 range), instead of ``bernoulli_``'s draw per
    element: 3x cheaper on the CPU (issue 31: dropout's draws were ~18 % of a MarioNet training
    step), and integer-only, hence the same bits on every CPU.  ``p`` is thereby rounded to a
    multiple of 2^-16 (0.1 acts as 0.100006), and the scale is that rounded rate's."""
    if not training or p <= 0.0:
        return x
    q = round(p * DROPOUT_LEVELS)
    if q <= 0:
        return x
    if q >= DROPOUT_LEVELS:
        return x * 0.0
    n = x.numel()
    words = torch.empty((n + 3) // 4, dtype=torch.int64, device=x.device)
    bits = words.random_(-(1 << 63), None).view(torch.int16)[:n].view(x.shape)
    keep = (bits >= q - DROPOUT_LEVELS // 2).to(x.dtype)
    return x * keep.mul_(DROPOUT_LEVELS / (DROPOUT_LEVELS - q))


class Dropout(nn.Module):
    """``nn.Dropout`` with :func:`dropout`'s cheaper mask (same ``p``, same train/eval
    behaviour)."""

    def __init__(self, p: float = 0.5):
        super().__init__()
        if not 0.0 <= p <= 1.0:
            raise ValueError(f"dropout probability has to be between 0 and 1, but got {p}")
        self.p = float(p)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return dropout(x, self.p, self.training)

    def extra_repr(self) -> str:
        return f"p={self.p}"


class Conv1d(nn.Conv1d):
    """``nn.Conv1d`` (the same parameters, initialisation and function) computed as the
    input's unfolded frames times the weight matrix: one ``linear`` over ``(N, L', C·k)``,
    whose product runs on :mod:`repro.gemm` under the kernel pin, where ``nn.Conv1d``'s
    im2col GEMM stays on MKL's SSE2 branch (issue 31: MACVAE's temporal convolutions were
    22 % of its training step).  Stride, dilation and groups other than 1 fall back to
    ``nn.Conv1d``'s own kernel."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if (self.stride != (1,) or self.dilation != (1,) or self.groups != 1
                or isinstance(self.padding, str) or x.dim() != 3):
            return super().forward(x)
        if self.padding_mode != "zeros":
            x = F.pad(x, self._reversed_padding_repeated_twice, mode=self.padding_mode)
        elif self.padding[0]:
            x = F.pad(x, (self.padding[0], self.padding[0]))
        N, C, L = x.shape
        k = self.kernel_size[0]
        if L < k:  # too short for the kernel: torch's own error
            return F.conv1d(x, self.weight, self.bias)
        cols = x.unfold(2, k, 1).permute(0, 2, 1, 3).reshape(N, L - k + 1, C * k)
        out = F.linear(cols, self.weight.reshape(self.out_channels, C * k), self.bias)
        return out.transpose(1, 2)


class Packing:
    """The valid tokens of a padded batch as one matrix (issue 31): ``valid`` (B, T) bool.
    :meth:`pack` takes (B, T, ...) to (N, ...), the N valid tokens in batch-major order;
    :meth:`unpack` puts them back, zeros at the padded places.  A position-wise layer (linear,
    layer norm, dropout) on packed tokens computes the padded layer's valid rows without the
    padded ones; attention unpacks its projected queries, keys and values, so every valid
    query sees the keys it saw before (padded keys are masked, or, causally, only seen by padded
    queries) and its output rows are the padded pass's (to rounding: a product over fewer rows;
    dropout draws one mask element per packed element)."""

    def __init__(self, valid: torch.Tensor):
        self.B, self.T = valid.shape
        # found on the host (a data-dependent size: one device sync, as ``nonzero`` has anyway)
        self.index = valid.reshape(-1).cpu().nonzero().squeeze(1).to(valid.device)

    def pack(self, x: torch.Tensor) -> torch.Tensor:
        return x.reshape(self.B * self.T, *x.shape[2:]).index_select(0, self.index)

    def unpack(self, x: torch.Tensor, fill: torch.Tensor | None = None) -> torch.Tensor:
        """(N, ...) -> (B, T, ...); the padded places zero, or ``fill`` (broadcast to one
        token's shape)."""
        shape = (self.B * self.T, *x.shape[1:])
        base = x.new_zeros(shape) if fill is None else fill.to(x.dtype).expand(shape).contiguous()
        return base.index_copy(0, self.index, x).view(self.B, self.T, *x.shape[1:])


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

    def project_kv(self, kv_in: torch.Tensor, packing: Packing | None = None
                   ) -> tuple[torch.Tensor, torch.Tensor]:
        """Keys and values (B, H, Lk, dh) of ``kv_in`` (B, Lk, d), or of packed tokens
        (N, d) with their ``packing`` (zeros at the padded keys)."""
        if packing is None:
            return self._split(self.k(kv_in)), self._split(self.v(kv_in))
        return self._split(packing.unpack(self.k(kv_in))), self._split(packing.unpack(self.v(kv_in)))

    def attend(self, q_in, k, v, *, causal: bool = False, key_padding_mask=None,
               packing: Packing | None = None) -> torch.Tensor:
        """Attention of queries ``q_in`` (B, Lq, d; packed (N, d) with ``packing``, and the
        output packed too) over projected keys/values."""
        q = self.q(q_in)
        q = self._split(q if packing is None else packing.unpack(q))
        mask = _padding_to_additive(key_padding_mask, q.dtype)
        if causal:
            Lq, Lk = q.shape[-2], k.shape[-2]
            c = torch.ones(Lq, Lk, dtype=torch.bool, device=q.device).tril(Lk - Lq)
            cm = torch.zeros(Lq, Lk, dtype=q.dtype, device=q.device).masked_fill(~c, float("-inf"))
            mask = cm if mask is None else mask + cm
        if self.training and self.dropout > 0.0:
            # attention-weight dropout with :func:`dropout`'s mask: the weights written out
            # (SDPA's own math path does the same, with bernoulli_ draws)
            s = torch.matmul(q * (1.0 / math.sqrt(q.shape[-1])), k.transpose(-2, -1))
            dead = None
            if mask is not None:
                s = s.add_(mask)
                # a query whose every key is masked (an item with no valid key) attends to
                # nothing, as SDPA's safe softmax has it: zero weights, finite gradients
                dead = torch.isneginf(mask).all(-1, keepdim=True)
                dead = dead if bool(dead.any()) else None
                if dead is not None:
                    s = s.masked_fill(dead, 0.0)
            w = torch.softmax(s, dim=-1)
            if dead is not None:
                w = w.masked_fill(dead, 0.0)
            o = torch.matmul(dropout(w, self.dropout), v)
        else:
            o = F.scaled_dot_product_attention(q, k, v, attn_mask=mask)
        B, H, L, dh = o.shape
        o = o.transpose(1, 2).reshape(B, L, H * dh)
        return self.out(o if packing is None else packing.pack(o))

    def forward(self, q_in, kv_in, *, causal: bool = False, key_padding_mask=None,
                packing: Packing | None = None):
        """Self-attention when ``kv_in`` is ``q_in``; ``packing`` packs both."""
        k, v = self.project_kv(kv_in, packing)
        return self.attend(q_in, k, v, causal=causal, key_padding_mask=key_padding_mask,
                           packing=packing)


class FeedForward(nn.Module):
    def __init__(self, d_model: int, d_ff: int, dropout: float, activation: str):
        super().__init__()
        self.lin1 = nn.Linear(d_model, d_ff)
        self.lin2 = nn.Linear(d_ff, d_model)
        self.drop = Dropout(dropout)
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
        self.drop1, self.drop2 = Dropout(dropout), Dropout(dropout)

    def forward(self, x, key_padding_mask=None, packing: Packing | None = None):
        x = self.norm1(x + self.drop1(self.attn(x, x, key_padding_mask=key_padding_mask,
                                                packing=packing)))
        return self.norm2(x + self.drop2(self.ff(x)))


class TransformerEncoder(nn.Module):
    def __init__(self, n_layers: int, d_model: int, n_heads: int, d_ff: int, dropout: float,
                 activation: str):
        super().__init__()
        self.layers = nn.ModuleList(
            EncoderLayer(d_model, n_heads, d_ff, dropout, activation) for _ in range(n_layers))

    def forward(self, x, key_padding_mask=None, packing: Packing | None = None):
        """``x`` (B, L, d), or its valid tokens (N, d) with their ``packing`` (output packed
        too: :class:`Packing`)."""
        for layer in self.layers:
            x = layer(x, key_padding_mask, packing)
        return x


@dataclass
class DecoderCache:
    """Per-layer state for incremental decoding, allocated once by
    :meth:`TransformerDecoder.init_cache` and written in place by :meth:`TransformerDecoder.step`.

    ``self_kv[i]``: layer ``i``'s self-attention keys, transposed, (B·H, dh, capacity) and
    values (B·H, capacity, dh) of the steps taken so far; a step projects its own row once,
    writes it at column/row ``length`` and attends over the filled prefix (no step reallocates
    or copies the past).  ``mem_kv[i]``: the memory's keys, transposed, (B·H, dh, Lk) and
    values (B·H, Lk, dh) for layer ``i``'s cross-attention, projected once per pass (the memory
    is the same at every step).  ``mem_bias``: the memory's padding as an additive
    (B·H, 1, Lk) mask, ``None`` when no key is padded.  ``weights[i]``: layer ``i``'s weights
    laid out for one-token steps (:meth:`DecoderLayer.step_weights`), copies made once per
    cache; the module's parameters are untouched.

    Issue 31: until then the cache held each layer's *inputs* and the raw memory and folded
    ``W_k`` into the query and ``W_v`` into the output at every step (per key ``d``
    multiply-adds per head instead of ``dh``); the projected form above is 1.40x faster on the
    paper-width sampler (docs/marionet.md, "Cached sampler").
    """

    mem_kv: list
    mem_bias: torch.Tensor | None
    weights: list
    self_kv: list = field(default_factory=list)
    length: int = 0

    @property
    def capacity(self) -> int:
        return int(self.self_kv[0][1].shape[1]) if self.self_kv else 0

    def reserve(self, n: int) -> None:
        """Make room for at least ``n`` steps (doubling; a copy only when a caller decodes past
        the length given to ``init_cache``)."""
        if n <= self.capacity:
            return
        cap = max(n, 2 * self.capacity)
        t = self.length
        for i, (k_t, v) in enumerate(self.self_kv):
            nk = k_t.new_empty(k_t.shape[0], k_t.shape[1], cap)
            nv = v.new_empty(v.shape[0], cap, v.shape[2])
            nk[:, :, :t] = k_t[:, :, :t]
            nv[:, :t] = v[:, :t]
            self.self_kv[i] = (nk, nv)


def _step_cross_weights(mha: MultiHeadAttention) -> tuple:
    """``mha``'s query and output weights for :func:`_step_cross_attention`: ``(q_w, q_b,
    out_w, out_b)``, the query projection transposed and pre-scaled by ``1/sqrt(dh)``, the
    output projection transposed."""
    s = 1.0 / math.sqrt(mha.d_model // mha.n_heads)
    return ((mha.q.weight * s).t().contiguous(), mha.q.bias * s,
            mha.out.weight.t().contiguous(), mha.out.bias)


def _memory_kv(mha: MultiHeadAttention, memory: torch.Tensor) -> tuple:
    """The memory's keys, transposed, (B·H, dh, Lk) and values (B·H, Lk, dh), projected once."""
    k, v = mha.project_kv(memory)                                       # (B, H, Lk, dh)
    B, H, Lk, dh = k.shape
    return (k.transpose(2, 3).reshape(B * H, dh, Lk).contiguous(),
            v.reshape(B * H, Lk, dh).contiguous())


def _attend_cached(q, keys_t, values, out_w, out_b, bias=None) -> torch.Tensor:
    """Scaled queries ``q`` (B·H, 1, dh) over cached keys, transposed, (B·H, dh, L) and values
    (B·H, L, dh), with an optional additive mask; the heads concatenated in order (B, d) and
    put through the output projection (``out_w`` transposed)."""
    scores = torch.bmm(q, keys_t) if bias is None else torch.baddbmm(bias, q, keys_t)
    o = torch.bmm(scores.softmax(-1), values)
    return torch.addmm(out_b, o.view(-1, out_w.shape[0]), out_w)


def _step_self_weights(mha: MultiHeadAttention) -> tuple:
    """``mha``'s weights for a one-token self-attention step: ``(qkv_w, qkv_b, out_w,
    out_b)``, the query, key and value projections stacked and transposed (B, 3d) in one
    ``addmm``, the query's part pre-scaled by ``1/sqrt(dh)``."""
    s = 1.0 / math.sqrt(mha.d_model // mha.n_heads)
    w = torch.cat([mha.q.weight * s, mha.k.weight, mha.v.weight])
    b = torch.cat([mha.q.bias * s, mha.k.bias, mha.v.bias])
    return w.t().contiguous(), b, mha.out.weight.t().contiguous(), mha.out.bias


def _step_self_attention(x, weights: tuple, self_kv: tuple, t: int) -> torch.Tensor:
    """One query row per item ``x`` (B, d) attending to the cached keys/values of steps
    ``0..t-1`` and its own, written at ``t`` (``self_kv``: keys transposed (B·H, dh, cap),
    values (B·H, cap, dh))."""
    qkv_w, qkv_b, out_w, out_b = weights
    keys_t, values = self_kv
    dh = keys_t.shape[1]
    q, k, v = torch.addmm(qkv_b, x, qkv_w).split(x.shape[1], dim=1)
    keys_t[:, :, t] = k.reshape(-1, dh)
    values[:, t] = v.reshape(-1, dh)
    return _attend_cached(q.reshape(-1, 1, dh), keys_t[:, :, :t + 1], values[:, :t + 1],
                          out_w, out_b)


def _step_cross_attention(x, weights: tuple, mem_kv: tuple, bias=None) -> torch.Tensor:
    """Multi-head attention (incl. the output projection) of one query row per item ``x``
    (B, d) over keys/values projected once from the memory (:func:`_memory_kv`)."""
    q_w, q_b, out_w, out_b = weights
    keys_t, values = mem_kv
    q = torch.addmm(q_b, x, q_w).view(-1, 1, keys_t.shape[1])          # (B·H, 1, dh), scaled
    return _attend_cached(q, keys_t, values, out_w, out_b, bias)


class DecoderLayer(nn.Module):
    """Post-norm transformer decoder layer: (causal) self-attention, cross-attention to a
    memory, feed-forward."""

    def __init__(self, d_model: int, n_heads: int, d_ff: int, dropout: float, activation: str):
        super().__init__()
        self.self_attn = MultiHeadAttention(d_model, n_heads, dropout)
        self.cross_attn = MultiHeadAttention(d_model, n_heads, dropout)
        self.ff = FeedForward(d_model, d_ff, dropout, activation)
        self.norm1, self.norm2, self.norm3 = (nn.LayerNorm(d_model) for _ in range(3))
        self.drop1, self.drop2, self.drop3 = (Dropout(dropout) for _ in range(3))

    def _tail(self, x, mem_k, mem_v, mem_mask, packing: Packing | None = None):
        x = self.norm2(x + self.drop2(self.cross_attn.attend(x, mem_k, mem_v,
                                                             key_padding_mask=mem_mask,
                                                             packing=packing)))
        return self.norm3(x + self.drop3(self.ff(x)))

    def forward(self, x, memory, *, causal: bool, self_padding_mask=None, mem_padding_mask=None,
                packing: Packing | None = None, mem_packing: Packing | None = None):
        sa = self.self_attn(x, x, causal=causal, key_padding_mask=self_padding_mask,
                            packing=packing)
        x = self.norm1(x + self.drop1(sa))
        mk, mv = self.cross_attn.project_kv(memory, mem_packing)
        return self._tail(x, mk, mv, mem_padding_mask, packing)

    def step_weights(self) -> tuple:
        """This layer's weights for :meth:`step`: the self-attention's
        (:func:`_step_self_weights`), the cross-attention's (:func:`_step_cross_weights`)
        and the feed-forward's ``(W1^T, b1, W2^T, b2)``
        (contiguous transposed copies, for ``addmm`` without a per-call transpose); made once
        per decoding pass."""
        ff = self.ff
        return (_step_self_weights(self.self_attn), _step_cross_weights(self.cross_attn),
                (ff.lin1.weight.t().contiguous(), ff.lin1.bias,
                 ff.lin2.weight.t().contiguous(), ff.lin2.bias))

    def step(self, x, cache: DecoderCache, i: int):
        """One new position ``x`` (B, d) attending to the cached past and itself, then to the
        memory (inference: no dropout): :meth:`forward` at one position.  Writes its key and
        value at position ``cache.length`` of layer ``i``'s cache;
        :meth:`TransformerDecoder.step` advances the length after the last layer."""
        self_w, cross_w, (f1_w, f1_b, f2_w, f2_b) = cache.weights[i]
        x = self.norm1(x + _step_self_attention(x, self_w, cache.self_kv[i], cache.length))
        x = self.norm2(x + _step_cross_attention(x, cross_w, cache.mem_kv[i], cache.mem_bias))
        return self.norm3(x + torch.addmm(f2_b, self.ff.act(torch.addmm(f1_b, x, f1_w)), f2_w))


class TransformerDecoder(nn.Module):
    """A stack of :class:`DecoderLayer` with a parallel path and a key/value-cached step path."""

    def __init__(self, n_layers: int, d_model: int, n_heads: int, d_ff: int, dropout: float,
                 activation: str):
        super().__init__()
        self.layers = nn.ModuleList(
            DecoderLayer(d_model, n_heads, d_ff, dropout, activation) for _ in range(n_layers))

    def forward(self, x, memory, *, causal: bool = False, self_padding_mask=None,
                mem_padding_mask=None, packing: Packing | None = None,
                mem_packing: Packing | None = None):
        """``x`` (B, L, d) over ``memory`` (B, Lm, d); either may be its valid tokens only with
        its :class:`Packing` (``packing``: the output is packed too)."""
        for layer in self.layers:
            x = layer(x, memory, causal=causal, self_padding_mask=self_padding_mask,
                      mem_padding_mask=mem_padding_mask, packing=packing, mem_packing=mem_packing)
        return x

    @torch.inference_mode()
    def init_cache(self, memory: torch.Tensor, mem_padding_mask=None,
                   max_len: int | None = None) -> DecoderCache:
        """Everything a decoding pass reuses, made once: per layer the memory's projected keys
        and values (:func:`_memory_kv`), the step weights (:meth:`DecoderLayer.step_weights`)
        and key/value buffers for ``max_len`` steps (default: the memory's length; :meth:`step`
        grows them if a caller goes further), the padding mask as an additive mask.
        Inference only."""
        B, Lk, d = memory.shape
        H = self.layers[0].cross_attn.n_heads if len(self.layers) else 1
        cap = Lk if max_len is None else max(1, int(max_len))
        bias = None
        if mem_padding_mask is not None and bool(mem_padding_mask.any()):
            bias = (_padding_to_additive(mem_padding_mask, memory.dtype)
                    .expand(B, H, 1, Lk).reshape(B * H, 1, Lk))
        return DecoderCache([_memory_kv(layer.cross_attn, memory) for layer in self.layers],
                            bias,
                            [layer.step_weights() for layer in self.layers],
                            [(memory.new_empty(B * H, d // H, cap),
                              memory.new_empty(B * H, cap, d // H)) for _ in self.layers])

    @torch.inference_mode()
    def step(self, x: torch.Tensor, cache: DecoderCache) -> torch.Tensor:
        """Decode one position ``x`` (B, 1, d); writes each layer's key and value into
        ``cache`` and advances ``cache.length``.  Inference only (dropout off, no gradient)."""
        cache.reserve(cache.length + 1)
        B = x.shape[0]
        x = x.reshape(B, -1)
        for i, layer in enumerate(self.layers):
            x = layer.step(x, cache, i)
        cache.length += 1
        return x.view(B, 1, -1)
