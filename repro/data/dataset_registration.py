"""Registering data-set specs (issue 16) and checking that a prepared copy is still the one a
spec describes.

Registration: ``--dataset path/to/spec.toml`` anywhere a data set is named
(:func:`register_spec_path`), or a folder of spec files (or a spec file) in ``$REPRO_DATASETS``
(:data:`ENV`; os.pathsep-separated), each registered under its ``name``
(:func:`declared_specs`); a name may not shadow a built-in data set.  The registry
(:mod:`repro.data.registry`) makes each declared spec a data set; it reads this module, never
the other way round (:func:`registrations` tells it when to rebuild).

Currency: a prepared copy records the spec file it was made from and :func:`spec_key`; on
every load :func:`check_current` says why it no longer matches (the spec, its labels file or
its source changed).  :func:`prepare_command` names the command that (re)prepares a data set,
for error messages.

The spec's fields, its validation and its key material live in :mod:`repro.data.dataset_spec`.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

from repro.data import dataset_spec as _spec  # its caps, read when used (tests lower them)
from repro.data.dataset_spec import (DatasetSpec, escape_name, key_material, load_dataset_spec,
                                     naming_material, role_of)
from repro.errors import SpecError

ENV = "REPRO_DATASETS"


def spec_files() -> tuple[list[Path], list[Path]]:
    """(files named in ``$REPRO_DATASETS``, ``*.toml`` of the folders named there), sorted.
    A named file must be a valid spec; a folder's other files may be anything (only the
    valid specs among them are registered)."""
    named: list[Path] = []
    found: list[Path] = []
    for item in filter(None, os.environ.get(ENV, "").split(os.pathsep)):
        p = Path(item)
        if p.is_dir():
            found += sorted(p.glob("*.toml"))
        else:
            named.append(p)
    return named, found


def declared_specs() -> tuple[dict[str, tuple[Path, DatasetSpec]], list[tuple[Path, str]]]:
    """{name: (spec file, spec)} of every registered spec, and the (file, problem) of the folder
    files skipped (not data-set specs, or invalid).  Two files declaring one name is a ConfigError naming
    both; so is a named file that is not a valid spec."""
    from repro.errors import ConfigError

    named, found = spec_files()
    out: dict[str, tuple[Path, DatasetSpec]] = {}
    skipped: list[tuple[Path, str]] = []
    for path, must in [(p, True) for p in named] + [(p, False) for p in found]:
        try:
            spec = load_dataset_spec(path)
        except SpecError as e:
            if must:
                raise
            skipped.append((path, str(e)))
            if not _regular_small(path):  # a FIFO, device or huge file: said once
                _warn_once(str(e))
            continue
        other = out.get(spec.name)
        if other is not None and other[0].resolve() != path.resolve():
            raise ConfigError(f"data set {spec.name!r} is declared by two spec files: "
                              f"{other[0]} and {path}")
        out[spec.name] = (path, spec)
    return out, skipped


_WARNED: set[str] = set()


def _regular_small(path: Path) -> bool:
    """Whether ``path`` is a regular file within
    :data:`~repro.data.dataset_spec.MAX_SPEC_BYTES` (``stat`` only)."""
    import stat

    try:
        st = path.stat()
    except (OSError, ValueError):
        return False
    return stat.S_ISREG(st.st_mode) and st.st_size <= _spec.MAX_SPEC_BYTES


def _warn_once(message: str) -> None:
    """One line on stderr per problem and process: a ``*.toml`` in a ``$REPRO_DATASETS`` folder
    that is no readable file is skipped, and commands about other data sets go on (issue 29: a
    FIFO or a link to /dev/zero there blocked ``repro data info bandai2-mini``)."""
    import sys

    if message not in _WARNED:
        _WARNED.add(message)
        print(f"repro: warning: skipped: {escape_name(message)}", file=sys.stderr)


def skipped_reason(name: str) -> str:
    """For the "unknown data set" error: why the spec file that declares ``name`` (its stem, or
    a ``name = "..."`` line in it) was skipped from a ``$REPRO_DATASETS`` folder (a refused
    pattern, a FIFO ...); else how many were skipped and the first problem; '' if none was."""
    from repro.errors import ReproError

    try:
        skipped = declared_specs()[1]
    except ReproError:
        return ""
    if not skipped:
        return ""
    line = re.compile(r"(?m)^\s*name\s*=\s*[\"']" + re.escape(name) + r"[\"']\s*(#.*)?$")

    def declares(path: Path) -> bool:
        from repro.data.sources import read_regular

        if path.stem == name:
            return True
        try:
            text = read_regular(path, _spec.MAX_SPEC_BYTES, "the data-set spec").decode(
                "utf-8", "replace")
        except ReproError:
            return False
        return line.search(text) is not None

    def flat(message: str) -> str:
        one = " ".join(message.split())
        return one if len(one) <= 300 else one[:297] + "..."

    mine = [m for p, m in skipped if declares(p)]
    if mine:
        return "; its spec file was skipped: " + "; ".join(flat(m) for m in mine[:2])
    return (f"; {len(skipped)} spec file(s) in ${ENV} were skipped, the first: "
            f"{flat(skipped[0][1])}")


def spec_file_of(name: str) -> Path | None:
    """The registered spec file that declares ``name``, if any."""
    found = declared_specs()[0].get(name)
    return None if found is None else found[0]


def is_spec_path(text: str) -> bool:
    return text.endswith(".toml") and Path(text).is_file()


#: how many times :func:`register_spec_path` ran (:func:`registrations`)
_REGISTERED = [0]


def register_spec_path(text: str) -> str:
    """Register the spec file ``text`` for this process and the job processes it starts (its
    path joins ``$REPRO_DATASETS``; the registry is rebuilt on its next use); returns the data
    set's name."""
    path = Path(text).resolve()
    spec = load_dataset_spec(path)
    items = [f for f in os.environ.get(ENV, "").split(os.pathsep) if f]
    if str(path) not in items:
        os.environ[ENV] = os.pathsep.join(items + [str(path)])
    _REGISTERED[0] += 1  # the registry is rebuilt on its next use (registrations())
    return spec.name


def registrations() -> int:
    """How many times :func:`register_spec_path` ran in this process: the registry
    (:data:`repro.data.registry.DATASETS`) rebuilds itself when the count changed since it
    was built, so a spec file registered here is a data set there."""
    return _REGISTERED[0]


def spec_key(spec: DatasetSpec, spec_path: Path) -> str:
    """What a prepared copy must have been made from, cheap to recompute on every load: the
    validated spec less its words (description, license, credit), the labels side file's
    bytes, and the source's size and modification time (its bytes enter the fingerprint at
    prepare time)."""
    import hashlib

    from repro.keys import content_key

    from repro.data.sources import read_regular
    from repro.errors import DataError

    here = Path(spec_path).resolve().parent
    side = here / spec.labels.file if spec.labels.file else None
    try:  # capped, and a FIFO is not waited on; a file that cannot be read keys as such
        labels = hashlib.sha256(read_regular(side, _spec.MAX_LABELS_BYTES, "the labels file")
                                ).hexdigest() if side and side.is_file() else None
    except DataError as e:
        labels = f"unreadable: {e.problem}"
    src = here / spec.source.path
    try:  # a folder: only the files the spec reads (another file beside them changes nothing)
        st = src.stat()
        src_state = [st.st_size, st.st_mtime_ns] if src.is_file() else sorted(
            [r, q.stat().st_size, q.stat().st_mtime_ns] for q in src.rglob("*")
            if q.is_file() and role_of(spec, r := q.relative_to(src).as_posix()))
        if src.is_dir():  # a name that is not UTF-8 cannot be keyed as it is
            src_state = [[r if r.isascii() or _utf8(r) else ascii(r), *rest]
                         for r, *rest in src_state]
    except (OSError, ValueError):
        src_state = None
    return content_key({
        "spec": key_material(spec),
        "labels": labels,
        "source": src_state, **naming_material(src)})


def _utf8(text: str) -> bool:
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


def check_current(name: str, spec_path: Path, pointer: dict) -> str | None:
    """Why the prepared copy ``pointer`` (current.json) is not the one ``spec_path``
    describes now, or None."""
    try:
        spec = load_dataset_spec(spec_path)
    except SpecError as e:
        return str(e)
    if pointer.get("spec_file") != str(Path(spec_path).resolve()):
        made_from = pointer.get("spec_file") or "another spec file"
        return f"data set {name!r} was prepared from {made_from}, not {spec_path}"
    if pointer.get("spec_key") != spec_key(spec, spec_path):
        return (f"{spec_path}, its labels file or its source changed since data set {name!r} "
                "was prepared")
    return None


def prepare_command(name: str = "bandai2") -> str:
    """The command that prepares ``name``, for error messages: a declared data set's
    ``repro data prepare SPEC`` (its registered spec file), else the stand-in's
    (:func:`repro.data.builtin_sets.standin_prepare_command`)."""
    from repro.data.builtin_sets import standin_prepare_command
    from repro.errors import ReproError

    try:
        spec = spec_file_of(name)
    except ReproError:  # a broken registration must not hide the error being reported
        spec = None
    if spec is not None:
        return f"repro data prepare {spec}"
    return standin_prepare_command(name)
