"""Names a package loads from its submodules on first use (PEP 562), so that importing one
submodule does not pull in the others."""

from __future__ import annotations

import importlib


def lazy_getattr(package: str, exports: dict[str, str]):
    """The module ``__getattr__`` of ``package``: ``exports`` maps each name to the submodule
    (relative to ``package``) that defines it; any other name is an AttributeError."""

    def __getattr__(name: str):
        if name in exports:
            return getattr(importlib.import_module(f"{package}.{exports[name]}"), name)
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    return __getattr__
