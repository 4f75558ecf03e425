"""The real-mocap stand-in ``bandai2`` (Bandai-Namco-Research-Motiondataset-2, CC BY-NC 4.0).

``prepare_bandai2(source)`` reads the upstream archive straight through :mod:`tarfile` (one
decompression pass, nothing unpacked to disk) or an extracted folder, parses every clip with
:mod:`repro.data.bvh` (a pool of worker threads), converts it to the harness conventions and
publishes a compact cache under ``datasets_root()/bandai2/<fingerprint>/``; ``load_bandai2()``
opens the last prepared cache memory-mapped.  The source is read by :mod:`repro.data.sources`
(size caps) and the cache's layout is :mod:`repro.data.cache`'s, shared with every prepared
data set; this module holds the Bandai conversion, its card and labels.

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
import time
from collections import deque
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable

import numpy as np

# the exact command that prepares a stand-in (error messages) lives with the built-in names
from repro.data.builtin_sets import standin_prepare_command as prepare_command  # noqa: F401
# The source reader (size caps) and the prepared-cache layout that this module used to hold
# live in repro.data.sources and repro.data.cache; their names stay importable from here.
# The caps are read from repro.data.sources when a source is read: patch them there.
from repro.data.cache import (ARRAYS, CACHE_VERSION, POINTER, SCHEMA, UNIT_TOL,  # noqa: F401
                              PrepareResult, cache_problem, current_cache, dataset_dir,
                              open_cache, prepared_problem, valid_cache, write_cache,
                              write_json_atomic)
from repro.data.sources import (MAX_MEMBER_BYTES, MAX_SOURCE_BYTES,  # noqa: F401
                                MAX_TAR_HEADER_BYTES, inside, iter_source, source_fingerprint)
from repro.errors import DataError, MissingDataError

# their names while they lived here
_inside, _iter_source = inside, iter_source
_valid_cache, _write_json_atomic = valid_cache, write_json_atomic

#: Bump when the conversion changes: it enters the cache fingerprint
#: (:func:`dataset_fingerprint`; the version stamped in meta.json is the cache's
#: :data:`~repro.data.cache.CACHE_VERSION`).
PREPARE_VERSION = 1
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
#: Folders with fewer BVH files than this are parsed in the caller's thread.
POOL_MIN_FILES = 64

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
    joints: int | None
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
        if self.joints is not None and joints != self.joints:
            bad.append(f"{joints} joints after dropping {DUMMY_ROOT} (card: {self.joints})")
        return bad


def card_of_spec(spec) -> DatasetCard:
    """The card a data-set spec declares (names, fps, ``[expect]`` counts, words): the
    built-in stand-in's facts live in its shipped spec, ``repro/data/bundled/bandai2.toml``."""
    exp = spec.expect
    return DatasetCard(name=spec.name, clips=exp and exp.clips, frames=exp and exp.frames,
                       fps=float(spec.frames.fps), class_names=tuple(spec.labels.classes),
                       style_names=tuple(spec.labels.styles), joints=exp and exp.joints,
                       license=spec.license, credit=spec.credit)


def _builtin_spec():
    """The shipped declaration of ``bandai2``, checked against this reader's fixed conventions
    (centimetres, ``joint_Root`` dropped, y up, labels and split as declared)."""
    from repro.data.dataset_spec import builtin_spec_path, load_dataset_spec

    path = builtin_spec_path("bandai2")
    spec = load_dataset_spec(path)
    sk = spec.skeleton
    if (sk.scale != CM_TO_M or sk.dummy_root != DUMMY_ROOT or sk.up_axis != "y"
            or spec.source.format != "bvh" or spec.split.by != "clip" or not spec.labels.classes
            or not spec.labels.styles or spec.frames.fps is None or spec.expect is None):
        raise DataError("the built-in bandai2 reader needs cm, dummy_root 'joint_Root', y up, "
                        "BVH, a clip split, classes, styles, fps and [expect]", path)
    return spec


BANDAI2_SPEC = _builtin_spec()
BANDAI2_CARD = card_of_spec(BANDAI2_SPEC)


def split_config(seed: int | None = None, test_fraction: float | None = None) -> dict:
    """The split a prepared stand-in records (and its fingerprint hashes): the shipped spec's
    ``[split]`` unless overridden."""
    declared = BANDAI2_SPEC.split
    return {"method": "stratified(action, style)",
            "seed": declared.seed if seed is None else int(seed),
            "test_fraction": declared.test_fraction if test_fraction is None
            else float(test_fraction)}


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


def _read_and_convert(source: Path, workers: int, progress: ProgressFn | None, total: int | None,
                      timings: dict):
    """Stream the source once; convert BVH files in ``workers`` threads (0: in the caller's).

    Threads, not processes (issue 31): the work releases the GIL where it is heavy (the xz
    decompression of the stream, the compiled MOTION reader, torch's rotation maths and
    forward kinematics), so the conversion runs beside the decompression without a process's
    start (torch imported again) and without pickling every file's bytes and arrays across.
    torch runs one intra-op thread meanwhile (restored afterwards); results are taken in
    submission order, so the cache is the same bytes whatever the number of workers."""
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
        for kind, label, data in iter_source(source):
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
        from concurrent.futures import ThreadPoolExecutor

        import torch

        threads = torch.get_num_threads()
        pending: deque = deque()
        ex = None
        try:
            torch.set_num_threads(1)
            ex = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="repro-prepare")

            def drain(limit: int) -> None:
                while len(pending) > limit or (pending and pending[0].done()):
                    for res in pending.popleft().result():
                        take(res)

            for kind, label, data in iter_source(source):
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
            if ex is not None:
                ex.shutdown(wait=True, cancel_futures=True)
            torch.set_num_threads(threads)
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



def _read_clips(source: Path, card: DatasetCard, workers: int, progress: ProgressFn | None,
                timings: dict):
    """Every clip, annotation and label file of ``source`` (:func:`_read_and_convert`; a folder
    of fewer than :data:`POOL_MIN_FILES` BVH files is parsed in the caller's thread)."""
    if source.is_dir():
        n_total = sum(1 for _ in source.rglob("*.bvh"))
        w = workers if n_total >= POOL_MIN_FILES else 0
    else:
        n_total, w = card.clips, workers
    clips, annotations, label_files = _read_and_convert(source, w, progress, n_total, timings)
    if not clips:
        raise DataError("no .bvh files found", source)
    return clips, annotations, label_files


def _checked_bvh_skeleton(clips: dict, order: list[str]) -> dict:
    """The first clip of ``order``, once every other clip is checked to share its hierarchy,
    OFFSETs (to :data:`OFFSET_TOL_CM`) and Frame Time (module docstring)."""
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
    return first


def _write_prepared(root: Path, fp: str, src_fp: str, source: Path, card: DatasetCard,
                    split_cfg: dict, clips: dict, order: list[str], labels: np.ndarray,
                    styles: np.ndarray) -> np.ndarray:
    """Check the converted ``clips`` against ``card``, split them, write the cache ``root/fp``
    and point ``root``'s pointer at it; the clip lengths.  Empties ``clips``."""
    from repro.data.splits import stratified_split
    from repro.motion.skeleton import Skeleton

    first = _checked_bvh_skeleton(clips, order)
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

    meta = {  # write_cache adds the cache's schema and prepare_version
        "name": card.name, "fingerprint": fp, "source_fingerprint": src_fp,
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
    write_json_atomic(root / POINTER, {"fingerprint": fp, "source": str(source)})
    return lengths


def prepare_bandai2(source: str | Path, *, card: DatasetCard = BANDAI2_CARD, workers: int = 2,
                    force: bool = False, progress: ProgressFn | None = None,
                    split_seed: int | None = None, test_fraction: float | None = None
                    ) -> PrepareResult:
    """Parse ``source`` (the upstream .tar.xz or an extracted folder) into the cache.

    The cache is rebuilt only when absent, damaged or ``force``; it is built in a temporary
    folder beside the target and moved into place, so a failure leaves any existing cache intact.
    """
    from filelock import FileLock

    t_start = time.perf_counter()
    source = Path(source).expanduser()
    if not source.exists():
        raise MissingDataError(f"source not found; get {card.name}'s archive (see "
                               f"../shared/data/bandai-namco-2/SOURCE.md) and pass --source", source)
    split_cfg = split_config(split_seed, test_fraction)
    timings: dict = {}
    t0 = time.perf_counter()
    src_fp = source_fingerprint(source)
    timings["fingerprint_s"] = time.perf_counter() - t0
    fp = dataset_fingerprint(src_fp, card, split_cfg)
    root = dataset_dir(card.name)
    root.mkdir(parents=True, exist_ok=True)
    final = root / fp
    with FileLock(str(root / ".lock")):
        meta = None if force else valid_cache(final)
        if meta is not None:
            write_json_atomic(root / POINTER, {"fingerprint": fp, "source": str(source)})
            return PrepareResult(final, fp, True, time.perf_counter() - t_start,
                                 len(meta["clip_names"]), int(meta["stats"]["frames"]), timings)
        clips, annotations, label_files = _read_clips(source, card, workers, progress, timings)
        t0 = time.perf_counter()
        order, labels, styles = _labels(clips, annotations, label_files, card)
        lengths = _write_prepared(root, fp, src_fp, source, card, split_cfg, clips, order,
                                  labels, styles)
        timings["assemble_write_s"] = time.perf_counter() - t0
    return PrepareResult(final, fp, False, time.perf_counter() - t_start, len(order),
                         int(lengths.sum()), timings)



# ------------------------------------------------------------------------ load
def load_bandai2(name: str = "bandai2", mmap: bool = True):
    """The last prepared cache as a :class:`~repro.data.clipset.ClipSet` (arrays memory-mapped,
    read-only).  Raises MissingDataError naming the prepare command when there is none."""
    found = current_cache(name)
    if found is None:
        raise MissingDataError(f"data set {name!r} is not prepared (or was prepared by an older "
                               f"version); run: {prepare_command(name)}", dataset_dir(name))
    from repro.data.dataset_registration import prepare_command as command

    path, meta = found
    return open_cache(path, meta, name, mmap=mmap, command=command)


