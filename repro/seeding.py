"""Explicit seeds everywhere: helpers that turn one integer into independent generators.

Same seed, same machine, same bytes: every random choice in ``repro`` takes a generator built
here (never the global RNG state), and sub-seeds are derived by hashing, so adding a consumer
never shifts another's stream.
"""

from __future__ import annotations

import hashlib

import numpy as np


def derive_seed(seed: int, *labels: object) -> int:
    """A 63-bit seed derived from ``seed`` and any labels (stable across runs and machines)."""
    h = hashlib.sha256(repr((int(seed),) + tuple(str(x) for x in labels)).encode()).digest()
    return int.from_bytes(h[:8], "little") & ((1 << 63) - 1)


def numpy_rng(seed: int, *labels: object) -> np.random.Generator:
    return np.random.default_rng(derive_seed(seed, *labels))


def torch_generator(seed: int, *labels: object):
    import torch

    g = torch.Generator()
    g.manual_seed(derive_seed(seed, *labels))
    return g


# ---------------------------------------------------------------------------------------------
# devices: the settings a job computes under, set in one place (prepare_device)

#: What a CUDA job computes under, set by :func:`prepare_device` before it computes and part of
#: its key (:func:`device_key`): cuDNN picks deterministic kernels and never benchmarks for
#: the fastest (the pick may differ run to run), torch's deterministic algorithms are on (an op
#: without a deterministic CUDA kernel warns rather than fails: ``warn_only``), cuBLAS gets the
#: fixed workspace its deterministic mode needs, and TF32 is off (full float32 matmuls, as on
#: the CPU).  Numbers on CUDA are still not bitwise the CPU's: kernels reduce in another order
#: and dropout/noise inside the model come from the CUDA generator's stream.
CUDA_DETERMINISM = {
    "cudnn_deterministic": True,
    "cudnn_benchmark": False,
    "deterministic_algorithms": True,
    "deterministic_warn_only": True,
    "cublas_workspace_config": ":4096:8",
    "tf32": False,
}


def device_type(device: object) -> str:
    """``"cpu"`` for None / ``"cpu"``, else the device's type (``"cuda:1"`` → ``"cuda"``)."""
    if device is None:
        return "cpu"
    return str(device).partition(":")[0]


def device_key(device: object) -> dict | None:
    """The key material of computing on ``device``: None on the CPU (a CPU job's key is what it
    was before jobs named a device), else the device type with :data:`CUDA_DETERMINISM`.  The
    card's index is placement, not content, and stays out."""
    kind = device_type(device)
    if kind == "cpu":
        return None
    return {"type": kind, **(CUDA_DETERMINISM if kind == "cuda" else {})}


def prepare_device(device: object):
    """The ``torch.device`` a job computes on, with :data:`CUDA_DETERMINISM` applied first when
    it is a CUDA device (process-wide settings: every CUDA job of a worker runs under the same
    ones).  The CPU changes nothing.  A CUDA device on a machine without one is a ConfigError."""
    import torch

    dev = torch.device("cpu" if device is None else str(device))
    if dev.type != "cuda":
        return dev
    if not torch.cuda.is_available():
        from repro.errors import ConfigError

        raise ConfigError(f"device {str(dev)!r}: torch.cuda.is_available() is false on this "
                          "machine; run with --device cpu")
    import os

    s = CUDA_DETERMINISM
    os.environ["CUBLAS_WORKSPACE_CONFIG"] = s["cublas_workspace_config"]
    torch.backends.cudnn.deterministic = s["cudnn_deterministic"]
    torch.backends.cudnn.benchmark = s["cudnn_benchmark"]
    torch.use_deterministic_algorithms(s["deterministic_algorithms"],
                                       warn_only=s["deterministic_warn_only"])
    torch.backends.cuda.matmul.allow_tf32 = s["tf32"]
    torch.backends.cudnn.allow_tf32 = s["tf32"]
    return dev
