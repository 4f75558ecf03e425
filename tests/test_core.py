"""Core conventions: content keys, error messages, Skeleton and FK basics, CLI exit codes."""

import subprocess
import sys
import time

import numpy as np
import pytest
import torch

from repro.errors import DataError
from repro.keys import canonical_json, content_key
from repro.motion import Skeleton, forward_kinematics


def test_content_key_is_order_invariant_and_type_stable():
    a = {"b": [1, 2.5, "x"], "a": {"y": 1, "x": (2, 3)}}
    b = {"a": {"x": [2, 3], "y": 1}, "b": [1, 2.5, "x"]}
    assert content_key(a) == content_key(b)
    assert content_key(a) != content_key({**a, "b": [1, 2.5000001, "x"]})
    assert canonical_json(np.float32(0.5)) == b"0.5"
    with pytest.raises(ValueError):
        canonical_json(float("nan"))


def test_data_error_names_file_and_line():
    e = DataError("truncated MOTION block", file="x.bvh", line=12)
    assert str(e) == "x.bvh:12: truncated MOTION block"


def test_fk_chain_and_gradient():
    sk = Skeleton(("a", "b", "c"), (-1, 0, 1), np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0.0]]))
    rz = torch.tensor([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])  # +90 deg about z
    R = torch.eye(3).repeat(3, 1, 1)
    R[0] = rz
    R.requires_grad_(True)
    p = forward_kinematics(sk, R, torch.tensor([0.0, 0, 5]))
    assert torch.allclose(p, torch.tensor([[0.0, 0, 5], [0, 1, 5], [-1, 1, 5]]), atol=1e-6)
    p.sum().backward()
    assert R.grad is not None and torch.isfinite(R.grad).all()


def test_skeleton_rejects_bad_topology():
    with pytest.raises(ValueError):
        Skeleton(("a", "b"), (-1, 2), np.zeros((2, 3)))


def test_cli_help_is_fast_and_unknown_command_fails():
    t = time.perf_counter()
    out = subprocess.run([sys.executable, "-m", "cli.main", "--help"], capture_output=True, text=True)
    dt = time.perf_counter() - t
    assert out.returncode == 0 and "repro" in out.stdout
    assert dt < 2.0  # generous under a loaded CI machine; the lazy-import check is below
    out = subprocess.run([sys.executable, "-c", "import cli.main, sys; cli.main.build_parser(); "
                          "print('torch' in sys.modules)"], capture_output=True, text=True)
    assert out.stdout.strip() == "False", "repro --help must not import torch"
