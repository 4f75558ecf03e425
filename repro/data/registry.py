"""The data-set registry: every data set the harness knows, whether it is ready, and loading.

``DATASETS`` maps a name to a :class:`DatasetEntry`: the stand-ins ``bandai2`` (prepared cache
under ``REPRO_HOME``) and ``bandai2-mini`` (bundled in the package), plus the papers' own data
sets listed by :mod:`repro.data.upstream` (``ENTRIES``), when that module is present.
:func:`load_clipset` returns a :class:`~repro.data.clipset.ClipSet`; unknown names raise a
ConfigError with a did-you-mean suggestion.
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass, field
from typing import Callable

from repro.errors import ConfigError, MissingDataError


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
    ``loader`` returns the ClipSet (``None``: the data set has no ClipSet loader here).
    """

    name: str
    description: str
    is_paper_dataset: bool
    status_fn: Callable[[], DatasetStatus] | None = field(default=None, repr=False, compare=False)
    loader: Callable[[], object] | None = field(default=None, repr=False, compare=False)

    def status(self) -> DatasetStatus:
        if self.status_fn is None:
            return DatasetStatus(False, "", None, "no status check is registered for this data set")
        return self.status_fn()

    def load(self):
        if self.loader is None:
            st = self.status()
            raise MissingDataError(f"data set {self.name!r} cannot be loaded as a clip set"
                                   + (f": {st.missing}" if st.missing else ""))
        return self.loader()


# ------------------------------------------------------------------------ the stand-ins
def _bandai2_status() -> DatasetStatus:
    from repro.data.bandai import current_cache, dataset_dir, prepare_command

    found = current_cache("bandai2")
    if found is not None:
        path, meta = found
        return DatasetStatus(True, str(path), meta["fingerprint"], None)
    from repro.paths import find_bandai_archive

    have = find_bandai_archive()
    hint = (f"not prepared; run: {prepare_command('bandai2')}" if have is not None else
            "archive not found (put bandai-namco-research-motiondataset-2.tar.xz in "
            "../shared/data/bandai-namco-2/ or set REPRO_DATA), then run: "
            f"{prepare_command('bandai2')}")
    return DatasetStatus(False, str(dataset_dir("bandai2")), None, hint)


def _load_bandai2():
    from repro.data.bandai import load_bandai2

    return load_bandai2("bandai2")


def _mini_status() -> DatasetStatus:
    from repro.data.bundle import META, NPZ, bundled_dir, mini_available

    d = bundled_dir()
    if not mini_available(d):
        return DatasetStatus(False, str(d), None, f"{NPZ}/{META} missing from the package; "
                             "rebuild with: repro data bundle --source PATH")
    import json

    from repro.keys import content_key, sha256_file

    meta = json.loads((d / META).read_text())
    fp = content_key({"dataset": "bandai2-mini", "npz": meta.get("npz_sha256"),
                      "meta": sha256_file(d / META)})
    return DatasetStatus(True, str(d), fp, None)


def _load_mini():
    from repro.data.bundle import load_mini

    return load_mini()


def _builtin_entries() -> list[DatasetEntry]:
    return [
        DatasetEntry("bandai2", "Bandai-Namco-Research-Motiondataset-2 (real mocap stand-in: "
                     "2,902 clips, 10 actions x 7 styles, 30 fps; CC BY-NC 4.0)", False,
                     _bandai2_status, _load_bandai2),
        DatasetEntry("bandai2-mini", "bundled deterministic subset of bandai2 (4 clips per "
                     "action x style; default at the quick scale; CC BY-NC 4.0)", False,
                     _mini_status, _load_mini),
    ]


def _upstream_entries() -> list[DatasetEntry]:
    import importlib

    try:
        mod = importlib.import_module("repro.data.upstream")
    except ModuleNotFoundError as e:
        if e.name == "repro.data.upstream":
            return []
        raise
    if getattr(mod, "__file__", None) is None:  # a bare folder (namespace package): no entries
        return []
    return list(mod.ENTRIES)


def _build() -> dict[str, DatasetEntry]:
    out: dict[str, DatasetEntry] = {}
    for e in _builtin_entries() + _upstream_entries():
        if e.name in out:
            raise RuntimeError(f"data set {e.name!r} is registered twice")
        out[e.name] = e
    return out


class _Registry(dict):
    """A dict built on first use (so importing this module stays cheap and the upstream
    module may import :class:`DatasetEntry` from here without a cycle)."""

    _built = False

    def _ensure(self) -> None:
        if not self._built:
            self._built = True
            self.update(_build())

    def __getitem__(self, k):
        self._ensure()
        return super().__getitem__(k)

    def __contains__(self, k):
        self._ensure()
        return super().__contains__(k)

    def __iter__(self):
        self._ensure()
        return super().__iter__()

    def __len__(self):
        self._ensure()
        return super().__len__()

    def keys(self):
        self._ensure()
        return super().keys()

    def values(self):
        self._ensure()
        return super().values()

    def items(self):
        self._ensure()
        return super().items()

    def get(self, k, default=None):
        self._ensure()
        return super().get(k, default)

    def __repr__(self) -> str:
        self._ensure()
        return super().__repr__()


DATASETS: dict[str, DatasetEntry] = _Registry()


def dataset_names() -> list[str]:
    """Registered names, stand-ins first, in registration order."""
    return list(DATASETS.keys())


def get_entry(name: str) -> DatasetEntry:
    """The entry for ``name``; a ConfigError with a did-you-mean suggestion if unknown."""
    if name in DATASETS:
        return DATASETS[name]
    near = difflib.get_close_matches(name, dataset_names(), n=1)
    hint = f"; did you mean {near[0]!r}?" if near else ""
    raise ConfigError(f"unknown data set {name!r}{hint} (known: {', '.join(dataset_names())})")


def load_clipset(name: str):
    """The named data set as a ClipSet.  ``bandai2``: the prepared cache (MissingDataError
    naming the ``repro data prepare`` command when absent); ``bandai2-mini``: the bundle."""
    return get_entry(name).load()


def clipset_summary(clips) -> dict:
    """Counts for ``repro data info``: clips, frames, classes, styles, per-class and per-style
    counts, fps, joints, clip length min/mean/max (frames), split sizes, fingerprint."""
    import numpy as np

    lengths = np.asarray(clips.lengths)
    labels = np.asarray(clips.labels)
    styles = np.asarray(clips.styles)
    split = np.asarray(clips.split)
    has_style = bool((styles >= 0).any())
    per_class = {n: int((labels == i).sum()) for i, n in enumerate(clips.label_names)}
    per_style = ({n: int((styles == i).sum()) for i, n in enumerate(clips.style_names)}
                 if has_style else {})
    return {
        "name": clips.name, "clips": len(clips), "frames": int(lengths.sum()),
        "classes": len(clips.label_names), "styles": len(clips.style_names) if has_style else 0,
        "fps": float(clips.fps), "joints": clips.skeleton.n_joints,
        "joint_names": list(clips.skeleton.names),
        "length_frames": {"min": int(lengths.min()), "mean": round(float(lengths.mean()), 2),
                          "max": int(lengths.max())},
        "per_class": per_class, "per_style": per_style,
        "split": {"train": int((split == 0).sum()), "test": int((split == 1).sum())},
        "fingerprint": clips.fingerprint,
    }
