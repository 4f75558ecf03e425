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
