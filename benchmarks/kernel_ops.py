"""The op battery of the kernel-pinning evidence (issue 25; docs/engine.md, "Kernel pinning").

Runs, in this process, every kind of float operation the harness's models, metrics and data
code rely on (torch elementwise maths, reductions, GEMM, convolution, LSTM / GRU forward and
backward, attention, the optimisers as :mod:`repro.kernels` builds them, numpy / scipy /
scikit-learn linear algebra, mixtures), hashes each result, and prints one JSON object
``{op: sha256 prefix}`` plus ``"_state"`` (the kernel paths in force, :func:`repro.kernels.state`).

Two processes that print the same hashes computed the same bytes.  ``bench_kernel_paths.py``
runs it under different ambient kernel settings and under an emulated Intel CPU
(``qemu-x86_64 -cpu Haswell``), pinned and unpinned; ``tests/test_kernels.py`` runs the fast part.

    python benchmarks/kernel_ops.py            # pinned (import repro first)
    REPRO_FAST_KERNELS=1 python benchmarks/kernel_ops.py   # the host's own paths
"""

from __future__ import annotations

import hashlib
import json

import repro  # noqa: F401  (pins the kernel paths before torch / numpy load)


def _h(x) -> str:
    import numpy as np
    import torch

    if isinstance(x, torch.Tensor):
        x = x.detach().contiguous().numpy()
    return hashlib.sha256(np.ascontiguousarray(x).tobytes()).hexdigest()[:16]


def battery() -> dict[str, str]:
    import numpy as np
    import roma
    import scipy.linalg
    import torch
    import torch.nn.functional as F
    from sklearn.mixture import GaussianMixture

    from repro import kernels

    state = kernels.check()
    torch.set_num_threads(1)
    g = torch.Generator().manual_seed(0)
    x = torch.randn(16, 60, 64, generator=g)
    out: dict[str, str] = {}
    ops = {
        "exp": torch.exp(x), "log": torch.log(x.abs() + 1), "tanh": torch.tanh(x),
        "sigmoid": torch.sigmoid(x), "sin": torch.sin(x), "erf": torch.erf(x),
        "gelu": F.gelu(x), "softmax": F.softmax(x, -1), "log_softmax": F.log_softmax(x, -1),
        "layer_norm": F.layer_norm(x, (64,)), "batch_norm": F.batch_norm(
            x.transpose(1, 2), None, None, training=True),
        "sum": x.sum(1), "mean": x.mean((0, 1)), "std": x.std(1), "norm": x.norm(dim=-1),
        "cumsum": x.cumsum(1), "rsqrt": (x.abs() + 0.1).rsqrt(),
        "sqrt_repro": kernels.sqrt(x.abs()), "sqrt_repro64": kernels.sqrt(x.abs().double()),
        "cos": torch.cos(x), "atan2": torch.atan2(x, x.flip(0)),
        "rotvec_to_rotmat": roma.rotvec_to_rotmat(x[0, :, :3].contiguous()),
        "special_gramschmidt": roma.special_gramschmidt(x[0, :, :6].reshape(-1, 3, 2)),
        "unitquat_to_rotvec": roma.unitquat_to_rotvec(roma.quat_normalize(x[0, :, :4])),
        "mm": x @ torch.randn(64, 96, generator=g),
        "bmm": torch.bmm(x, x.transpose(1, 2)),
        "sdpa": F.scaled_dot_product_attention(x[:4, None], x[4:8, None], x[8:12, None]),
        "sq_dist64": ((x[0].double()[:, None] - x[1].double()[None]) ** 2).sum(-1),
    }
    # torch ops the library does not use because their bits depend on the host (MKL's vector
    # maths): reported apart, so the evidence shows why they are avoided
    unused = {"torch_sqrt": torch.sqrt(x.abs()), "torch_sqrt64": torch.sqrt(x.abs().double()),
              "torch_acos": torch.acos(x.clamp(-1, 1)),
              "torch_cdist64": torch.cdist(x[0].double(), x[1].double())}
    for k, v in ops.items():
        out[k] = _h(v)
    out["_unused"] = {k: _h(v) for k, v in unused.items()}
    torch.manual_seed(0)
    lstm = torch.nn.LSTM(64, 64, 2, batch_first=True)
    gru = torch.nn.GRU(64, 64, 1, batch_first=True)
    conv = torch.nn.Conv1d(64, 64, 5, padding=2)
    y1, _ = lstm(x)
    y2, _ = gru(x)
    y3 = conv(x.transpose(1, 2))
    xb = torch.randn(128, 64, 60, generator=g)  # batch >= 16: NNPACK's case when it is on
    y4 = conv(xb)
    out.update(lstm=_h(y1), gru=_h(y2), conv=_h(y3), conv_b128=_h(y4))
    (y1.pow(2).mean() + y2.pow(2).mean() + y3.pow(2).mean() + y4.pow(2).mean()).backward()
    norm = torch.nn.utils.clip_grad_norm_(list(lstm.parameters()) + list(conv.parameters()), 0.01)
    out.update(lstm_grad=_h(lstm.weight_hh_l0.grad), gru_grad=_h(gru.weight_hh_l0.grad),
               conv_grad=_h(conv.weight.grad), clip_grad_norm=_h(norm))
    for name, make in (("adam", kernels.adam), ("adamw", kernels.adamw)):
        torch.manual_seed(0)
        lin = torch.nn.Linear(64, 32)
        opt = make(lin.parameters(), lr=1e-3)
        for _ in range(3):
            opt.zero_grad()
            lin(x).pow(2).mean().backward()
            opt.step()
        out[name] = _h(lin.weight)
    torch.manual_seed(5)
    out["dropout"] = _h(F.dropout(x, 0.3))
    # issue 31's layers: dropout from 64-bit integer draws, Conv1d as an unfolded product
    # (repro.gemm), a linear layer's addmm with its gradient
    from repro.models import layers

    torch.manual_seed(5)
    out["dropout_repro"] = _h(layers.dropout(x, 0.3))
    torch.manual_seed(0)
    rconv = layers.Conv1d(64, 64, 5, padding=2, padding_mode="replicate")
    xr = x.transpose(1, 2).clone().requires_grad_()
    y5 = rconv(xr)
    y5.pow(2).mean().backward()
    out.update(conv_repro=_h(y5), conv_repro_grad=_h(rconv.weight.grad),
               conv_repro_input_grad=_h(xr.grad))
    lin = torch.nn.Linear(64, 48)
    xl = x.clone().requires_grad_()
    y6 = lin(xl)
    y6.pow(2).mean().backward()
    out.update(linear=_h(y6), linear_grad=_h(lin.weight.grad), linear_input_grad=_h(xl.grad),
               baddbmm=_h(torch.baddbmm(x[:, :8, :8], x[:, :8], x.transpose(1, 2)[:, :, :8],
                                        beta=0.5, alpha=2.0)))
    out["randn"] = _h(torch.randn(1000, generator=torch.Generator().manual_seed(1)))
    a = np.random.default_rng(0).standard_normal((50, 20))
    out.update(np_exp=_h(np.exp(a)), np_log=_h(np.log(np.abs(a))), np_sin=_h(np.sin(a)),
               np_tanh32=_h(np.tanh(a.astype(np.float32))), np_sum32=_h(a.astype(np.float32).sum(0)),
               np_dot=_h(a @ a.T), np_svd=_h(np.linalg.svd(a, full_matrices=False)[1]),
               np_eigh=_h(np.linalg.eigh(a.T @ a)[0]),
               sqrtm=_h(scipy.linalg.sqrtm(a.T @ a + np.eye(20)).real),
               gmm=_h(GaussianMixture(3, random_state=0).fit(a).means_))
    out["_state"] = state
    return out


if __name__ == "__main__":
    print(json.dumps(battery(), sort_keys=True))
