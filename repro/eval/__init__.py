"""Evaluation classifiers (Action2Motion GRU, its UESTC variant, a transformer recogniser),
the real-data rows and their gate.  See docs/evaluators.md.

Public API (imported lazily, so ``import repro.eval`` stays light):

- :class:`Evaluator` (``.fingerprint``, ``.kind``, ``.describe()``, ``.features()``, ``.logits()``)
- :func:`get_evaluator` (dataset, kind, scale, seed) → Evaluator, trained once, then from the store
- :func:`test_accuracy` (evaluator, clipset) → TestAccuracy (top-1, top-5, confusion matrix)
- :func:`real_rows` (dataset, scale, replicates, seed) → dict; :func:`check_real_gate`
- :func:`resolve_settings` (scale) → EvaluatorSettings
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    "Evaluator": "repro.eval.evaluator",
    "get_evaluator": "repro.eval.provider",
    "evaluator_key": "repro.eval.provider",
    "evaluator_stats": "repro.eval.provider",
    "test_accuracy": "repro.eval.training",
    "train_evaluator": "repro.eval.training",
    "TestAccuracy": "repro.eval.training",
    "real_rows": "repro.eval.real",
    "check_real_gate": "repro.eval.gate",
    "gate_failures": "repro.eval.gate",
    "RealGateError": "repro.eval.gate",
    "resolve_settings": "repro.eval.settings",
    "EvaluatorSettings": "repro.eval.settings",
    "KINDS": "repro.eval.settings",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    mod = _EXPORTS.get(name)
    if mod is None:
        raise AttributeError(f"module 'repro.eval' has no attribute {name!r}")
    return getattr(importlib.import_module(mod), name)
