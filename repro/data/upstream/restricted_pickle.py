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

Bounded allocations (issue 16)
------------------------------
Admitting a global is not enough: ``bytearray(2**60)`` or ``numpy.ndarray((10**7, 10**7))``
name only admitted globals yet ask for exabytes (a MemoryError traceback), and a size that
fits would really be allocated.  So every call the pickle makes, every array state it applies
and every length field it declares is checked **before** anything is built:

- :data:`MAX_ARRAY_BYTES` (2 GiB): no single array, buffer or string may be larger, whatever
  the file.  The largest array in the papers' files is a few hundred MB.
- :data:`FILE_SIZE_FACTOR` x the pickle's own length + :data:`SIZE_SLACK` (4x + 16 MiB): the
  bytes the file builds through calls and array states together.  A numpy pickle carries its
  array data raw and uncompressed (protocol 2 spells it as a latin-1 string that is encoded
  once more, so a legitimate file builds at most about twice its length), so more than that
  means a number in the file, not data in it, asks for the memory.

Checks made, each a :class:`DataError` naming the file:

- ``numpy.ndarray`` is only accepted as the class argument of ``_reconstruct`` (how numpy
  pickles arrays); a direct call or ``__new__`` is refused;
- ``_reconstruct`` and ``ndarray.__setstate__``: shape (at most 32 non-negative integers) x
  itemsize within the caps; the raw data must be exactly that many bytes (object arrays: a list
  of exactly that many items; a short list would leave numpy reading unset pointers);
- ``numpy.dtype`` only from a typecode string, never structured or sub-array; a dtype's
  ``__setstate__`` may not change its size, alignment or flags (numpy would otherwise let a
  later state turn an 8-byte item into a terabyte one, or claim object pointers);
- ``bytes``/``bytearray``/``str``/``_codecs.encode``/containers: argument types checked, sizes
  charged before the call (``range`` counts as its length), only text codecs
  (latin-1, ascii, utf-8);
- ``BYTEARRAY8`` may not declare more bytes than the file holds (the pure-Python unpickler
  allocates the declared length before reading);
- dictionary keys and set items must be scalars or small tuples of scalars, so hashing cannot
  walk an exponentially shared tuple graph;
- ``__setstate__`` / ``__dict__`` updates (pickle's BUILD) only on numpy arrays, dtypes and the
  caller's ``extra`` classes.

The pure-Python :class:`pickle._Unpickler` is used (not the C one) so that BUILD and the
opcodes above can be checked; the files are a few thousand arrays, so speed is unchanged in
practice.  Memory for containers built by opcodes alone stays linear in the file size.
"""

from __future__ import annotations

import codecs
import io
import math
import pickle
import struct
from pathlib import Path
from typing import Any, ClassVar, Iterable

import numpy as np
from numpy._core.multiarray import _reconstruct
from numpy._core.multiarray import scalar as _scalar
from numpy._core.numeric import _frombuffer

from repro.errors import DataError, MissingDataError

#: Largest single array, buffer or string a pickle may build (bytes): 2 GiB (issue 16).
MAX_ARRAY_BYTES = 2 * 1024 ** 3
#: The bytes built by calls and array states together may not exceed this many times the
#: pickle's own length (plus :data:`SIZE_SLACK`): a numpy pickle carries its data raw.
FILE_SIZE_FACTOR = 4
#: Allowance on top of ``FILE_SIZE_FACTOR x length`` so small files may hold small empty arrays.
SIZE_SLACK = 16 * 1024 ** 2
#: Most dimensions accepted for an array (numpy's own limit is 64; the data here use <= 4).
MAX_NDIM = 32
#: Most scalars visited when checking one dictionary key or set item (a tuple graph bomb).
MAX_KEY_NODES = 256
#: Text codecs ``_codecs.encode``/``bytes``/``str`` may name (no zlib/base64/... transforms).
_TEXT_CODECS = {"iso8859-1": 1, "ascii": 1, "utf-8": 4}

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

_SCALARS = (type(None), bool, int, float, complex, str, bytes, np.generic)
_BYTES_LIKE = (bytes, bytearray, memoryview)


def _canonical_module(module: str) -> str:
    for old, new in _NUMPY_ALIASES.items():
        if module == old or module.startswith(old + "."):
            return new + module[len(old):]
    return module


def _gib(n: int) -> str:
    if n >= 1024 ** 6:
        return "more than 1 EiB"  # (and never a float overflow on a 400-digit request)
    return f"{n / 1024 ** 3:.3g} GiB" if n >= 1024 ** 3 else f"{n / 1024 ** 2:.3g} MiB"


def _shape_text(shape: tuple[int, ...]) -> str:
    """A shape for an error line: short, and no 5,000-digit numbers."""
    if len(shape) > 8 or any(n >= 10 ** 15 for n in shape):
        return f"({len(shape)} dimensions, some huge)" if shape else "()"
    return str(shape)


class _Refused(Exception):
    """A check failed; :meth:`RestrictedUnpickler.load` turns it into a DataError."""


def _clip(text: str, n: int = 200) -> str:
    return text if len(text) <= n else text[:n] + "..."


def _typename(x: Any) -> str:
    return type(x).__name__


class RestrictedUnpickler(pickle._Unpickler):
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
        self._extra_classes: tuple[type, ...] = ()
        self._size = size
        self._budget = (None if size is None else FILE_SIZE_FACTOR * int(size) + SIZE_SLACK)
        self._built = 0
        self._built_dtypes: set[int] = set()
        self._checks = {
            _reconstruct: self._check_reconstruct, _frombuffer: self._check_frombuffer,
            _scalar: self._check_scalar, np.dtype: self._check_dtype_call,
            codecs.encode: self._check_encode, bytes: self._check_bytes,
            bytearray: self._check_bytes, str: self._check_str, list: self._check_container,
            tuple: self._check_container, set: self._check_set,
            frozenset: self._check_set, dict: self._check_dict,
            int: self._check_scalars, float: self._check_scalars,
            complex: self._check_scalars, bool: self._check_scalars,
            slice: self._check_scalars, range: self._check_scalars,
        }

    def load(self) -> Any:
        """Unpickle; a failed check is a DataError naming the file (``source``)."""
        try:
            return super().load()
        except _Refused as e:
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

    # ------------------------------------------------------------------ size accounting
    def _charge(self, n: int, what: str) -> None:
        n = int(n)
        if n > MAX_ARRAY_BYTES:
            raise _Refused(f"{what} would take {_gib(n)}, over the {_gib(MAX_ARRAY_BYTES)} cap "
                           "on one array (MAX_ARRAY_BYTES)")
        self._built += n
        if self._budget is not None and self._built > self._budget:
            raise _Refused(
                f"{what} would bring the data this pickle builds to {_gib(self._built)}, but "
                f"the file is only {self._size} bytes (cap: {FILE_SIZE_FACTOR} x its length "
                f"+ {_gib(SIZE_SLACK)}; a numpy pickle carries its array data raw)")

    # ------------------------------------------------------------------ numpy checks
    def _dtype_of(self, x: Any, what: str) -> np.dtype:
        """A dtype from a dtype object or a short typecode; never structured or sub-array."""
        if isinstance(x, np.dtype):
            d = x
        elif isinstance(x, (str, bytes)) and len(x) <= 64:
            try:
                d = np.dtype(x)
            except (TypeError, ValueError, SyntaxError, KeyError):  # numpy parses "f8,i4"
                raise _Refused(f"{what}: {x[:64]!r} is not a numpy typecode") from None
        else:
            raise _Refused(f"{what}: dtype must be a numpy dtype or a typecode string, got "
                           f"{_typename(x)}")
        if d.fields is not None or d.subdtype is not None:
            raise _Refused(f"{what}: structured and sub-array numpy dtypes are not accepted")
        if d.itemsize > MAX_ARRAY_BYTES:
            raise _Refused(f"{what}: dtype item of {_gib(d.itemsize)} is over the "
                           f"{_gib(MAX_ARRAY_BYTES)} cap (MAX_ARRAY_BYTES)")
        return d

    @staticmethod
    def _shape_of(x: Any, what: str) -> tuple[int, ...]:
        if isinstance(x, (int, np.integer)) and not isinstance(x, bool):
            x = (x,)
        if not isinstance(x, (tuple, list)) or len(x) > MAX_NDIM:
            raise _Refused(f"{what}: shape must be a tuple of at most {MAX_NDIM} integers, got "
                           f"{_typename(x)}" + (f" of {len(x)}" if isinstance(x, (tuple, list))
                                                else ""))
        out = []
        for n in x:
            if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
                raise _Refused(f"{what}: shape entries must be non-negative integers")
            out.append(int(n))
        return tuple(out)

    def _array_bytes(self, shape: tuple[int, ...], d: np.dtype, what: str) -> int:
        n = math.prod(shape) * d.itemsize
        self._charge(n, f"{what} of shape {_shape_text(shape)} ({d.str})")
        return n

    def _check_reconstruct(self, args: tuple, kwargs: dict) -> None:
        if kwargs or len(args) != 3:
            raise _Refused("numpy _reconstruct takes (ndarray, shape, dtype)")
        cls, shape, dtype = args
        if cls is not np.ndarray:
            raise _Refused(f"numpy _reconstruct may only rebuild numpy.ndarray, got "
                           f"{getattr(cls, '__name__', _typename(cls))}")
        self._array_bytes(self._shape_of(shape, "array"), self._dtype_of(dtype, "array"),
                          "an array")

    def _check_frombuffer(self, args: tuple, kwargs: dict) -> None:
        if kwargs or len(args) not in (4, 5):
            raise _Refused("numpy _frombuffer takes (buffer, dtype, shape, order[, axes])")
        buf, dtype, shape, order = args[:4]
        if len(args) == 5 and args[4] is not None:
            self._shape_of(args[4], "array axis order")
        if not isinstance(buf, _BYTES_LIKE):
            raise _Refused(f"numpy _frombuffer needs bytes, got {_typename(buf)}")
        d = self._dtype_of(dtype, "array")
        if d.hasobject:
            raise _Refused("numpy _frombuffer cannot hold objects")
        shape = self._shape_of(shape, "array")
        if math.prod(shape) * d.itemsize != memoryview(buf).nbytes:
            raise _Refused(f"array data is {memoryview(buf).nbytes} bytes, its shape "
                           f"{_shape_text(shape)} and dtype {d.str} need "
                           f"{_gib(math.prod(shape) * d.itemsize)}")
        if order not in ("C", "F", "K"):
            raise _Refused("numpy _frombuffer order must be 'C', 'F' or 'K'")
        # A view of ``buf``: nothing new is allocated.

    def _check_scalar(self, args: tuple, kwargs: dict) -> None:
        if kwargs or not 1 <= len(args) <= 2:
            raise _Refused("numpy scalar takes (dtype, data)")
        d = self._dtype_of(args[0], "numpy scalar")
        if d.hasobject:
            return  # returns the object it is given
        data = args[1] if len(args) == 2 else None
        if data is not None:
            if not isinstance(data, (str, bytes)):
                raise _Refused(f"numpy scalar data must be bytes, got {_typename(data)}")
            if len(data) != d.itemsize:
                raise _Refused(f"numpy scalar of {d.str} needs {d.itemsize} bytes, got "
                               f"{len(data)}")
            if d.kind == "U":  # numpy fails with a SystemError on a code point past U+10FFFF
                raw = data.encode("latin1") if isinstance(data, str) else data
                if (np.frombuffer(raw, d.byteorder.replace("|", "=") + "u4") > 0x10FFFF).any():
                    raise _Refused("numpy string scalar holds an invalid code point")
        self._charge(d.itemsize, "a numpy scalar")

    def _check_dtype_call(self, args: tuple, kwargs: dict) -> None:
        if kwargs or len(args) != 3 or not isinstance(args[0], (str, bytes)):
            raise _Refused("numpy.dtype may only be built as numpy pickles it: "
                           "(typecode, align, copy)")
        if not all(a in (0, 1) and isinstance(a, int) for a in args[1:]):
            raise _Refused("numpy.dtype flags must be booleans")  # (0/1 from numpy on Python 2)
        if not args[2]:
            # copy=False returns numpy's shared dtype, whose state BUILD would then set
            raise _Refused("numpy.dtype must be built as a copy (as numpy pickles it)")
        self._dtype_of(args[0], "numpy.dtype")

    def _check_array_state(self, state: Any) -> None:
        if not isinstance(state, tuple) or len(state) not in (4, 5):
            raise _Refused("array state must be (version, shape, dtype, fortran, data)")
        shape, dtype, fortran, raw = state[-4:]
        shape = self._shape_of(shape, "array")
        if not isinstance(dtype, np.dtype):
            raise _Refused(f"array state: dtype must be a numpy dtype, got {_typename(dtype)}")
        d = self._dtype_of(dtype, "array")
        if not isinstance(fortran, (bool, int, np.bool_)):
            raise _Refused("array state: the Fortran-order flag must be a boolean")
        n = self._array_bytes(shape, d, "an array")  # first: the numbers below are now small
        count = math.prod(shape)
        if d.hasobject:
            if not isinstance(raw, list) or len(raw) != count:
                raise _Refused(f"object array of shape {_shape_text(shape)} needs a list of "
                               f"{count} items, got {_typename(raw)}"
                               + (f" of {len(raw)}" if isinstance(raw, list) else ""))
        elif not isinstance(raw, (str, bytes, bytearray)):
            raise _Refused(f"array data must be bytes, got {_typename(raw)}")
        elif len(raw) != n:
            raise _Refused(f"array data is {len(raw)} bytes, its shape {_shape_text(shape)} "
                           f"and dtype {d.str} need {n}")
        if isinstance(raw, str):
            self._charge(n, "an array's latin-1 data")  # numpy encodes it to bytes first

    def _check_dtype_state(self, d: np.dtype, state: Any) -> None:
        if id(d) in self._built_dtypes:
            raise _Refused("a numpy dtype's state may be set only once")
        # Exactly the tuple numpy writes: version 4 with a (None, (unit, num, den, events))
        # tail for datetimes (numpy reads that tail unchecked: a version-3 state on a
        # datetime dtype is a segmentation fault), version 3 and no tail otherwise.
        dt = d.kind in "mM"
        if (not isinstance(state, tuple) or len(state) != (9 if dt else 8)
                or state[0] != (4 if dt else 3) or state[1] not in ("<", ">", "|", "=")):
            raise _Refused("numpy dtype state must be the tuple numpy writes for "
                           f"{'a datetime' if dt else 'this'} dtype")
        if dt:
            tail = state[8]
            if not (isinstance(tail, tuple) and len(tail) == 2 and tail[0] is None
                    and isinstance(tail[1], tuple) and len(tail[1]) == 4
                    and isinstance(tail[1][0], bytes) and len(tail[1][0]) <= 16
                    and all(type(v) is int and 0 < v < 2 ** 31 for v in tail[1][1:])):
                raise _Refused("numpy datetime dtype state has a malformed unit")
        if state[2] is not None or state[3] is not None or state[4] is not None:
            raise _Refused("structured and sub-array numpy dtypes are not accepted")
        elsize, align, flags = state[5], state[6], state[7]
        if (elsize not in (-1, d.itemsize) or align not in (-1, d.alignment)
                or flags != d.flags):
            raise _Refused(f"numpy dtype state would change {d.str}'s size, alignment or flags")
        self._built_dtypes.add(id(d))

    # ------------------------------------------------------------------ builtin checks
    def _codec_factor(self, encoding: Any) -> int:
        if not isinstance(encoding, str) or len(encoding) > 32:
            raise _Refused("encoding must be a codec name")
        try:
            name = codecs.lookup(encoding).name
        except LookupError:
            raise _Refused(f"unknown encoding {encoding[:32]!r}") from None
        if name not in _TEXT_CODECS:
            raise _Refused(f"encoding {encoding[:32]!r} is not a text codec "
                           f"(allowed: latin-1, ascii, utf-8)")
        return _TEXT_CODECS[name]

    def _check_encode(self, args: tuple, kwargs: dict) -> None:
        if kwargs or not 1 <= len(args) <= 3 or not isinstance(args[0], str):
            raise _Refused("_codecs.encode may only encode a string")
        factor = self._codec_factor(args[1]) if len(args) > 1 else 4
        if len(args) > 2 and not isinstance(args[2], str):
            raise _Refused("errors must be a string")
        self._charge(len(args[0]) * factor, "an encoded string")

    def _check_bytes(self, args: tuple, kwargs: dict) -> None:
        if kwargs or len(args) > 3:
            raise _Refused("bytes/bytearray take at most (source, encoding, errors)")
        if not args:
            return
        src = args[0]
        if isinstance(src, bool):
            raise _Refused("bytes/bytearray of a boolean")
        if isinstance(src, (int, np.integer)):
            if src < 0:
                raise _Refused("bytes/bytearray of a negative size")
            self._charge(int(src), "a zero-filled buffer")
        elif isinstance(src, str):
            factor = self._codec_factor(args[1]) if len(args) > 1 else 4
            self._charge(len(src) * factor, "an encoded string")
        elif isinstance(src, _BYTES_LIKE):
            self._charge(memoryview(src).nbytes, "a copy of a buffer")
        elif isinstance(src, (list, tuple, range)):
            self._charge(len(src), "a buffer")
        else:
            raise _Refused(f"bytes/bytearray of a {_typename(src)}")

    def _check_str(self, args: tuple, kwargs: dict) -> None:
        if kwargs or len(args) > 3:
            raise _Refused("str takes at most (object, encoding, errors)")
        if not args:
            return
        src = args[0]
        if len(args) > 1:
            if not isinstance(src, _BYTES_LIKE):
                raise _Refused(f"str(..., encoding) of a {_typename(src)}")
            self._codec_factor(args[1])
            self._charge(4 * memoryview(src).nbytes, "a decoded string")
        elif isinstance(src, (str, bytes)):
            self._charge(4 * len(src), "a string")
        elif not isinstance(src, _SCALARS):
            # str() of a container would print it, and a shared list graph prints forever
            raise _Refused(f"str() of a {_typename(src)}")

    def _check_scalars(self, args: tuple, kwargs: dict) -> None:
        if kwargs:
            raise _Refused("keyword arguments are not accepted")
        for a in args:
            if not isinstance(a, _SCALARS):
                raise _Refused(f"argument of type {_typename(a)} where a number or string is "
                               "expected")

    def _check_container(self, args: tuple, kwargs: dict) -> None:
        if kwargs or len(args) > 1:
            raise _Refused("containers take at most one iterable")
        if not args:
            return
        src = args[0]
        if not isinstance(src, (list, tuple, set, frozenset, dict, range, str, bytes)):
            raise _Refused(f"container built from a {_typename(src)}")
        self._charge(8 * len(src), "a container")

    def _check_set(self, args: tuple, kwargs: dict) -> None:
        """set/frozenset: as a container, and the items they will hash are checked."""
        self._check_container(args, kwargs)
        if args and isinstance(args[0], (list, tuple)):
            for item in args[0]:
                self._check_key(item)

    def _check_dict(self, args: tuple, kwargs: dict) -> None:
        """dict: as a container, and the keys of the (key, value) pairs are checked."""
        self._check_container(args, kwargs)
        if args and isinstance(args[0], (list, tuple)):
            for item in args[0]:
                if not (isinstance(item, (list, tuple)) and len(item) == 2):
                    raise _Refused("dict() needs (key, value) pairs")
                self._check_key(item[0])

    def _check_key(self, key: Any) -> None:
        """A dict key / set item must be a scalar or a small tuple of scalars."""
        budget = [MAX_KEY_NODES]

        def walk(x: Any) -> None:
            budget[0] -= 1
            if budget[0] < 0:
                raise _Refused(f"a dictionary key or set item nests more than {MAX_KEY_NODES} "
                               "values")
            if isinstance(x, _SCALARS):
                return
            if isinstance(x, tuple):
                for y in x:
                    walk(y)
                return
            raise _Refused(f"a dictionary key or set item of type {_typename(x)}")

        walk(key)

    # ------------------------------------------------------------------ calls and BUILD
    def _check_call(self, func: Any, args: Any, kwargs: Any = None) -> None:
        if not isinstance(args, tuple) or not isinstance(kwargs or {}, dict):
            raise _Refused("call arguments must be a tuple")
        if func is np.ndarray:
            raise _Refused("numpy.ndarray may only be rebuilt through numpy's _reconstruct "
                           "(as numpy pickles arrays), not called directly")
        if isinstance(func, type) and issubclass(func, self._extra_classes or ()):
            return  # the caller admitted this class by exact name
        check = self._checks.get(func)
        if check is None:
            raise _Refused(f"calling {getattr(func, '__name__', _typename(func))} is not "
                           "accepted")
        check(args, kwargs or {})

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
        state, inst = self.stack[-1], self.stack[-2]
        if type(inst) is np.ndarray:
            self._check_array_state(state)
        elif isinstance(inst, np.dtype):
            self._check_dtype_state(inst, state)
        elif not (self._extra_classes and isinstance(inst, self._extra_classes)):
            raise _Refused(f"setting the state of a {_typename(inst)} is not accepted")
        super().load_build()

    # ------------------------------------------------------------------ opcodes
    def load_bytearray8(self):
        # The pure-Python unpickler allocates the declared length before reading it.
        (n,) = struct.unpack("<Q", self.read(8))
        if self._size is not None and n > self._size:
            raise _Refused(f"a byte array declares {n} bytes but the file is only {self._size}")
        if n > MAX_ARRAY_BYTES:
            raise _Refused(f"a byte array of {_gib(n)} is over the {_gib(MAX_ARRAY_BYTES)} cap")
        b = bytearray(n)
        if self.readinto(b) != n:
            raise _Refused("the file ends inside a byte array")
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
