"""The prepared-cache layout every prepared data set shares.

A prepared data set lives under ``datasets_root()/<name>/`` (:func:`dataset_dir`): one folder
per fingerprint holding the :data:`ARRAYS` as ``.npy`` files and a ``meta.json`` (stamped with
:data:`SCHEMA`, :data:`CACHE_VERSION` and the fingerprint), plus :data:`POINTER`
(``current.json``) naming the last prepared fingerprint.  This module writes such a folder
atomically (:func:`write_cache`, :func:`write_json_atomic`), tells whether one is complete
(:func:`valid_cache`) or damaged and why (:func:`cache_problem`, :func:`prepared_problem`,
used by ``repro doctor``), and opens it as a :class:`~repro.data.clipset.ClipSet`
(:func:`current_cache`, :func:`open_cache`).  Its writers: the built-in stand-in
(:mod:`repro.data.bandai`), declared data sets (:mod:`repro.data.dataset_spec`) and the
unpacked ``bandai2-mini`` bundle (:mod:`repro.data.bundle`).  It imports none of them: a
message that names the command preparing a data set takes it from the caller (``command``).
"""

from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from repro.errors import DataError

#: Layout version of the cache folder (meta.json ``schema``).
SCHEMA = 1
#: The ``prepare_version`` :func:`write_cache` stamps into every meta.json and that
#: :func:`valid_cache` / :func:`cache_problem` accept: bumping it invalidates every prepared
#: cache (each data set's own conversion version enters its fingerprint instead, e.g.
#: :data:`repro.data.bandai.PREPARE_VERSION`).
CACHE_VERSION = 1
ARRAYS = ("rotations", "root", "joints", "starts", "lengths", "labels", "styles", "split")
POINTER = "current.json"
#: Largest deviation from unit length tolerated in the sampled rotations (float32 xyzw).
UNIT_TOL = 1e-3


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


# ------------------------------------------------------------------------ write


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


def write_json_atomic(path: Path, obj) -> None:
    """Write ``obj`` as JSON to ``path`` atomically (:func:`repro.store.atomic.
    atomic_write_bytes`; used for :data:`POINTER`)."""
    from repro.store.atomic import atomic_write_bytes

    atomic_write_bytes(path, json.dumps(obj, indent=1, sort_keys=True).encode("utf-8"),
                       mode=0o644)


def valid_cache(path: Path) -> dict | None:
    """The meta of the cache folder ``path`` when it is this layout's and complete (a cheap
    check: meta.json and the file names; :func:`cache_problem` reads further), else ``None``."""
    try:
        meta = json.loads((path / "meta.json").read_text())
    except (OSError, ValueError):
        return None
    if meta.get("schema") != SCHEMA or meta.get("prepare_version") != CACHE_VERSION:
        return None
    if not all((path / f"{a}.npy").is_file() for a in ARRAYS):
        return None
    return meta


def first_non_finite(a: np.ndarray) -> tuple[int, int] | None:
    """``(count, first frame)`` of the NaN and infinite values of a float array (frames along
    its first axis), or None when it has none (also for an array that is not float).  The one
    finiteness check: :func:`write_cache` and :func:`repro.data.prepare_caps.check_finite` use
    it (a float64 value over 3.4e38 is infinite once stored as float32: check as stored)."""
    a = np.asarray(a)
    if a.dtype.kind != "f" or a.size == 0 or np.isfinite(a).all():
        return None
    bad = ~np.isfinite(a.reshape(len(a), -1) if a.ndim else a.reshape(1, 1))
    return int(bad.sum()), int(np.argmax(bad.any(axis=1)))


def _check_finite(arrays: dict[str, np.ndarray], meta: dict, where: Path) -> None:
    """A DataError naming the first clip (``meta["clip_names"]``, by ``arrays["starts"]``) whose
    frames hold a non-finite value in a float array (:func:`first_non_finite`): nothing
    non-finite is published."""
    for k in ARRAYS:
        found = first_non_finite(arrays[k])
        if found is None:
            continue
        row = found[1]
        starts = np.asarray(arrays.get("starts", [0]))
        clip = max(int(np.searchsorted(starts, row, side="right")) - 1, 0)
        names = meta.get("clip_names") or []
        name = names[clip] if clip < len(names) else f"#{clip}"
        raise DataError(f"clip {str(name)[:80]!r}: non-finite values in {k} (frame "
                        f"{row - int(starts[clip]) + 1 if clip < len(starts) else row + 1} of "
                        "the clip); nothing was published", where)


def write_cache(root: Path, fp: str, arrays: dict[str, np.ndarray], meta: dict, *,
                replace: bool = True) -> Path:
    """Publish ``arrays`` (the :data:`ARRAYS`) and ``meta`` as ``root/fp/`` atomically: built in
    a temporary folder beside it, then renamed, so readers never see a half-written cache and a
    failure leaves any existing one untouched.  With ``replace=False`` a valid cache already
    at ``root/fp`` (e.g. published meanwhile by another process) is kept and ours discarded.
    Arrays holding a NaN or an infinity are refused before anything is written (issue 29)."""
    _check_finite(arrays, meta, root / fp)
    root.mkdir(parents=True, exist_ok=True)
    final = root / fp
    tmp = Path(tempfile.mkdtemp(prefix=f".tmp-{fp[:12]}-", dir=root))
    try:
        os.chmod(tmp, 0o755)
        for k in ARRAYS:
            np.save(tmp / f"{k}.npy", arrays[k], allow_pickle=False)
        meta = {**meta, "schema": SCHEMA, "prepare_version": CACHE_VERSION, "fingerprint": fp}
        (tmp / "meta.json").write_text(json.dumps(meta, indent=1, sort_keys=True))
        if replace:
            _publish(tmp, final)
        else:
            try:
                os.replace(tmp, final)
            except OSError:
                if valid_cache(final) is None:
                    raise
                shutil.rmtree(tmp, ignore_errors=True)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return final


# ------------------------------------------------------------------------ validate
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


class _Damaged(Exception):
    """A problem :func:`cache_problem` reports, ``"<file>: <problem>"``, raised by its checks."""


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
    try:
        meta, n_clips, n_joints, n_labels, n_styles = _meta_problem(path)
        heads = _header_problem(path)
        small = _clip_arrays(path, heads, n_clips)
        frames = _clip_array_problem(path, meta, small, n_clips, n_labels, n_styles)
        _frame_array_problem(path, heads, frames, n_joints)
    except _Damaged as e:
        return str(e)
    return None


def _meta_problem(path: Path) -> tuple[dict, int, int, int, int]:
    """``meta.json`` parsed, this version's and naming the folder's fingerprint: (meta, clips,
    joints, classes, styles) it names; :class:`_Damaged` otherwise."""
    meta_p = path / "meta.json"
    try:
        meta = json.loads(meta_p.read_text())
    except OSError as e:
        raise _Damaged(f"{meta_p}: cannot be read ({e.strerror or e})") from None
    except ValueError as e:
        raise _Damaged(f"{meta_p}: not valid JSON ({e})") from None
    try:
        if meta.get("schema") != SCHEMA or meta.get("prepare_version") != CACHE_VERSION:
            raise _Damaged(f"{meta_p}: schema {repr(meta.get('schema'))[:20]} / prepare version "
                           f"{repr(meta.get('prepare_version'))[:20]}, this version reads "
                           f"{SCHEMA} / {CACHE_VERSION}")
        if meta.get("fingerprint") != path.name:
            raise _Damaged(f"{meta_p}: fingerprint {str(meta.get('fingerprint'))[:16]!r} is not "
                           "the folder's")
        n_clips = len(meta["clip_names"])
        n_joints = len(meta["skeleton"]["names"])
        n_labels, n_styles = len(meta["label_names"]), len(meta["style_names"])
    except (AttributeError, KeyError, TypeError) as e:
        raise _Damaged(f"{meta_p}: lacks or garbles {str(e)[:100]} (expected the keys "
                       "write_cache writes)") from None
    return meta, n_clips, n_joints, n_labels, n_styles


def _header_problem(path: Path) -> dict:
    """Every ``.npy`` of :data:`ARRAYS` with a readable header, exactly the size it implies and
    a dtype prepare writes: their (shape, dtype, size) by name; :class:`_Damaged` otherwise."""
    heads = {}
    for k in ARRAYS:
        f = path / f"{k}.npy"
        try:
            shape, dtype, want = heads[k] = _npy_header(f)
            have = f.stat().st_size
        except (OSError, ValueError, SyntaxError, TypeError, RecursionError) as e:
            raise _Damaged(f"{f}: not a readable .npy ({type(e).__name__}: {str(e)[:200]})") \
                from None
        if have != want:
            raise _Damaged(f"{f}: {have} bytes, its header ({dtype.str} {shape}) implies {want} "
                           "(truncated?)")
        if dtype.kind not in ("f" if k in ("rotations", "root", "joints") else "iu"):
            raise _Damaged(f"{f}: dtype {dtype.str} is not what prepare writes")
    return heads


def _clip_arrays(path: Path, heads: dict, n_clips: int) -> dict[str, np.ndarray]:
    """The per-clip arrays, each of one value per clip ``meta.json`` names, loaded;
    :class:`_Damaged` otherwise."""
    small = {}
    for k in ("starts", "lengths", "labels", "styles", "split"):
        f = path / f"{k}.npy"
        if heads[k][0] != (n_clips,):
            raise _Damaged(f"{f}: shape {heads[k][0]}, meta.json names {n_clips} clips")
        try:
            small[k] = np.load(f, allow_pickle=False)
        except (OSError, ValueError) as e:
            raise _Damaged(f"{f}: not a readable .npy ({e})") from None
    return small


def _clip_array_problem(path: Path, meta: dict, small: dict[str, np.ndarray], n_clips: int,
                        n_labels: int, n_styles: int) -> int:
    """The per-clip arrays agree (lengths positive, starts their running sum, the frames
    ``meta.json`` states, labels / styles / split in range): the frames in all;
    :class:`_Damaged` otherwise."""
    lengths = small["lengths"].astype(np.int64)
    frames = int(lengths.sum())
    if n_clips and lengths.min() < 1:
        raise _Damaged(f"{path / 'lengths.npy'}: a clip has {int(lengths.min())} frames")
    if not np.array_equal(small["starts"], np.concatenate([[0], np.cumsum(lengths)[:-1]])
                          if n_clips else small["starts"]):
        raise _Damaged(f"{path / 'starts.npy'}: not the running sum of lengths.npy")
    stats = meta.get("stats")
    stated = stats.get("frames") if isinstance(stats, dict) else None
    if stated is not None and stated != frames:
        raise _Damaged(f"{path / 'lengths.npy'}: {frames} frames in all, meta.json says "
                       f"{str(stated)[:20]}")
    for k, hi, lo in (("labels", n_labels, 0), ("styles", n_styles, -1), ("split", 2, 0)):
        a = small[k]
        if n_clips and (a.min() < lo or a.max() >= hi):
            raise _Damaged(f"{path / f'{k}.npy'}: values {int(a.min())}..{int(a.max())} outside "
                           f"{lo}..{hi - 1}")
    return frames


def _frame_array_problem(path: Path, heads: dict, frames: int, n_joints: int) -> None:
    """The per-frame arrays have ``frames`` rows of ``n_joints`` joints, and their first and
    last frame hold unit quaternions and finite positions; :class:`_Damaged` otherwise."""
    for k, tail in (("rotations", (n_joints, 4)), ("root", (3,)), ("joints", (n_joints, 3))):
        if heads[k][0] != (frames, *tail):
            raise _Damaged(f"{path / f'{k}.npy'}: shape {heads[k][0]}, expected "
                           f"{(frames, *tail)}")
    if frames:
        try:
            q = np.load(path / "rotations.npy", mmap_mode="r")[[0, frames - 1]]
            x = np.concatenate([np.load(path / f"{k}.npy", mmap_mode="r")[[0, frames - 1]]
                                .reshape(2, -1) for k in ("root", "joints")], axis=1)
        except (OSError, ValueError) as e:
            raise _Damaged(f"{path}: cannot be read ({e})") from None
        dev = float(np.abs(np.linalg.norm(q.astype(np.float64), axis=-1) - 1).max())
        if not dev <= UNIT_TOL:
            raise _Damaged(f"{path / 'rotations.npy'}: first/last frame rotations are not unit "
                           "quaternions")
        if not np.isfinite(x).all():
            raise _Damaged(f"{path}: non-finite positions in the first/last frame of "
                           "root/joints.npy")


def prepared_problem(name: str = "bandai2", rebuild: str | None = None, *,
                     command: Callable[[str], str] | None = None) -> str | None:
    """Why the last prepared cache of ``name`` is damaged (file named, with the command that
    rebuilds it: ``rebuild``, else ``command(name)`` + ``--force``, ``command`` naming the data
    set's prepare command, e.g. :func:`repro.data.dataset_registration.prepare_command`);
    ``None`` when it is intact or was never prepared.  See :func:`cache_problem`.  Any data set
    prepared with :func:`write_cache` can register it as its ``DatasetEntry.validate_fn``."""
    root = dataset_dir(name)
    ptr = root / POINTER
    if not ptr.exists():
        return None
    fix = f"; rebuild with: {rebuild or command(name) + ' --force'}"
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
    meta = valid_cache(path)
    return None if meta is None else (path, meta)


def open_cache(path: Path, meta: dict, name: str, mmap: bool = True, *,
               command: Callable[[str], str]):
    """The ClipSet stored in the cache folder ``path`` (see :func:`write_cache`); a file that
    cannot be read is a DataError naming ``command(name) --force`` (``command``: the data
    set's prepare command, e.g. :func:`repro.data.dataset_registration.prepare_command`)."""
    from repro.data.clipset import ClipSet
    from repro.motion.skeleton import Skeleton

    arrs = {}
    for k in ARRAYS:
        try:
            arrs[k] = np.load(path / f"{k}.npy", mmap_mode="r" if mmap else None, allow_pickle=False)
        except (OSError, ValueError) as e:
            raise DataError(f"prepared cache is damaged ({e}); run: {command(name)} --force",
                            path / f"{k}.npy") from None
    return ClipSet(
        name=name, skeleton=Skeleton.from_dict(meta["skeleton"]), fps=float(meta["fps"]),
        rotations=arrs["rotations"], root=arrs["root"], joints=arrs["joints"],
        starts=arrs["starts"], lengths=arrs["lengths"], labels=arrs["labels"],
        label_names=tuple(meta["label_names"]), styles=arrs["styles"],
        style_names=tuple(meta["style_names"]), clip_names=tuple(meta["clip_names"]),
        split=arrs["split"], fingerprint=meta["fingerprint"],
    )
