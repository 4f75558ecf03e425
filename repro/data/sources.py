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


def source_fingerprint(source: Path, select: Callable[[str], object] | None = None) -> str:
    """sha256 of the archive bytes, or for a folder the content key of the sorted
    (relative name, sha256) list of its files (those ``select``, given the path inside the
    folder, accepts: a declared data set's clips and ASF; default every file).  A folder
    holding a symbolic link that leads out of it is refused here, before any cached copy could
    be reused (DataError naming it)."""
    from repro.keys import content_key, sha256_file

    if source.is_dir():
        entries = sorted(source.rglob("*"))
        out = next((p for p in entries if not inside(p, source)), None)
        if out is not None:
            raise DataError("a symbolic link that leads out of the source folder (copy the "
                            "file in instead)", out)
        files = [p for p in entries if p.is_file()
                 and (select is None or select(p.relative_to(source).as_posix()))]
        return content_key([[p.relative_to(source).as_posix(), sha256_file(p)] for p in files])
    return sha256_file(source)


def inside(path: Path, folder: Path) -> bool:
    """False for a symlink (file or folder on the way) that leads out of ``folder``: a folder
    source reads only what lies inside it (such a link is refused by :func:`iter_source`)."""
    try:
        return path.resolve().is_relative_to(folder.resolve())
    except OSError:
        return False


def _mib(n: int) -> str:
    return f"{n / 1024 ** 2:,.1f} MiB"


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


def iter_source(source: Path, kind_of: Callable[[str], str | None] | None = None
                ) -> Iterator[tuple[str, str, bytes]]:
    """Yield (kind, label-for-errors, bytes) for each .bvh, .json and cfg label file (the
    built-in stand-in's kinds; or each file to which ``kind_of``, given the path inside the
    source, gives a kind: a declared data set's, :mod:`repro.data.dataset_spec`).

    Sizes are checked before anything is read: a file over :data:`MAX_MEMBER_BYTES`, or a
    source whose files add up to more than :data:`MAX_SOURCE_BYTES`, is a DataError naming the
    archive, the member and the cap (from the tar header's ``size``; for a folder, ``stat``).
    """
    total = 0

    def admit(size: int, where: str, member: str, *, read: bool) -> None:
        nonlocal total
        if read and size > MAX_MEMBER_BYTES:
            raise DataError(f"{member} is {_mib(size)}, over the {_mib(MAX_MEMBER_BYTES)} cap on "
                            "one file (sources.MAX_MEMBER_BYTES); not read", where)
        total += size
        if total > MAX_SOURCE_BYTES:
            raise DataError(f"the files up to {member} add up to {_mib(total)}, over the "
                            f"{_mib(MAX_SOURCE_BYTES)} cap on a source (sources.MAX_SOURCE_BYTES); "
                            "not read", where)

    def bandai_kind(name: str) -> str | None:
        base = name.rsplit("/", 1)[-1]
        if base.endswith(".bvh"):
            return "bvh"
        if base.endswith(".json"):
            return "json"
        if base in ("content_label.txt", "style_label.txt"):
            return base
        return None

    kind_of = kind_of or bandai_kind
    if source.is_dir():
        for p in sorted(source.rglob("*")):
            k = kind_of(p.relative_to(source).as_posix())
            if k and not inside(p, source):
                raise DataError("a symbolic link that leads out of the source folder (copy "
                                "the file in instead)", p)
            if k and p.is_file():
                admit(p.stat().st_size, str(source), p.relative_to(source).as_posix(),
                      read=True)
                yield k, str(p), p.read_bytes()
        return
    import lzma
    import zlib

    broken = (tarfile.TarError, EOFError, OSError, lzma.LZMAError, zlib.error)
    raw = None
    try:
        raw = _open_decompressed(source)
        tf = tarfile.open(fileobj=raw, mode="r|", tarinfo=_CappedTarInfo)
    except (_TarCapError, *broken) as e:
        if raw is not None:
            raw.close()
        why = str(e) if isinstance(e, _TarCapError) else f"not a readable tar archive or folder ({e})"
        raise DataError(why, source) from None
    try:
        with raw, tf:
            for m in tf:
                k = kind_of(m.name)
                if m.isfile():  # the header is read; the member's data is not yet
                    admit(m.size, str(source), m.name, read=k is not None)
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
