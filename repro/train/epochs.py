"""How many epochs a method config trains (:func:`config_epochs`).

Kept apart from :mod:`repro.engine.evidence` (which reads it for the training budgets) so that a
train job's source hash, which follows every import of :mod:`repro.engine.steps`, does not
cover how verdicts are worded: rewording a verdict must not retrain a model.
"""

from __future__ import annotations

#: methods trained in stages, each with its own epoch count (DLow-Gen: the VAE, then DLow)
STAGE_EPOCH_FIELDS = ("vae_epochs", "dlow_epochs")


def config_epochs(config: dict) -> int | None:
    """The epochs a method config trains: ``epochs``, or the sum of its stages' epochs
    (:data:`STAGE_EPOCH_FIELDS`); None for a method that does not train by epochs."""
    if config.get("epochs") is not None:
        return int(config["epochs"])
    stages = [config[k] for k in STAGE_EPOCH_FIELDS if isinstance(config.get(k), int)]
    return sum(stages) if stages else None


__all__ = ["STAGE_EPOCH_FIELDS", "config_epochs"]
