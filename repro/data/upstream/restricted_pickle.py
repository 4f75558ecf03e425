"""A restricted unpickler for the upstream files whose format is a pickle (HumanAct12, UESTC).

``pickle.load`` on a downloaded file runs whatever callables the file names.  The formats
``repro`` must read (ACTOR's ``humanact12poses.pkl``, ``vibe_cache_refined.pkl``; SMPL model
``.pkl`` files) only ever need numpy arrays, numpy scalars and dtypes inside Python containers,
so :class:`RestrictedUnpickler` resolves exactly those globals and refuses every other one with a
:class:`~repro.errors.DataError` naming the file and the refused global (``os.system``,
``builtins.eval``, ``subprocess.Popen``, ...).  Nothing is executed before the refusal: the
check happens when the pickle *names* a global, before it can be called.

Admitted globals (module, name), numpy 1.x and 2.x spellings alike:

- ``numpy.core.multiarray._reconstruct`` / ``numpy._core.multiarray._reconstruct``: array rebuild
  (pickle protocols 2-4); ``numpy.core.numeric._frombuffer`` / ``numpy._core.numeric._frombuffer``
  (protocol 5);
- ``numpy.ndarray``, ``numpy.dtype``, ``numpy.core.multiarray.scalar`` / ``numpy._core...scalar``;
- ``_codecs.encode`` (how protocol 2 spells ``bytes`` under Python 3: it only encodes a string);
- the builtin containers and scalars ``list, dict, tuple, set, frozenset, bytearray, bytes,
  str, int, float, complex, bool, slice, range``.

Callers may admit a few more *classes* by exact name (``extra``), e.g. the SMPL loader admits
``scipy.sparse`` matrix classes, which pickle rebuilds by ``__new__`` + ``__dict__`` update
without calling user code.
"""

from __future__ import annotations

import io
import pickle
from pathlib import Path
from typing import Any, Iterable

from repro.errors import DataError, MissingDataError

# numpy 1.x spelling -> numpy 2.x; Python 2 / protocol-2 spelling of the builtins module.
_NUMPY_ALIASES = {"numpy.core": "numpy._core", "__builtin__": "builtins"}

ALLOWED_GLOBALS: frozenset[tuple[str, str]] = frozenset(
    {
        ("numpy._core.multiarray", "_reconstruct"),
        ("numpy._core.multiarray", "scalar"),
        ("numpy._core.numeric", "_frombuffer"),
        ("numpy", "ndarray"),
        ("numpy", "dtype"),
        ("_codecs", "encode"),
    }
    | {("builtins", n) for n in ("list", "dict", "tuple", "set", "frozenset", "bytearray",
                                  "bytes", "str", "int", "float", "complex", "bool", "slice",
                                  "range")}
)


def _canonical_module(module: str) -> str:
    for old, new in _NUMPY_ALIASES.items():
        if module == old or module.startswith(old + "."):
            return new + module[len(old):]
    return module


class RestrictedUnpickler(pickle.Unpickler):
    """``pickle.Unpickler`` whose ``find_class`` admits only :data:`ALLOWED_GLOBALS` (+ extra)."""

    def __init__(self, file, *, source: str | Path = "<pickle>",
                 extra: Iterable[tuple[str, str]] = ()):
        # latin1 lets Python-2 pickles of numpy arrays load (their byte strings are str).
        super().__init__(file, encoding="latin1")
        self._source = str(source)
        self._extra = frozenset((_canonical_module(m), n) for m, n in extra)

    def find_class(self, module: str, name: str) -> Any:
        key = (_canonical_module(module), name)
        if key in ALLOWED_GLOBALS or key in self._extra:
            return super().find_class(key[0], name)
        raise DataError(
            f"refused to unpickle global {module}.{name}: this file may only contain numpy "
            "arrays and Python containers (restricted unpickler)", self._source)


def load_restricted(path: str | Path, *, extra: Iterable[tuple[str, str]] = ()) -> Any:
    """Unpickle ``path`` with :class:`RestrictedUnpickler`.

    Raises :class:`MissingDataError` if the file is absent and :class:`DataError` (naming the
    file) if it is not a readable pickle or names a refused global.
    """
    path = Path(path)
    if not path.is_file():
        raise MissingDataError("file not found", path)
    with open(path, "rb") as f:
        return loads_restricted(f.read(), source=path, extra=extra)


def loads_restricted(data: bytes, *, source: str | Path = "<pickle>",
                     extra: Iterable[tuple[str, str]] = ()) -> Any:
    """Unpickle bytes with :class:`RestrictedUnpickler` (``source`` names them in errors)."""
    try:
        return RestrictedUnpickler(io.BytesIO(data), source=source, extra=extra).load()
    except DataError:
        raise
    except (pickle.UnpicklingError, EOFError, AttributeError, ImportError, IndexError,
            TypeError, ValueError, KeyError, UnicodeDecodeError) as e:
        raise DataError(f"not a readable pickle ({type(e).__name__}: {e})", source) from None
