"""What a store object is, apart from the store that keeps it: the key format
(:func:`check_key`), the manifest's name and schema, the records :class:`repro.store.objects.Store`
hands out (:class:`StoredObject`, :class:`ObjectInfo`, :class:`CorruptObject`,
:class:`VerifyReport`, :class:`GcReport`) and the folder helpers it uses (an object's payload
files, a folder's size, removing a read-only folder, a size in words).  The layout of the store
and its guarantees are in :mod:`repro.store.objects`.
"""

from __future__ import annotations

import os
import re
import shutil
import stat
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

STORE_SCHEMA = 1
MANIFEST = "manifest.json"
#: a store key: 64 lowercase hex digits (a sha256)
KEY_RE = re.compile(r"^[0-9a-f]{64}$")


def check_key(key: str) -> str:
    """Return ``key`` if it is a 64-character lowercase sha256 hex digest, else raise."""
    if not isinstance(key, str) or not KEY_RE.match(key):
        raise ValueError(f"not a store key (64 lowercase hex digits): {key!r}")
    return key


@dataclass(frozen=True)
class StoredObject:
    """A published (verified) object: its folder and manifest.

    ``hit`` says whether the call that returned it found it already stored (``True``) or
    computed it (``False``); ``ephemeral`` marks outputs of uncacheable jobs that live in a
    temporary folder and are never published.
    """

    key: str
    kind: str
    path: Path
    files: dict[str, dict[str, Any]]
    created: str
    meta: dict[str, Any] = field(default_factory=dict)
    hit: bool = True
    ephemeral: bool = False

    def file(self, name: str) -> Path:
        """The path of payload file ``name`` (a manifest entry, ``/``-separated)."""
        if name not in self.files:
            raise KeyError(f"object {self.key[:12]} ({self.kind}) has no file {name!r}; "
                           f"it has {sorted(self.files)}")
        return self.path / name

    def read_bytes(self, name: str) -> bytes:
        return self.file(name).read_bytes()

    def read_text(self, name: str) -> str:
        return self.file(name).read_text(encoding="utf-8")

    def read_json(self, name: str) -> Any:
        import json

        return json.loads(self.read_text(name))

    @property
    def size(self) -> int:
        return int(sum(int(f["size"]) for f in self.files.values()))


@dataclass(frozen=True)
class ObjectInfo:
    """One line of :meth:`Store.ls`."""

    key: str
    kind: str
    size: int
    n_files: int
    created: str
    meta: dict[str, Any]
    problem: str | None = None


@dataclass(frozen=True)
class CorruptObject:
    """A corrupt object that was found (and quarantined unless another process held its lock)."""

    key: str
    problem: str
    quarantined_to: Path | None


@dataclass
class VerifyReport:
    ok: list[str] = field(default_factory=list)
    corrupt: list[CorruptObject] = field(default_factory=list)


@dataclass
class GcReport:
    """What :meth:`Store.gc` removed (or, with ``dry_run``, would remove)."""

    dry_run: bool
    objects: list[ObjectInfo] = field(default_factory=list)
    temp_dirs: list[Path] = field(default_factory=list)
    scratch_dirs: list[Path] = field(default_factory=list)
    quarantine_dirs: list[Path] = field(default_factory=list)
    kept_locked: list[str] = field(default_factory=list)
    freed_bytes: int = 0


def tree_size(path: Path) -> int:
    """Bytes of the plain files under ``path`` (links and unreadable files not counted)."""
    total = 0
    for p in path.rglob("*"):
        try:
            if p.is_file() and not p.is_symlink():
                total += p.stat().st_size
        except OSError:
            pass
    return total


def rmtree(path: Path) -> None:
    """Remove a folder whose files may be read-only (the folders themselves are writable)."""

    def onerror(func, p, exc_info):  # pragma: no cover - only with odd permissions
        try:
            os.chmod(p, stat.S_IRWXU)
            func(p)
        except OSError:
            pass

    if path.exists():
        shutil.rmtree(path, onerror=onerror)


def payload_files(folder: Path) -> Iterator[tuple[str, Path]]:
    """(manifest name, path) of every payload file under ``folder``, sorted; refuses links."""
    for p in sorted(folder.rglob("*")):
        rel = p.relative_to(folder).as_posix()
        if p.is_symlink():
            raise ValueError(f"store payloads must be plain files; {rel} is a symbolic link")
        if p.is_dir():
            continue
        if not p.is_file():
            raise ValueError(f"store payloads must be plain files; {rel} is not one")
        if rel == MANIFEST:
            continue
        yield rel, p




def describe_bytes(n: int) -> str:
    """Human-readable size (binary units)."""
    size = float(n)
    for unit in ("B", "KiB", "MiB", "GiB", "TiB"):
        if size < 1024 or unit == "TiB":
            return f"{size:.0f} {unit}" if unit == "B" else f"{size:.1f} {unit}"
        size /= 1024
    return f"{n} B"  # pragma: no cover


__all__ = ["StoredObject", "ObjectInfo", "CorruptObject", "VerifyReport", "GcReport",
           "STORE_SCHEMA", "MANIFEST", "KEY_RE", "check_key", "describe_bytes", "payload_files",
           "rmtree", "tree_size"]
