"""Class registries keyed by a class attribute (methods by ``method_id``, protocols by ``id``)."""

from __future__ import annotations


def add_to_registry(registry: dict, cls, attr: str, label: str):
    """Put ``cls`` into ``registry`` under its ``attr`` (a non-empty str, else TypeError); a key
    another class (by qualified name) already holds is a TypeError naming it as ``label``.
    Returns ``cls`` (the body of a class decorator)."""
    key = getattr(cls, attr, None)
    if not isinstance(key, str) or not key:
        raise TypeError(f"{cls.__name__} needs a non-empty str {attr}")
    other = registry.get(key)
    if other is not None and other.__qualname__ != cls.__qualname__:
        raise TypeError(f"{label} {key!r} is taken by {other.__qualname__}")
    registry[key] = cls
    return cls
