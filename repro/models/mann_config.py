"""MANN's configuration (Zhang et al., SIGGRAPH 2018), torch-free so that a table's plan reads it
without importing the network (issue 31); the method and the sources of its defaults:
:mod:`repro.models.mann`."""

from __future__ import annotations

from pydantic import model_validator

from repro.models.base import GeneratorConfig, MethodCard, register_card


class MANNConfig(GeneratorConfig):
    """MANN hyper-parameters; defaults = Zhang et al. 2018 and the authors' code."""

    n_experts: int = 8
    hidden: int = 512                  # motion prediction network width
    gating_hidden: int = 32            # gating network width
    dropout: float = 0.3               # keep probability 0.7
    # trajectory window (MANN/PFNN: 12 samples over 2 s around the frame)
    traj_past: int = 6
    traj_future: int = 6
    traj_step: int = 5                 # frames between samples (1/6 s at 30 fps)
    progress_input: bool = False       # add t/T to the input (not in MANN)
    # training (authors' code: AdamWR)
    batch_size: int = 32
    epochs: int = 150
    lr: float = 1e-4
    weight_decay: float = 2.5e-3
    restart_period: int = 10           # T_e, epochs
    restart_mult: int = 2              # T_mult
    sample_batch_size: int = 256

    @model_validator(mode="after")
    def _check(self):
        for f in ("n_experts", "hidden", "gating_hidden", "traj_step", "batch_size", "epochs",
                  "restart_period", "restart_mult", "sample_batch_size"):
            if getattr(self, f) < 1:
                raise ValueError(f"{f} must be >= 1")
        if self.traj_past < 0 or self.traj_future < 1:
            raise ValueError("traj_past must be >= 0 and traj_future >= 1 (the window holds t)")
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError("dropout must lie in [0, 1)")
        if self.lr <= 0 or self.weight_decay < 0:
            raise ValueError("lr must be > 0 and weight_decay >= 0")
        return self

    def offsets(self) -> list[int]:
        """Frame offsets of the trajectory samples around ``t``."""
        return [self.traj_step * k for k in range(-self.traj_past, self.traj_future)]


MANN = register_card(MethodCard("mann", MANNConfig))
