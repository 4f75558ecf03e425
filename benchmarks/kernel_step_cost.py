"""Training-step cost of the layer families the harness trains, in this process's kernel mode
(issue 25's cost measurement; run by ``bench_kernel_paths.py --steps``, pinned and unpinned).

Prints ``{family: ms per step}`` for forward + backward + a fused Adam step at quick-like sizes
(batch 64, 60 frames, one thread): a transformer encoder (MarioNet, ACTOR, MACVAE, SSMCT, the
recogniser), a 2×128 and a 4×256 GRU (the recognisers, A2M), a 2×128 LSTM (ODMO), Conv1d
stacks (MACVAE, SSMCT) and an MLP (MANN).
"""

from __future__ import annotations

import json
import time

import repro  # noqa: F401  (pins the kernel paths unless REPRO_FAST_KERNELS=1)


def main() -> None:
    import torch

    from repro import kernels

    kernels.check()
    torch.set_num_threads(1)
    torch.manual_seed(0)
    B, T, D = 64, 60, 128
    x = torch.randn(B, T, D)
    nets = {
        "transformer_2x128": torch.nn.TransformerEncoder(
            torch.nn.TransformerEncoderLayer(D, 4, 256, batch_first=True), 2),
        "gru_2x128": torch.nn.GRU(D, 128, 2, batch_first=True),
        "gru_4x256": torch.nn.GRU(D, 256, 4, batch_first=True),
        "lstm_2x128": torch.nn.LSTM(D, 128, 2, batch_first=True),
        "conv1d_k5_x3": torch.nn.Sequential(*[torch.nn.Conv1d(D, D, 5, padding=2)
                                              for _ in range(3)]),
        "mlp_3x512": torch.nn.Sequential(torch.nn.Linear(D, 512), torch.nn.ELU(),
                                         torch.nn.Linear(512, 512), torch.nn.ELU(),
                                         torch.nn.Linear(512, D)),
    }
    out = {}
    for name, net in nets.items():
        opt = kernels.adam(net.parameters(), lr=1e-3)
        inp = x.transpose(1, 2) if name.startswith("conv") else x

        def step():
            opt.zero_grad()
            y = net(inp)
            y = y[0] if isinstance(y, tuple) else y
            y.pow(2).mean().backward()
            opt.step()

        step()
        n, t0 = 0, time.perf_counter()
        while n < 3 or time.perf_counter() - t0 < 3.0:
            step()
            n += 1
        out[name] = round((time.perf_counter() - t0) / n * 1e3, 2)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
