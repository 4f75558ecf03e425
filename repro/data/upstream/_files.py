"""Small readers shared by the upstream formats: CSV split lists, joint ``.npy`` files, text lists.

Every error names the file (and line where there is one).
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from repro.errors import DataError, MissingDataError


def read_csv_rows(path: Path) -> list[tuple[int, str, str]]:
    """(line number, motion, action_type) of each non-blank row of a split/clip CSV list
    (A2M/ODMO format: a header naming ``motion`` and ``action_type``; other columns ignored)."""
    if not path.is_file():
        raise MissingDataError("split list not found", path)
    with open(path, newline="", encoding="utf-8") as f:
        reader = csv.reader(f)
        try:
            header = next(reader)
        except StopIteration:
            raise DataError("empty CSV (expected columns motion, action_type)", path) from None
        cols = [h.strip() for h in header]
        if "motion" not in cols or "action_type" not in cols:
            raise DataError(f"CSV header {cols} lacks motion and action_type", path, 1)
        im, ia = cols.index("motion"), cols.index("action_type")
        rows = []
        for lineno, row in enumerate(reader, start=2):
            if not any(c.strip() for c in row):
                continue
            if len(row) <= max(im, ia):
                raise DataError(f"row has {len(row)} fields, expected {len(cols)}", path, lineno)
            rows.append((lineno, row[im].strip(), row[ia].strip()))
    return rows


def load_joint_npy(npy: Path, n_joints: int, listed_in: Path, lineno: int) -> np.ndarray:
    """A clip's joints (T, n_joints, 3) float32 from a plain ``.npy`` (no pickles admitted)."""
    if not npy.is_file():
        raise MissingDataError(f"clip listed on line {lineno} of {listed_in.name} is missing",
                               npy)
    try:
        a = np.load(npy, allow_pickle=False)
    except (ValueError, OSError) as e:
        raise DataError(f"not a plain .npy array ({e})", npy) from None
    if a.ndim == 2 and a.shape[1] == 3 * n_joints:
        a = a.reshape(a.shape[0], n_joints, 3)
    if a.ndim != 3 or a.shape[1:] != (n_joints, 3) or a.shape[0] == 0:
        raise DataError(f"expected (T, {n_joints}, 3) joints, got {a.shape}", npy)
    if not np.isfinite(a).all():
        raise DataError("non-finite joint coordinates", npy)
    return a.astype(np.float32)


def read_lines(path: Path) -> list[str]:
    """Non-blank, stripped lines of a UTF-8 text list."""
    if not path.is_file():
        raise MissingDataError("file not found", path)
    with open(path, encoding="utf-8") as f:
        return [ln.strip() for ln in f.read().splitlines() if ln.strip()]
