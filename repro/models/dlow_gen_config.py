"""DLow-Gen's configuration (DLow, Yuan & Kitani, ECCV 2020), torch-free so that a table's plan
reads it without importing the network (issue 31); the method and the sources of its defaults:
:mod:`repro.models.dlow_gen`."""

from __future__ import annotations

from pydantic import model_validator

from repro.models.base import GeneratorConfig, MethodCard, register_card


class DLowGenConfig(GeneratorConfig):
    """DLow-Gen hyper-parameters; defaults = DLow's Human3.6M config (``h36m_nsamp10.yml``)
    with ODMO's epochs (:mod:`repro.models.dlow_gen`)."""

    nz: int = 128                               # latent size
    nh_rnn: int = 128                           # GRU / history feature size
    nh_mlp: tuple[int, ...] = (300, 200)        # VAE MLPs (DLow's default)
    dlow_nh_mlp: tuple[int, ...] = (1024, 512)  # DLow network MLP (dlow_specs.nh_mlp)
    nk: int = 10                                # K flows (h36m_nsamp10)
    beta: float = 0.1                           # VAE KL weight
    lambda_kl: float = 1.0                      # DLow KL weight (config default)
    lambda_j: float = 25.0                      # diversity weight
    d_scale: float = 100.0                      # diversity kernel scale (units²)
    lambda_recon: float = 2.0                   # min-of-K reconstruction weight
    vae_lr: float = 1e-3
    dlow_lr: float = 1e-4
    batch_size: int = 64                        # DLow's batch_size and dlow_batch_size
    windows_per_epoch: int = 2048               # ODMO's epoch (DLow: 5,000)
    vae_epochs: int = 5000                      # ODMO supp. §2.4 (DLow: 500)
    dlow_epochs: int = 600                      # ODMO supp. §2.4 (DLow: 500)
    vae_epochs_fix: int = 100                   # constant-lr epochs, then linear decay
    dlow_epochs_fix: int = 100
    val_windows: int = 512                      # fixed validation draw (when val_items)
    sample_batch_size: int = 512

    @model_validator(mode="after")
    def _check(self):
        for f in ("nz", "nh_rnn", "nk", "batch_size", "windows_per_epoch", "vae_epochs",
                  "dlow_epochs", "val_windows", "sample_batch_size"):
            if getattr(self, f) < 1:
                raise ValueError(f"{f} must be >= 1")
        if self.nk < 2:
            raise ValueError("nk must be >= 2 (DLow's diversity needs pairs)")
        for f in ("nh_mlp", "dlow_nh_mlp"):
            if not getattr(self, f) or min(getattr(self, f)) < 1:
                raise ValueError(f"{f} must be a non-empty list of sizes >= 1")
        for f in ("beta", "lambda_kl", "lambda_j", "lambda_recon", "vae_epochs_fix",
                  "dlow_epochs_fix"):
            if getattr(self, f) < 0:
                raise ValueError(f"{f} must be >= 0")
        if self.d_scale <= 0 or self.vae_lr <= 0 or self.dlow_lr <= 0:
            raise ValueError("d_scale and learning rates must be > 0")
        return self


DLOW_GEN = register_card(MethodCard("dlow_gen", DLowGenConfig))
