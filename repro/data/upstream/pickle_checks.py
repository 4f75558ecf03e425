"""The checks the restricted unpickler (:mod:`repro.data.upstream.restricted_pickle`) makes
before a pickle builds anything: the size caps and the argument checks of every constructor
it may call.  :class:`AllocationChecks` is the unpickler's mixin; its state is set up by
:meth:`AllocationChecks._init_checks` and a failed check raises :class:`Refused`, which the
unpickler turns into a :class:`~repro.errors.DataError` naming the file.

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
"""

from __future__ import annotations

import codecs
import math
from typing import Any

import numpy as np
from numpy._core.multiarray import _reconstruct
from numpy._core.multiarray import scalar as _scalar
from numpy._core.numeric import _frombuffer

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

_SCALARS = (type(None), bool, int, float, complex, str, bytes, np.generic)
_BYTES_LIKE = (bytes, bytearray, memoryview)


def _gib(n: int) -> str:
    if n >= 1024 ** 6:
        return "more than 1 EiB"  # (and never a float overflow on a 400-digit request)
    return f"{n / 1024 ** 3:.3g} GiB" if n >= 1024 ** 3 else f"{n / 1024 ** 2:.3g} MiB"


def _shape_text(shape: tuple[int, ...]) -> str:
    """A shape for an error line: short, and no 5,000-digit numbers."""
    if len(shape) > 8 or any(n >= 10 ** 15 for n in shape):
        return f"({len(shape)} dimensions, some huge)" if shape else "()"
    return str(shape)


class Refused(Exception):
    """A check failed; :meth:`~repro.data.upstream.restricted_pickle.RestrictedUnpickler.load`
    turns it into a DataError."""


def _typename(x: Any) -> str:
    return type(x).__name__


class AllocationChecks:
    """Mixin of :class:`~repro.data.upstream.restricted_pickle.RestrictedUnpickler`: every
    call, array state and declared length is checked here against the caps (module docstring)
    before anything is allocated.  ``_extra_classes`` holds the classes the caller admitted by
    name (set as the pickle names them)."""

    def _init_checks(self, size: int | None) -> None:
        """``size``: the pickle's length in bytes (it sets the file-size budget); ``None``
        leaves only :data:`MAX_ARRAY_BYTES` per object."""
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

    # ------------------------------------------------------------------ size accounting
    def _charge(self, n: int, what: str) -> None:
        n = int(n)
        if n > MAX_ARRAY_BYTES:
            raise Refused(f"{what} would take {_gib(n)}, over the {_gib(MAX_ARRAY_BYTES)} cap "
                          "on one array (MAX_ARRAY_BYTES)")
        self._built += n
        if self._budget is not None and self._built > self._budget:
            raise Refused(
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
                raise Refused(f"{what}: {x[:64]!r} is not a numpy typecode") from None
        else:
            raise Refused(f"{what}: dtype must be a numpy dtype or a typecode string, got "
                          f"{_typename(x)}")
        if d.fields is not None or d.subdtype is not None:
            raise Refused(f"{what}: structured and sub-array numpy dtypes are not accepted")
        if d.itemsize > MAX_ARRAY_BYTES:
            raise Refused(f"{what}: dtype item of {_gib(d.itemsize)} is over the "
                          f"{_gib(MAX_ARRAY_BYTES)} cap (MAX_ARRAY_BYTES)")
        return d

    @staticmethod
    def _shape_of(x: Any, what: str) -> tuple[int, ...]:
        if isinstance(x, (int, np.integer)) and not isinstance(x, bool):
            x = (x,)
        if not isinstance(x, (tuple, list)) or len(x) > MAX_NDIM:
            raise Refused(f"{what}: shape must be a tuple of at most {MAX_NDIM} integers, got "
                          f"{_typename(x)}" + (f" of {len(x)}" if isinstance(x, (tuple, list))
                                               else ""))
        out = []
        for n in x:
            if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
                raise Refused(f"{what}: shape entries must be non-negative integers")
            out.append(int(n))
        return tuple(out)

    def _array_bytes(self, shape: tuple[int, ...], d: np.dtype, what: str) -> int:
        n = math.prod(shape) * d.itemsize
        self._charge(n, f"{what} of shape {_shape_text(shape)} ({d.str})")
        return n

    def _check_reconstruct(self, args: tuple, kwargs: dict) -> None:
        if kwargs or len(args) != 3:
            raise Refused("numpy _reconstruct takes (ndarray, shape, dtype)")
        cls, shape, dtype = args
        if cls is not np.ndarray:
            raise Refused(f"numpy _reconstruct may only rebuild numpy.ndarray, got "
                          f"{getattr(cls, '__name__', _typename(cls))}")
        self._array_bytes(self._shape_of(shape, "array"), self._dtype_of(dtype, "array"),
                          "an array")

    def _check_frombuffer(self, args: tuple, kwargs: dict) -> None:
        if kwargs or len(args) not in (4, 5):
            raise Refused("numpy _frombuffer takes (buffer, dtype, shape, order[, axes])")
        buf, dtype, shape, order = args[:4]
        if len(args) == 5 and args[4] is not None:
            self._shape_of(args[4], "array axis order")
        if not isinstance(buf, _BYTES_LIKE):
            raise Refused(f"numpy _frombuffer needs bytes, got {_typename(buf)}")
        d = self._dtype_of(dtype, "array")
        if d.hasobject:
            raise Refused("numpy _frombuffer cannot hold objects")
        shape = self._shape_of(shape, "array")
        if math.prod(shape) * d.itemsize != memoryview(buf).nbytes:
            raise Refused(f"array data is {memoryview(buf).nbytes} bytes, its shape "
                          f"{_shape_text(shape)} and dtype {d.str} need "
                          f"{_gib(math.prod(shape) * d.itemsize)}")
        if order not in ("C", "F", "K"):
            raise Refused("numpy _frombuffer order must be 'C', 'F' or 'K'")
        # A view of ``buf``: nothing new is allocated.

    def _check_scalar(self, args: tuple, kwargs: dict) -> None:
        if kwargs or not 1 <= len(args) <= 2:
            raise Refused("numpy scalar takes (dtype, data)")
        d = self._dtype_of(args[0], "numpy scalar")
        if d.hasobject:
            return  # returns the object it is given
        data = args[1] if len(args) == 2 else None
        if data is not None:
            if not isinstance(data, (str, bytes)):
                raise Refused(f"numpy scalar data must be bytes, got {_typename(data)}")
            if len(data) != d.itemsize:
                raise Refused(f"numpy scalar of {d.str} needs {d.itemsize} bytes, got "
                              f"{len(data)}")
            if d.kind == "U":  # numpy fails with a SystemError on a code point past U+10FFFF
                raw = data.encode("latin1") if isinstance(data, str) else data
                if (np.frombuffer(raw, d.byteorder.replace("|", "=") + "u4") > 0x10FFFF).any():
                    raise Refused("numpy string scalar holds an invalid code point")
        self._charge(d.itemsize, "a numpy scalar")

    def _check_dtype_call(self, args: tuple, kwargs: dict) -> None:
        if kwargs or len(args) != 3 or not isinstance(args[0], (str, bytes)):
            raise Refused("numpy.dtype may only be built as numpy pickles it: "
                          "(typecode, align, copy)")
        if not all(a in (0, 1) and isinstance(a, int) for a in args[1:]):
            raise Refused("numpy.dtype flags must be booleans")  # (0/1 from numpy on Python 2)
        if not args[2]:
            # copy=False returns numpy's shared dtype, whose state BUILD would then set
            raise Refused("numpy.dtype must be built as a copy (as numpy pickles it)")
        self._dtype_of(args[0], "numpy.dtype")

    def _check_array_state(self, state: Any) -> None:
        if not isinstance(state, tuple) or len(state) not in (4, 5):
            raise Refused("array state must be (version, shape, dtype, fortran, data)")
        shape, dtype, fortran, raw = state[-4:]
        shape = self._shape_of(shape, "array")
        if not isinstance(dtype, np.dtype):
            raise Refused(f"array state: dtype must be a numpy dtype, got {_typename(dtype)}")
        d = self._dtype_of(dtype, "array")
        if not isinstance(fortran, (bool, int, np.bool_)):
            raise Refused("array state: the Fortran-order flag must be a boolean")
        n = self._array_bytes(shape, d, "an array")  # first: the numbers below are now small
        count = math.prod(shape)
        if d.hasobject:
            if not isinstance(raw, list) or len(raw) != count:
                raise Refused(f"object array of shape {_shape_text(shape)} needs a list of "
                              f"{count} items, got {_typename(raw)}"
                              + (f" of {len(raw)}" if isinstance(raw, list) else ""))
        elif not isinstance(raw, (str, bytes, bytearray)):
            raise Refused(f"array data must be bytes, got {_typename(raw)}")
        elif len(raw) != n:
            raise Refused(f"array data is {len(raw)} bytes, its shape {_shape_text(shape)} "
                          f"and dtype {d.str} need {n}")
        if isinstance(raw, str):
            self._charge(n, "an array's latin-1 data")  # numpy encodes it to bytes first

    def _check_dtype_state(self, d: np.dtype, state: Any) -> None:
        if id(d) in self._built_dtypes:
            raise Refused("a numpy dtype's state may be set only once")
        # Exactly the tuple numpy writes: version 4 with a (None, (unit, num, den, events))
        # tail for datetimes (numpy reads that tail unchecked: a version-3 state on a
        # datetime dtype is a segmentation fault), version 3 and no tail otherwise.
        dt = d.kind in "mM"
        if (not isinstance(state, tuple) or len(state) != (9 if dt else 8)
                or state[0] != (4 if dt else 3) or state[1] not in ("<", ">", "|", "=")):
            raise Refused("numpy dtype state must be the tuple numpy writes for "
                          f"{'a datetime' if dt else 'this'} dtype")
        if dt:
            tail = state[8]
            if not (isinstance(tail, tuple) and len(tail) == 2 and tail[0] is None
                    and isinstance(tail[1], tuple) and len(tail[1]) == 4
                    and isinstance(tail[1][0], bytes) and len(tail[1][0]) <= 16
                    and all(type(v) is int and 0 < v < 2 ** 31 for v in tail[1][1:])):
                raise Refused("numpy datetime dtype state has a malformed unit")
        if state[2] is not None or state[3] is not None or state[4] is not None:
            raise Refused("structured and sub-array numpy dtypes are not accepted")
        elsize, align, flags = state[5], state[6], state[7]
        if (elsize not in (-1, d.itemsize) or align not in (-1, d.alignment)
                or flags != d.flags):
            raise Refused(f"numpy dtype state would change {d.str}'s size, alignment or flags")
        self._built_dtypes.add(id(d))

    # ------------------------------------------------------------------ builtin checks
    def _codec_factor(self, encoding: Any) -> int:
        if not isinstance(encoding, str) or len(encoding) > 32:
            raise Refused("encoding must be a codec name")
        try:
            name = codecs.lookup(encoding).name
        except LookupError:
            raise Refused(f"unknown encoding {encoding[:32]!r}") from None
        if name not in _TEXT_CODECS:
            raise Refused(f"encoding {encoding[:32]!r} is not a text codec "
                          f"(allowed: latin-1, ascii, utf-8)")
        return _TEXT_CODECS[name]

    def _check_encode(self, args: tuple, kwargs: dict) -> None:
        if kwargs or not 1 <= len(args) <= 3 or not isinstance(args[0], str):
            raise Refused("_codecs.encode may only encode a string")
        factor = self._codec_factor(args[1]) if len(args) > 1 else 4
        if len(args) > 2 and not isinstance(args[2], str):
            raise Refused("errors must be a string")
        self._charge(len(args[0]) * factor, "an encoded string")

    def _check_bytes(self, args: tuple, kwargs: dict) -> None:
        if kwargs or len(args) > 3:
            raise Refused("bytes/bytearray take at most (source, encoding, errors)")
        if not args:
            return
        src = args[0]
        if isinstance(src, bool):
            raise Refused("bytes/bytearray of a boolean")
        if isinstance(src, (int, np.integer)):
            if src < 0:
                raise Refused("bytes/bytearray of a negative size")
            self._charge(int(src), "a zero-filled buffer")
        elif isinstance(src, str):
            factor = self._codec_factor(args[1]) if len(args) > 1 else 4
            self._charge(len(src) * factor, "an encoded string")
        elif isinstance(src, _BYTES_LIKE):
            self._charge(memoryview(src).nbytes, "a copy of a buffer")
        elif isinstance(src, (list, tuple, range)):
            self._charge(len(src), "a buffer")
        else:
            raise Refused(f"bytes/bytearray of a {_typename(src)}")

    def _check_str(self, args: tuple, kwargs: dict) -> None:
        if kwargs or len(args) > 3:
            raise Refused("str takes at most (object, encoding, errors)")
        if not args:
            return
        src = args[0]
        if len(args) > 1:
            if not isinstance(src, _BYTES_LIKE):
                raise Refused(f"str(..., encoding) of a {_typename(src)}")
            self._codec_factor(args[1])
            self._charge(4 * memoryview(src).nbytes, "a decoded string")
        elif isinstance(src, (str, bytes)):
            self._charge(4 * len(src), "a string")
        elif not isinstance(src, _SCALARS):
            # str() of a container would print it, and a shared list graph prints forever
            raise Refused(f"str() of a {_typename(src)}")

    def _check_scalars(self, args: tuple, kwargs: dict) -> None:
        if kwargs:
            raise Refused("keyword arguments are not accepted")
        for a in args:
            if not isinstance(a, _SCALARS):
                raise Refused(f"argument of type {_typename(a)} where a number or string is "
                              "expected")

    def _check_container(self, args: tuple, kwargs: dict) -> None:
        if kwargs or len(args) > 1:
            raise Refused("containers take at most one iterable")
        if not args:
            return
        src = args[0]
        if not isinstance(src, (list, tuple, set, frozenset, dict, range, str, bytes)):
            raise Refused(f"container built from a {_typename(src)}")
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
                    raise Refused("dict() needs (key, value) pairs")
                self._check_key(item[0])

    def _check_key(self, key: Any) -> None:
        """A dict key / set item must be a scalar or a small tuple of scalars."""
        budget = [MAX_KEY_NODES]

        def walk(x: Any) -> None:
            budget[0] -= 1
            if budget[0] < 0:
                raise Refused(f"a dictionary key or set item nests more than {MAX_KEY_NODES} "
                              "values")
            if isinstance(x, _SCALARS):
                return
            if isinstance(x, tuple):
                for y in x:
                    walk(y)
                return
            raise Refused(f"a dictionary key or set item of type {_typename(x)}")

        walk(key)

    # ------------------------------------------------------------------ calls and BUILD
    def _check_call(self, func: Any, args: Any, kwargs: Any = None) -> None:
        if not isinstance(args, tuple) or not isinstance(kwargs or {}, dict):
            raise Refused("call arguments must be a tuple")
        if func is np.ndarray:
            raise Refused("numpy.ndarray may only be rebuilt through numpy's _reconstruct "
                          "(as numpy pickles arrays), not called directly")
        if isinstance(func, type) and issubclass(func, self._extra_classes or ()):
            return  # the caller admitted this class by exact name
        check = self._checks.get(func)
        if check is None:
            raise Refused(f"calling {getattr(func, '__name__', _typename(func))} is not "
                          "accepted")
        check(args, kwargs or {})

    def _check_state(self, inst: Any, state: Any) -> None:
        """BUILD (``__setstate__`` / ``__dict__`` update): only on numpy arrays, dtypes and the
        caller's extra classes."""
        if type(inst) is np.ndarray:
            self._check_array_state(state)
        elif isinstance(inst, np.dtype):
            self._check_dtype_state(inst, state)
        elif not (self._extra_classes and isinstance(inst, self._extra_classes)):
            raise Refused(f"setting the state of a {_typename(inst)} is not accepted")

    def _check_declared_bytes(self, n: int) -> None:
        """A length a byte array declares (opcode BYTEARRAY8), before it is allocated."""
        if self._size is not None and n > self._size:
            raise Refused(f"a byte array declares {n} bytes but the file is only {self._size}")
        if n > MAX_ARRAY_BYTES:
            raise Refused(f"a byte array of {_gib(n)} is over the {_gib(MAX_ARRAY_BYTES)} cap")
