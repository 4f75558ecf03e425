"""Generated samples on disk: one compressed ``.npz`` per replicate, shared by every protocol.

A file holds ``meta`` (canonical JSON: ``format``, ``protocol``, the skeleton, ``fps`` and
whatever the protocol adds) and, per motion set with prefix ``p`` (``""`` for the samples,
e.g. ``"ref_"`` for a second pass), ``p+root`` (N, T, 3) metres, ``p+rot6d`` (N, T, J, 6),
``p+lengths`` (N,) and ``p+labels`` (N,) int64, plus any extra arrays.  Written atomically
(temp file + rename); read with ``allow_pickle=False``; anything that is not such a file, or
whose shapes do not fit, is a :class:`~repro.errors.DataError` naming it.
"""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path

import numpy as np
import torch

from repro.errors import DataError


def motion_arrays(generated, prefix: str = "") -> dict[str, np.ndarray]:
    """The arrays of one motion set (a GeneratedItems) under ``prefix``."""
    m = generated.motion
    return {prefix + "root": m.root.detach().cpu().numpy(),
            prefix + "rot6d": m.rot6d.detach().cpu().numpy(),
            prefix + "lengths": generated.lengths.cpu().numpy().astype(np.int64),
            prefix + "labels": generated.labels.cpu().numpy().astype(np.int64)}


def save_samples(path: str | Path, meta: dict, arrays: dict[str, np.ndarray]) -> Path:
    """Write ``meta`` (JSON) and ``arrays`` to the npz file ``path``, atomically."""
    from repro.store.atomic import atomic_write_bytes

    path = Path(path)
    buf = io.BytesIO()
    np.savez_compressed(buf, meta=np.array(json.dumps(meta, sort_keys=True)), **arrays)
    atomic_write_bytes(path, buf.getvalue())
    return path


def load_samples(path: str | Path, *, protocol: str, fmt: int) -> tuple[dict, dict, object]:
    """(meta, arrays, skeleton) of a file :func:`save_samples` wrote for ``protocol`` in
    format ``fmt``."""
    from repro.motion.skeleton import Skeleton

    path = Path(path)
    if not path.is_file():
        raise DataError("no such samples file", path)
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
        meta = json.loads(str(data["meta"]))
        skeleton = Skeleton.from_dict(meta["skeleton"])
    except (OSError, ValueError, KeyError, TypeError, zipfile.BadZipFile) as e:
        raise DataError(f"not a {protocol} samples file ({type(e).__name__}: {e})",
                        path) from None
    if meta.get("format") != fmt or meta.get("protocol") != protocol:
        raise DataError(f"samples of format {meta.get('format')!r} / protocol "
                        f"{meta.get('protocol')!r}, expected {fmt} / {protocol!r}", path)
    return meta, data, skeleton


def motion_set(data: dict, meta: dict, skeleton, path, prefix: str = ""):
    """The GeneratedItems stored under ``prefix`` (shapes checked)."""
    from repro.data.action_items import GeneratedItems
    from repro.motion.motion import Motion

    try:
        motion = Motion(torch.from_numpy(data[prefix + "root"]),
                        torch.from_numpy(data[prefix + "rot6d"]), skeleton, meta["fps"])
        lengths = torch.from_numpy(data[prefix + "lengths"].astype(np.int64))
        labels = torch.from_numpy(data[prefix + "labels"].astype(np.int64))
    except (KeyError, ValueError, TypeError) as e:
        raise DataError(f"malformed samples ({type(e).__name__}: {e})", path) from None
    n, t = motion.batch_size, motion.n_frames
    if lengths.shape != (n,) or labels.shape != (n,) or (n and (
            int(lengths.min()) < 1 or int(lengths.max()) > t)):
        raise DataError(f"malformed samples: lengths/labels do not fit {n} motions of {t} "
                        "frames", path)
    return GeneratedItems(motion, lengths, labels)
