"""Which ASF skeleton each AMC clip of a declared data set moves (issue 28).

CMU ships one ASF per subject (``01/01.asf`` beside ``01/01_01.amc``), and bone lengths differ
between subjects by centimetres.  A spec's ``[source] asf`` is therefore one of two forms:

- a path (``asf = "01/01.asf"``): that one file for every clip, as before.  Since pairing
  subject 02's clips with subject 01's skeleton puts their joints centimetres off without any
  other sign, a clip whose own folder (or a folder above it, up to the source) holds another
  ASF file is refused, naming the folders, with the pattern form as the fix;
- a pattern (``*``, ``?`` or ``[``, matched like ``include``: case-insensitive, ``*`` crosses
  folders; ``asf = "*.asf"``): each AMC clip takes the matching ASF **nearest** to it: in its
  own folder, else in the closest folder above.  A folder holding several matching ASFs gives
  each clip the one whose file stem begins the clip's stem (the longest such: CMU's flat
  layout ``02.asf`` beside ``02_01.amc``); none, or a tie, is an error naming the clip and the
  candidates.

The ASF files are read before the clips (in an archive: one decompression pass, through the
same caps as the clips), each parsed once.  What "one skeleton per data set" then means (one
joint set and hierarchy; bone lengths equal within ``[skeleton] offset_tolerance``, the clips
posed on the reference clip's skeleton) is :mod:`repro.data.dataset_skeleton`'s.
"""

from __future__ import annotations

import hashlib
from pathlib import Path, PurePosixPath

from repro.data.dataset_spec import DatasetSpec, is_pattern, role_of
from repro.errors import DataError, MissingDataError

#: how many names a list in an error message shows before "and N more"
SHOWN = 10


def shown(names: list[str], n: int = SHOWN) -> str:
    """``names`` joined by commas, at most ``n`` of them, then "and K more"."""
    head = ", ".join(names[:n])
    return head + (f" and {len(names) - n} more" if len(names) > n else "")


def inner_path(label: str, source: Path) -> str:
    """The path inside ``source`` of a file :func:`repro.data.sources.iter_source` labelled
    ``label`` (a folder's file: its path; an archive's member: ``archive:member``)."""
    prefix = f"{source}:"
    if label.startswith(prefix):
        return label[len(prefix):].strip("/")
    try:
        return Path(label).relative_to(source).as_posix()
    except ValueError:
        return label


class SkeletonFiles:
    """The ASF files of a source: the ones the spec reads (``files``: path inside the source
    -> (bytes, where for errors)) and the paths of every other ``*.asf`` (``others``), so that
    a clip can be given its own (:meth:`asf_for`) and a single ASF applied across subjects
    refused (:meth:`check_single`)."""

    def __init__(self, spec: DatasetSpec, files: dict[str, tuple[bytes, str]],
                 others: list[str]):
        self.spec, self.files, self.others = spec, files, sorted(others)
        self._parsed: dict[str, object] = {}

    @property
    def pattern(self) -> bool:
        return is_pattern(self.spec.source.asf or "")

    def digest(self) -> bytes:
        """What the ASFs add to the fingerprint: the one file's ``sha256`` as before (a spec
        using one file keeps its fingerprint), or every matched file's path and ``sha256``."""
        if not self.pattern:
            (data, _), = self.files.values()
            return b"asf\0" + hashlib.sha256(data).digest()
        return b"".join(b"asf\0" + p.encode("utf-8", "surrogateescape") + b"\0" +
                        hashlib.sha256(d).digest() for p, (d, _) in sorted(self.files.items()))

    def parsed(self, path: str):
        """The :class:`repro.data.asf_amc.Asf` of the file at ``path`` (parsed once)."""
        from repro.data.asf_amc import parse_asf

        if path not in self._parsed:
            data, where = self.files[path]
            self._parsed[path] = parse_asf(data, where)
        return self._parsed[path]

    def asf_for(self, clip: str) -> str:
        """The path of the ASF the clip at ``clip`` (its path inside the source) moves."""
        if not self.pattern:
            return next(iter(self.files))
        stem = PurePosixPath(clip).stem.lower()
        folder = PurePosixPath(clip).parent
        for here in (folder, *folder.parents):
            near = sorted(p for p in self.files if PurePosixPath(p).parent == here)
            if len(near) == 1:
                return near[0]
            if near:
                best = _longest_prefix(near, stem)
                if len(best) == 1:
                    return best[0]
                raise DataError(f"its folder {str(here)!r} holds {len(near)} ASFs matching "
                                f"{self.spec.source.asf!r} ({shown(near)}) and the clip's "
                                "stem does not begin with exactly one's stem: each AMC takes "
                                "the nearest ASF the pattern matches (docs/datasets.md, "
                                "[source] asf)", clip)
        raise DataError(f"no ASF matching {self.spec.source.asf!r} in its folder or any folder "
                        "above: each AMC takes the nearest ASF the pattern matches "
                        "(docs/datasets.md, [source] asf)", clip)

    def check_single(self, clips: list[str], source: Path) -> None:
        """With one ``asf`` file: refuse clips whose folder (or a folder above) holds another
        ASF, which is almost surely their own subject's skeleton (one line: the folders, the
        spec's file and the fix)."""
        if self.pattern or not self.others:
            return
        mine = next(iter(self.files))
        folders = {str(PurePosixPath(p).parent): p for p in self.others}
        hit: dict[str, str] = {}
        own = str(PurePosixPath(mine).parent)
        for c in clips:
            for here in map(str, PurePosixPath(c).parents):
                if here == own:  # the spec's ASF is the nearest
                    break
                if here in folders:
                    hit.setdefault(folders[here], c)
                    break
        if hit:
            names = [f"{c} beside {o}" for o, c in sorted(hit.items())]
            raise DataError(f"asf = {self.spec.source.asf!r} is applied to every clip, but "
                            f"{len(hit)} folder(s) of clips hold their own ASF ({shown(names)});"
                            " one ASF per subject: write asf = \"*.asf\" (each AMC takes the "
                            "nearest ASF, its own folder's first)", source)


def _longest_prefix(paths: list[str], stem: str) -> list[str]:
    """Of ``paths``, those whose file stem is the longest that begins ``stem``."""
    fits = [p for p in paths if stem.startswith(PurePosixPath(p).stem.lower())]
    if not fits:
        return []
    best = max(len(PurePosixPath(p).stem) for p in fits)
    return [p for p in fits if len(PurePosixPath(p).stem) == best]


def read_skeleton_files(source: Path, spec: DatasetSpec) -> SkeletonFiles:
    """The spec's ASF file(s) inside a source folder or archive, their paths matched
    case-insensitively in both (an archive costs one more decompression pass, through the same
    caps; a folder's file must not be a link out of it), and the paths of the source's other
    ``*.asf`` files."""
    from repro.data.sources import MAX_MEMBER_BYTES, inside, iter_source, read_regular

    asf = spec.source.asf
    files: dict[str, tuple[bytes, str]] = {}
    others: list[str] = []
    clips: list[str] = []  # the clips' paths: a single ASF across subjects is refused up front
    if source.is_dir():
        for q in sorted(source.rglob("*")):
            rel = q.relative_to(source).as_posix()
            role = role_of(spec, rel)
            if role != "asf":
                if role == "clip":
                    clips.append(rel)
                elif rel.lower().endswith(".asf") and q.is_file():
                    others.append(rel)
                continue
            if not q.is_file():
                continue
            if not inside(q, source):
                raise DataError("a symbolic link that leads out of the source folder (copy the "
                                "file in instead)", q)
            if files and not is_pattern(asf):  # one file (a second spelling of its name
                continue                         # on a case-sensitive system: the first)
            files[rel] = (read_regular(q, MAX_MEMBER_BYTES, "the ASF skeleton file"), str(q))
        if not files:
            if is_pattern(asf):
                raise MissingDataError(f"no ASF skeleton file in the source folder matches "
                                       f"{asf!r}", source)
            raise MissingDataError("the spec's ASF skeleton file is not in the source folder",
                                   source / asf)
        found = SkeletonFiles(spec, files, others)
        found.check_single(clips, source)
        return found

    def kind(name: str) -> str | None:
        role = role_of(spec, name)
        if role == "clip":
            clips.append(name.strip("/"))
        elif role is None and name.lower().endswith(".asf"):
            others.append(name.strip("/"))
        return "asf" if role == "asf" else None

    for _, label, data in iter_source(source, kind_of=kind):
        if files and not is_pattern(asf):  # the first, as before
            continue
        files[inner_path(label, source)] = (data, label)
    if not files:
        what = f"no ASF skeleton file matches {asf!r} in the archive" if is_pattern(asf) else \
            f"the spec's ASF skeleton file {asf!r} is not in the archive"
        raise MissingDataError(what, source)
    found = SkeletonFiles(spec, files, others)
    found.check_single(clips, source)
    return found


__all__ = ["SkeletonFiles", "inner_path", "read_skeleton_files", "shown"]
