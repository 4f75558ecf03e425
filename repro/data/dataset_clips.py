"""Which clips a declared data set holds, their labels and its split, from file names alone
(issue 28): no clip is parsed.

Labels come from the file names (the spec's pattern) or from a side file, and the split from
the labels (and styles / subjects), so everything :func:`repro.data.dataset_prepare.
prepare_dataset` needs to refuse a data set whose split cannot be scored is known before a
single clip is read: :func:`select_clips` lists the clip files (a folder: its names; an
archive: one pass over its headers, decompressing but reading no clip), labels them
(:func:`repro.data.dataset_labels.labels_for`, which also drops the clips of classes a
``[labels] classes`` subset leaves out), makes the split (:func:`make_split`) and checks it
(:func:`split_problems`: every class needs a training and a test clip, each missing one named
with its clip count and the spec fields that fix it).  ``repro data check`` prints the same
facts (:func:`check_report`) without preparing, and adds what Neural Marionette's per-class
split (the Marionette tables' own, :func:`repro.data.splits.marionette_split`) would give.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from repro.data.dataset_labels import Labels, clip_stem, labels_for
from repro.data.dataset_spec import DatasetSpec, is_excluded, role_of
from repro.errors import DataError


@dataclass(frozen=True)
class ClipSelection:
    """The clip files of a source, sorted as they are read (``files``: the names
    :func:`repro.data.sources.iter_source` gives them, ``rel``: their paths inside the
    source), the kept ones (``keep``: positions), their labels and the split."""

    source: Path
    files: list[str]
    rel: list[str]
    excluded: int
    labels: Labels
    split: np.ndarray

    @property
    def kept_rel(self) -> set[str]:
        return {self.rel[i] for i in self.labels.kept}

    @property
    def stems(self) -> list[str]:
        return [clip_stem(self.files[i], self.source) for i in self.labels.kept]


def list_clip_files(source: Path, spec: DatasetSpec) -> tuple[list[tuple[str, str]], int]:
    """((name as read, path inside the source) of every clip file, sorted as
    :func:`repro.data.sources.iter_source` reads them; the number of files an ``exclude``
    pattern left out).  A folder costs a directory walk, an archive one decompression pass
    over its headers (no clip is kept in memory), under the same caps as reading it."""
    from repro.data.sources import check_utf8_name, iter_source

    found: list[tuple[str, str]] = []
    excluded = 0

    def seen(name: str) -> None:
        nonlocal excluded
        if role_of(spec, name) == "clip":
            if source.is_dir():  # as the fingerprint would: a name that is not text
                check_utf8_name(name, source)
            found.append((str(source / name) if source.is_dir() else f"{source}:{name}", name))
        elif is_excluded(spec, name):
            excluded += 1

    for _ in iter_source(source, kind_of=lambda name: None, on_skip=seen):
        pass  # every file is "skipped": only its name is looked at
    found.sort(key=lambda t: t[0])
    return found, excluded


def select_clips(spec: DatasetSpec, spec_path: Path, source: Path) -> ClipSelection:
    """The clips of the data set, their labels and split, checked (module docstring):
    DataError naming the spec file and every class left without a test or training clip."""
    from repro.data.dataset_spec import clip_patterns

    here = Path(spec_path).resolve().parent
    found, excluded = list_clip_files(source, spec)
    if not found:
        raise DataError(f"no file matches {' or '.join(map(repr, clip_patterns(spec)))} "
                        "(case-insensitive)" + (f"; {excluded} excluded" if excluded else ""),
                        source)
    files = [f for f, _ in found]
    stems = [clip_stem(f, source) for f in files]
    seen: dict[str, str] = {}
    for f, st in zip(files, stems):
        if st in seen:
            raise DataError(f"two clips share the name {st!r}: {seen[st]} and {f} (clip names "
                            "must be unique)", source)
        seen[st] = f
    lab = labels_for(spec, here, stems)
    split = make_split(spec, lab, spec_path)
    problems = split_problems(spec, lab, split)
    if problems:
        raise DataError("; ".join(problems), spec_path)
    return ClipSelection(source, files, [r for _, r in found], excluded, lab, split)


def make_split(spec: DatasetSpec, lab: Labels, spec_path: Path) -> np.ndarray:
    """The data set's own split of the kept clips (``[split]``): stratified by (action,
    style), whole subjects in a seeded order, or whole groups covering every action
    (:func:`repro.data.splits.group_split`); a split that cannot be made is a DataError
    naming the spec and the fix."""
    from repro.data.splits import NoGroupSplit, group_split, stratified_split, subject_split

    sp = spec.split
    if sp.grouped_by_action:
        groups = lab.subjects if sp.by == "subject" else [lab.style_names[i] for i in lab.styles]
        try:
            return group_split(lab.labels, groups, test_fraction=sp.test_fraction, seed=sp.seed)
        except NoGroupSplit as e:
            names = ", ".join(repr(lab.classes[a]) for a in e.actions)
            single = ", ".join(repr(lab.classes[a]) for a in e.single)
            why = (f"; {single} {'has' if len(e.single) == 1 else 'have'} all clips in one "
                   f"{sp.by}" if single else "")
            raise DataError(f"[split] by = {sp.by!r}: no choice of whole {sp.by}s gives "
                            f"{names} a test and a training clip{why}; fix: drop the class "
                            "(list the others in [labels] classes), or split by clip "
                            "([split] by = \"clip\")", spec_path) from None
    if sp.by == "subject":
        try:
            return subject_split(lab.subjects, test_fraction=sp.test_fraction, seed=sp.seed)
        except ValueError as e:
            raise DataError(str(e), spec_path) from None
    return stratified_split(lab.labels, lab.styles, test_fraction=sp.test_fraction,
                            seed=sp.seed)


def min_clips_for_test(fraction: float) -> int:
    """The fewest clips a stratum needs for ``round(n·fraction)`` (half up) to be at least 1."""
    n = max(1, math.ceil(0.5 / fraction) - 1)
    while math.floor(n * fraction + 0.5) < 1:
        n += 1
    return n


def _clips(n: int) -> str:
    return f"{n} clip{'' if n == 1 else 's'}"


def split_problems(spec: DatasetSpec, lab: Labels, split: np.ndarray) -> list[str]:
    """One sentence per side (test, train) that some class has no clip of, naming each class
    with its clip count and the fix: the spec fields that drop the class or change the split
    (empty when every class is on both sides)."""
    sp = spec.split
    out = []
    counts = np.bincount(lab.labels, minlength=len(lab.classes))
    for side, value in (("test", 1), ("training", 0)):
        none = [c for c in range(len(lab.classes))
                if not ((lab.labels == c) & (split == value)).any()]
        if not none:
            continue
        names = ", ".join(f"{lab.classes[c]!r} ({_clips(int(counts[c]))})" for c in none)
        drop = "" if len(none) == len(lab.classes) else (
            "drop the class (list only the others in [labels] classes, or leave its files out "
            "with [source] exclude)")
        if sp.by == "clip":
            how = (f"split stratified by action and style (round(n × {sp.test_fraction:g}) of "
                   "each (action, style) cell's n clips go to test)")
            if side == "test":
                fixes = ['split by whole styles ([split] by = "style")'] if lab.style_names \
                    else []
                cell = max(_largest_cells(lab, none))
                if cell >= 2:  # round(cell·f) >= 1 from f = 0.5 / cell on
                    fixes.append(f"raise [split] test_fraction to at least "
                                 f"{math.ceil(50 / cell) / 100:g}")
                fixes += ["add clips", drop]
            else:
                fixes = ["lower [split] test_fraction below 0.5", "add clips", drop]
        elif sp.by == "subject" and not sp.grouped_by_action:
            how = "split by whole subjects (not stratified by action)"
            fixes = ["choose the subjects by action ([split] stratify = \"action\")",
                     "another [split] seed", drop]
        else:
            how = f"split by whole {sp.by}s"
            fixes = [drop or "add clips"]
        out.append(f"{'class' if len(none) == 1 else 'classes'} {names} would have no {side} "
                   f"clip under the data set's {how}; fix: " + ", or ".join(f for f in fixes if f))
    return out


def _largest_cells(lab: Labels, classes: list[int]) -> list[int]:
    """The clip count of the largest (action, style) cell of each of ``classes`` (0 for a
    class without clips)."""
    out = [0]
    for c in classes:
        st = lab.styles[lab.labels == c]
        out.append(int(np.unique(st, return_counts=True)[1].max()) if st.size else 0)
    return out


def check_report(spec: DatasetSpec, spec_path: Path) -> dict:
    """``repro data check``'s facts of a spec whose source is there, without preparing:
    clip files, clips kept, dropped (by class, unlisted), per-class clips and the data set's
    own train / test counts, problems (as :func:`select_clips` would refuse them), and the
    classes Neural Marionette's per-class split would leave without a test clip.  A source
    without a clip file gives only ``files`` (0) and ``excluded``: nothing to check yet."""
    from repro.data.splits import marionette_split

    here = Path(spec_path).resolve().parent
    source = here / spec.source.path
    found, excluded = list_clip_files(source, spec)
    if not found:
        return {"files": 0, "excluded": excluded}
    files = [f for f, _ in found]
    lab = labels_for(spec, here, [clip_stem(f, source) for f in files], strict_classes=False)
    present = set(lab.labels.tolist())
    unused = [c for i, c in enumerate(lab.classes) if i not in present]
    try:
        split = make_split(spec, lab, spec_path)
        problems = split_problems(spec, lab, split)
    except DataError as e:
        split, problems = np.zeros_like(lab.labels, np.int8), [e.problem]
    if unused:
        problems.insert(0, f"class(es) {unused} have no clip (remove them from [labels] "
                        "classes)")
    nm = marionette_split(lab.labels)
    per_class = {c: {"clips": int((lab.labels == i).sum()),
                     "train": int(((lab.labels == i) & (split == 0)).sum()),
                     "test": int(((lab.labels == i) & (split == 1)).sum()),
                     "marionette_test": int(((lab.labels == i) & (nm == 1)).sum())}
                 for i, c in enumerate(lab.classes)}
    return {"files": len(files), "excluded": excluded, "clips": int(lab.labels.size),
            "dropped_by_class": dict(lab.dropped), "unlisted": len(lab.unlisted),
            "per_class": per_class, "unused_classes": unused, "problems": problems,
            "marionette_no_test": [c for c, v in per_class.items()
                                   if v["clips"] and not v["marionette_test"]],
            "marionette_min_clips": min_clips_for_test(0.2)}
