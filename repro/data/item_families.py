"""Every item family, by the name a description gives it (data layer).

A training job's ``items`` entry is an :meth:`repro.data.item_sources.ItemSource.describe`
output; its ``builder`` names the family (:class:`repro.data.pairs_build.PairSource`'s
``"multiact_pairs"``, MultiAct §4.1; :class:`repro.data.odmo_items.WindowSource`'s
``"odmo_windows"``, ODMO §3.1); a description without one is Neural Marionette's
(:class:`repro.data.contexts.ActionSource`, §4.2, supp. §3), whose descriptions predate the
field.  This module imports every family, so :mod:`repro.data.item_sources` (which each of
them imports) need not.
"""

from __future__ import annotations

from repro.data.contexts import ActionSource
from repro.data.item_sources import ItemSource
from repro.data.odmo_items import WindowSource
from repro.data.pairs_build import PairSource
from repro.errors import DataError

__all__ = ["FAMILIES", "source_from_description"]

#: ``builder`` of a description -> its family (None: Neural Marionette's, no builder field)
FAMILIES: dict[str | None, type[ItemSource]] = {
    None: ActionSource, "multiact_pairs": PairSource, "odmo_windows": WindowSource}


def source_from_description(d: dict) -> ItemSource:
    """The item source ``d`` (a ``describe()`` output) describes, of the family its
    ``builder`` names; an unknown builder is a DataError."""
    builder = d.get("builder") if isinstance(d, dict) else None
    family = FAMILIES.get(builder)
    if family is None:
        raise DataError(f"items described by an unknown builder {builder!r} (known: "
                        f"{', '.join(sorted(b for b in FAMILIES if b))})")
    return family.from_description(d)
