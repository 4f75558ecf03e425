"""ACTOR's configuration (Petrovich et al., ICCV 2021), torch-free so that a table's plan reads it
without importing the network (issue 31); the method and the sources of its defaults:
:mod:`repro.models.actor`."""

from __future__ import annotations

from typing import Literal

from pydantic import model_validator

from repro.models.base import GeneratorConfig, MethodCard, register_card


class ACTORConfig(GeneratorConfig):
    """ACTOR hyper-parameters; defaults = the authors' commands (UESTC-length schedule)."""

    latent_dim: int = 256
    ff_size: int = 1024
    num_layers: int = 8
    num_heads: int = 4
    dropout: float = 0.1
    activation: Literal["relu", "gelu"] = "gelu"
    lambda_rc: float = 1.0
    lambda_rcxyz: float = 1.0
    lambda_kl: float = 1e-5
    batch_size: int = 20
    epochs: int = 1000                 # UESTC's (HumanAct12: 5,000; NTU13: 2,000)
    lr: float = 1e-4
    weight_decay: float = 0.01         # torch.optim.AdamW's default, as the authors use it
    sample_batch_size: int = 256

    @model_validator(mode="after")
    def _check(self):
        if self.latent_dim % self.num_heads:
            raise ValueError(f"latent_dim {self.latent_dim} is not divisible by num_heads "
                             f"{self.num_heads}")
        if self.latent_dim % 2:
            raise ValueError("latent_dim must be even (sinusoidal positions)")
        for f in ("ff_size", "num_layers", "num_heads", "batch_size", "epochs",
                  "sample_batch_size"):
            if getattr(self, f) < 1:
                raise ValueError(f"{f} must be >= 1")
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError("dropout must lie in [0, 1)")
        return self


ACTOR = register_card(MethodCard("actor", ACTORConfig))
