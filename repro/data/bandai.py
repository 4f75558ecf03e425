"""The real-mocap stand-in ``bandai2`` (Bandai-Namco-Research-Motiondataset-2, CC BY-NC 4.0).

``prepare_bandai2(source)`` reads the upstream archive straight through :mod:`tarfile` (one
decompression pass, nothing unpacked to disk) or an extracted folder, parses every clip with
:mod:`repro.data.bvh` (a pool of worker processes), converts it to the harness conventions and
publishes a compact cache under ``datasets_root()/bandai2/<fingerprint>/``; ``load_bandai2()``
opens the last prepared cache memory-mapped.

Conversion (the one place where units change; see docs/data.md):

- centimetres -> metres (:data:`CM_TO_M`); Y is already up, axes are kept;
- ``joint_Root`` is checked to be an all-zero dummy (offset and channels) and dropped, so
  ``Hips`` is the root and its position channels are the root translation;
- local rotations are stored exactly as the file gives them (relative to the BVH rest pose, in
  which every bone lies along ±X), as xyzw quaternions (roma), composed intrinsically in channel
  order (``Zrotation Xrotation Yrotation`` -> ``Rz·Rx·Ry``); no re-targeting;
- the position channels of the other joints must equal their OFFSETs (to :data:`POS_TOL_CM`),
  because a ClipSet has one skeleton; joint positions are forward kinematics of the file's own
  channels, in metres;
- every clip must share one skeleton (names, parents, offsets to :data:`OFFSET_TOL_CM`).

A :class:`DatasetCard` records what the data must look like (2,902 clips, 384,931 frames,
10 classes, 7 styles, 30 fps, 21 joints); ``prepare`` fails with a DataError when it disagrees.
The default split (stratified by action and style, 80/20, seeded) is stored with the cache.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import tarfile
import tempfile
import time
from collections import deque
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from repro.errors import DataError, MissingDataError

#: Bump when the conversion changes: it enters the cache fingerprint.
PREPARE_VERSION = 1
#: Layout version of the cache folder (meta.json ``schema``).
SCHEMA = 1
#: The reader boundary's unit change: the BVH files are in centimetres.
CM_TO_M = 0.01
DUMMY_ROOT = "joint_Root"
#: Largest |value| (cm or degrees) tolerated in the dummy root's offset and channels.
DUMMY_TOL = 1e-4
#: Largest distance (cm) between a non-root joint's position channels and its OFFSET.
POS_TOL_CM = 1e-3
#: Largest difference (cm) between a clip's OFFSETs and the first clip's.
OFFSET_TOL_CM = 1e-3
#: Clips per conversion task (rotations and forward kinematics run batched over a task).
BATCH = 16
#: Folders with fewer BVH files than this are parsed in-process (a pool costs seconds to start).
POOL_MIN_FILES = 64
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
ARRAYS = ("rotations", "root", "joints", "starts", "lengths", "labels", "styles", "split")
POINTER = "current.json"

ProgressFn = Callable[[int, "int | None"], None]


# ----------------------------------------------------------------------------- the card
@dataclass(frozen=True)
class DatasetCard:
    """What a prepared data set must look like.  ``None`` counts are not checked (used for
    subsets in tests); names and fps always are."""

    name: str
    clips: int | None
    frames: int | None
    fps: float
    class_names: tuple[str, ...]
    style_names: tuple[str, ...]
    joints: int
    license: str = "CC BY-NC 4.0"
    credit: str = "Bandai Namco Research Inc."

    def to_dict(self) -> dict:
        d = asdict(self)
        d["class_names"] = list(self.class_names)
        d["style_names"] = list(self.style_names)
        return d

    def disagreements(self, *, clips: int, frames: int, fps: float, classes: set[int],
                      styles: set[int], joints: int) -> list[str]:
        bad = []
        if self.clips is not None and clips != self.clips:
            bad.append(f"{clips} clips (card: {self.clips})")
        if self.frames is not None and frames != self.frames:
            bad.append(f"{frames} frames (card: {self.frames})")
        if abs(fps - self.fps) > 1e-3:
            bad.append(f"{fps:g} fps (card: {self.fps:g})")
        if self.clips is not None and len(classes) != len(self.class_names):
            bad.append(f"{len(classes)} classes (card: {len(self.class_names)})")
        if self.clips is not None and len(styles) != len(self.style_names):
            bad.append(f"{len(styles)} styles (card: {len(self.style_names)})")
        if joints != self.joints:
            bad.append(f"{joints} joints after dropping {DUMMY_ROOT} (card: {self.joints})")
        return bad


BANDAI2_CARD = DatasetCard(
    name="bandai2", clips=2902, frames=384931, fps=30.0,
    class_names=("walk", "walk-turn-left", "walk-turn-right", "run", "wave-both-hands",
                 "wave-left-hand", "wave-right-hand", "raise-up-both-hands", "raise-up-left-hand",
                 "raise-up-right-hand"),
    style_names=("active", "elderly", "exhausted", "feminine", "masculine", "normal", "youthful"),
    joints=21,
)


@dataclass
class PrepareResult:
    path: Path
    fingerprint: str
    reused: bool
    seconds: float
    clips: int = 0
    frames: int = 0
    timings: dict = field(default_factory=dict)


# ------------------------------------------------------------------------ locations
def dataset_dir(name: str = "bandai2") -> Path:
    from repro.paths import datasets_root

    return datasets_root() / name


def prepare_command(name: str = "bandai2") -> str:
    """The exact command that prepares ``name`` (for error messages)."""
    from repro.paths import BANDAI_ARCHIVE_NAME, find_bandai_archive, shared_data_dir

    src = find_bandai_archive() or (shared_data_dir() / BANDAI_ARCHIVE_NAME)
    return f"repro data prepare {name} --source {src}"


def source_fingerprint(source: Path) -> str:
    """sha256 of the archive bytes, or for a folder the content key of the sorted
    (relative name, sha256) list of its files."""
    from repro.keys import content_key, sha256_file

    if source.is_dir():
        files = sorted(p for p in source.rglob("*") if _inside(p, source) and p.is_file())
        return content_key([[p.relative_to(source).as_posix(), sha256_file(p)] for p in files])
    return sha256_file(source)


def _inside(path: Path, folder: Path) -> bool:
    """False for a symlink (file or folder on the way) that leads out of ``folder``: a folder
    source reads only what lies inside it (such a link is refused by :func:`_iter_source`)."""
    try:
        return path.resolve().is_relative_to(folder.resolve())
    except OSError:
        return False


def dataset_fingerprint(source_fp: str, card: DatasetCard, split: dict) -> str:
    from repro.keys import content_key

    return content_key({"dataset": card.name, "source": source_fp,
                        "prepare_version": PREPARE_VERSION, "split": split})


# ------------------------------------------------------------------------ the source
def _label_lines(data: bytes) -> list[str]:
    out = []
    for ln in data.decode("utf-8", "replace").splitlines():
        ln = ln.strip()
        if ln:
            out.append(ln.split("_", 1)[1] if ln.startswith("dataset-2_") else ln)
    return out


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
                               "(bandai.MAX_TAR_HEADER_BYTES); not read")
        if self.type == tarfile.GNUTYPE_SPARSE:
            raise _TarCapError(f"{self.name} is a GNU sparse member; re-create the archive "
                               "without --sparse")
        return super()._proc_member(tf)


def _iter_source(source: Path, kind_of: Callable[[str], str | None] | None = None
                 ) -> Iterator[tuple[str, str, bytes]]:
    """Yield (kind, label-for-errors, bytes) for each .bvh, .json and cfg label file (or each
    file to which ``kind_of``, given the path inside the source, gives a kind: a declared
    data set's, :mod:`repro.data.dataset_spec`).

    Sizes are checked before anything is read: a file over :data:`MAX_MEMBER_BYTES`, or a
    source whose files add up to more than :data:`MAX_SOURCE_BYTES`, is a DataError naming the
    archive, the member and the cap (from the tar header's ``size``; for a folder, ``stat``).
    """
    total = 0

    def admit(size: int, where: str, member: str, *, read: bool) -> None:
        nonlocal total
        if read and size > MAX_MEMBER_BYTES:
            raise DataError(f"{member} is {_mib(size)}, over the {_mib(MAX_MEMBER_BYTES)} cap on "
                            "one file (bandai.MAX_MEMBER_BYTES); not read", where)
        total += size
        if total > MAX_SOURCE_BYTES:
            raise DataError(f"the files up to {member} add up to {_mib(total)}, over the "
                            f"{_mib(MAX_SOURCE_BYTES)} cap on a source (bandai.MAX_SOURCE_BYTES); "
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
            if k and not _inside(p, source):
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


def _clip_name(label: str) -> str:
    base = label.rsplit("/", 1)[-1].rsplit(":", 1)[-1]
    return base.rsplit(".", 1)[0]


# ------------------------------------------------------------------------ one clip
def _check_clip(label: str, b) -> tuple[np.ndarray, np.ndarray]:
    """Check one parsed clip against the conversion rules; return its per-frame local
    translations (T, J-1, 3) cm without the dummy root, and its offsets (J-1, 3) cm."""
    if b.names[0] != DUMMY_ROOT:
        raise DataError(f"root joint is {b.names[0]!r}, expected the dummy {DUMMY_ROOT!r}", label)
    kids = [j for j, p in enumerate(b.parents) if p == 0]
    if kids != [1]:
        raise DataError(f"{DUMMY_ROOT} must have exactly one child joint (the hips), has "
                        f"{len(kids)}", label)
    ch0 = len(b.channels[0])
    dev = max(float(np.abs(b.offsets[0]).max()),
              float(np.abs(b.motion[:, :ch0]).max()) if ch0 else 0.0)
    if dev > DUMMY_TOL:
        raise DataError(f"{DUMMY_ROOT} is not an all-zero dummy (offset/channels reach {dev:g}); "
                        f"dropping it would move the body", label)
    if not {"Xposition", "Yposition", "Zposition"} <= set(b.channels[1]):
        raise DataError(f"root joint {b.names[1]!r} lacks X/Y/Zposition channels (root "
                        f"translation)", label)
    trans = b.local_translations()[:, 1:]  # position channels honoured
    offsets = b.offsets[1:].copy()
    offsets[0] = 0.0  # the root's OFFSET is replaced by its position channels
    for j, chans in enumerate(b.channels[2:], start=1):
        if any(c.endswith("position") for c in chans):
            d = float(np.abs(trans[:, j] - offsets[j]).max())
            if d > POS_TOL_CM:
                raise DataError(f"position channels of {b.names[j + 1]!r} move it {d:.4g} cm from "
                                f"its OFFSET; one skeleton per data set is required", label)
    return trans, offsets


def convert_clips(items: list[tuple[str, bytes]]) -> list[dict]:
    """Parse and convert BVH files (module docstring), batching the rotation conversion and
    forward kinematics over all clips that share a hierarchy.  Each result holds numpy arrays
    ``rotations`` (T, J, 4) float32 xyzw, ``root`` (T, 3) float32 m, ``joints`` (T, J, 3)
    float32 m, ``offsets`` (J, 3) float64 cm, plus ``name``, ``label``, ``names``,
    ``parents``, ``frame_time``."""
    import dataclasses

    import roma
    import torch

    from repro.data.bvh import parse_bvh
    from repro.motion.skeleton import Skeleton, forward_kinematics

    parsed = []
    for label, data in items:
        b = parse_bvh(data, label)
        trans, offsets = _check_clip(label, b)
        parsed.append((label, b, trans, offsets))
    groups: dict[tuple, list[int]] = {}
    for i, (_, b, _, _) in enumerate(parsed):
        groups.setdefault((b.names, b.parents, b.channels), []).append(i)
    out: list[dict | None] = [None] * len(parsed)
    for members in groups.values():
        b0 = parsed[members[0]][1]
        lengths = [parsed[i][1].n_frames for i in members]
        motion = np.concatenate([parsed[i][1].motion for i in members])
        q = dataclasses.replace(b0, motion=motion).local_rotations(as_quaternions=True)[:, 1:]
        R = roma.unitquat_to_rotmat(q)
        trans = torch.from_numpy(np.concatenate([parsed[i][2] for i in members]) * CM_TO_M)
        skel = Skeleton(b0.names[1:], tuple(p - 1 for p in b0.parents[1:]),
                        parsed[members[0]][3] * CM_TO_M)
        joints = forward_kinematics(skel, R, trans[:, 0], offsets=trans).numpy().astype(np.float32)
        qn = q.numpy().astype(np.float32)
        root = trans[:, 0].numpy().astype(np.float32)
        s = 0
        for i, n in zip(members, lengths):
            label, b, _, offsets = parsed[i]
            out[i] = {
                "name": _clip_name(label), "label": label,
                "rotations": qn[s:s + n].copy(), "root": root[s:s + n].copy(),
                "joints": joints[s:s + n].copy(), "offsets": offsets,
                "names": skel.names, "parents": skel.parents, "frame_time": b.frame_time,
            }
            s += n
    return out  # type: ignore[return-value]


def convert_clip(label: str, data: bytes) -> dict:
    """:func:`convert_clips` of one file."""
    return convert_clips([(label, data)])[0]


def _worker_init() -> None:
    import torch

    torch.set_num_threads(1)


# ------------------------------------------------------------------------ prepare
def _read_and_convert(source: Path, workers: int, progress: ProgressFn | None, total: int | None,
                      timings: dict):
    """Stream the source once; convert BVH files in ``workers`` processes (0: in-process)."""
    clips: dict[str, dict] = {}
    annotations: dict[str, tuple[str, bytes]] = {}
    label_files: dict[str, tuple[str, bytes]] = {}
    done = 0

    def take(res: dict) -> None:
        nonlocal done
        if res["name"] in clips:
            raise DataError(f"clip {res['name']!r} appears twice in the source", res["label"])
        clips[res["name"]] = res
        done += 1
        if progress is not None:
            progress(done, total)

    t0 = time.perf_counter()
    batch: list[tuple[str, bytes]] = []
    if workers <= 0:
        for kind, label, data in _iter_source(source):
            if kind == "bvh":
                batch.append((label, data))
                if len(batch) == BATCH:
                    for res in convert_clips(batch):
                        take(res)
                    batch = []
            elif kind == "json":
                annotations[_clip_name(label)] = (label, data)
            else:
                label_files[kind] = (label, data)
        for res in convert_clips(batch) if batch else []:
            take(res)
    else:
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        ex = ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn"),
                                 initializer=_worker_init)
        pending: deque = deque()
        try:
            def drain(limit: int) -> None:
                while len(pending) > limit or (pending and pending[0].done()):
                    for res in pending.popleft().result():
                        take(res)

            for kind, label, data in _iter_source(source):
                if kind == "bvh":
                    batch.append((label, data))
                    if len(batch) == BATCH:
                        pending.append(ex.submit(convert_clips, batch))
                        batch = []
                    drain(4 * workers)
                elif kind == "json":
                    annotations[_clip_name(label)] = (label, data)
                else:
                    label_files[kind] = (label, data)
            if batch:
                pending.append(ex.submit(convert_clips, batch))
            drain(0)
        finally:
            ex.shutdown(wait=True, cancel_futures=True)
    timings["read_parse_s"] = time.perf_counter() - t0
    return clips, annotations, label_files


def _labels(clips: dict, annotations: dict, label_files: dict, card: DatasetCard):
    for kind, names in (("content_label.txt", card.class_names), ("style_label.txt", card.style_names)):
        if kind in label_files:
            lbl, data = label_files[kind]
            got = _label_lines(data)
            if tuple(got) != tuple(names):
                raise DataError(f"label list {got} disagrees with the {card.name} card {list(names)}", lbl)
    order = sorted(clips)
    labels = np.empty(len(order), np.int64)
    styles = np.empty(len(order), np.int64)
    for i, name in enumerate(order):
        res = clips[name]
        if name not in annotations:
            raise DataError(f"no annotation {name}.json beside the BVH file", res["label"])
        lbl, data = annotations[name]
        try:
            ann = json.loads(data)
            c, s = int(ann["content"]), int(ann["style"])
        except (ValueError, KeyError, TypeError) as e:
            raise DataError(f"annotation must be JSON with integer 'content' and 'style' ({e})",
                            lbl) from None
        if not (0 <= c < len(card.class_names) and 0 <= s < len(card.style_names)):
            raise DataError(f"content {c} / style {s} out of range", lbl)
        parts = name.split("_")
        if len(parts) != 4 or parts[1] != card.class_names[c] or parts[2] != card.style_names[s]:
            raise DataError(f"file name disagrees with its annotation (content {c} = "
                            f"{card.class_names[c]!r}, style {s} = {card.style_names[s]!r}); "
                            f"expected dataset-2_{{content}}_{{style}}_{{NNN}}", res["label"])
        labels[i], styles[i] = c, s
    return order, labels, styles


def _publish(tmp: Path, final: Path) -> None:
    """Move the finished ``tmp`` folder to ``final`` atomically; a damaged ``final`` (no valid
    meta.json) is moved aside first and then removed."""
    if final.exists():
        trash = final.with_name(f".trash-{final.name}-{os.getpid()}-{time.time_ns()}")
        os.replace(final, trash)
        os.replace(tmp, final)
        shutil.rmtree(trash, ignore_errors=True)
    else:
        os.replace(tmp, final)


def _write_json_atomic(path: Path, obj) -> None:
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            json.dump(obj, fh, indent=1, sort_keys=True)
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _valid_cache(path: Path) -> dict | None:
    try:
        meta = json.loads((path / "meta.json").read_text())
    except (OSError, ValueError):
        return None
    if meta.get("schema") != SCHEMA or meta.get("prepare_version") != PREPARE_VERSION:
        return None
    if not all((path / f"{a}.npy").is_file() for a in ARRAYS):
        return None
    return meta


def write_cache(root: Path, fp: str, arrays: dict[str, np.ndarray], meta: dict, *,
                replace: bool = True) -> Path:
    """Publish ``arrays`` (the :data:`ARRAYS`) and ``meta`` as ``root/fp/`` atomically: built in
    a temporary folder beside it, then renamed, so readers never see a half-written cache and a
    failure leaves any existing one untouched.  With ``replace=False`` a valid cache already
    at ``root/fp`` (e.g. published meanwhile by another process) is kept and ours discarded."""
    root.mkdir(parents=True, exist_ok=True)
    final = root / fp
    tmp = Path(tempfile.mkdtemp(prefix=f".tmp-{fp[:12]}-", dir=root))
    try:
        os.chmod(tmp, 0o755)
        for k in ARRAYS:
            np.save(tmp / f"{k}.npy", arrays[k], allow_pickle=False)
        meta = {**meta, "schema": SCHEMA, "prepare_version": PREPARE_VERSION, "fingerprint": fp}
        (tmp / "meta.json").write_text(json.dumps(meta, indent=1, sort_keys=True))
        if replace:
            _publish(tmp, final)
        else:
            try:
                os.replace(tmp, final)
            except OSError:
                if _valid_cache(final) is None:
                    raise
                shutil.rmtree(tmp, ignore_errors=True)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return final


def prepare_bandai2(source: str | Path, *, card: DatasetCard = BANDAI2_CARD, workers: int = 2,
                    force: bool = False, progress: ProgressFn | None = None,
                    split_seed: int | None = None, test_fraction: float | None = None
                    ) -> PrepareResult:
    """Parse ``source`` (the upstream .tar.xz or an extracted folder) into the cache.

    The cache is rebuilt only when absent, damaged or ``force``; it is built in a temporary
    folder beside the target and moved into place, so a failure leaves any existing cache intact.
    """
    from filelock import FileLock

    from repro.data.splits import DEFAULT_SPLIT_SEED, DEFAULT_TEST_FRACTION, stratified_split
    from repro.motion.skeleton import Skeleton

    t_start = time.perf_counter()
    source = Path(source).expanduser()
    if not source.exists():
        raise MissingDataError(f"source not found; get {card.name}'s archive (see "
                               f"../shared/data/bandai-namco-2/SOURCE.md) and pass --source", source)
    split_cfg = {"method": "stratified(action, style)",
                 "seed": DEFAULT_SPLIT_SEED if split_seed is None else int(split_seed),
                 "test_fraction": DEFAULT_TEST_FRACTION if test_fraction is None else float(test_fraction)}
    timings: dict = {}
    t0 = time.perf_counter()
    src_fp = source_fingerprint(source)
    timings["fingerprint_s"] = time.perf_counter() - t0
    fp = dataset_fingerprint(src_fp, card, split_cfg)
    root = dataset_dir(card.name)
    root.mkdir(parents=True, exist_ok=True)
    final = root / fp
    with FileLock(str(root / ".lock")):
        meta = None if force else _valid_cache(final)
        if meta is not None:
            _write_json_atomic(root / POINTER, {"fingerprint": fp, "source": str(source)})
            return PrepareResult(final, fp, True, time.perf_counter() - t_start,
                                 len(meta["clip_names"]), int(meta["stats"]["frames"]), timings)
        if source.is_dir():
            n_total = sum(1 for _ in source.rglob("*.bvh"))
            w = workers if n_total >= POOL_MIN_FILES else 0
        else:
            n_total, w = card.clips, workers
        clips, annotations, label_files = _read_and_convert(source, w, progress, n_total, timings)
        if not clips:
            raise DataError("no .bvh files found", source)
        t0 = time.perf_counter()
        order, labels, styles = _labels(clips, annotations, label_files, card)
        first = clips[order[0]]
        for name in order[1:]:
            c = clips[name]
            if c["names"] != first["names"] or c["parents"] != first["parents"]:
                raise DataError(f"hierarchy differs from {order[0]}'s; one skeleton per data set "
                                f"is required", c["label"])
            d = float(np.abs(c["offsets"] - first["offsets"]).max())
            if d > OFFSET_TOL_CM:
                raise DataError(f"OFFSETs differ from {order[0]}'s by up to {d:.4g} cm; one "
                                f"skeleton per data set is required", c["label"])
            if abs(c["frame_time"] - first["frame_time"]) > 1e-9:
                raise DataError(f"Frame Time {c['frame_time']:g} differs from {order[0]}'s "
                                f"{first['frame_time']:g}", c["label"])
        lengths = np.array([clips[n]["root"].shape[0] for n in order], np.int64)
        starts = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64)
        fps = round(1.0 / first["frame_time"], 3)
        bad = card.disagreements(clips=len(order), frames=int(lengths.sum()), fps=fps,
                                 classes=set(labels.tolist()), styles=set(styles.tolist()),
                                 joints=len(first["names"]))
        if bad:
            raise DataError(f"the data disagrees with the {card.name} dataset card: "
                            + "; ".join(bad), source)
        split = stratified_split(labels, styles, test_fraction=split_cfg["test_fraction"],
                                 seed=split_cfg["seed"])
        skel = Skeleton(first["names"], first["parents"], first["offsets"] * CM_TO_M)
        arrays = {
            "rotations": np.concatenate([clips[n]["rotations"] for n in order]),
            "root": np.concatenate([clips[n]["root"] for n in order]),
            "joints": np.concatenate([clips[n]["joints"] for n in order]),
            "starts": starts, "lengths": lengths, "labels": labels, "styles": styles,
            "split": split,
        }
        clips.clear()
        from repro import __version__

        meta = {
            "schema": SCHEMA, "name": card.name, "prepare_version": PREPARE_VERSION,
            "fingerprint": fp, "source_fingerprint": src_fp,
            "source_kind": "folder" if source.is_dir() else "archive",
            "fps": fps, "skeleton": skel.to_dict(), "units": "metres, Y up",
            "rotations": "local, xyzw, relative to the BVH rest pose (bones along ±X)",
            "label_names": list(card.class_names), "style_names": list(card.style_names),
            "clip_names": order, "split": split_cfg, "card": card.to_dict(),
            "stats": {"clips": len(order), "frames": int(lengths.sum())},
            "repro_version": __version__,
        }
        write_cache(root, fp, arrays, meta)
        del arrays
        _write_json_atomic(root / POINTER, {"fingerprint": fp, "source": str(source)})
        timings["assemble_write_s"] = time.perf_counter() - t0
    return PrepareResult(final, fp, False, time.perf_counter() - t_start, len(order),
                         int(lengths.sum()), timings)


# ------------------------------------------------------------------------ validate
#: Largest deviation from unit length tolerated in the sampled rotations (float32 xyzw).
UNIT_TOL = 1e-3


def _npy_header(path: Path) -> tuple[tuple[int, ...], np.dtype, int]:
    """(shape, dtype, bytes the header implies for the whole file) of a ``.npy``, reading
    only its header; ValueError/OSError if it is not one."""
    fmt = np.lib.format
    with open(path, "rb") as fh:
        version = fmt.read_magic(fh)
        if version == (1, 0):
            shape, _, dtype = fmt.read_array_header_1_0(fh)
        elif version == (2, 0):
            shape, _, dtype = fmt.read_array_header_2_0(fh)
        else:
            raise ValueError(f"unsupported .npy version {version}")
        offset = fh.tell()
    if dtype.hasobject:
        raise ValueError("holds Python objects")
    return shape, dtype, offset + math.prod(shape) * dtype.itemsize


def cache_problem(path: Path) -> str | None:
    """Why the prepared cache folder ``path`` (see :func:`write_cache`) is damaged, as
    ``"<file>: <problem>"``; ``None`` when it reads back intact.  Used by ``repro doctor``.

    Cheap, nothing but headers and the per-clip arrays is read: ``meta.json`` parses, is this
    version's and names the folder's fingerprint; every ``.npy`` has a readable header, a
    numeric dtype, the shape ``meta.json`` implies (clips, frames, joints) and exactly the size
    its header implies (a truncated or padded file fails); the per-clip arrays agree (starts are
    the running sum of lengths, labels and styles name existing classes, split is 0/1); the
    first and last frame hold unit quaternions and finite positions (a file zero-filled after
    a crash fails).
    """
    meta_p = path / "meta.json"
    try:
        meta = json.loads(meta_p.read_text())
    except OSError as e:
        return f"{meta_p}: cannot be read ({e.strerror or e})"
    except ValueError as e:
        return f"{meta_p}: not valid JSON ({e})"
    try:
        if meta.get("schema") != SCHEMA or meta.get("prepare_version") != PREPARE_VERSION:
            return (f"{meta_p}: schema {repr(meta.get('schema'))[:20]} / prepare version "
                    f"{repr(meta.get('prepare_version'))[:20]}, this version reads {SCHEMA} / "
                    f"{PREPARE_VERSION}")
        if meta.get("fingerprint") != path.name:
            return f"{meta_p}: fingerprint {str(meta.get('fingerprint'))[:16]!r} is not the folder's"
        n_clips = len(meta["clip_names"])
        n_joints = len(meta["skeleton"]["names"])
        n_labels, n_styles = len(meta["label_names"]), len(meta["style_names"])
    except (AttributeError, KeyError, TypeError) as e:
        return f"{meta_p}: lacks or garbles {str(e)[:100]} (expected the keys write_cache writes)"
    heads = {}
    for k in ARRAYS:
        f = path / f"{k}.npy"
        try:
            shape, dtype, want = heads[k] = _npy_header(f)
            have = f.stat().st_size
        except (OSError, ValueError, SyntaxError, TypeError, RecursionError) as e:
            return f"{f}: not a readable .npy ({type(e).__name__}: {str(e)[:200]})"
        if have != want:
            return f"{f}: {have} bytes, its header ({dtype.str} {shape}) implies {want} (truncated?)"
        if dtype.kind not in ("f" if k in ("rotations", "root", "joints") else "iu"):
            return f"{f}: dtype {dtype.str} is not what prepare writes"
    small = {}
    for k in ("starts", "lengths", "labels", "styles", "split"):
        f = path / f"{k}.npy"
        if heads[k][0] != (n_clips,):
            return f"{f}: shape {heads[k][0]}, meta.json names {n_clips} clips"
        try:
            small[k] = np.load(f, allow_pickle=False)
        except (OSError, ValueError) as e:
            return f"{f}: not a readable .npy ({e})"
    lengths = small["lengths"].astype(np.int64)
    frames = int(lengths.sum())
    if n_clips and lengths.min() < 1:
        return f"{path / 'lengths.npy'}: a clip has {int(lengths.min())} frames"
    if not np.array_equal(small["starts"], np.concatenate([[0], np.cumsum(lengths)[:-1]])
                          if n_clips else small["starts"]):
        return f"{path / 'starts.npy'}: not the running sum of lengths.npy"
    stats = meta.get("stats")
    stated = stats.get("frames") if isinstance(stats, dict) else None
    if stated is not None and stated != frames:
        return f"{path / 'lengths.npy'}: {frames} frames in all, meta.json says {str(stated)[:20]}"
    for k, hi, lo in (("labels", n_labels, 0), ("styles", n_styles, -1), ("split", 2, 0)):
        a = small[k]
        if n_clips and (a.min() < lo or a.max() >= hi):
            return f"{path / f'{k}.npy'}: values {int(a.min())}..{int(a.max())} outside {lo}..{hi - 1}"
    for k, tail in (("rotations", (n_joints, 4)), ("root", (3,)), ("joints", (n_joints, 3))):
        if heads[k][0] != (frames, *tail):
            return f"{path / f'{k}.npy'}: shape {heads[k][0]}, expected {(frames, *tail)}"
    if frames:
        try:
            q = np.load(path / "rotations.npy", mmap_mode="r")[[0, frames - 1]]
            x = np.concatenate([np.load(path / f"{k}.npy", mmap_mode="r")[[0, frames - 1]]
                                .reshape(2, -1) for k in ("root", "joints")], axis=1)
        except (OSError, ValueError) as e:
            return f"{path}: cannot be read ({e})"
        dev = float(np.abs(np.linalg.norm(q.astype(np.float64), axis=-1) - 1).max())
        if not dev <= UNIT_TOL:
            return f"{path / 'rotations.npy'}: first/last frame rotations are not unit quaternions"
        if not np.isfinite(x).all():
            return f"{path}: non-finite positions in the first/last frame of root/joints.npy"
    return None


def prepared_problem(name: str = "bandai2", rebuild: str | None = None) -> str | None:
    """Why the last prepared cache of ``name`` is damaged (file named, with the command that
    rebuilds it: ``rebuild``, default :func:`prepare_command` + ``--force``); ``None`` when it
    is intact or was never prepared.  See :func:`cache_problem`.  Any data set prepared with
    :func:`write_cache` can register it as its ``DatasetEntry.validate_fn``."""
    root = dataset_dir(name)
    ptr = root / POINTER
    if not ptr.exists():
        return None
    fix = f"; rebuild with: {rebuild or prepare_command(name) + ' --force'}"
    try:
        fp = json.loads(ptr.read_text())["fingerprint"]
        if not isinstance(fp, str) or not fp or "/" in fp or fp.startswith("."):
            raise TypeError("fingerprint is not a folder name")
    except (OSError, ValueError, KeyError, TypeError) as e:
        return f"{ptr}: cannot be read ({type(e).__name__}: {e}){fix}"
    if not (root / fp).is_dir():
        return f"{root / fp}: the prepared cache {POINTER} points to is gone{fix}"
    why = cache_problem(root / fp)
    return None if why is None else why + fix


# ------------------------------------------------------------------------ load
def current_cache(name: str = "bandai2") -> tuple[Path, dict] | None:
    """(folder, meta) of the last prepared cache of ``name``, or ``None``."""
    root = dataset_dir(name)
    try:
        ptr = json.loads((root / POINTER).read_text())
        path = root / str(ptr["fingerprint"])
    except (OSError, ValueError, KeyError, TypeError):
        return None
    meta = _valid_cache(path)
    return None if meta is None else (path, meta)


def load_bandai2(name: str = "bandai2", mmap: bool = True):
    """The last prepared cache as a :class:`~repro.data.clipset.ClipSet` (arrays memory-mapped,
    read-only).  Raises MissingDataError naming the prepare command when there is none."""
    found = current_cache(name)
    if found is None:
        raise MissingDataError(f"data set {name!r} is not prepared (or was prepared by an older "
                               f"version); run: {prepare_command(name)}", dataset_dir(name))
    path, meta = found
    return open_cache(path, meta, name, mmap=mmap)


def open_cache(path: Path, meta: dict, name: str, mmap: bool = True):
    """The ClipSet stored in the cache folder ``path`` (see :func:`write_cache`)."""
    from repro.data.clipset import ClipSet
    from repro.motion.skeleton import Skeleton

    arrs = {}
    for k in ARRAYS:
        try:
            arrs[k] = np.load(path / f"{k}.npy", mmap_mode="r" if mmap else None, allow_pickle=False)
        except (OSError, ValueError) as e:
            raise DataError(f"prepared cache is damaged ({e}); run: {prepare_command(name)} --force",
                            path / f"{k}.npy") from None
    return ClipSet(
        name=name, skeleton=Skeleton.from_dict(meta["skeleton"]), fps=float(meta["fps"]),
        rotations=arrs["rotations"], root=arrs["root"], joints=arrs["joints"],
        starts=arrs["starts"], lengths=arrs["lengths"], labels=arrs["labels"],
        label_names=tuple(meta["label_names"]), styles=arrs["styles"],
        style_names=tuple(meta["style_names"]), clip_names=tuple(meta["clip_names"]),
        split=arrs["split"], fingerprint=meta["fingerprint"],
    )
