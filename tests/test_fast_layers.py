"""Issue 31's number-changing layers (repro/models/layers.py): dropout from 16 random bits per
element and ``Conv1d`` as an unfolded product are the functions they replace — the rate, the
scale, train/eval, gradients; the convolution equal to ``nn.Conv1d``'s to rounding, with its
gradients — the attention with weight dropout written out equals SDPA without dropout, and
layers run on packed valid tokens give the padded layers' valid rows."""

from __future__ import annotations

import pytest
import torch

from repro.models import layers


def test_dropout_rate_scale_and_eval():
    x = torch.ones(400_000)
    torch.manual_seed(0)
    y = layers.dropout(x, 0.1, True)
    kept = y != 0
    q = round(0.1 * layers.DROPOUT_LEVELS) / layers.DROPOUT_LEVELS
    assert abs(1 - kept.float().mean().item() - q) < 0.003  # ~5 standard errors
    assert torch.allclose(y[kept], torch.full_like(y[kept], 1 / (1 - q)))
    assert torch.equal(layers.dropout(x, 0.1, False), x) and layers.dropout(x, 0.0) is x
    assert torch.equal(layers.dropout(x[:10], 1.0), torch.zeros(10))
    m = layers.Dropout(0.3)
    m.eval()
    assert torch.equal(m(x[:50]), x[:50])
    with pytest.raises(ValueError):
        layers.Dropout(1.5)


def test_dropout_is_seeded_odd_sized_and_differentiable():
    x = torch.randn(3, 7, 5, requires_grad=True)  # 105 elements: not a multiple of four
    torch.manual_seed(3)
    a = layers.dropout(x, 0.5)
    torch.manual_seed(3)
    b = layers.dropout(x, 0.5)
    assert torch.equal(a, b) and a.shape == x.shape
    a.sum().backward()
    assert set(x.grad.unique().tolist()) <= {0.0, 2.0}  # the mask times 1 / (1 - p)
    assert torch.equal(x.grad != 0, a != 0)


def test_dropout_masks_are_independent_across_positions():
    torch.manual_seed(1)
    keep = (layers.dropout(torch.ones(4, 100_000), 0.5) != 0).float()
    # neighbours in one 64-bit draw are uncorrelated
    for lag in (1, 2, 3, 4):
        r = torch.corrcoef(torch.stack([keep[0, :-lag], keep[0, lag:]]))[0, 1]
        assert abs(r.item()) < 0.02


@pytest.mark.parametrize("kw", [{}, {"padding": 2, "padding_mode": "replicate"},
                                {"padding": 1}, {"bias": False}])
def test_conv1d_is_nn_conv1d(kw):
    torch.manual_seed(0)
    conv = layers.Conv1d(6, 4, 5, **kw).double()
    x = torch.randn(3, 6, 11, dtype=torch.float64, requires_grad=True)
    assert torch.allclose(conv(x), torch.nn.Conv1d.forward(conv, x), atol=1e-12)
    assert torch.autograd.gradcheck(conv, (x,))
    strided = layers.Conv1d(6, 4, 3, stride=2).double()  # falls back to nn.Conv1d's kernel
    assert torch.equal(strided(x), torch.nn.Conv1d.forward(strided, x))
    with pytest.raises(RuntimeError):
        layers.Conv1d(6, 4, 5)(torch.randn(1, 6, 3))  # shorter than the kernel


def test_attention_with_weight_dropout_off_equals_sdpa():
    """The written-out attention (training with weight dropout) is SDPA's function: with the
    dropout rate set to 0 in its formula the two agree to rounding, masks included."""
    torch.manual_seed(0)
    att = layers.MultiHeadAttention(16, 4, dropout=0.2)
    q, kv = torch.randn(3, 6, 16), torch.randn(3, 9, 16)
    pad = torch.zeros(3, 9, dtype=torch.bool)
    pad[1, 5:] = True
    att.eval()
    ref = att(q, kv, key_padding_mask=pad)
    att.train()
    att.dropout = 1e-9  # below the mask's resolution: nothing dropped, the explicit path taken
    assert torch.allclose(att(q, kv, key_padding_mask=pad), ref, atol=1e-6)
    causal_ref = (att.eval(), att(q, q, causal=True))[1]
    att.train()
    assert torch.allclose(att(q, q, causal=True), causal_ref, atol=1e-6)


def test_attention_with_every_key_padded_attends_to_nothing_with_finite_gradients():
    """An item whose keys are all padded (and queries past a short key sequence under the
    causal mask) get zero attention in training as in evaluation (SDPA's safe softmax), and
    the gradients stay finite (a NaN there would poison every weight at the next step)."""
    torch.manual_seed(0)
    att = layers.MultiHeadAttention(16, 4, dropout=0.1)
    q, kv = torch.randn(3, 6, 16, requires_grad=True), torch.randn(3, 9, 16)
    pad = torch.zeros(3, 9, dtype=torch.bool)
    pad[1, :] = True
    out = att(q, kv, key_padding_mask=pad)
    out.sum().backward()
    assert torch.isfinite(out).all() and torch.isfinite(q.grad).all()
    assert all(torch.isfinite(p.grad).all() for p in att.parameters() if p.grad is not None)
    att.eval()
    ref = att(q, kv, key_padding_mask=pad)
    assert torch.allclose(out[1], ref[1], atol=1e-6)  # the padded item: the output bias alone


def test_packed_tokens_compute_the_padded_layers_valid_rows():
    """``Packing`` (issue 31, MarioNet's ``packed_frames``): an encoder and a causal decoder
    over a memory, run on the valid tokens only, give the padded pass's valid rows (eval mode:
    no dropout draws) and the same gradients, to rounding; pack and unpack are inverse on the
    valid rows, ``unpack`` fills the padded ones."""
    torch.manual_seed(0)
    B, T, d = 3, 7, 16
    lengths = torch.tensor([7, 3, 5])
    valid = torch.arange(T)[None] < lengths[:, None]
    pk = layers.Packing(valid)
    x = torch.randn(B, T, d, requires_grad=True)
    assert torch.equal(pk.unpack(pk.pack(x))[valid], x[valid])
    assert torch.equal(pk.unpack(pk.pack(x))[~valid], torch.zeros(int((~valid).sum()), d))
    assert torch.equal(pk.unpack(pk.pack(x), torch.ones(d))[~valid],
                       torch.ones(int((~valid).sum()), d))
    enc = layers.TransformerEncoder(2, d, 4, 32, 0.1, "gelu").eval()
    dec = layers.TransformerDecoder(2, d, 4, 32, 0.1, "relu").eval()

    def run(packed: bool):
        x.grad = None
        for p in (*enc.parameters(), *dec.parameters()):
            p.grad = None
        p = pk if packed else None
        h = enc(pk.pack(x) if packed else x, key_padding_mask=~valid, packing=p)
        y = dec(h, h, causal=True, mem_padding_mask=~valid, packing=p, mem_packing=p)
        y = pk.unpack(y) if packed else y
        (y[valid] ** 2).sum().backward()
        return y[valid].detach(), [x.grad.clone()] + [q.grad.clone() for q in (
            *enc.parameters(), *dec.parameters())]

    (y1, g1), (y0, g0) = run(True), run(False)
    assert torch.allclose(y1, y0, atol=1e-5)
    for a, b in zip(g1, g0):
        assert torch.allclose(a, b, rtol=1e-4, atol=1e-5)
