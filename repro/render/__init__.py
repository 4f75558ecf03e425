"""Rendering: comparison strips of stick figures (:mod:`repro.render.strips`, PNG) with a
multi-channel OpenEXR copy (:mod:`repro.render.exr`: colour, depth, joint ids).

Conventions (camera, colours, depth, layout) are documented in :mod:`repro.render.strips`.
Plots (:mod:`repro.render.plots`) are not imported here, so ``import repro.render`` stays light.
"""

from repro.render.exr import read_exr, write_exr
from repro.render.strips import (
    Panel,
    Segment,
    StripImage,
    key_frame_indices,
    render_strip,
    save_png,
)

__all__ = ["Panel", "Segment", "StripImage", "key_frame_indices", "read_exr", "render_strip",
           "save_png", "write_exr"]
