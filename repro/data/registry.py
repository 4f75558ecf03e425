"""The data-set registry: every data set the harness knows, whether it is ready, and loading.

``DATASETS`` maps a name to a :class:`DatasetEntry`: the stand-ins ``bandai2`` (prepared cache
under ``REPRO_HOME``) and ``bandai2-mini`` (bundled in the package), plus the papers' own data
sets listed by :mod:`repro.data.upstream` (``ENTRIES``), when that module is present.
:func:`load_clipset` returns a :class:`~repro.data.clipset.ClipSet`; unknown names raise a
ConfigError with a did-you-mean suggestion.
"""

from __future__ import annotations

import difflib

from repro.data.builtin_sets import STANDINS, upstream_entries
from repro.data.dataset_entry import DatasetEntry, DatasetStatus  # noqa: F401 (the registry's)
from repro.errors import ConfigError, MissingDataError


# ------------------------------------------------------------------------ the stand-ins
def _bandai2_status() -> DatasetStatus:
    from repro.data.bandai import prepare_command
    from repro.data.cache import current_cache, dataset_dir

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


def _bandai2_validate() -> str | None:
    from repro.data.cache import prepared_problem
    from repro.data.dataset_registration import prepare_command

    return prepared_problem("bandai2", command=prepare_command)


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


def _mini_validate() -> str | None:
    """The bundle against the sha256 its .json records, its .npz members, and the decoded
    cache built from it on first load (if there is one)."""
    import json
    import zipfile

    from repro.data.bundle import (
        META,
        MINI_NAME,
        MINI_SCHEMA,
        NPZ,
        bundled_dir,
        mini_available,
    )
    from repro.data.cache import cache_problem, dataset_dir
    from repro.keys import content_key, sha256_file

    d = bundled_dir()
    if not mini_available(d):
        return None
    fix = "; rebuild with: repro data bundle --source PATH"
    try:
        meta = json.loads((d / META).read_text())
        if meta.get("schema") != MINI_SCHEMA:
            return f"{d / META}: schema {meta.get('schema')!r}, expected {MINI_SCHEMA}{fix}"
        recorded = meta.get("npz_sha256")
    except (OSError, ValueError, AttributeError) as e:
        return f"{d / META}: cannot be read ({type(e).__name__}: {e}){fix}"
    npz_sha = sha256_file(d / NPZ)
    if npz_sha != recorded:
        return f"{d / NPZ}: content does not match the sha256 recorded in {META}{fix}"
    try:
        with zipfile.ZipFile(d / NPZ) as z:
            names = set(z.namelist())
    except (OSError, zipfile.BadZipFile) as e:
        return f"{d / NPZ}: not a readable .npz ({e}){fix}"
    want = {f"{k}.npy" for k in ("rotations_q", "root", "lengths", "labels", "styles", "split")}
    if not want <= names:
        return f"{d / NPZ}: lacks {', '.join(sorted(want - names))}{fix}"
    fp = content_key({"dataset": MINI_NAME, "npz": npz_sha, "meta": sha256_file(d / META)})
    cache = dataset_dir(MINI_NAME) / fp
    if (cache / "meta.json").is_file():
        why = cache_problem(cache)
        if why is not None:
            return f"{why}; delete {cache} (it is rebuilt from the bundle on next use)"
    return None


def _builtin_entries() -> list[DatasetEntry]:
    bandai2, mini = STANDINS
    return [
        DatasetEntry(bandai2, "Bandai-Namco-Research-Motiondataset-2 (real mocap stand-in: "
                     "2,902 clips, 10 actions x 7 styles, 30 fps; CC BY-NC 4.0)", False,
                     _bandai2_status, _load_bandai2, _bandai2_validate),
        DatasetEntry(mini, "bundled deterministic subset of bandai2 (4 clips per "
                     "action x style; default at the quick scale; CC BY-NC 4.0)", False,
                     _mini_status, _load_mini, _mini_validate),
    ]


def _spec_current(name: str, path):
    """(folder, meta) of the prepared copy of a declared data set, or (None, why not)."""
    import json

    from repro.data.cache import POINTER, current_cache, dataset_dir
    from repro.data.dataset_registration import check_current

    found = current_cache(name)
    if found is None:
        return None, f"not prepared; run: repro data prepare {path}"
    try:
        pointer = json.loads((dataset_dir(name) / POINTER).read_text())
    except (OSError, ValueError):
        pointer = {}
    why = check_current(name, path, pointer)
    if why is not None:
        return None, f"{why}; run: repro data prepare {path}"
    return found, None


def _spec_status(name: str, path) -> DatasetStatus:
    from repro.data.cache import dataset_dir

    found, why = _spec_current(name, path)
    if found is None:
        return DatasetStatus(False, str(dataset_dir(name)), None, why)
    return DatasetStatus(True, str(found[0]), found[1]["fingerprint"], None)


def _spec_load(name: str, path):
    from repro.data.cache import open_cache
    from repro.data.dataset_registration import prepare_command

    found, why = _spec_current(name, path)
    if found is None:
        raise MissingDataError(f"data set {name!r}: {why}")
    return open_cache(found[0], found[1], name, command=prepare_command)


def _spec_entries() -> list[DatasetEntry]:
    """The data sets of the spec files registered in ``$REPRO_DATASETS``
    (:mod:`repro.data.dataset_registration`)."""
    from functools import partial

    from repro.data.cache import prepared_problem
    from repro.data.dataset_registration import declared_specs

    out = []
    for name, (path, spec) in declared_specs()[0].items():
        out.append(DatasetEntry(name, spec.description or f"declared in {path}", False,
                                partial(_spec_status, name, path),
                                partial(_spec_load, name, path),
                                partial(prepared_problem, name,
                                        f"repro data prepare {path} --force")))
    return out


def _build() -> dict[str, DatasetEntry]:
    out: dict[str, DatasetEntry] = {}
    for e in _builtin_entries() + upstream_entries():
        if e.name in out:
            raise RuntimeError(f"data set {e.name!r} is registered twice")
        out[e.name] = e
    for e in _spec_entries():  # names of built-ins are refused by the spec loader
        out[e.name] = e
    return out


def reset() -> None:
    """Forget the registry (rebuilt on next use: after $REPRO_DATASETS changed)."""
    DATASETS.clear()
    DATASETS._built = False


class _Registry(dict):
    """A dict built on first use (so importing this module stays cheap), and again after a
    spec file was registered (:func:`repro.data.dataset_registration.registrations` changed
    since it was built: what :func:`reset` does, without that module importing this one)."""

    _built = False
    _registrations = 0

    def _ensure(self) -> None:
        from repro.data.dataset_registration import registrations

        if self._built and self._registrations != registrations():
            self.clear()
            self._built = False
        if not self._built:
            self._built = True
            self._registrations = registrations()
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
    """The entry for ``name`` (a registered name, or the path of a data-set spec file, which
    is registered on the way); a ConfigError with a did-you-mean suggestion if unknown."""
    from repro.data.dataset_registration import is_spec_path, register_spec_path

    if is_spec_path(name):
        name = register_spec_path(name)
    if name in DATASETS:
        return DATASETS[name]
    raise ConfigError(unknown_dataset_message(name))


def unknown_dataset_message(name: str) -> str:
    """The one refusal of a data-set name nothing declares (``--dataset``, ``repro data``):
    the closest known name, the known ones, why a spec file that declares it was skipped
    (issue 29), and how to use a data set of one's own (issue 28: the message named neither
    a spec path nor ``$REPRO_DATASETS``)."""
    import os

    from repro.data.dataset_registration import ENV, skipped_reason

    near = difflib.get_close_matches(name, dataset_names(), n=1)
    hint = f"; did you mean {near[0]!r}?" if near else ""
    return (f"unknown data set {name!r}{hint} (known: {', '.join(dataset_names())})"
            f"{skipped_reason(name)}; a data set of your own: pass its spec file "
            f"(--dataset path/to/spec.toml), or register it by name in ${ENV}: a folder of "
            f"spec files or a spec file, several joined by {os.pathsep} (docs/datasets.md)")


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
