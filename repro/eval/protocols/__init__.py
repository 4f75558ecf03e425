"""Evaluation protocols and their registry (see :mod:`repro.eval.protocols.base`).

- :func:`get_protocol` ``(protocol_id, params) -> Protocol``: the protocol with validated
  parameters; an unknown id is a ConfigError with a did-you-mean hint, and an id that the
  table specs name (``repro.specs.names.PROTOCOLS``) but that nobody has built yet is a
  ConfigError saying it is not implemented;
- :func:`is_implemented` ``(protocol_id) -> bool``;
- :func:`protocol_class` ``(protocol_id)``: the class, for its ``metrics`` / ``Params``.

Protocol modules are imported lazily, so ``repro --help`` stays fast.
"""

from __future__ import annotations

import difflib
import importlib
from typing import Any, Mapping

from repro.errors import ConfigError
from repro.registries import add_to_registry

#: protocol id -> the module that defines (and registers) it.  Add a line per new protocol.
PROTOCOL_MODULES: dict[str, str] = {
    "single_action": "repro.eval.protocols.single_action",
    "multi_action": "repro.eval.protocols.multi_action",
    "ss_ar": "repro.eval.protocols.ss_ar",
    "multiact_conditioned": "repro.eval.protocols.multiact_conditioned",
    "transition": "repro.eval.protocols.transition",
    "long_term": "repro.eval.protocols.long_term",
    "odmo_generation": "repro.eval.protocols.odmo_generation",
    "latent_modes": "repro.eval.protocols.latent_modes",
    "trajectory_customisation": "repro.eval.protocols.trajectory_customisation",
}
_REGISTRY: dict[str, type] = {}


def register(cls):
    """Class decorator: make a Protocol subclass findable by :func:`get_protocol`."""
    return add_to_registry(_REGISTRY, cls, "id", "protocol id")


def _spec_protocols() -> tuple[str, ...]:
    from repro.specs.names import PROTOCOLS

    return tuple(PROTOCOLS)


def is_implemented(protocol_id: str) -> bool:
    """True when a module implements ``protocol_id``."""
    return protocol_id in _REGISTRY or protocol_id in PROTOCOL_MODULES


def protocol_class(protocol_id: str):
    """The Protocol subclass registered under ``protocol_id`` (ConfigError otherwise)."""
    if protocol_id not in _REGISTRY and protocol_id in PROTOCOL_MODULES:
        importlib.import_module(PROTOCOL_MODULES[protocol_id])
    cls = _REGISTRY.get(protocol_id)
    if cls is not None:
        return cls
    if protocol_id in _spec_protocols():
        raise ConfigError(f"protocol {protocol_id!r} is not implemented yet (implemented: "
                          f"{', '.join(sorted(set(PROTOCOL_MODULES) | set(_REGISTRY)))})")
    known = sorted(set(_spec_protocols()) | set(PROTOCOL_MODULES) | set(_REGISTRY))
    near = difflib.get_close_matches(str(protocol_id), known, n=1)
    hint = f"; did you mean {near[0]!r}?" if near else f"; known: {', '.join(known)}"
    raise ConfigError(f"unknown protocol {protocol_id!r}{hint}")


def get_protocol(protocol_id: str, params: Mapping[str, Any] | None = None):
    """The protocol ``protocol_id`` with ``params`` validated by its ``Params`` model."""
    return protocol_class(protocol_id)(params)


__all__ = ["PROTOCOL_MODULES", "get_protocol", "is_implemented", "protocol_class", "register"]
