"""ODMO's configuration (Lu et al., ACM MM'22, §3), torch-free so that a table's plan reads it
without importing the network (issue 31); the method and the sources of its defaults:
:mod:`repro.models.odmo`."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from repro.models.base import GeneratorConfig, MethodCard, register_card


class ODMOConfig(GeneratorConfig):
    """ODMO hyper-parameters.  Defaults: the released code's reading wherever the paper and the
    code disagree (the paper's reading is the field's other value), the paper's values where
    they agree (module docstring, docs/odmo.md)."""

    latent_dim: int = Field(20, ge=1)
    enc_hidden: int = Field(64, ge=1)      # Table S2
    enc_feature: int = Field(256, ge=1)    # feature-layer width (Table S2 silent; the code 256)
    embed: int | None = Field(None, ge=1)  # embedding widths; None = hidden (the code)
    hidden: int = Field(128, ge=1)         # Table S2
    encoder_head: Literal["code", "compact"] = "code"   # compact: 1 FC + 2 heads (harness)
    trajectory_input: Literal["code", "repeat"] = "code"  # repeat: one input, repeated (harness)
    window: int | None = Field(None, ge=2)  # T the network is built for; None: the items' (fit)
    decoder_time: bool = True              # the code's (t+1)/T decoder input; §3.2(iii): False
    contrastive: bool = True
    contrastive_form: Literal["code", "paper"] = "code"
    margin: float = Field(5.0, ge=0)
    kl_form: Literal["code", "paper"] = "code"
    sigma2: float = Field(0.05, gt=0)
    sigma_reading: Literal["std", "variance"] = "std"
    traj_loss: bool = True
    traj_target: Literal["position", "velocity"] = "position"  # the code; Eq. 2: "velocity"
    cons_loss: bool = True
    use_end: bool = True
    y_weight: float | None = Field(None, gt=0)  # None: the items' (5 HumanAct12/UESTC, 1 MoCap)
    reduction: Literal["code", "sum", "mean"] = "code"  # paper's Σ: "sum"; "mean": harness
    classic_mu_prior: bool = False         # −L_es: True = the paper's "classic VAE" μᵀμ (supp. §3.1)
    lambda_mre: float = Field(1.0, ge=0)
    lambda_r: float = Field(1.0, ge=0)
    lambda_cons: float = Field(1.0, ge=0)
    lambda_es: float = Field(1.0, ge=0)    # the contrastive terms
    lambda_kl: float = Field(1.0, ge=0)
    tf_start: float = Field(1.0, ge=0, le=1)
    tf_end: float = Field(0.3, ge=0, le=1)
    tf_decay_epochs: int = Field(4000, ge=0)
    lr: float = Field(1e-3, gt=0)
    grad_clip: float = Field(1.0, gt=0)
    batch_size: int = Field(512, ge=1)     # pairs
    windows_per_epoch: int = Field(2048, ge=1)
    epochs: int = Field(100_000, ge=0)
    val_pairs: int = Field(512, ge=1)
    sample_batch_size: int = Field(1024, ge=1)
    # inference only (ODMO.inference_fields)
    sampling: Literal["mode_preserving", "conventional"] = "mode_preserving"
    k_rule: Literal["code", "paper", "discovery"] = "code"
    conventional_form: Literal["code", "paper"] = "code"
    bank_iters: int = Field(15, ge=1)      # HumanAct12's num_itr (MoCap 5, UESTC 8)


ODMO = register_card(MethodCard("odmo", ODMOConfig, inference_fields=(
    "sampling", "k_rule", "conventional_form", "bank_iters")))
