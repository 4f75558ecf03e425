"""The compiled MOTION reader (repro.data.bvh_numbers, issue 31): bitwise what ``float`` and
``np.loadtxt`` read on the fixed-point subset, and a refusal (``None``) on everything else, so
the general parser decides and names the culprit."""

from __future__ import annotations

import io

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from repro.data import bvh_numbers
from repro.data.bvh import parse_bvh
from repro.errors import DataError

pytest.importorskip("numba")


def _loadtxt(text: bytes) -> np.ndarray:
    return np.loadtxt(io.BytesIO(text), dtype=np.float64, comments=None, ndmin=2)


def _bits(a: np.ndarray) -> bytes:
    return np.ascontiguousarray(a).tobytes()


# A fixed-point decimal as motion capture writes it: sign, up to 15 significant digits.
_decimal = st.builds(
    lambda sign, whole, frac: f"{sign}{whole}{'.' + frac if frac is not None else ''}",
    st.sampled_from(["", "-", "+"]),
    st.from_regex(r"[0-9]{1,9}", fullmatch=True),
    st.one_of(st.none(), st.from_regex(r"[0-9]{0,6}", fullmatch=True)),
)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.lists(_decimal, min_size=3, max_size=3), min_size=1, max_size=6),
       st.sampled_from([" ", "\t", "  ", " \t "]), st.booleans())
def test_fixed_point_rows_read_bitwise_like_float_and_loadtxt(rows, sep, trailing):
    text = "\n".join(sep.join(r) + (" " if trailing else "") for r in rows) + "\n"
    got = bvh_numbers.read_rows(text.encode(), len(rows), 3)
    assert got is not None
    want = np.array([[float(v) for v in r] for r in rows])
    assert _bits(got) == _bits(want)
    assert _bits(got) == _bits(_loadtxt(text.encode()))


def test_negative_zero_and_edge_forms():
    got = bvh_numbers.read_rows(b"-0.000000 .5 5. 0\n\n  \n-.25 +3 007.100 1\n", 2, 4)
    assert got is not None
    assert np.signbit(got[0, 0]) and got[0, 0] == 0.0
    assert got.tolist() == [[-0.0, 0.5, 5.0, 0.0], [-0.25, 3.0, 7.1, 1.0]]


def test_largest_exact_significand_and_the_first_it_refuses():
    ok = bvh_numbers.read_rows(b"9007199254740991 0.9007199254740991\n", 1, 2)
    assert ok is not None and ok.tolist() == [[9007199254740991.0, 0.9007199254740991]]
    assert bvh_numbers.read_rows(b"9007199254740992\n", 1, 1) is None  # 2**53: not exact
    assert bvh_numbers.read_rows(b"0.0000000000000000001\n", 1, 1) is None  # 19 digits


@pytest.mark.parametrize("body, rows, cols", [
    (b"1e5 2\n", 1, 2),          # an exponent
    (b"nan 2\n", 1, 2),          # not digits
    (b"1.2.3 2\n", 1, 2),        # a second point
    (b"- 2\n", 1, 2),            # a sign alone
    (b"1 2 3\n", 1, 2),          # a row too long
    (b"1\n", 1, 2),              # a row too short
    (b"1 2\n3 4\n", 1, 2),       # a row too many
    (b"1 2\n", 2, 2),            # a row too few
    (b"1 2\x0b\n", 1, 2),        # whitespace numpy may read otherwise
    (b"12345678901234567890 1\n", 1, 2),  # more than 18 digits
    (b"", 0, 2),                 # nothing to read
    (b"1 2\r\n", 1, 2),          # a CR (parse_bvh turns line ends into LF before)
])
def test_outside_the_subset_is_refused(body, rows, cols):
    assert bvh_numbers.read_rows(body, rows, cols) is None


_HEAD = b"""HIERARCHY
ROOT Hips
{
\tOFFSET 0 0 0
\tCHANNELS 3 Xposition Yposition Zposition
\tEnd Site
\t{
\t\tOFFSET 0 1 0
\t}
}
MOTION
"""


def test_parse_bvh_falls_back_for_exponents_and_still_names_bad_lines():
    b = parse_bvh(_HEAD + b"Frames: 2\nFrame Time: 0.1\n1e-3 2 3\n4 5 6\n", "x.bvh")
    assert b.motion.tolist() == [[1e-3, 2.0, 3.0], [4.0, 5.0, 6.0]]  # read by np.loadtxt
    with pytest.raises(DataError) as ei:
        parse_bvh(_HEAD + b"Frames: 2\nFrame Time: 0.1\n1 2 3\n4 five 6\n", "x.bvh")
    assert "x.bvh" in str(ei.value) and "'five' is not a number" in str(ei.value)


def test_without_a_kernel_the_general_parser_reads_the_same(monkeypatch):
    """numba missing or unable to compile: every block goes to np.loadtxt, same values."""
    body = _HEAD + b"Frames: 2\nFrame Time: 0.1\n-0.000000 2.5 3\n4 5 6.125\n"
    fast = parse_bvh(body, "x.bvh").motion
    monkeypatch.setattr(bvh_numbers, "_KERNEL", False)
    assert bvh_numbers.read_rows(b"1 2\n", 1, 2) is None
    assert _bits(parse_bvh(body, "x.bvh").motion) == _bits(fast)


def test_a_failing_compile_is_a_warning_and_a_fallback(monkeypatch):
    def broken():
        raise RuntimeError("cannot cache function: no locator available")

    monkeypatch.setattr(bvh_numbers, "_KERNEL", None)
    monkeypatch.setattr(bvh_numbers, "_compile", broken)
    with pytest.warns(RuntimeWarning, match="no locator available"):
        assert bvh_numbers.read_rows(b"1 2\n", 1, 2) is None
    assert bvh_numbers._KERNEL is False
