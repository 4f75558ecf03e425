"""MarioNet's configuration (Neural Marionette, Wang et al., Sec. 4.2; supp. Table 2), torch-free
so that a table's plan reads it without importing the network (issue 31); the method and the
sources of its defaults: :mod:`repro.models.marionet`."""

from __future__ import annotations

from typing import Literal

from pydantic import model_validator

from repro.models.base import GeneratorConfig, MethodCard, register_card


class MarioNetConfig(GeneratorConfig):
    """MarioNet hyper-parameters; defaults = the paper (supp. Table 2 and Sec. 3)."""

    # widths (supp. Table 2); d_model is every block's width except the trajectory encoder's
    d_model: int = 256
    traj_dim: int = 32                 # d − d̃: trajectory share of a frame control (d̃ = 224)
    cond_heads: int = 8
    cond_ff: int = 1024
    cond_layers: int = 2
    cond_dropout: float = 0.1
    cond_activation: Literal["relu", "gelu"] = "gelu"
    traj_heads: int = 1
    traj_ff: int = 64
    traj_layers: int = 1
    traj_dropout: float = 0.001
    traj_activation: Literal["relu", "gelu"] = "relu"
    unroll_heads: int = 8
    unroll_ff: int = 1024
    unroll_layers: int = 2
    unroll_dropout: float = 0.01
    unroll_activation: Literal["relu", "gelu"] = "relu"
    dec_heads: int = 8
    dec_ff: int = 1024
    dec_layers: int = 6
    dec_dropout: float = 0.1
    dec_activation: Literal["relu", "gelu"] = "gelu"
    share_pose_encoder: bool = True    # one pose_encode FC for encoder and decoder (Fig. 3)
    traj_positional: bool = True       # sinusoidal positions added to the embedded trajectory
    standardize_poses: bool = True     # pose features z-scored with training statistics
    # losses (Eq. 1-2; weights from supp. Sec. 3)
    lambda_kl: float = 1e-8
    lambda_d: float = 0.5
    lambda_r: float = 1.0
    lambda_j: float = 2.0
    lambda_v: float = 2.0
    joint_loss: Literal["local", "global"] = "local"  # L_J on root-relative or world joints
    # training (supp. Sec. 3)
    batch_size: int = 30
    lr: float = 1e-4
    epochs: int = 1000
    grad_clip: float | None = None
    # scheduled sampling (supp. Sec. 3, Fig. 2)
    scheduled_sampling: bool = True
    ss_activate_epoch: int = 250
    ss_accomplish_epoch: int = 750
    ss_lambda1: float = 0.1
    ss_lambda2: float = 0.9
    ss_threshold_m: float = 0.1        # "close enough": first-pass mean per-joint error (m)
    ss_detach: bool = True             # first-pass predictions enter the mix without gradient
    # ablation switches (Table 2)
    time_unrolling: bool = True
    tag_injection: bool = True
    next_tag: bool = True
    # sampling
    sample_batch_size: int = 64
    kv_cache: bool = True
    # training computes the valid frames of a padded batch only (repro.models.layers.Packing;
    # issue 31): the same function, to rounding and dropout's draws; False: every padded frame
    packed_frames: bool = True

    @model_validator(mode="after")
    def _check(self):
        for block in ("cond", "unroll", "dec"):
            h = getattr(self, f"{block}_heads")
            if self.d_model % h:
                raise ValueError(f"d_model {self.d_model} is not divisible by {block}_heads {h}")
        if not 0 < self.traj_dim < self.d_model:
            raise ValueError("traj_dim must lie strictly between 0 and d_model")
        if self.traj_dim % self.traj_heads:
            raise ValueError(f"traj_dim {self.traj_dim} is not divisible by traj_heads")
        if self.ss_accomplish_epoch < self.ss_activate_epoch:
            raise ValueError("ss_accomplish_epoch must not precede ss_activate_epoch")
        for f in ("batch_size", "epochs", "sample_batch_size", "cond_layers", "dec_layers",
                  "traj_layers", "unroll_layers"):
            if getattr(self, f) < 1:
                raise ValueError(f"{f} must be >= 1")
        return self


MARIONET = register_card(MethodCard("marionet", MarioNetConfig))
