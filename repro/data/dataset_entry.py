"""What a registered data set is: a :class:`DatasetEntry` (its name, words, and how to check,
load and validate it) and the :class:`DatasetStatus` its status check answers.

The registry (:mod:`repro.data.registry`) holds one entry per data set; the papers' own data
sets (:mod:`repro.data.upstream`) build theirs from these classes without importing the
registry.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

from repro.errors import MissingDataError


@dataclass(frozen=True)
class DatasetStatus:
    """Whether a data set is ready: ``location`` is where it is (or is looked for),
    ``missing`` says what is absent and how to get it (``None`` when prepared)."""

    prepared: bool
    location: str
    fingerprint: str | None
    missing: str | None


@dataclass(frozen=True)
class DatasetEntry:
    """One registered data set.

    ``status_fn`` answers :meth:`status` (subclasses may override :meth:`status` instead);
    ``loader`` returns the ClipSet (``None``: the data set has no ClipSet loader here);
    ``validate_fn`` answers :meth:`validate` (``None``: nothing beyond :meth:`status` is checked).
    """

    name: str
    description: str
    is_paper_dataset: bool
    status_fn: Callable[[], DatasetStatus] | None = field(default=None, repr=False, compare=False)
    loader: Callable[[], object] | None = field(default=None, repr=False, compare=False)
    validate_fn: Callable[[], str | None] | None = field(default=None, repr=False,
                                                         compare=False)

    def status(self) -> DatasetStatus:
        if self.status_fn is None:
            return DatasetStatus(False, "", None, "no status check is registered for this data set")
        return self.status_fn()

    def validate(self) -> str | None:
        """Open the data set's files cheaply (headers, shapes, stored checksums, the reader's
        own checks) and say why they are damaged, naming the file; ``None`` when they read back
        intact or are not there (:meth:`status` says what is missing).  ``repro doctor`` reports
        it (issue 16: it used to say "prepared yes" for any file present)."""
        return None if self.validate_fn is None else self.validate_fn()

    def load(self):
        if self.loader is None:
            st = self.status()
            raise MissingDataError(f"data set {self.name!r} cannot be loaded as a clip set"
                                   + (f": {st.missing}" if st.missing else ""))
        return self.loader()
