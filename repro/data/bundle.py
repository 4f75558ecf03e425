"""``bandai2-mini``: a small deterministic subset of ``bandai2`` shipped inside the package.

It is the default data set at the ``quick`` scale, so a fresh machine with nothing else can run
every table.  Built by ``repro data bundle`` (:func:`build_mini`) from a prepared ``bandai2``:

- selection: for every (action, style) cell (10 × 7), :data:`MINI_TRAIN` clips from the
  ``bandai2`` train split and :data:`MINI_TEST` from its test split, drawn with a seeded
  generator (:data:`MINI_SEED`); each clip keeps its ``bandai2`` split, so the mini split is
  the full split restricted to the subset;
- representation: local rotations as xyzw quaternions quantised to int16 (``round(q·32767)``,
  error ≤ 1.6e-5 per component, i.e. < 0.1 mm on a joint 1 m down the chain), stored as the
  first frame and per-frame differences (int16, wrapping) for compression; root translation
  float32 metres, unchanged; joint positions are recomputed at load by forward kinematics of
  the dequantised rotations on the stored skeleton;
- files: ``bandai2-mini.npz`` (written with a fixed zip timestamp: the same inputs give the
  same bytes), ``bandai2-mini.json`` (names, skeleton, provenance) and ``NOTICE`` (credit and
  licence: Bandai Namco Research Inc., CC BY-NC 4.0, derived subset).
"""

from __future__ import annotations

import io
import json
import os
import tempfile
import zipfile
from pathlib import Path

import numpy as np

from repro.errors import DataError, MissingDataError

MINI_NAME = "bandai2-mini"
MINI_TRAIN = 3
MINI_TEST = 1
MINI_SEED = 0
MINI_SCHEMA = 1
QUAT_SCALE = 32767
#: Size limit of the bundled files together (bytes).
MINI_MAX_BYTES = 8 * 1024 * 1024
NPZ = f"{MINI_NAME}.npz"
META = f"{MINI_NAME}.json"

NOTICE_TEXT = """\
bandai2-mini: a derived subset of Bandai-Namco-Research-Motiondataset-2
=======================================================================

The motion data in this folder (bandai2-mini.npz, bandai2-mini.json) is derived from
Bandai-Namco-Research-Motiondataset-2 by Bandai Namco Research Inc.
(https://github.com/BandaiNamcoResearchInc/Bandai-Namco-Research-Motiondataset;
Kobayashi et al. 2023, "Motion Capture Dataset for Practical Use of AI-based Motion Editing
and Stylization", arXiv 2306.08861).
(c) 2022 Bandai Namco Research Inc.

It is licensed under the Creative Commons Attribution-NonCommercial 4.0 International licence
(CC BY-NC 4.0, https://creativecommons.org/licenses/by-nc/4.0/). Non-commercial use only.
This licence applies to the data files in this folder, not to the repro source code.

Changes made (this is not the original data):
- subset: {n_clips} of the 2,902 clips ({per_cell} per action x style cell: {train} from the
  harness's seeded 80/20 train split and {test} from its test split; seed {seed});
- units: centimetres converted to metres;
- axes: unchanged (Y up); the all-zero dummy root joint `joint_Root` was removed, so `Hips` is
  the root and carries the root translation;
- representation: BVH Euler angles (Z, X, Y intrinsic, degrees) converted to local unit
  quaternions (xyzw), quantised to int16 (q * 32767) and stored as per-clip frame differences;
  joint positions are recomputed by forward kinematics when loaded; annotations (content and
  style ids) are kept as integer labels with their names.

Rebuild with: repro data bundle --source PATH/bandai-namco-research-motiondataset-2.tar.xz
"""


def bundled_dir() -> Path:
    """The package folder that holds the bundled data."""
    return Path(__file__).resolve().parent / "bundled"


def select_mini(labels, styles, split, *, n_train: int = MINI_TRAIN, n_test: int = MINI_TEST,
                seed: int = MINI_SEED) -> np.ndarray:
    """Sorted clip indices of the subset: per (label, style) cell, ``n_train`` train and
    ``n_test`` test clips drawn with a seeded generator (all when a cell has fewer)."""
    from repro.data.clipset import TEST, TRAIN
    from repro.seeding import numpy_rng

    labels, styles, split = (np.asarray(a) for a in (labels, styles, split))
    out: list[int] = []
    for lab in np.unique(labels).tolist():
        for sty in np.unique(styles[labels == lab]).tolist():
            for part, k in ((TRAIN, n_train), (TEST, n_test)):
                idx = np.flatnonzero((labels == lab) & (styles == sty) & (split == part))
                out += numpy_rng(seed, MINI_NAME, lab, sty, part).permutation(idx)[:k].tolist()
    return np.array(sorted(out), dtype=np.int64)


def _encode_rotations(q: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    qi = np.round(np.asarray(q, np.float64) * QUAT_SCALE).astype(np.int16)
    out = qi.copy()
    s = 0
    for n in lengths.tolist():
        if n > 1:
            out[s + 1:s + n] = qi[s + 1:s + n] - qi[s:s + n - 1]  # int16 arithmetic wraps
        s += n
    return out


def _decode_rotations(d: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    qi = np.empty_like(d)
    s = 0
    for n in lengths.tolist():
        qi[s:s + n] = np.cumsum(d[s:s + n], axis=0, dtype=np.int16)  # wraps back exactly
        s += n
    q = qi.astype(np.float32) / QUAT_SCALE
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def _write_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """A deterministic .npz: sorted members, fixed timestamp, deflate level 9."""
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    os.close(fd)
    try:
        with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=9) as zf:
            for k in sorted(arrays):
                buf = io.BytesIO()
                np.lib.format.write_array(buf, np.ascontiguousarray(arrays[k]), allow_pickle=False)
                info = zipfile.ZipInfo(f"{k}.npy", date_time=(1980, 1, 1, 0, 0, 0))
                info.compress_type = zipfile.ZIP_DEFLATED
                info.external_attr = 0o644 << 16
                zf.writestr(info, buf.getvalue(), compresslevel=9)
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _write_text(path: Path, text: str) -> None:
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="\n") as fh:
            fh.write(text)
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def build_mini(clips, out_dir: str | Path | None = None, *, n_train: int = MINI_TRAIN,
               n_test: int = MINI_TEST, seed: int = MINI_SEED) -> dict:
    """Write ``bandai2-mini`` from the ``bandai2`` ClipSet ``clips`` into ``out_dir`` (default:
    the package's bundled folder).  Returns a summary (clips, frames, bytes, files)."""
    out = Path(out_dir) if out_dir is not None else bundled_dir()
    out.mkdir(parents=True, exist_ok=True)
    sel = select_mini(clips.labels, clips.styles, clips.split, n_train=n_train, n_test=n_test,
                      seed=seed)
    lengths = np.asarray(clips.lengths)[sel].astype(np.int32)
    rows = np.concatenate([np.arange(clips.starts[i], clips.starts[i] + clips.lengths[i])
                           for i in sel.tolist()])
    q = np.asarray(clips.rotations[rows])
    arrays = {
        "rotations_q": _encode_rotations(q, lengths),
        "root": np.asarray(clips.root[rows], np.float32),
        "lengths": lengths,
        "labels": np.asarray(clips.labels)[sel].astype(np.int8),
        "styles": np.asarray(clips.styles)[sel].astype(np.int8),
        "split": np.asarray(clips.split)[sel].astype(np.int8),
    }
    _write_npz(out / NPZ, arrays)
    from repro.keys import sha256_file

    meta = {
        "schema": MINI_SCHEMA, "name": MINI_NAME, "fps": clips.fps,
        "skeleton": clips.skeleton.to_dict(), "label_names": list(clips.label_names),
        "style_names": list(clips.style_names),
        "clip_names": [clips.clip_names[i] for i in sel.tolist()],
        "derived_from": {"dataset": clips.name, "fingerprint": clips.fingerprint},
        "selection": {"per_cell_train": n_train, "per_cell_test": n_test, "seed": seed},
        "encoding": {"rotations_q": f"int16 round(xyzw*{QUAT_SCALE}); first frame of each clip, "
                                    f"then per-frame differences (wrapping)",
                     "root": "float32 metres, Y up", "joints": "recomputed by forward kinematics"},
        "npz_sha256": sha256_file(out / NPZ),
        "license": "CC BY-NC 4.0", "credit": "Bandai Namco Research Inc.",
    }
    _write_text(out / META, json.dumps(meta, indent=1, sort_keys=True) + "\n")
    _write_text(out / "NOTICE", NOTICE_TEXT.format(n_clips=len(sel), per_cell=n_train + n_test,
                                                   train=n_train, test=n_test, seed=seed))
    size = sum((out / f).stat().st_size for f in (NPZ, META, "NOTICE"))
    return {"out": str(out), "clips": int(len(sel)), "frames": int(lengths.sum()), "bytes": size,
            "files": [NPZ, META, "NOTICE"]}


def mini_available(folder: str | Path | None = None) -> bool:
    d = Path(folder) if folder is not None else bundled_dir()
    return (d / NPZ).is_file() and (d / META).is_file()


def load_mini(folder: str | Path | None = None):
    """The bundled ``bandai2-mini`` as a :class:`~repro.data.clipset.ClipSet`.

    The first load decodes the rotations and runs forward kinematics (about half a second);
    the result is kept as a memory-mapped cache under ``datasets_root()/bandai2-mini/<key>/``
    (key: the bundle's content), so later loads are instant.  An unwritable cache is skipped.
    """
    from repro.data.builtin_sets import standin_prepare_command as command
    from repro.data.cache import dataset_dir, open_cache, valid_cache, write_cache
    from repro.keys import content_key, sha256_file

    d = Path(folder) if folder is not None else bundled_dir()
    if not mini_available(d):
        raise MissingDataError(f"{MINI_NAME} is not bundled here; rebuild it with: "
                               f"repro data bundle --source PATH", d)
    npz_sha = sha256_file(d / NPZ)
    fp = content_key({"dataset": MINI_NAME, "npz": npz_sha, "meta": sha256_file(d / META)})
    cache_root = dataset_dir(MINI_NAME)
    meta = valid_cache(cache_root / fp)
    if meta is not None:
        return open_cache(cache_root / fp, meta, MINI_NAME, command=command)
    arrays, meta = _decode_bundle(d, npz_sha)
    meta["fingerprint"] = fp
    try:
        path = write_cache(cache_root, fp, arrays, meta, replace=False)
    except OSError:
        path = None
    if path is not None and (m := valid_cache(path)) is not None:
        return open_cache(path, m, MINI_NAME, command=command)
    from repro.data.clipset import ClipSet
    from repro.motion.skeleton import Skeleton

    return ClipSet(name=MINI_NAME, skeleton=Skeleton.from_dict(meta["skeleton"]),
                   fps=float(meta["fps"]), label_names=tuple(meta["label_names"]),
                   style_names=tuple(meta["style_names"]), clip_names=tuple(meta["clip_names"]),
                   fingerprint=fp, **arrays)


def _decode_bundle(d: Path, npz_sha: str) -> tuple[dict, dict]:
    """Arrays in the layout of :data:`repro.data.cache.ARRAYS` and the cache meta."""
    import roma
    import torch

    from repro.motion.skeleton import Skeleton, forward_kinematics

    try:
        meta = json.loads((d / META).read_text())
    except ValueError as e:
        raise DataError(f"not valid JSON ({e})", d / META) from None
    if meta.get("schema") != MINI_SCHEMA:
        raise DataError(f"schema {meta.get('schema')!r}, expected {MINI_SCHEMA}; rebuild with "
                        f"repro data bundle", d / META)
    if npz_sha != meta.get("npz_sha256"):
        raise DataError("content does not match the sha256 recorded in bandai2-mini.json; "
                        "rebuild with repro data bundle", d / NPZ)
    try:
        with np.load(d / NPZ, allow_pickle=False) as z:
            a = {k: z[k] for k in z.files}
    except (OSError, ValueError, zipfile.BadZipFile) as e:
        raise DataError(f"cannot read ({e})", d / NPZ) from None
    lengths = a["lengths"].astype(np.int64)
    q = _decode_rotations(a["rotations_q"], lengths)
    skel = Skeleton.from_dict(meta["skeleton"])
    R = roma.unitquat_to_rotmat(torch.from_numpy(q.astype(np.float64)))
    joints = forward_kinematics(skel, R, torch.from_numpy(a["root"].astype(np.float64)))
    arrays = {
        "rotations": q, "root": a["root"].astype(np.float32),
        "joints": joints.numpy().astype(np.float32), "lengths": lengths,
        "starts": np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64),
        "labels": a["labels"].astype(np.int64), "styles": a["styles"].astype(np.int64),
        "split": a["split"].astype(np.int8),
    }
    cache_meta = {k: meta[k] for k in ("name", "fps", "skeleton", "label_names", "style_names",
                                       "clip_names", "derived_from")}
    return arrays, cache_meta
