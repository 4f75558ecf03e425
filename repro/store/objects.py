"""Content-addressed object store under ``REPRO_HOME/store`` (issue 4, item 4).

An *object* is a folder of payload files named by a 64-hex content key (see
:func:`repro.keys.content_key`; the key is computed from what *produces* the payload, not from the
payload itself)::

    store/objects/<key[:2]>/<key>/manifest.json      {schema, key, kind, files, created, meta}
    store/objects/<key[:2]>/<key>/<payload files>     read-only once published
    store/objects/<key[:2]>/.tmp-<key>-<pid>-<hex>/   a computation in progress (or a stale one)
    store/locks/<key[:2]>/<key>.lock                  one file lock per key
    store/scratch/<key>/                              resumable work (checkpoints) for that key
    store/stamps/<key[:2]>/<key>.json                 "verified at" stamps of big files
    store/quarantine/<key>-<time>/                    corrupt objects, moved aside, with REASON.txt
    store/logs/<key[:2]>/<key>.log                    job logs (never part of a payload)

Guarantees:

- **Atomic publish.** The payload is written into a temp folder beside the object, hashed into
  the manifest, made read-only and published with one ``os.replace``: readers see a complete
  object or none.
- **One computation per key.** :meth:`Store.compute` takes the key's file lock, re-checks the
  store, and only then computes; a concurrent caller blocks on the lock and then reads the
  object the first one published.
- **Verified reads.** :meth:`Store.get` checks every file's size and sha256 against the
  manifest.  A mismatch is *reported* (a warning naming key and file, and an entry in
  :attr:`Store.corrupt`), the object is moved to ``quarantine/`` and ``None`` is returned, so
  the caller rebuilds it.  Files of at least ``stamp_min_bytes`` (default 64 MiB) whose
  (size, mtime, inode) still match a stamp written after a full hash are not re-hashed by
  :meth:`get`; :meth:`verify` always hashes everything (see ``docs/store.md`` for the timings).

The key format, the manifest and the records the store hands out (:class:`StoredObject`, …)
are in :mod:`repro.store.object_files`.
"""

from __future__ import annotations

import logging
import os
import secrets
import shutil
import stat
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from repro.keys import sha256_file
from repro.store.atomic import atomic_write_json, fsync_dir, jsonable, utc_now
from repro.store.object_files import (KEY_RE, MANIFEST, STORE_SCHEMA, CorruptObject, GcReport,
                                      ObjectInfo, StoredObject, VerifyReport, check_key,
                                      payload_files, rmtree, tree_size)

STAMP_MIN_BYTES = 64 << 20
_TMP_PREFIX = ".tmp-"
_OLD_PREFIX = ".old-"

log = logging.getLogger("repro.store")

# Keys whose lock the current thread holds (so a corrupt object found while we hold its lock is
# quarantined by us instead of being mistaken for someone else's rebuild).
_held = threading.local()


def _held_keys() -> set[str]:
    s = getattr(_held, "keys", None)
    if s is None:
        s = _held.keys = set()
    return s


def _hash_file_fsync(path: Path) -> str:
    digest = sha256_file(path)
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)
    return digest


class Store:
    """The content-addressed store rooted at ``root`` (default :func:`repro.paths.store_root`)."""

    def __init__(self, root: str | Path | None = None, *, stamp_min_bytes: int = STAMP_MIN_BYTES):
        if root is None:
            from repro.paths import store_root

            root = store_root()
        self.root = Path(root)
        self.stamp_min_bytes = int(stamp_min_bytes)
        #: every corrupt object this instance found (for reports); see :meth:`get`.
        self.corrupt: list[CorruptObject] = []

    # ------------------------------------------------------------------ layout
    @property
    def objects_dir(self) -> Path:
        return self.root / "objects"

    def object_dir(self, key: str) -> Path:
        check_key(key)
        return self.objects_dir / key[:2] / key

    def lock_path(self, key: str) -> Path:
        return self.root / "locks" / key[:2] / f"{key}.lock"

    def stamp_path(self, key: str) -> Path:
        return self.root / "stamps" / key[:2] / f"{key}.json"

    def log_path(self, key: str) -> Path:
        return self.root / "logs" / key[:2] / f"{key}.log"

    @property
    def quarantine_dir(self) -> Path:
        return self.root / "quarantine"

    @property
    def plans_dir(self) -> Path:
        return self.root / "plans"

    @property
    def tmp_dir(self) -> Path:
        return self.root / "tmp"

    # ------------------------------------------------------------------ locks
    def _filelock(self, key: str):
        from filelock import FileLock

        p = self.lock_path(key)
        p.parent.mkdir(parents=True, exist_ok=True)
        return FileLock(str(p))

    @contextmanager
    def lock(self, key: str, *, blocking: bool = True) -> Iterator[bool]:
        """Hold the key's file lock.  Yields ``True`` when held; with ``blocking=False`` yields
        ``False`` at once if another process (or thread) holds it.  Re-entrant per thread."""
        from filelock import Timeout

        check_key(key)
        held = _held_keys()
        if key in held:
            yield True
            return
        fl = self._filelock(key)
        try:
            fl.acquire(timeout=0)
        except Timeout:
            if not blocking:
                yield False
                return
            log.info("waiting for another process computing %s", key[:12])
            fl.acquire()
        held.add(key)
        try:
            yield True
        finally:
            held.discard(key)
            fl.release()

    # ------------------------------------------------------------------ reading
    def has(self, key: str) -> bool:
        """Whether a published object exists for ``key`` (cheap; not verified)."""
        return (self.object_dir(key) / MANIFEST).is_file()

    def _read_manifest(self, key: str) -> tuple[dict | None, str | None]:
        import json

        mpath = self.object_dir(key) / MANIFEST
        try:
            man = json.loads(mpath.read_text(encoding="utf-8"))
        except FileNotFoundError:
            return None, f"{MANIFEST} missing"
        except (OSError, ValueError) as e:
            return None, f"{MANIFEST} unreadable ({e})"
        if not isinstance(man, dict):
            return None, f"{MANIFEST} is not a JSON object"
        if man.get("schema") != STORE_SCHEMA:
            return None, f"{MANIFEST} has schema {man.get('schema')!r}, expected {STORE_SCHEMA}"
        if man.get("key") != key:
            return None, f"{MANIFEST} names key {str(man.get('key'))[:12]}, not this one"
        if not isinstance(man.get("files"), dict) or not isinstance(man.get("kind"), str):
            return None, f"{MANIFEST} lacks 'files' or 'kind'"
        return man, None

    def _load_stamps(self, key: str) -> dict:
        import json

        try:
            data = json.loads(self.stamp_path(key).read_text(encoding="utf-8"))
            if data.get("schema") == STORE_SCHEMA and isinstance(data.get("files"), dict):
                return data["files"]
        except (OSError, ValueError, AttributeError):
            pass
        return {}

    def _write_stamps(self, key: str, files: dict[str, dict]) -> None:
        d = self.object_dir(key)
        stamps = {}
        for name, ent in files.items():
            if int(ent["size"]) < self.stamp_min_bytes:
                continue
            st = (d / name).stat()
            stamps[name] = [st.st_size, st.st_mtime_ns, st.st_ino, ent["sha256"]]
        path = self.stamp_path(key)
        if stamps:
            atomic_write_json(path, {"schema": STORE_SCHEMA, "key": key, "verified": utc_now(),
                                     "files": stamps})
        else:
            path.unlink(missing_ok=True)

    def _check(self, key: str, *, use_stamps: bool) -> tuple[dict | None, str | None]:
        """Verify the object of ``key``: (manifest, None) when sound, else (None, problem)."""
        man, problem = self._read_manifest(key)
        if problem:
            return None, problem
        d = self.object_dir(key)
        stamps = self._load_stamps(key) if use_stamps else {}
        expected = man["files"]
        try:
            present = {rel for rel, _ in payload_files(d)}
        except (ValueError, OSError) as e:
            return None, str(e)
        extra = sorted(present - set(expected))
        if extra:
            return None, f"unexpected file {extra[0]} (not in the manifest)"
        hashed = False
        for name in sorted(expected):
            ent = expected[name]
            p = d / name
            try:
                st = p.stat()
            except FileNotFoundError:
                return None, f"file {name} missing"
            if st.st_size != int(ent.get("size", -1)):
                return None, f"file {name} has {st.st_size} bytes, manifest says {ent.get('size')}"
            stamp = stamps.get(name)
            if (stamp is not None and st.st_size >= self.stamp_min_bytes
                    and stamp == [st.st_size, st.st_mtime_ns, st.st_ino, ent.get("sha256")]):
                continue
            try:
                digest = sha256_file(p)
            except OSError as e:
                return None, f"file {name} unreadable ({e})"
            hashed = True
            if digest != ent.get("sha256"):
                return None, f"file {name} sha256 mismatch (stored {str(ent.get('sha256'))[:12]}, " \
                             f"read {digest[:12]})"
        if hashed and any(int(e["size"]) >= self.stamp_min_bytes for e in expected.values()):
            try:
                self._write_stamps(key, expected)
            except OSError:
                pass
        return man, None

    def _object(self, key: str, man: dict, *, hit: bool) -> StoredObject:
        return StoredObject(key=key, kind=man["kind"], path=self.object_dir(key),
                            files=man["files"], created=str(man.get("created", "")),
                            meta=man.get("meta") or {}, hit=hit)

    def get(self, key: str) -> StoredObject | None:
        """The verified object for ``key``, or ``None`` if absent or corrupt (then quarantined and
        reported, so the caller rebuilds it)."""
        d = self.object_dir(key)
        if not d.exists():
            return None
        man, problem = self._check(key, use_stamps=True)
        if problem is None:
            return self._object(key, man, hit=True)
        self._handle_corrupt(key, problem)
        return None

    def _handle_corrupt(self, key: str, problem: str) -> CorruptObject | None:
        with self.lock(key, blocking=False) as held:
            if not held:
                # Someone is computing this key right now (a forced rebuild replaces the folder
                # under us, or a rebuild after corruption): not ours to move; treat as a miss.
                log.info("object %s unreadable while another process holds its lock (%s)",
                         key[:12], problem)
                return None
            if not self.object_dir(key).exists():
                return None
            _, problem_again = self._check(key, use_stamps=False)
            if problem_again is None:
                return None  # replaced by a sound object meanwhile
            dest = self._quarantine(key, problem_again)
        rec = CorruptObject(key=key, problem=problem_again, quarantined_to=dest)
        self.corrupt.append(rec)
        log.warning("corrupt store object %s: %s; moved to %s and will be rebuilt",
                    key, problem_again, dest)
        return rec

    def _quarantine(self, key: str, problem: str) -> Path:
        qdir = self.quarantine_dir
        qdir.mkdir(parents=True, exist_ok=True)
        dest = qdir / f"{key}-{time.strftime('%Y%m%dT%H%M%S')}-{secrets.token_hex(3)}"
        os.replace(self.object_dir(key), dest)
        self.stamp_path(key).unlink(missing_ok=True)
        try:
            (dest / "REASON.txt").write_text(f"{utc_now()} {problem}\n", encoding="utf-8")
        except OSError:
            pass
        return dest

    # ------------------------------------------------------------------ writing
    def scratch(self, key: str) -> Path:
        """A persistent, key-addressed folder for resumable work (checkpoints).

        It survives a killed process and is handed to the next attempt with the same key;
        :meth:`compute` removes it once the object is published.
        """
        p = self.root / "scratch" / check_key(key)
        p.mkdir(parents=True, exist_ok=True)
        return p

    def _new_tmp(self, key: str) -> Path:
        parent = self.objects_dir / key[:2]
        parent.mkdir(parents=True, exist_ok=True)
        tmp = parent / f"{_TMP_PREFIX}{key}-{os.getpid()}-{secrets.token_hex(4)}"
        tmp.mkdir()
        return tmp

    def _publish(self, key: str, kind: str, tmp: Path, meta: dict | None) -> StoredObject:
        files = {}
        for rel, p in payload_files(tmp):
            files[rel] = {"sha256": _hash_file_fsync(p), "size": p.stat().st_size}
        if (tmp / MANIFEST).exists():
            raise ValueError(f"a payload may not contain a file named {MANIFEST} (reserved)")
        man = {"schema": STORE_SCHEMA, "key": key, "kind": kind, "files": files,
               "created": utc_now(), "meta": jsonable(meta or {})}
        atomic_write_json(tmp / MANIFEST, man)
        for rel in files:
            os.chmod(tmp / rel, stat.S_IRUSR | stat.S_IRGRP | stat.S_IROTH)
        final = self.object_dir(key)
        old = None
        if final.exists():
            old = final.parent / f"{_OLD_PREFIX}{key}-{os.getpid()}-{secrets.token_hex(4)}"
            os.replace(final, old)
        os.replace(tmp, final)
        fsync_dir(final.parent)
        if old is not None:
            rmtree(old)
        self._write_stamps(key, files)
        return self._object(key, man, hit=False)

    def compute(self, key: str, kind: str, fn: Callable[[Path], Any],
                meta: dict | None = None, *, force: bool = False) -> StoredObject:
        """The object for ``key``, computing it with ``fn(out_dir)`` if it is not stored.

        ``fn`` writes the payload files into ``out_dir`` (a fresh temp folder beside the object).
        Takes the key's file lock, re-checks the store (a concurrent caller that computed it
        meanwhile makes this a hit), computes, publishes atomically, removes the key's scratch
        folder.  On any exception (``KeyboardInterrupt`` included) the temp folder is removed and
        the scratch folder is left for the next attempt.  ``force`` recomputes even when stored.
        ``result.hit`` tells whether it was found (True) or computed here (False).
        """
        check_key(key)
        if not isinstance(kind, str) or not kind:
            raise ValueError("an object needs a non-empty kind")
        if not force:
            obj = self.get(key)
            if obj is not None:
                return obj
        with self.lock(key):
            if not force:
                obj = self.get(key)
                if obj is not None:
                    return obj
            tmp = self._new_tmp(key)
            try:
                fn(tmp)
                obj = self._publish(key, kind, tmp, meta)
            except BaseException:
                rmtree(tmp)
                raise
            rmtree(self.root / "scratch" / key)
            return obj

    def put(self, key: str, src_folder: str | Path, kind: str, meta: dict | None = None,
            *, force: bool = False) -> StoredObject:
        """Publish a copy of ``src_folder``'s files as the object ``key`` (a hit if stored)."""
        src = Path(src_folder)
        if not src.is_dir():
            raise ValueError(f"{src} is not a folder")

        def copy(out: Path) -> None:
            shutil.copytree(src, out, dirs_exist_ok=True)

        return self.compute(key, kind, copy, meta, force=force)

    # ------------------------------------------------------------------ maintenance
    def keys(self) -> list[str]:
        """Keys of every published object folder (sorted)."""
        out = []
        if not self.objects_dir.is_dir():
            return out
        for sub in sorted(self.objects_dir.iterdir()):
            if not sub.is_dir() or sub.name.startswith("."):
                continue
            for d in sorted(sub.iterdir()):
                if d.is_dir() and KEY_RE.match(d.name):
                    out.append(d.name)
        return out

    def info(self, key: str) -> ObjectInfo:
        man, problem = self._read_manifest(key)
        if man is None:
            return ObjectInfo(key, "?", tree_size(self.object_dir(key)), 0, "", {}, problem)
        files = man["files"]
        return ObjectInfo(key=key, kind=man["kind"],
                          size=int(sum(int(f.get("size", 0)) for f in files.values())),
                          n_files=len(files), created=str(man.get("created", "")),
                          meta=man.get("meta") or {})

    def ls(self, kind: str | None = None) -> list[ObjectInfo]:
        """Every object (kind, size, created), sorted by creation time."""
        infos = [self.info(k) for k in self.keys()]
        if kind is not None:
            infos = [i for i in infos if i.kind == kind]
        return sorted(infos, key=lambda i: (i.created, i.key))

    def verify(self, keys: Iterable[str] | None = None,
               progress: Callable[[int, int], None] | None = None) -> VerifyReport:
        """Re-hash every file of every object (no stamps); quarantine and report corrupt ones."""
        ks = list(self.keys() if keys is None else keys)
        rep = VerifyReport()
        for i, key in enumerate(ks):
            man, problem = self._check(key, use_stamps=False)
            if problem is None:
                rep.ok.append(key)
                try:
                    self._write_stamps(key, man["files"])
                except OSError:
                    pass
            else:
                rec = self._handle_corrupt(key, problem)
                rep.corrupt.append(rec or CorruptObject(key, problem, None))
            if progress is not None:
                progress(i + 1, len(ks))
        return rep

    def _stale_temp_dirs(self) -> list[tuple[str, Path]]:
        out = []
        if not self.objects_dir.is_dir():
            return out
        for sub in self.objects_dir.iterdir():
            if not sub.is_dir():
                continue
            for d in sub.iterdir():
                for prefix in (_TMP_PREFIX, _OLD_PREFIX):
                    if d.name.startswith(prefix):
                        key = d.name[len(prefix):len(prefix) + 64]
                        if KEY_RE.match(key):
                            out.append((key, d))
        return out

    def gc(self, referenced: Iterable[str], *, dry_run: bool = False,
           keep_created_after: str | None = None, include_scratch: bool = False) -> GcReport:
        """Remove objects whose key is not in ``referenced``, stale temp folders, scratch of
        published keys (all unlocked scratch with ``include_scratch``), and the quarantine.

        Objects created at or after ``keep_created_after`` (ISO time; the start of the oldest
        live run) and objects whose lock is held are kept.  ``dry_run`` only reports.
        """
        refs = set(referenced)
        rep = GcReport(dry_run=dry_run)
        for key in self.keys():
            if key in refs:
                continue
            info = self.info(key)
            if keep_created_after and info.created and info.created >= keep_created_after:
                continue
            with self.lock(key, blocking=False) as held:
                if not held:
                    rep.kept_locked.append(key)
                    continue
                rep.objects.append(info)
                rep.freed_bytes += info.size
                if not dry_run:
                    rmtree(self.object_dir(key))
                    self.stamp_path(key).unlink(missing_ok=True)
        for key, d in self._stale_temp_dirs():
            with self.lock(key, blocking=False) as held:
                if held:
                    rep.temp_dirs.append(d)
                    rep.freed_bytes += tree_size(d)
                    if not dry_run:
                        rmtree(d)
        scratch_root = self.root / "scratch"
        if scratch_root.is_dir():
            for d in sorted(scratch_root.iterdir()):
                if not KEY_RE.match(d.name):
                    continue
                if not (include_scratch or self.has(d.name)):
                    continue
                with self.lock(d.name, blocking=False) as held:
                    if held:
                        rep.scratch_dirs.append(d)
                        rep.freed_bytes += tree_size(d)
                        if not dry_run:
                            rmtree(d)
        for parent, found in ((self.quarantine_dir, rep.quarantine_dirs),
                              (self.tmp_dir, rep.temp_dirs)):
            if not parent.is_dir():
                continue
            for d in sorted(parent.iterdir()):
                if parent == self.tmp_dir and _owner_alive(d.name):
                    continue
                found.append(d)
                rep.freed_bytes += tree_size(d) if d.is_dir() else d.stat().st_size
                if not dry_run:
                    if d.is_dir():
                        rmtree(d)
                    else:
                        d.unlink(missing_ok=True)
        return rep

    def ephemeral_dir(self) -> Path:
        """A fresh folder for outputs of uncacheable jobs (never published; removed by gc once
        the process that made it has ended)."""
        d = self.tmp_dir / f"uncached-{os.getpid()}-{secrets.token_hex(4)}"
        d.mkdir(parents=True)
        return d


def _owner_alive(name: str) -> bool:
    """Whether the process whose pid is embedded in ``uncached-<pid>-<hex>`` still runs."""
    parts = name.split("-")
    if len(parts) < 3 or not parts[1].isdigit():
        return False
    try:
        os.kill(int(parts[1]), 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


__all__ = ["Store"]
