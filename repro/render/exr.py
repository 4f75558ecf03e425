"""Multi-channel OpenEXR copies of comparison strips (colour, depth and joint ids in one file).

:func:`write_exr` writes one single-part scanline image (ZIP compression) with the channels

- ``R``, ``G``, ``B``, ``A``: HALF, **scene-linear** colour (the PNG's sRGB-encoded bytes
  decoded with the sRGB transfer function, :func:`srgb_to_linear`, as compositors expect) with
  **premultiplied** alpha (the OpenEXR convention: ``R = linear(r/255) * a/255``), so the
  transparent background is ``(0, 0, 0, 0)``;
- ``Z``: FLOAT, the strip's depth in metres from the camera plane (see
  :mod:`repro.render.strips`); where nothing was drawn it stays **+inf** (IEEE infinity, which
  EXR stores as is: "infinitely far", never confused with a real depth);
- ``JointIndex``: UINT, 0 for none, ``j + 1`` for joint j's disc or the bone to its parent.

The file is written to a temporary file in the target folder and moved into place with
``os.replace``, so a reader never sees half a file.  :func:`read_exr` reads any such file back
as ``{channel name: (H, W) array}`` (float16, float32, uint32 as stored).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import OpenEXR

from repro.render.strips import StripImage, atomic_write


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """The sRGB transfer function undone (IEC 61966-2-1), values in [0, 1]."""
    c = np.asarray(c, np.float32)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4).astype(np.float32)


def exr_channels(image: StripImage) -> dict[str, np.ndarray]:
    """The channels :func:`write_exr` stores, as arrays."""
    rgba = image.rgba.astype(np.float32) / 255.0
    a = rgba[..., 3]
    lin = srgb_to_linear(rgba[..., :3])
    out = {c: np.ascontiguousarray((lin[..., i] * a).astype(np.float16))
           for i, c in enumerate("RGB")}
    out["A"] = np.ascontiguousarray(a.astype(np.float16))
    out["Z"] = np.ascontiguousarray(image.depth, dtype=np.float32)
    out["JointIndex"] = np.ascontiguousarray(image.joint_index, dtype=np.uint32)
    return out


def write_exr(image: StripImage, path) -> Path:
    """Write ``image`` as a multi-channel OpenEXR file at ``path`` (atomically); returns it."""
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    channels = exr_channels(image)
    return atomic_write(path, lambda tmp: OpenEXR.File(header, channels).write(tmp))


def read_exr(path) -> dict[str, np.ndarray]:
    """Channel name -> (H, W) array of an OpenEXR file (any single-part scanline file)."""
    f = OpenEXR.File(str(path), separate_channels=True)
    return {name: np.asarray(ch.pixels) for name, ch in f.channels().items()}


__all__ = ["exr_channels", "read_exr", "write_exr"]
