"""A declared data set's labels (issue 16; hardened in issue 29): each clip's action, style and
subject, from its file name (the spec's ``[labels] pattern``) or from a CSV / JSON side file.

Every name that comes out of here (clip names, actions, styles, subjects, class names) is a
non-empty string without control characters (:func:`repro.data.dataset_spec.bad_char`: C0,
DEL, C1, lone surrogates), so nothing a file or file name holds reaches a terminal raw.  The
side file is read through :func:`repro.data.sources.read_regular` (a regular file of at most
:data:`~repro.data.dataset_spec.MAX_LABELS_BYTES`); a JSON object that repeats a key and a CSV
header that repeats a column are refused; the pattern, checked for its shape when the spec is
loaded (:func:`~repro.data.dataset_spec.pattern_problem`), is also matched under a time bound
(:data:`~repro.data.dataset_spec.MATCH_SECONDS`).  Used by
:mod:`repro.data.dataset_prepare`.
"""

from __future__ import annotations

import collections
import contextlib
import csv
import io
import json
import re
from pathlib import Path
from typing import NamedTuple

import numpy as np

from repro.data import dataset_spec as _caps  # the caps, read when used (tests lower them)
from repro.data.dataset_spec import DatasetSpec, LabelSpec, bad_char
from repro.errors import DataError


def clip_stem(label: str, source: Path) -> str:
    """The clip name of a file read from ``source``: its file name less the extension, for a
    folder's file and for an archive member alike (``clips.tar.xz:walk_01.bvh`` and
    ``clips.tar.xz:sub/walk_01.bvh`` are both ``walk_01``; issue 29: a member at the archive's
    root was named ``clips.tar.xz:walk_01`` and ``^``-anchored patterns failed)."""
    prefix = f"{source}:"
    base = label[len(prefix):] if label.startswith(prefix) else Path(label).name
    return Path(base.rsplit("/", 1)[-1]).stem


def _name(v, what: str, clip: str, where, *, required: bool = False) -> str | None:
    """A label value as a non-empty name without control characters (``None`` stays None: no
    style or subject, unless ``required``)."""
    if v is None and not required:
        return None
    if not isinstance(v, str) or not v.strip() or bad_char(v) is not None:
        raise DataError(f"clip {clip!r:.80}: {what} must be a non-empty name (no control "
                        f"characters), got {v!r:.60}", where)
    return v.strip()


def _check_stems(stems: list[str], where) -> None:
    """Clip names come from file names: refused when empty or holding a control character (a
    file named ``\\x1b]0;PWNED\\x07.bvh``; a byte that is not UTF-8 becomes a lone surrogate)."""
    for s in stems:
        ch = bad_char(s)
        if ch is not None or not s.strip():
            why = "is empty" if ch is None else f"holds the control character U+{ord(ch):04X}"
            raise DataError(f"the clip name {s!r:.100} (from its file name) {why}; rename the "
                            "file", where)


def _no_duplicates(pairs: list[tuple]) -> dict:
    """``json`` ``object_pairs_hook``: a key given twice is refused (``json`` keeps the last)."""
    out: dict = {}
    for k, v in pairs:
        if k in out:
            raise _DuplicateKey(k)
        out[k] = v
    return out


class _DuplicateKey(Exception):
    """A JSON object repeats a key; becomes a DataError naming it."""


def _side_table(lab: LabelSpec, side: Path) -> dict[str, tuple]:
    """clip -> (action, style, subject) of a CSV or JSON labels file (duplicates refused)."""
    from repro.data.sources import read_regular

    raw_bytes = read_regular(side, _caps.MAX_LABELS_BYTES, "the labels file")
    try:
        text = raw_bytes.decode("utf-8-sig")  # a spreadsheet's BOM is no header
    except UnicodeDecodeError as e:
        raise DataError(f"the labels file is not UTF-8 text (byte {e.start})", side) from None
    table: dict[str, tuple] = {}

    def put(clip, action, style, subject, where: str) -> None:
        clip = _name(clip, f"the clip name ({where})", str(clip), side, required=True)
        if clip in table:
            raise DataError(f"clip {clip!r} is labelled twice ({where})", side)
        table[clip] = (_name(action, "action", clip, side, required=True),
                       _name(style, "style", clip, side), _name(subject, "subject", clip, side))

    if lab.from_ == "csv":
        reader = csv.DictReader(io.StringIO(text))
        try:
            reader.fieldnames = [f.strip() for f in reader.fieldnames or []]
            if not {"clip", "action"} <= set(reader.fieldnames):
                # the header is not quoted: the file may be anything (/etc/passwd)
                raise DataError("a labels CSV needs a header row with columns clip, action"
                                f"[, style][, subject] (its first line has "
                                f"{len(reader.fieldnames)} column(s), not these)", side)
            # a Counter, not .count() per column (quadratic: 40,000 columns took 24 s); empty
            # names are the trailing empty columns spreadsheets export (``clip,action,,``)
            counts = collections.Counter(f for f in reader.fieldnames if f)
            twice = sorted(f for f, n in counts.items() if n > 1)
            if twice:
                raise DataError(f"the header names column {twice[0]!r:.40} more than once",
                                side)
            for n, r in enumerate(reader, start=2):
                put(r.get("clip"), r.get("action"), r.get("style") or None,
                    r.get("subject") or None, f"line {n}")
        except csv.Error as e:  # e.g. a field over the csv module's size limit
            raise DataError(f"not a readable CSV at line {reader.line_num} ({e})", side) from None
        return table
    try:
        raw = json.loads(text, object_pairs_hook=_no_duplicates)
    except _DuplicateKey as e:
        raise DataError(f"key {e.args[0]!r:.80} is given twice in one JSON object", side) from None
    except (ValueError, RecursionError) as e:
        raise DataError(f"not JSON ({type(e).__name__}: {str(e)[:80]})", side) from None
    if not isinstance(raw, dict):
        raise DataError("labels JSON must map clip -> action or {action, style, subject}", side)
    for k, v in raw.items():
        if isinstance(v, dict):
            put(k, v.get("action"), v.get("style"), v.get("subject"), f"key {k!r:.80}")
        else:
            put(k, v, None, None, f"key {k!r:.80}")
    return table


class _MatchTimeout(Exception):
    """Raised by the alarm of :func:`_time_bound`."""


@contextlib.contextmanager
def _time_bound(seconds: float):
    """Raise :class:`_MatchTimeout` in the block after ``seconds`` (``re`` checks for signals
    while it backtracks).  Only in the main thread of a process with SIGALRM, and only when no
    other timer is set; elsewhere the pattern's shape check is the only bound."""
    import signal
    import threading

    usable = (hasattr(signal, "setitimer") and threading.current_thread() is threading.main_thread()
              and signal.getitimer(signal.ITIMER_REAL) == (0.0, 0.0))
    if not usable:
        yield
        return

    def ring(signum, frame):
        raise _MatchTimeout

    old = signal.signal(signal.SIGALRM, ring)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0.0)
        # None: a handler not installed from Python; SIG_DFL is the closest we can restore
        signal.signal(signal.SIGALRM, signal.SIG_DFL if old is None else old)


def _from_names(lab: LabelSpec, stems: list[str], where) -> dict[str, tuple]:
    """clip -> (action, style, subject) by the spec's pattern over each clip name, all the
    matching within :data:`~repro.data.dataset_spec.MATCH_SECONDS`; a name the pattern does
    not match is absent when ``[labels] unlisted = "drop"``, else refused."""
    rx = re.compile(lab.pattern)
    got: dict[str, tuple] = {}
    s = ""
    try:
        with _time_bound(_caps.MATCH_SECONDS):
            found = []
            for s in stems:
                found.append(rx.search(s))
    except _MatchTimeout:
        raise DataError(f"the labels pattern {lab.pattern!r:.100} took over "
                        f"{_caps.MATCH_SECONDS:g} s (at file name {s!r:.60}); simplify it",
                        where) from None
    for s, m in zip(stems, found):
        if m is None or m.group("action") is None:
            if lab.unlisted == "drop":
                continue
            raise DataError(f"file name {s!r} does not match the labels pattern "
                            f"{lab.pattern!r} (leave such files out: [source] exclude, or "
                            "[labels] unlisted = \"drop\")", where)
        g = m.groupdict()
        got[s] = (_name(m.group("action"), "action", s, where),
                  _name(g.get("style"), "style", s, where),
                  _name(g.get("subject"), "subject", s, where))
    return got


class Labels(NamedTuple):
    """What :func:`labels_for` makes of the clips: the first six fields describe the *kept*
    clips (those of a listed class that the labels name), in the order given."""

    labels: np.ndarray          # (n,) class index per kept clip
    styles: np.ndarray          # (n,) style index per kept clip, -1 for none
    classes: list[str]
    style_names: list[str]      # [] when no clip has a style
    subjects: list              # a name per kept clip, or None
    unused_rows: list[str]      # side-file clips that name no clip of the source
    kept: list[int]             # positions in the given stems of the kept clips
    dropped: dict[str, int]     # clips of an action not in [labels] classes, per action
    unlisted: list[str]         # clips the labels do not name (unlisted = "drop")


def labels_for(spec: DatasetSpec, spec_dir: Path, stems: list[str], *,
               strict_classes: bool = True) -> Labels:
    """The labels of the clips ``stems`` (every name checked: a non-empty string, each clip
    labelled once, classes and styles unique and used; ``subjects`` a name per clip or None;
    the unused rows: side-file clips that name no clip of the source).

    Two ways a clip is left out, by design and counted (issue 28): its action is not one of
    a ``[labels] classes`` list that names a subset of the actions, or the labels do not name
    it (no side-file row, a file name the pattern does not match) under ``[labels] unlisted =
    "drop"`` (the default, ``"error"``, refuses such a clip as before).  A listed class with
    no clip is refused unless ``strict_classes`` is False (``repro data check`` reports it)."""
    lab = spec.labels
    got: dict[str, tuple[str, str | None, str | None]] = {}
    where = spec_dir / (lab.file or spec.source.path)
    _check_stems(stems, spec_dir / spec.source.path)
    unused_rows: list[str] = []
    if lab.from_ == "filename":
        got = _from_names(lab, stems, where)
    else:
        table = _side_table(lab, where)
        for s in stems:
            if s in table:
                got[s] = table[s]
            elif lab.unlisted == "error":
                raise DataError(f"clip {s!r} has no label (label it, leave its file out with "
                                "[source] exclude, or set [labels] unlisted = \"drop\")", where)
        unused_rows = sorted(set(table) - set(stems))
    for what, given in (("classes", lab.classes), ("styles", lab.styles)):
        if given is not None and len(set(given)) != len(given):
            raise DataError(f"[labels] {what} repeats a name: {given}", spec_dir)
    unlisted = [s for s in stems if s not in got]
    classes = list(lab.classes) if lab.classes else sorted({a for a, _, _ in got.values()})
    cidx = {c: i for i, c in enumerate(classes)}
    dropped = dict(sorted(collections.Counter(
        a for a, _, _ in got.values() if a not in cidx).items()))
    kept = [i for i, s in enumerate(stems) if s in got and got[s][0] in cidx]
    stems = [stems[i] for i in kept]
    for group, at in (("subject", 2), ("style", 1)):
        if spec.split.by == group:
            missing = next((s for s in stems if got[s][at] is None), None)
            if missing is not None:
                raise DataError(f"clip {missing!r} has no {group}; [split] by = {group!r} "
                                "needs one for every clip", where)
    subjects = [got[s][2] for s in stems]
    style_vals = {st for s in stems for st in [got[s][1]] if st is not None}
    styles = list(lab.styles) if lab.styles else sorted(style_vals)
    sidx = {s: i for i, s in enumerate(styles)}
    labels, style_ids = [], []
    for s in stems:
        a, st, _ = got[s]
        if st is not None and st not in sidx:
            raise DataError(f"clip {s!r}: style {st!r} is not one of {styles}", where)
        labels.append(cidx[a])
        style_ids.append(-1 if st is None else sidx[st])
    present = {got[s][0] for s in stems}
    unused = [c for c in classes if c not in present]
    if unused and strict_classes:
        raise DataError(f"class(es) {unused} have no clip (remove them from [labels] classes)",
                        where)
    if not stems:
        raise DataError("no clip is left once the labels are applied (every clip dropped)",
                        where)
    return Labels(np.array(labels, np.int64), np.array(style_ids, np.int64), classes,
                  styles if style_vals else [], subjects, unused_rows, kept, dropped, unlisted)
