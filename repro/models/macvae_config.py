"""MACVAE's configuration (MultiAct, Lee, Moon & Lee, AAAI 2023), torch-free so that a table's plan
reads it without importing the network (issue 31); the method and the sources of its defaults:
:mod:`repro.models.macvae`."""

from __future__ import annotations

from typing import Literal

from pydantic import model_validator

from repro.models.base import GeneratorConfig, MethodCard, register_card


class MACVAEConfig(GeneratorConfig):
    """MACVAE hyper-parameters and ablation switches.  Defaults: the released code where it and
    the paper disagree (the paper's reading is the other value of the field; docs/multiact.md,
    "Paper and released code"), the paper where the code agrees or is silent."""

    # network (supp. "Implementation details"; protocols.md §4.2 for ff/dropout/activation)
    d_model: int = 512                 # "512 inner dimensions"; also the latent size d
    layers: int = 8                    # encoder and decoder layers each
    heads: int = 4
    ff_size: int = 2048                # reference config
    dropout: float = 0.1               # PyTorch Transformer default (reference uses it)
    activation: Literal["relu", "gelu"] = "gelu"
    # optimisation (supp. "Implementation details")
    optimizer: Literal["adamw", "adam"] = "adamw"
    lr: float = 5e-5
    weight_decay: float = 0.01         # torch.optim.AdamW's default; the paper states none
    batch_size: int = 16
    epochs: int = 1200                 # released envs/train.yaml end_epoch; the paper says 1,300
    lambda_acc: float = 1.0
    lambda_kl: float = 1e-5
    # ablations
    prevnet_frames: int | Literal["all"] = 4      # Table 1 "whole S_p", Table A (2..6)
    max_prev_frames: int = 120         # "all": S_p width PrevNet reads (our choice: MultiAct's
    #                                    120-frame max input length); longer S_p keep their end
    separate_latent: bool = True       # Table 1 "w/o separate latent"
    prevnet_action_label: bool = False  # Table 1 "a_c to PrevNet" (one-hot appended)
    # paper <-> released code (default = code; docs/multiact.md "Paper and released code")
    posterior_pooling: Literal["per_part", "global"] = "per_part"   # code: z_p over T, z_c over S_c; paper: one mean
    decoder_causal: bool = True        # code: subsequent_mask + causal conv; paper: unmasked
    transition_pos_enc: bool = True    # code: LayeredPositionalEncoding; paper: plain sinusoid
    temporal_kernel: int = 5           # code: Conv2d (5, d); paper silent
    acc_loss: Literal["squared_output", "l1_target"] = "squared_output"   # code: AccelLoss
    encoder_embedding: Literal["joint", "split"] = "joint"   # code: Linear(cat(p, E_d(a))); paper: d/2 + d/2
    posterior_head: Literal["per_frame", "pooled"] = "per_frame"   # code: conv-BN-ReLU-FC per frame; paper: 4 FC after the mean
    decoder_head: Literal["conv", "conv_linear"] = "conv"    # code: one conv d -> P; paper: conv + Linear
    pos_encoding: Literal["transposed", "standard"] = "transposed"   # code: PositionalEncoding's swapped axes
    loss_frames: Literal["whole", "generated"] = "whole"     # code: losses on the postprocessed [S_p, T, S_c]; paper: l_t + l_c frames
    canonicalization: Literal["face_front", "zero", "none"] = "face_front"   # Table 1
    backbone: Literal["transformer", "lstm", "gru", "mlp"] = "transformer"   # Table B
    postprocessor: bool = True         # Table B's postprocessor ablation
    # inference-only (the protocol's choice of previous motions; the model ignores it)
    prev_motion_source: Literal["test", "train", "actor"] = "test"
    sample_batch_size: int = 256

    @model_validator(mode="after")
    def _check(self):
        if self.d_model % 2:
            raise ValueError("d_model must be even (pose and action embeddings of d/2 each)")
        if self.backbone == "transformer" and self.d_model % self.heads:
            raise ValueError(f"d_model {self.d_model} is not divisible by heads {self.heads}")
        for f in ("layers", "heads", "ff_size", "batch_size", "epochs", "sample_batch_size",
                  "max_prev_frames", "temporal_kernel"):
            if getattr(self, f) < 1:
                raise ValueError(f"{f} must be >= 1")
        if self.prevnet_frames != "all" and (isinstance(self.prevnet_frames, bool)
                                             or self.prevnet_frames < 1):
            raise ValueError("prevnet_frames must be >= 1 or 'all'")
        if self.temporal_kernel % 2 == 0:
            raise ValueError("temporal_kernel must be odd (the encoder's convolution is centred)")
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError("dropout must lie in [0, 1)")
        if self.lr <= 0 or self.weight_decay < 0 or self.lambda_acc < 0 or self.lambda_kl < 0:
            raise ValueError("lr must be > 0; weight_decay and loss weights >= 0")
        return self


#: ``prev_motion_source`` changes what a protocol feeds, not what is trained
MACVAE = register_card(MethodCard("macvae", MACVAEConfig,
                                  inference_fields=("prev_motion_source",)))
