"""Act-MoCoGAN's configuration (MoCoGAN, Tulyakov et al., CVPR 2018, on joint positions),
torch-free so that a table's plan reads it without importing the network (issue 31); the method
and the sources of its defaults: :mod:`repro.models.act_mocogan`."""

from __future__ import annotations

from pydantic import model_validator

from repro.models.base import GeneratorConfig, MethodCard, register_card


class ActMoCoGANConfig(GeneratorConfig):
    """Act-MoCoGAN hyper-parameters: MoCoGAN's defaults where it has them
    (:mod:`repro.models.act_mocogan`)."""

    dim_z_content: int = 50            # MoCoGAN train.py default
    dim_z_motion: int = 10             # MoCoGAN train.py default (GRU cell input = hidden)
    g_hidden: int = 512                # pose generator MLP width (choice)
    g_layers: int = 2                  # pose generator hidden layers (choice)
    di_hidden: int = 256               # A2M PoseDiscriminator hidden width (choice)
    di_root_relative: bool = True      # D_I sees the pose minus its own root (A2M)
    di_class: bool = False             # D_I also sees the one-hot (MoCoGAN / A2M: no)
    dv_hidden: int = 128               # D_V GRU width (choice)
    dv_layers: int = 2                 # D_V GRU layers (choice)
    dv_head: int = 30                  # A2M's Linear(h, 30) → tanh
    use_categories: bool = True        # D_V's class head learns the real categories (CE)
    use_infogan: bool = True           # G makes fakes D_V classifies as their category (CE)
    lr: float = 2e-4                   # MoCoGAN, all three networks
    beta1: float = 0.5
    beta2: float = 0.999
    weight_decay: float = 1e-5
    batch_size: int = 512              # ODMO reference loader
    windows_per_epoch: int = 2048      # ODMO reference loader
    epochs: int = 25000                # 100,000 MoCoGAN iterations / 4 batches per epoch
    val_windows: int = 512             # fixed validation draw (when val_items are given)
    sample_batch_size: int = 512

    @model_validator(mode="after")
    def _check(self):
        for f in ("dim_z_content", "dim_z_motion", "g_hidden", "di_hidden", "dv_hidden",
                  "dv_layers", "dv_head", "batch_size", "windows_per_epoch", "epochs",
                  "val_windows", "sample_batch_size"):
            if getattr(self, f) < 1:
                raise ValueError(f"{f} must be >= 1")
        if self.g_layers < 0:
            raise ValueError("g_layers must be >= 0")
        if not self.lr > 0 or self.weight_decay < 0:
            raise ValueError("lr must be > 0 and weight_decay >= 0")
        if not (0.0 <= self.beta1 < 1.0 and 0.0 <= self.beta2 < 1.0):
            raise ValueError("Adam betas must lie in [0, 1)")
        return self


ACT_MOCOGAN = register_card(MethodCard("act_mocogan", ActMoCoGANConfig))
