"""Reading a data set's source: a folder or a tar archive, under size caps (issue 16).

:func:`iter_source` streams the files of a source once (an archive through :mod:`tarfile`,
decompressed as it is read, nothing unpacked to disk; a folder in sorted order) and checks
every size *before* a byte of the file is read: :data:`MAX_MEMBER_BYTES` per file,
:data:`MAX_SOURCE_BYTES` for the whole source, :data:`MAX_TAR_HEADER_BYTES` per tar extension
header; GNU sparse members and symbolic links out of a folder are refused.
:func:`source_fingerprint` names a source by its bytes.  Used by the built-in stand-in
(:mod:`repro.data.bandai`) and by declared data sets (:mod:`repro.data.dataset_spec`).

The caps are read when a source is read, so a test may lower them with
``monkeypatch.setattr(repro.data.sources, "MAX_MEMBER_BYTES", ...)``.
"""

from __future__ import annotations

import tarfile
from pathlib import Path
from typing import Callable, Iterator

from repro.errors import DataError

#: Largest single file read from a source (bytes), checked from the tar header's size (or
#: ``stat``) before a byte of it is read (issue 16: a 46 KB .tar.xz holding one 300 MB .bvh
#: used ~1 GB of memory before it was refused).  The largest real Bandai-2 clip is 615 KB.
MAX_MEMBER_BYTES = 64 * 1024 ** 2
#: Largest total size of the files a source holds (bytes; every regular archive member counts,
#: since a stream must decompress a member even to skip it).  The real archive holds 515 MB.
MAX_SOURCE_BYTES = 4 * 1024 ** 3
#: Largest tar extension header (a GNU long name or link, a pax header), which :mod:`tarfile`
#: reads whole into memory before the member it describes; real ones are a few hundred bytes.
MAX_TAR_HEADER_BYTES = 1024 ** 2
#: Longest path of an archive member (characters) and most folders on its way: a 1 MiB pax
#: name of 200,000 ``a/`` (issue 29) is refused instead of costing memory in every step that
#: looks at its parent folders.  A file system's own limit is 4096 bytes (PATH_MAX).
MAX_MEMBER_NAME = 4096
MAX_MEMBER_DEPTH = 64
#: Most entries (files, folders, links) an archive may hold: each costs a header parse even
#: when skipped, so 40,000 members of 4 KB names in a 1.4 MB .tar.gz took a minute (issue 29).
#: The real Bandai-2 archive holds about 3,000.
MAX_MEMBERS = 200_000


def source_fingerprint(source: Path, select: Callable[[str], object] | None = None) -> str:
    """sha256 of the archive bytes, or for a folder the content key of the sorted
    (relative name, sha256) list of its files (those ``select``, given the path inside the
    folder, accepts: a declared data set's clips and ASF; default every file).  A folder
    holding a symbolic link that leads out of it is refused here, before any cached copy could
    be reused (DataError naming it)."""
    from repro.keys import content_key, sha256_file

    check_source(source)
    if source.is_dir():
        entries = sorted(source.rglob("*"))
        out = next((p for p in entries if not inside(p, source)), None)
        if out is not None:
            raise DataError(_OUT_OR_LOOP, out)
        files = [p for p in entries if p.is_file()
                 and (select is None or select(p.relative_to(source).as_posix()))]
        for p in files:
            check_utf8_name(p.relative_to(source).as_posix(), source)
        return content_key([[p.relative_to(source).as_posix(), sha256_file(p)] for p in files])
    return sha256_file(source)


def inside(path: Path, folder: Path) -> bool:
    """False for a symlink (file or folder on the way) that leads out of ``folder``, or that
    loops (Python 3.11's ``resolve`` raises RuntimeError on a loop): a folder source reads only
    what lies inside it (such a link is refused by :func:`iter_source`)."""
    try:
        return path.resolve().is_relative_to(folder.resolve())
    except (OSError, RuntimeError):
        return False


_OUT_OR_LOOP = ("a symbolic link that leads out of the source folder, or loops (copy the file "
                "in instead)")


def check_source(source: Path) -> None:
    """A source must be a folder or a regular file (an archive): ``/dev/zero`` would be hashed
    forever, and opening a FIFO blocks until a writer comes (issue 29).  ``stat`` only, so
    nothing is opened; DataError naming the source otherwise."""
    import stat

    try:
        mode = source.stat().st_mode
    except (OSError, ValueError) as e:
        why = getattr(e, "strerror", None) or "not a valid path"
        raise DataError(f"cannot read the source ({why})", source) from None
    if not (stat.S_ISDIR(mode) or stat.S_ISREG(mode)):
        raise DataError(f"the source is a {_kind(mode)}, not a folder or an archive file",
                        source)


def check_utf8_name(name: str, source: Path) -> None:
    """A folder file's name must be text: a byte that is not UTF-8 comes out of ``os`` as a
    lone surrogate, which no key, JSON file or terminal can take (DataError naming it
    escaped, and the folder)."""
    try:
        name.encode("utf-8")
    except UnicodeEncodeError:
        raise DataError(f"the file name {ascii(name)} is not UTF-8 text; rename the file",
                        source) from None


def _kind(mode: int) -> str:
    import stat

    for test, word in ((stat.S_ISFIFO, "FIFO (named pipe)"), (stat.S_ISCHR, "character device"),
                       (stat.S_ISBLK, "block device"), (stat.S_ISSOCK, "socket"),
                       (stat.S_ISDIR, "folder")):
        if test(mode):
            return word
    return "special file"


def read_regular(path: Path, cap: int, what: str, error: type = DataError) -> bytes:
    """The bytes of the file ``path`` (``what`` it is, for messages), which must be a regular
    file of at most ``cap`` bytes: opened without blocking (``O_NONBLOCK``: a FIFO is refused,
    not waited on), checked with ``fstat``, and read at most ``cap + 1`` bytes so a file that
    grows, or lies about its size, is still refused (issue 29: ``/dev/zero`` or a 3 GB sparse
    CSV as a labels file).  ``error`` (a ReproError subclass taking ``(message, path)``)
    otherwise; the message never quotes the file's content."""
    import os
    import stat

    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except FileNotFoundError:
        raise error(f"{what} not found", path) from None
    except (OSError, ValueError) as e:  # ValueError: a NUL in the name
        why = getattr(e, "strerror", None) or "not a valid path"
        raise error(f"cannot read {what} ({why})", path) from None
    with os.fdopen(fd, "rb", buffering=0) as f:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise error(f"{what} is a {_kind(st.st_mode)}, not a regular file", path)
        if st.st_size > cap:
            raise error(f"{what} is {_mib(st.st_size)}, over the {_mib(cap)} cap; not read",
                        path)
        chunks, n = [], 0
        try:
            while n <= cap:
                b = f.read(cap + 1 - n)
                if not b:
                    break
                chunks.append(b)
                n += len(b)
        except OSError as e:
            raise error(f"cannot read {what} ({e.strerror})", path) from None
        if n > cap:
            raise error(f"{what} is over the {_mib(cap)} cap (it grew while read); not read",
                        path)
        return b"".join(chunks)


def _mib(n: int) -> str:
    """A size for messages: bytes under 1 MiB (a lowered cap is not "0.0 MiB"), else MiB."""
    return f"{n:,} bytes" if n < 1024 ** 2 else f"{n / 1024 ** 2:,.1f} MiB"


class _TarCapError(Exception):
    """Raised inside :mod:`tarfile` by :class:`_CappedTarInfo`; becomes a DataError."""


def _open_decompressed(source: Path):
    """The archive's bytes, decompressed as they are read (xz, gzip, bz2 or plain tar).

    Not :mod:`tarfile`'s own ``r|*``: it inflates each 10 KB compressed chunk whole, and 10 KB
    of compressed zeros is tens of megabytes (issue 16).  These readers inflate no more than
    each read asks for.
    """
    import bz2
    import gzip
    import lzma

    with open(source, "rb") as f:
        magic = f.read(6)
    if magic.startswith(b"\xfd7zXZ\x00"):
        return lzma.open(source, "rb")
    if magic.startswith(b"\x1f\x8b"):
        return gzip.open(source, "rb")
    if magic.startswith(b"BZh"):
        return bz2.open(source, "rb")
    return open(source, "rb")


class _CappedTarInfo(tarfile.TarInfo):
    """A TarInfo that refuses, before :mod:`tarfile` reads them, extension headers over
    :data:`MAX_TAR_HEADER_BYTES` and GNU sparse members (whose block maps :mod:`tarfile` also
    reads whole; a sparse BVH file is no data set's)."""

    def _proc_member(self, tf):
        meta = (tarfile.GNUTYPE_LONGNAME, tarfile.GNUTYPE_LONGLINK, tarfile.XHDTYPE,
                tarfile.XGLTYPE, tarfile.SOLARIS_XHDTYPE)
        if self.type in meta and self.size > MAX_TAR_HEADER_BYTES:
            raise _TarCapError(f"a tar extension header of {_mib(self.size)} is over the "
                               f"{_mib(MAX_TAR_HEADER_BYTES)} cap "
                               "(sources.MAX_TAR_HEADER_BYTES); not read")
        if self.type == tarfile.GNUTYPE_SPARSE:
            raise _TarCapError(f"{self.name} is a GNU sparse member; re-create the archive "
                               "without --sparse")
        return super()._proc_member(tf)


def iter_source(source: Path, kind_of: Callable[[str], str | None] | None = None,
                on_skip: Callable[[str], None] | None = None
                ) -> Iterator[tuple[str, str, bytes]]:
    """Yield (kind, label-for-errors, bytes) for each .bvh, .json and cfg label file (the
    built-in stand-in's kinds; or each file to which ``kind_of``, given the path inside the
    source, gives a kind: a declared data set's, :mod:`repro.data.dataset_spec`).

    Sizes are checked before anything is read: a file over :data:`MAX_MEMBER_BYTES`, or a
    source whose files add up to more than :data:`MAX_SOURCE_BYTES`, is a DataError naming the
    archive, the member and the cap (from the tar header's ``size``; for a folder, ``stat``).
    ``on_skip``, if given, is called with the path of each file (not folder) given no kind.
    An archive is streamed in bounded memory: at most :data:`MAX_MEMBERS` entries, and
    :mod:`tarfile`'s list of the members seen is emptied as it goes (it kept every TarInfo:
    100,000 members of 4 KB names held 470 MB).
    """
    kind_of = kind_of or _bandai_kind
    check_source(source)
    if source.is_dir():
        yield from _iter_folder(source, kind_of, on_skip, _Admit(str(source)))
        return
    yield from _iter_archive(source, kind_of, on_skip, _Admit(str(source)))


def _bandai_kind(name: str) -> str | None:
    """The built-in stand-in's kind of the file at ``name``: ``bvh``, ``json``, its label file's
    name (``content_label.txt``, ``style_label.txt``) or None (not read)."""
    base = name.rsplit("/", 1)[-1]
    if base.endswith(".bvh"):
        return "bvh"
    if base.endswith(".json"):
        return "json"
    if base in ("content_label.txt", "style_label.txt"):
        return base
    return None


class _Admit:
    """The size caps of one source read: each file admitted by its size before it is read
    (:data:`MAX_MEMBER_BYTES` for a file that is read, :data:`MAX_SOURCE_BYTES` for them all,
    counted as they come; DataError naming ``where``, the member and the cap)."""

    def __init__(self, where: str):
        self.where, self.total = where, 0

    def __call__(self, size: int, member: str, *, read: bool) -> None:
        if read and size > MAX_MEMBER_BYTES:
            raise DataError(f"{member} is {_mib(size)}, over the {_mib(MAX_MEMBER_BYTES)} cap on "
                            "one file (sources.MAX_MEMBER_BYTES); not read", self.where)
        self.total += size
        if self.total > MAX_SOURCE_BYTES:
            raise DataError(f"the files up to {member} add up to {_mib(self.total)}, over the "
                            f"{_mib(MAX_SOURCE_BYTES)} cap on a source (sources.MAX_SOURCE_BYTES); "
                            "not read", self.where)


def _iter_folder(source: Path, kind_of: Callable[[str], str | None],
                 on_skip: Callable[[str], None] | None, admit: _Admit
                 ) -> Iterator[tuple[str, str, bytes]]:
    """:func:`iter_source` over a folder: its files in sorted order, sizes from ``stat``; a
    file given a kind that a symbolic link leads out of the folder (or round a loop) is
    refused."""
    for p in sorted(source.rglob("*")):
        k = kind_of(p.relative_to(source).as_posix())
        if k and not inside(p, source):
            raise DataError(_OUT_OR_LOOP, p)
        if k and p.is_file():
            admit(p.stat().st_size, p.relative_to(source).as_posix(), read=True)
            yield k, str(p), p.read_bytes()
        elif not k and on_skip is not None and p.is_file():
            on_skip(p.relative_to(source).as_posix())


def _broken_archive_errors() -> tuple[type[BaseException], ...]:
    """What reading a damaged or truncated archive raises (tar, xz, gzip and bz2 readers)."""
    import lzma
    import zlib

    return (tarfile.TarError, EOFError, OSError, lzma.LZMAError, zlib.error)


def _open_archive(source: Path):
    """``(raw, tf)``: the archive decompressed as it is read and :mod:`tarfile`'s stream over
    it (with :class:`_CappedTarInfo`); DataError when it is no readable tar archive."""
    broken = _broken_archive_errors()
    raw = None
    try:
        raw = _open_decompressed(source)
        tf = tarfile.open(fileobj=raw, mode="r|", tarinfo=_CappedTarInfo)
    except (_TarCapError, *broken) as e:
        if raw is not None:
            raw.close()
        why = str(e) if isinstance(e, _TarCapError) else f"not a readable tar archive or folder ({e})"
        raise DataError(why, source) from None
    return raw, tf


def _check_member(m: tarfile.TarInfo, count: int, source: Path) -> None:
    """The ``count``-th entry ``m`` of the archive is within :data:`MAX_MEMBERS` and its path
    within :data:`MAX_MEMBER_NAME` characters and :data:`MAX_MEMBER_DEPTH` folders."""
    if count > MAX_MEMBERS:
        raise DataError(f"the archive holds over {MAX_MEMBERS:,} entries, the cap "
                        "(sources.MAX_MEMBERS); not read further", source)
    if len(m.name) > MAX_MEMBER_NAME or m.name.count("/") > MAX_MEMBER_DEPTH:
        raise DataError(f"a member's path of {len(m.name):,} characters and "
                        f"{m.name.count('/'):,} folders is over the cap "
                        f"({MAX_MEMBER_NAME} characters, {MAX_MEMBER_DEPTH} "
                        "folders: sources.MAX_MEMBER_NAME / MAX_MEMBER_DEPTH); "
                        "not read", source)


def _iter_archive(source: Path, kind_of: Callable[[str], str | None],
                  on_skip: Callable[[str], None] | None, admit: _Admit
                  ) -> Iterator[tuple[str, str, bytes]]:
    """:func:`iter_source` over a tar archive: one streamed pass, each member's header checked
    (:func:`_check_member`) and its size admitted before its data is read; a damaged archive
    is a DataError naming it."""
    broken = _broken_archive_errors()
    raw, tf = _open_archive(source)
    try:
        with raw, tf:
            count = 0
            while (m := tf.next()) is not None:
                tf.members = []  # streamed: nothing looks back (tarfile kept every TarInfo)
                count += 1
                _check_member(m, count, source)
                k = kind_of(m.name)
                if m.isfile():  # the header is read; the member's data is not yet
                    admit(m.size, m.name, read=k is not None)
                if k is None and on_skip is not None and not m.isdir():
                    on_skip(m.name)
                if k is None or not m.isfile():
                    continue
                fh = tf.extractfile(m)
                if fh is None:
                    continue
                yield k, f"{source}:{m.name}", fh.read()
    except _TarCapError as e:
        raise DataError(str(e), source) from None
    except (*broken, RecursionError) as e:
        # RecursionError: a chain of thousands of extension headers (tarfile recurses on each)
        raise DataError(f"archive is damaged or truncated ({type(e).__name__}: {e})", source) from None
