"""Action2Motion's configuration (Guo et al., ACM MM 2020, as Neural Marionette adapted it, supp.
Sec. 4.1), torch-free so that a table's plan reads it without importing the network (issue 31);
the method and the sources of its defaults: :mod:`repro.models.a2m`."""

from __future__ import annotations

from typing import Literal

from pydantic import model_validator

from repro.models.base import GeneratorConfig, MethodCard, register_card


class A2MConfig(GeneratorConfig):
    """Action2Motion hyper-parameters; defaults = the authors' HumanAct12 settings, with Neural
    Marionette's two adaptations (6D rotations, the initial pose) switched on."""

    representation: Literal["6d", "lie", "xyz"] = "6d"  # NM: 6D (A2M: Lie algebra or xyz)
    initial_pose: bool = True                     # NM: x_0 = last initial pose (A2M: rest pose)
    dim_z: int = 30
    hidden: int = 128
    prior_layers: int = 1
    posterior_layers: int = 1
    decoder_layers: int = 2
    time_counter: bool = True
    lambda_kld: float = 1e-3
    lambda_param: float = 0.0          # extra MSE on the pose parameters (0: A2M's joint loss)
    self_feed_ratio: float = 0.6       # authors' --tf_ratio (see module docstring)
    batch_size: int = 128
    epochs: int = 1000                 # ≈ A2M's 50,000 iterations of 128 on BABEL-MAG's size
    lr: float = 2e-4
    weight_decay: float = 1e-5
    sample_batch_size: int = 256

    @model_validator(mode="after")
    def _check(self):
        for f in ("dim_z", "hidden", "prior_layers", "posterior_layers", "decoder_layers",
                  "batch_size", "epochs", "sample_batch_size"):
            if getattr(self, f) < 1:
                raise ValueError(f"{f} must be >= 1")
        if not 0.0 <= self.self_feed_ratio <= 1.0:
            raise ValueError("self_feed_ratio must lie in [0, 1]")
        if self.lambda_kld < 0 or self.lambda_param < 0 or self.lr <= 0:
            raise ValueError("loss weights must be >= 0 and lr > 0")
        return self

A2M = register_card(MethodCard("a2m", A2MConfig))
