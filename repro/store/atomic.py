"""Atomic file writes: temp file in the same folder, fsync, ``os.replace``.

A reader never sees half a file: either the old bytes or the new ones.  Used for every file
the store and the run records persist (manifests, ``run.json``, ``values.jsonl``, ...).

The rename also means a write never goes through a link: a symbolic link at the target name is
replaced, its target untouched.  :func:`output_dir`, :func:`output_subdir` and
:func:`write_output` apply that to the folders a command writes into (``repro report |
strips | export --out``): the named folder must be a folder (not a file, a device or
``/proc``), a linked sub-folder inside it is replaced by a real one, never written through,
and a failed write is one :class:`~repro.errors.ConfigError` naming the file.
"""

from __future__ import annotations

import json
import math
import os
import secrets
import stat
from datetime import datetime, timezone
from pathlib import Path
from typing import Any


def utc_now() -> str:
    """The current UTC time as ISO 8601 with microseconds and a ``Z`` suffix."""
    return datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def fsync_dir(path: Path) -> None:
    """Make a rename inside ``path`` durable (no-op where directories cannot be opened)."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def atomic_write_bytes(path: str | Path, data: bytes, *, mode: int | None = None) -> None:
    """Write ``data`` to ``path`` atomically (temp file beside it, fsync, rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.parent / f".{path.name}.tmp-{os.getpid()}-{secrets.token_hex(4)}"
    try:
        with open(tmp, "xb") as f:  # a fresh file: never through a link planted at that name
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        if mode is not None:
            os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    fsync_dir(path.parent)


def jsonable(obj: Any) -> Any:
    """Plain-JSON form of ``obj``: numpy scalars/arrays to numbers/lists, tuples to lists,
    non-finite floats to ``None`` (JSON has no NaN), paths to strings."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, (set, frozenset)):
        return sorted(jsonable(v) for v in obj)
    if isinstance(obj, bool) or obj is None or isinstance(obj, (str, int)):
        return obj
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, Path):
        return str(obj)
    tolist = getattr(obj, "tolist", None)
    if callable(tolist):
        return jsonable(tolist())
    if hasattr(obj, "model_dump"):
        return jsonable(obj.model_dump(mode="json"))
    raise TypeError(f"cannot write {type(obj).__name__} as JSON")


def dumps(obj: Any, *, indent: int | None = 2) -> str:
    """JSON text of :func:`jsonable` ``obj`` with sorted keys (stable, diff-friendly)."""
    return json.dumps(jsonable(obj), indent=indent, sort_keys=True, ensure_ascii=False, allow_nan=False)


def atomic_write_json(path: str | Path, obj: Any, *, mode: int | None = None) -> None:
    atomic_write_bytes(path, (dumps(obj) + "\n").encode("utf-8"), mode=mode)


# ---------------------------------------------------------------------- command outputs
#: longest output folder name accepted (Linux's PATH_MAX)
MAX_OUT_CHARS = 4096


def _out_error(option: str, text: str, problem: str):
    from repro.errors import ConfigError

    return ConfigError(f"{option} {text!r}: {problem}")


def output_dir(path: str | Path, *, option: str = "--out", create: bool = True) -> Path:
    """The folder ``path`` (created with its parents when missing) that a command writes its
    outputs into, or a ConfigError naming ``option``: an empty name (it would mean the current
    folder), a NUL, a name over :data:`MAX_OUT_CHARS`, something that exists but is not a folder
    (a file, ``/dev/null``, a pipe), or a place where no folder can be made (``/proc/x``).
    A link the user names as the folder itself is followed (they chose it).  ``create=False``
    only checks (a command does that before its work, so a bad name costs nothing)."""
    text = os.fspath(path)
    if text == "":
        raise _out_error(option, text, "the folder name is empty (name a folder to write "
                                       "into, e.g. ./out)")
    if "\0" in text:
        raise _out_error(option, text, "the folder name holds a NUL character")
    if len(text) > MAX_OUT_CHARS:
        raise _out_error(option, text[:60] + "...", f"the folder name is longer than "
                                                    f"{MAX_OUT_CHARS} characters")
    p = Path(text)
    try:
        st = os.stat(p)
    except FileNotFoundError:
        st = None
    except (OSError, ValueError) as e:
        raise _out_error(option, text, f"cannot use it as a folder "
                                       f"({getattr(e, 'strerror', None) or e})") from None
    if st is not None and not stat.S_ISDIR(st.st_mode):
        kind = ("a file" if stat.S_ISREG(st.st_mode) else
                "a special file (device, pipe or socket)")
        raise _out_error(option, text, f"is {kind}, not a folder")
    if not create:
        if st is None:
            _can_make(p, option, text)
        return p
    try:
        p.mkdir(parents=True, exist_ok=True)
        probe = p / f".repro-write-probe-{os.getpid()}-{secrets.token_hex(4)}"
        os.close(os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o600))
        os.unlink(probe)
    except (OSError, ValueError) as e:
        raise _out_error(option, text, f"cannot write into it "
                                       f"({getattr(e, 'strerror', None) or e})") from None
    return p


def _can_make(p: Path, option: str, text: str) -> None:
    """Whether the missing folder ``p`` could be made: its nearest existing ancestor is a
    folder this process may write into and search (``os.access``; nothing is made, so a
    check never writes outside the folder named), on a file system mounted writable that can
    hold files at all (``statvfs``: ``/proc`` and ``/sys`` have no blocks, and root passes
    ``os.access`` anywhere).  Whatever still fails at creation :func:`output_dir` turns into
    one line."""
    anc = p.absolute().parent
    while not os.path.lexists(anc) and anc != anc.parent:
        anc = anc.parent
    if not anc.is_dir():
        raise _out_error(option, text, f"cannot be made: {str(anc)!r} is not a folder")
    if not os.access(anc, os.W_OK | os.X_OK):
        raise _out_error(option, text, f"cannot be made: no permission to write into "
                                       f"{str(anc)!r}")
    try:
        fs = os.statvfs(anc)
    except OSError:
        return
    if fs.f_flag & os.ST_RDONLY or fs.f_blocks == 0:  # a read-only mount; /proc, /sys
        raise _out_error(option, text, f"cannot be made: {str(anc)!r} is on a read-only or "
                                       "pseudo file system")


def output_subdir(parent: str | Path, name: str) -> Path:
    """``parent/name`` as a real folder: a symbolic link there is removed (its target is left
    alone) and a folder made in its place, so nothing is written through it; a file or
    special file there is a ConfigError."""
    p = Path(parent) / name
    try:
        st = os.lstat(p)
    except FileNotFoundError:
        st = None
    except OSError as e:
        raise _out_error("output folder", str(p), e.strerror or str(e)) from None
    try:
        if st is not None and stat.S_ISLNK(st.st_mode):
            p.unlink()
            st = None
        if st is not None and not stat.S_ISDIR(st.st_mode):
            raise _out_error("output folder", str(p), "is a file, not a folder (move it away)")
        if st is None:
            p.mkdir()
    except OSError as e:
        raise _out_error("output folder", str(p), f"cannot create it "
                                                  f"({e.strerror or e})") from None
    return p


def write_output(path: str | Path, data: bytes | str) -> Path:
    """Write one output file atomically (:func:`atomic_write_bytes`: a link at ``path`` is
    replaced, never followed); an OS error is a ConfigError naming the file."""
    path = Path(path)
    if isinstance(data, str):
        data = data.encode("utf-8")
    try:
        atomic_write_bytes(path, data)
    except OSError as e:
        raise _out_error("cannot write", str(path), e.strerror or str(e)) from None
    return path
