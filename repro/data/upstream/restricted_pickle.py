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

Bounded allocations (issue 16): naming only admitted globals, ``bytearray(2**60)`` or
``numpy.ndarray((10**7, 10**7))`` would still ask for exabytes, so every call the pickle makes,
every array state it applies and every length it declares is checked against stated caps
(:data:`MAX_ARRAY_BYTES` per object, :data:`FILE_SIZE_FACTOR` x the file's length +
:data:`SIZE_SLACK` in all) **before** anything is built.  The caps and checks are
:mod:`repro.data.upstream.pickle_checks`'s (lower a cap there); their names stay importable
from here.

The pure-Python :class:`pickle._Unpickler` is used (not the C one) so that BUILD and the
opcodes that build containers can be checked; the files are a few thousand arrays, so speed is unchanged in
practice.  Memory for containers built by opcodes alone stays linear in the file size.
"""

from __future__ import annotations

import io
import pickle
import struct
from pathlib import Path
from typing import Any, ClassVar, Iterable

from repro.errors import DataError, MissingDataError

from .pickle_checks import (FILE_SIZE_FACTOR, MAX_ARRAY_BYTES,  # noqa: F401
                            MAX_KEY_NODES, MAX_NDIM, SIZE_SLACK, AllocationChecks, Refused)

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


def _clip(text: str, n: int = 200) -> str:
    return text if len(text) <= n else text[:n] + "..."


class RestrictedUnpickler(AllocationChecks, pickle._Unpickler):
    """Pure-Python unpickler whose ``find_class`` admits only :data:`ALLOWED_GLOBALS` (+ extra)
    and which checks every call, array state and declared length against the caps (module
    docstring) before anything is allocated.

    ``size`` is the pickle's length in bytes (it sets the file-size budget); unknown (``None``)
    leaves only :data:`MAX_ARRAY_BYTES` per object.
    """

    def __init__(self, file, *, source: str | Path = "<pickle>",
                 extra: Iterable[tuple[str, str]] = (), size: int | None = None):
        # latin1 lets Python-2 pickles of numpy arrays load (their byte strings are str).
        super().__init__(file, encoding="latin1")
        self._source = str(source)
        self._extra = frozenset((_canonical_module(m), n) for m, n in extra)
        self._init_checks(size)

    def load(self) -> Any:
        """Unpickle; a failed check is a DataError naming the file (``source``)."""
        try:
            return super().load()
        except Refused as e:
            raise DataError(f"refused to unpickle: {_clip(str(e), 300)} (restricted unpickler)",
                            self._source) from None

    # ------------------------------------------------------------------ globals
    def find_class(self, module: str, name: str) -> Any:
        key = (_canonical_module(module), name)
        if key in ALLOWED_GLOBALS or key in self._extra:
            obj = super().find_class(key[0], name)
            if key in self._extra and isinstance(obj, type):
                self._extra_classes += (obj,)
            return obj
        raise DataError(
            f"refused to unpickle global {module}.{name}: this file may only contain numpy "
            "arrays and Python containers (restricted unpickler)", self._source)

    # ------------------------------------------------------------------ calls and BUILD
    # (the checks: :class:`AllocationChecks`)
    def load_reduce(self):
        args = self.stack[-1]
        self._check_call(self.stack[-2], args)
        super().load_reduce()

    def load_newobj(self):
        self._check_call(self.stack[-2], self.stack[-1])
        super().load_newobj()

    def load_newobj_ex(self):
        self._check_call(self.stack[-3], self.stack[-2], self.stack[-1])
        super().load_newobj_ex()

    def _instantiate(self, klass, args):
        self._check_call(klass, tuple(args))
        super()._instantiate(klass, args)

    def load_build(self):
        self._check_state(self.stack[-2], self.stack[-1])
        super().load_build()

    # ------------------------------------------------------------------ opcodes
    def load_bytearray8(self):
        # The pure-Python unpickler allocates the declared length before reading it.
        (n,) = struct.unpack("<Q", self.read(8))
        self._check_declared_bytes(n)
        b = bytearray(n)
        if self.readinto(b) != n:
            raise Refused("the file ends inside a byte array")
        self.append(b)

    def load_setitem(self):
        self._check_key(self.stack[-2])
        super().load_setitem()

    # After a MARK, ``self.stack`` holds exactly the items pushed since (pickle's pop_mark):
    # their keys are checked before pickle hashes them.
    def load_setitems(self):
        for k in self.stack[::2]:
            self._check_key(k)
        super().load_setitems()

    def load_additems(self):
        for k in self.stack:
            self._check_key(k)
        super().load_additems()

    def load_frozenset(self):
        for k in self.stack:
            self._check_key(k)
        super().load_frozenset()

    def load_dict(self):
        for k in self.stack[::2]:
            self._check_key(k)
        super().load_dict()

    dispatch: ClassVar[dict] = dict(pickle._Unpickler.dispatch)
    dispatch[pickle.REDUCE[0]] = load_reduce
    dispatch[pickle.NEWOBJ[0]] = load_newobj
    dispatch[pickle.NEWOBJ_EX[0]] = load_newobj_ex
    dispatch[pickle.BUILD[0]] = load_build
    dispatch[pickle.BYTEARRAY8[0]] = load_bytearray8
    dispatch[pickle.SETITEM[0]] = load_setitem
    dispatch[pickle.SETITEMS[0]] = load_setitems
    dispatch[pickle.ADDITEMS[0]] = load_additems
    dispatch[pickle.FROZENSET[0]] = load_frozenset
    dispatch[pickle.DICT[0]] = load_dict


def load_restricted(path: str | Path, *, extra: Iterable[tuple[str, str]] = ()) -> Any:
    """Unpickle ``path`` with :class:`RestrictedUnpickler`.

    Raises :class:`MissingDataError` if the file is absent and :class:`DataError` (naming the
    file) if it is not a readable pickle, names a refused global, or asks for more memory than
    the caps allow (module docstring).
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
        return RestrictedUnpickler(io.BytesIO(data), source=source, extra=extra,
                                   size=len(data)).load()
    except DataError:
        raise
    except MemoryError:
        raise DataError("refused to unpickle: it asks for more memory than there is "
                        "(restricted unpickler)", source) from None
    except (pickle.UnpicklingError, EOFError, AttributeError, ImportError, IndexError,
            TypeError, ValueError, KeyError, UnicodeDecodeError, OverflowError, struct.error,
            RecursionError, SystemError, SyntaxError) as e:  # numpy, on malformed states
        raise DataError(f"not a readable pickle ({type(e).__name__}: {_clip(str(e))})",
                        source) from None
