"""Matrix products on the pinned OpenBLAS (issue 31, repro/gemm.py): under the pin torch's CPU
``mm``/``addmm``/``bmm``/``baddbmm`` are numpy's OpenBLAS products, with torch's semantics
(dtypes, ``beta``/``alpha``, errors, autograd), and ``--fast-kernels`` keeps torch's own."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from repro import gemm, kernels


@pytest.fixture(autouse=True)
def _pinned():
    kernels.check()
    assert gemm.installed()
    yield
    gemm.install()


def _close(a, b, tol=1e-5):
    return torch.allclose(a.double(), b.double(), rtol=tol, atol=tol)


def test_products_are_openblas_s_bits():
    g = torch.Generator().manual_seed(0)
    a, b = torch.randn(70, 33, generator=g), torch.randn(33, 41, generator=g)
    want = torch.from_numpy(np.matmul(a.numpy(), b.numpy()))
    assert torch.equal(a @ b, want) and torch.equal(torch.mm(a, b), want)
    # a transposed operand goes to BLAS as it is (no copy changes the sum)
    assert torch.equal(b.t() @ a.t(), torch.from_numpy(np.matmul(b.numpy().T, a.numpy().T)))
    x, y = torch.randn(5, 7, 9, generator=g), torch.randn(5, 9, 4, generator=g)
    assert torch.equal(torch.bmm(x, y), torch.from_numpy(np.matmul(x.numpy(), y.numpy())))


def test_semantics_match_torch_s_own_kernels():
    g = torch.Generator().manual_seed(1)
    a, b = torch.randn(6, 5, generator=g), torch.randn(5, 4, generator=g)
    bias = torch.randn(4, generator=g)
    x, y, c = (torch.randn(3, 6, 5, generator=g), torch.randn(3, 5, 4, generator=g),
               torch.randn(3, 6, 4, generator=g))
    routed = [torch.addmm(bias, a, b), torch.addmm(bias, a, b, beta=0.5, alpha=-2.0),
              torch.baddbmm(c, x, y, beta=2.0, alpha=0.25), torch.mm(a.double(), b.double()),
              torch.mm(torch.arange(6).view(2, 3), torch.arange(6).view(3, 2)),
              torch.mm(a.half(), b.half()), torch.mm(a.bfloat16(), b.bfloat16()),
              torch.mm(torch.complex(a, a), torch.complex(b, -b)),
              torch.addmm(torch.full((4,), math.nan), a, b, beta=0)]  # self unread at beta 0
    gemm.uninstall()
    own = [torch.addmm(bias, a, b), torch.addmm(bias, a, b, beta=0.5, alpha=-2.0),
           torch.baddbmm(c, x, y, beta=2.0, alpha=0.25), torch.mm(a.double(), b.double()),
           torch.mm(torch.arange(6).view(2, 3), torch.arange(6).view(3, 2)),
           torch.mm(a.half(), b.half()), torch.mm(a.bfloat16(), b.bfloat16()),
           torch.mm(torch.complex(a, a), torch.complex(b, -b)),
           torch.addmm(torch.full((4,), math.nan), a, b, beta=0)]
    gemm.install()
    for r, o in zip(routed, own):
        assert r.dtype == o.dtype and r.shape == o.shape
        tol = 1e-2 if r.dtype in (torch.float16, torch.bfloat16) else 1e-5
        if r.is_complex():
            assert _close(torch.view_as_real(r), torch.view_as_real(o), tol)
        else:
            assert _close(r, o, tol)
    assert not torch.isnan(routed[-1]).any()


def test_views_expanded_and_conjugate_operands():
    g = torch.Generator().manual_seed(2)
    w = torch.randn(8, 3, generator=g)
    e = torch.randn(1, 8, generator=g).expand(4, 8)  # zero stride: copied for BLAS
    z = torch.complex(torch.randn(2, 3, generator=g), torch.randn(2, 3, generator=g))
    got = [e @ w, w[::2].t() @ w[::2], z.conj() @ z.t()]
    want = [np.matmul(e.numpy(), w.numpy()), np.matmul(w[::2].numpy().T, w[::2].numpy()),
            np.matmul(np.conj(z.numpy()), z.numpy().T)]
    for r, o in zip(got, want):
        assert np.allclose(r.numpy(), o, rtol=1e-6, atol=1e-6)
    assert torch.mm(torch.empty(0, 3), torch.empty(3, 2)).shape == (0, 2)
    assert torch.equal(torch.mm(torch.ones(2, 0), torch.ones(0, 3)), torch.zeros(2, 3))


def test_errors_are_runtime_errors():
    with pytest.raises(RuntimeError, match="cannot be multiplied"):
        torch.mm(torch.randn(2, 3), torch.randn(4, 2))
    with pytest.raises(RuntimeError, match="same dtype"):
        torch.mm(torch.randn(2, 3), torch.randn(3, 2).double())
    with pytest.raises(RuntimeError, match="same number of batches"):
        torch.bmm(torch.randn(2, 2, 3), torch.randn(3, 3, 2))


def test_gradients_flow_through_the_routed_products():
    g = torch.Generator().manual_seed(3)
    lin = torch.nn.Linear(5, 4).double()
    x = torch.randn(7, 5, dtype=torch.float64, generator=g, requires_grad=True)
    assert torch.autograd.gradcheck(lambda t: lin(t).tanh(), (x,))
    a = torch.randn(2, 3, 4, dtype=torch.float64, generator=g, requires_grad=True)
    b = torch.randn(2, 4, 5, dtype=torch.float64, generator=g, requires_grad=True)
    assert torch.autograd.gradcheck(torch.bmm, (a, b))


def test_the_pin_requires_the_route_and_records_it():
    st = kernels.state()
    assert st["gemm"] == gemm.NAME and st["openblas_threads"] == [1]
    gemm.uninstall()
    bad = kernels.pinned_in_force(kernels.state())
    gemm.install()
    assert any("matrix products" in b for b in bad)
    rec = kernels.record()
    assert rec["version"] == kernels.PIN_VERSION >= 2
    assert "OpenBLAS Haswell" in kernels.describe(rec)


def test_every_layout_reaches_blas():
    """Operands numpy's matmul would hand to its own slow loop (zero strides, a batch
    transposed as a whole, a stepped slice) are copied first; BLAS-ready ones are not."""
    a = np.ones((4, 3, 5), dtype=np.float32)
    assert gemm._blas_ready(a) is a
    assert gemm._blas_ready(a[0].T) is a[0].T or gemm._blas_ready(a[0].T).base is a
    f = np.asfortranarray(a)  # each matrix's rows strided by the batch: not BLAS-ready
    assert gemm._blas_ready(f).flags.c_contiguous
    s = np.ones((6, 8), dtype=np.float32)[:, ::2]
    assert gemm._blas_ready(s).flags.c_contiguous
    e = np.broadcast_to(np.ones(5, dtype=np.float32), (3, 5))
    assert gemm._blas_ready(e).flags.c_contiguous



def test_addmm_edge_cases_follow_torch():
    """alpha = 0 leaves the product unread (BLAS's convention), and ``self`` must have the
    products' dtype and broadcast to their shape even when beta = 0."""
    nan = torch.full((1, 2), math.nan)
    assert torch.equal(torch.addmm(torch.ones(1, 2), nan, torch.ones(2, 2), alpha=0),
                       torch.ones(1, 2))
    with pytest.raises(RuntimeError, match="same dtype"):
        torch.addmm(torch.ones(2, dtype=torch.float64), torch.ones(3, 4), torch.ones(4, 2))
    with pytest.raises(RuntimeError, match="broadcast"):
        torch.addmm(torch.ones(5), torch.ones(3, 4), torch.ones(4, 2), beta=0)
