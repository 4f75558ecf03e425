"""SSMCT's configuration (Duan et al. 2021, arXiv 2103.00776), torch-free so that a table's plan
reads it without importing the network (issue 31); the method and the sources of its defaults:
:mod:`repro.models.ssmct`."""

from __future__ import annotations

from typing import Literal

from pydantic import model_validator

from repro.models.base import GeneratorConfig, MethodCard, register_card


class SSMCTConfig(GeneratorConfig):
    """SSMCT hyper-parameters (module docstring says where each default comes from)."""

    d_model: int = 256
    layers: int = 8
    heads: int = 8
    ff_size: int = 512
    dropout: float = 0.1
    activation: Literal["relu", "gelu"] = "gelu"
    kernel_size: int = 3
    context_frames: int = 10
    target_frames: int = 2
    max_window: int = 160          # learned positions: context + l_t + target must fit
    lambda_pose: float = 1.0
    lambda_pos: float = 1.0
    batch_size: int = 128
    epochs: int = 1200
    lr: float = 1e-4
    weight_decay: float = 1e-5
    sample_batch_size: int = 256

    @model_validator(mode="after")
    def _check(self):
        if self.d_model % self.heads:
            raise ValueError(f"d_model {self.d_model} is not divisible by heads {self.heads}")
        for f in ("d_model", "layers", "heads", "ff_size", "context_frames", "target_frames",
                  "batch_size", "epochs", "sample_batch_size"):
            if getattr(self, f) < 1:
                raise ValueError(f"{f} must be >= 1")
        if self.kernel_size < 1 or self.kernel_size % 2 == 0:
            raise ValueError("kernel_size must be odd and >= 1")
        if self.max_window < self.context_frames + self.target_frames + 1:
            raise ValueError("max_window must hold the context, one missing frame and the "
                             "target frames")
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError("dropout must lie in [0, 1)")
        if self.lambda_pose < 0 or self.lambda_pos < 0:
            raise ValueError("loss weights must be >= 0")
        return self


SSMCT = register_card(MethodCard("ssmct", SSMCTConfig))
