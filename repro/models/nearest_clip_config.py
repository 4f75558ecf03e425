"""``nearest_clip``'s configuration (a harness reference method, not a method of any paper),
torch-free so that a table's plan reads it without importing the network (issue 31); the method
and the sources of its defaults: :mod:`repro.models.nearest_clip`."""

from __future__ import annotations

from pydantic import Field

from repro.models.base import GeneratorConfig, MethodCard, register_card


class NearestClipConfig(GeneratorConfig):
    """Retrieval settings (harness choices; docs/protocols.md)."""

    match_frames: int | None = Field(
        None, ge=1, description="last initial frames compared (None: all of them)")


#: retrieval on the CPU: its jobs carry no device (no GPU asked for)
NEAREST_CLIP = register_card(MethodCard("nearest_clip", NearestClipConfig, uses_device=False))
