"""Portable matrix products at AVX2 speed (issue 31; docs/engine.md, "Kernel pinning").

Under the kernel pin (:mod:`repro.kernels`) torch's CPU matrix products ran on MKL's
vendor-neutral ``COMPATIBLE`` branch, SSE2 code: the one MKL branch that gives Intel and AMD
CPUs the same bits, and 2.7-2.9x slower per GEMM here than AVX2 code (measured on the AMD
EPYC: 1800x128 @ 128x256 in float32, one thread, 3.1 ms against 1.1 ms).  Training time is
mostly those products (MarioNet's steps: ~60 % ``mm``/``addmm``/``bmm``).

While the pin is in force (:func:`install`, called by :func:`repro.kernels.apply_runtime`
before every job and training), torch's CPU kernels of ``aten::mm``, ``addmm``, ``bmm`` and
``baddbmm`` are replaced by this module's, which compute the product with numpy's ``matmul``,
i.e. with numpy's OpenBLAS, whose core the pin fixes to ``Haswell`` (``OPENBLAS_CORETYPE``)
and whose thread count it fixes to one (``OPENBLAS_NUM_THREADS``): the same AVX2/FMA kernels
and the same blocking on every x86-64 CPU with AVX2, whatever its vendor or cache sizes, so the
same bits (checked by the op battery, ``benchmarks/kernel_ops.py``, natively, under every
ambient setting, and under an emulated Intel CPU; ``tests/golden/kernel_ops.json``).  Because
the replacement sits at the dispatcher, every caller of those operators takes it:
``nn.Linear`` (``addmm``), ``matmul`` (``mm``/``bmm``), the training path's attention,
``nn.GRU``/``nn.LSTM`` gates and every backward formula that multiplies matrices.  What calls
other operators stays on MKL's COMPATIBLE branch, also portable: the in-place and ``out=``
variants (``addmm_``, ``mm(out=)``), SDPA's fused CPU kernel (attention without dropout, i.e.
at evaluation and sampling), ``mv``, ``dot`` and convolutions' own im2col GEMM.

Two differences from torch's kernels that no code here meets: a result's storage is numpy's
(``resize_`` of it raises, as for any ``torch.from_numpy`` tensor), and a product that makes
an Inf or NaN from finite numbers (a diverging training) may print numpy's ``RuntimeWarning:
invalid value encountered in matmul`` once (inside a user's ``np.errstate(all="raise")`` it
would raise FloatingPointError); silencing it per call (``np.errstate``) cost ~2 µs a call.

Semantics follow torch's: same-dtype operands (float, complex and integer; half and bfloat16
are computed in float32 and rounded once), ``addmm(self, m1, m2, beta, alpha) = beta * self +
alpha * (m1 @ m2)`` with ``self`` ignored when ``beta`` is 0, shape errors as RuntimeError.
The summation order is OpenBLAS's, not MKL's, so numbers differ from the unrouted kernels in
the last bits (hence pin version 2 in every job key).  ``--fast-kernels`` keeps torch's own.
"""

from __future__ import annotations

import threading
import warnings

#: the aten operators (default overloads) whose CPU kernels :func:`install` replaces
OPS = ("mm", "addmm", "bmm", "baddbmm")
#: what the pin's record and ``repro doctor`` call this path
NAME = "numpy OpenBLAS (Haswell core, 1 thread)"

_LOCK = threading.Lock()
_LIB = None  # the torch.library.Library holding the replacements (None: torch's own kernels)


def _array(t, dtype=None):
    """``t`` as a numpy array sharing its memory where it can (conjugate and negative views
    resolved; bool refused as torch does), cast to ``dtype`` when given."""
    import torch

    t = t.detach()
    if t.is_conj():
        t = t.resolve_conj()
    if t.is_neg():
        t = t.resolve_neg()
    if t.dtype == torch.bool:
        raise NotImplementedError("\"addmm_impl_cpu_\" not implemented for 'Bool'")
    if dtype is not None:
        t = t.to(dtype)
    return _blas_ready(t.numpy())


def _blas_ready(a):
    """``a`` itself when numpy's matmul can hand its last two dimensions to BLAS (one of them
    unit-stride, the other's stride a whole row), else a C-contiguous copy, so that every
    product runs OpenBLAS's kernels rather than numpy's fallback loop."""
    flags = a.flags
    if flags.c_contiguous or (flags.f_contiguous and a.ndim == 2) or a.ndim < 2 or 0 in a.shape:
        return a
    import numpy as np

    item = a.itemsize
    s0, s1 = a.strides[-2], a.strides[-1]
    n0, n1 = a.shape[-2], a.shape[-1]
    row = s1 == item and s0 % item == 0 and s0 >= n1 * item
    col = s0 == item and s1 % item == 0 and s1 >= n0 * item
    if (row or col) and a.flags.aligned and all(s >= 0 for s in a.strides):
        return a
    return np.ascontiguousarray(a)


def _compute_dtype(t):
    """The dtype numpy multiplies ``t`` in (None: its own): half and bfloat16 in float32."""
    import torch

    return torch.float32 if t.dtype in (torch.float16, torch.bfloat16) else None


def _fast_product(a, b, want: int):
    """The product of two same-dtype float32/float64 operands of ``want`` dimensions whose
    shapes fit, as :func:`_product` computes it, with the fewest steps (most calls: the
    training steps' products); None when any of that does not hold."""
    if a.dtype not in _BLAS_DTYPES or b.dtype is not a.dtype or a.dim() != want \
            or b.dim() != want or a.shape[-1] != b.shape[-2] \
            or (want == 3 and a.shape[0] != b.shape[0]):
        return None
    try:
        x, y = a.detach().numpy(), b.detach().numpy()
    except RuntimeError:  # a conjugate or negative view
        return None
    return _matmul_into_torch(_blas_ready(x), _blas_ready(y))


def _matmul_into_torch(x, y):
    """``x @ y`` by numpy's matmul, as a tensor sharing the result's memory (numpy's
    allocation: a torch-allocated ``out=`` cost ~6 µs more per call, a tenth of A2M's steps)."""
    return _TORCH.from_numpy(_np.matmul(x, y))


def _product(a, b, name: str, batched: bool):
    import torch

    want = 3 if batched else 2
    fast = _fast_product(a, b, want)
    if fast is not None:
        return fast
    if a.dim() != want or b.dim() != want:
        raise RuntimeError(f"{name}: expected {want}-D tensors, got {a.dim()}-D and {b.dim()}-D")
    if a.dtype != b.dtype:
        raise RuntimeError(f"{name}: expected mat1 and mat2 to have the same dtype, but got: "
                           f"{a.dtype} != {b.dtype}")
    if batched and a.shape[0] != b.shape[0]:
        raise RuntimeError(f"{name}: batch1 and batch2 must have same number of batches, got "
                           f"{a.shape[0]} and {b.shape[0]}")
    if a.shape[-1] != b.shape[-2]:
        raise RuntimeError(f"{name}: mat1 and mat2 shapes cannot be multiplied "
                           f"({'x'.join(map(str, a.shape))} and {'x'.join(map(str, b.shape))})")
    cd = _compute_dtype(a)
    x, y = _array(a, cd), _array(b, cd)
    r = _matmul_into_torch(x, y)
    return r.to(a.dtype) if cd is not None else r


def _accumulate(r, self_, beta, alpha, name: str):
    """``beta * self + alpha * r`` as torch's addmm defines it: ``self`` of the products'
    dtype and broadcastable to their shape, its values unread when beta == 0, and the product
    unread when alpha == 0 (BLAS's convention: an Inf or NaN in the matrices does not reach the
    result then)."""
    import torch

    if self_.dtype != r.dtype:
        raise RuntimeError(f"{name}: self and mat2 must have the same dtype, but got "
                           f"{self_.dtype} and {r.dtype}")
    shape = self_.shape
    try:  # a bias row or a same-shape matrix (most calls) needs no general broadcast check
        if not (shape == r.shape or (len(shape) == 1 and shape[0] == r.shape[-1])):
            torch.broadcast_shapes(shape, r.shape)
    except RuntimeError:
        raise RuntimeError(f"{name}: the shape of self {tuple(self_.shape)} does not broadcast "
                           f"to the product's {tuple(r.shape)}") from None
    if alpha == 0:
        r = r.zero_()
    elif alpha != 1:
        r = r.mul_(alpha)
    if beta == 0:
        return r
    return r.add_(self_ if beta == 1 else self_ * beta)


def mm(self, mat2):
    """``aten::mm`` on the CPU (module docstring)."""
    return _product(self, mat2, "mm", False)


def bmm(self, mat2):
    """``aten::bmm`` on the CPU."""
    return _product(self, mat2, "bmm", True)


def addmm(self, mat1, mat2, *, beta=1, alpha=1):
    """``aten::addmm`` on the CPU: ``beta * self + alpha * (mat1 @ mat2)``."""
    return _accumulate(_product(mat1, mat2, "addmm", False), self, beta, alpha, "addmm")


def baddbmm(self, batch1, batch2, *, beta=1, alpha=1):
    """``aten::baddbmm`` on the CPU: ``beta * self + alpha * (batch1 @ batch2)``."""
    return _accumulate(_product(batch1, batch2, "baddbmm", True), self, beta, alpha,
                       "baddbmm")


_np = _TORCH = None  # numpy and torch, bound by install()
_BLAS_DTYPES: tuple = ()


def install() -> bool:
    """Replace torch's CPU kernels of :data:`OPS` with this module's (once per process);
    True when installed now or before."""
    global _LIB, _np, _TORCH, _BLAS_DTYPES
    with _LOCK:
        if _LIB is not None:
            return True
        import numpy
        import torch

        _np, _TORCH, _BLAS_DTYPES = numpy, torch, (torch.float32, torch.float64)

        lib = torch.library.Library("aten", "IMPL")
        with warnings.catch_warnings():  # "overriding a previously registered kernel"
            warnings.simplefilter("ignore")
            for name in OPS:
                lib.impl(name, globals()[name], "CPU")
        _LIB = lib
        return True


def uninstall() -> None:
    """Give torch its own kernels back (the throughput benchmark's "before" path, tests)."""
    global _LIB
    with _LOCK:
        if _LIB is not None:
            _LIB._destroy()
            _LIB = None


def installed() -> bool:
    """Whether :func:`install` is in force in this process."""
    return _LIB is not None


__all__ = ["NAME", "OPS", "addmm", "baddbmm", "bmm", "install", "installed", "mm", "uninstall"]
