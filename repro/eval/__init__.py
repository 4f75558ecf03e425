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

from repro.lazy_exports import lazy_getattr

_EXPORTS = {
    "Evaluator": "evaluator",
    "get_evaluator": "provider",
    "evaluator_key": "provider",
    "evaluator_stats": "provider",
    "test_accuracy": "training",
    "train_evaluator": "training",
    "TestAccuracy": "training",
    "real_rows": "real",
    "check_real_gate": "gate",
    "gate_failures": "gate",
    "RealGateError": "gate",
    "resolve_settings": "settings",
    "EvaluatorSettings": "settings",
    "KINDS": "settings",
}

__all__ = sorted(_EXPORTS)
__getattr__ = lazy_getattr(__name__, _EXPORTS)
