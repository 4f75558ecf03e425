"""SQLite index over the run folders (``repro_home()/runs.sqlite``), for fast listing.

The folders are the truth; this file is derived.  :class:`RunIndex` updates one run after each
write of its recorder, :meth:`RunIndex.sync` (run before every listing) adds folders the index
lacks or that changed since (compared by file mtimes), drops rows whose folder is gone and
marks dead RUNNING runs INTERRUPTED, and :meth:`RunIndex.reindex` rebuilds the whole file
(``repro runs reindex``).  A missing or older-schema index is rebuilt silently.
Writers serialise on a file lock beside the database; a rebuild is written to a temp file and
swapped in with ``os.replace``.

The index heals: before a listing it is checked (``PRAGMA quick_check``, and a digest of each
listed row, so an edited byte that SQLite cannot see is caught too), and reads go through no
SQL index (``NOT INDEXED``).  An index that is damaged (corrupt pages, not a database, a
folder or a special file in its place, or any SQLite error but a lock timeout while it is
used) is moved aside to ``runs.sqlite.corrupt-<UTC time>`` with one warning and rebuilt from
the run folders, and the operation is tried once more.  A run folder whose record is damaged
(:mod:`repro.store.run_checks`) is left out with one warning naming it; run folders are never
changed or deleted by the index.

Tables: ``runs`` (one row per run: status, table, scale, dataset, spec, git, times, job counts,
the full ``run.json`` text), ``run_values`` (run_id, row_name, column_name, replicate, value,
extra JSON), ``run_keys`` (run_id, key, mode = read | written), ``meta`` (schema).
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import secrets
import sqlite3
import stat
import time
from contextlib import closing, contextmanager
from pathlib import Path
from typing import Any

from repro.errors import ConfigError, DataError
from repro.store.run_files import (RUN_JSON, RUNNING, QUEUED, VALUES_JSONL, load_run,
                                   reconcile_stale, run_dirs)

INDEX_SCHEMA = 2
log = logging.getLogger("repro.runs")

_DDL = """
CREATE TABLE meta (name TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE runs (
  run_id TEXT PRIMARY KEY, status TEXT NOT NULL, table_id TEXT, scale TEXT, dataset TEXT,
  spec_version TEXT, spec_hash TEXT, git_commit TEXT, git_dirty INTEGER,
  created TEXT, started TEXT, ended TEXT, host TEXT,
  n_jobs INTEGER, n_hits INTEGER, n_computed INTEGER, n_values INTEGER,
  stamp TEXT NOT NULL, run_json TEXT NOT NULL, digest TEXT NOT NULL);
CREATE INDEX runs_table ON runs(table_id, created);
CREATE TABLE run_values (
  run_id TEXT NOT NULL, seq INTEGER NOT NULL, row_name TEXT NOT NULL, column_name TEXT NOT NULL,
  replicate INTEGER, value REAL, extra TEXT, PRIMARY KEY (run_id, seq));
CREATE TABLE run_keys (run_id TEXT NOT NULL, key TEXT NOT NULL, mode TEXT NOT NULL,
  PRIMARY KEY (run_id, key, mode));
CREATE INDEX run_keys_key ON run_keys(key);
"""


def index_path() -> Path:
    from repro.paths import repro_home

    return repro_home() / "runs.sqlite"


def _stamp(run_dir: Path) -> str:
    parts = []
    for name in (RUN_JSON, VALUES_JSONL):
        try:
            parts.append(str((run_dir / name).stat().st_mtime_ns))
        except OSError:
            parts.append("-")
    return ":".join(parts)


#: the columns ``repro runs ls`` shows (and :func:`_digest` covers)
_LISTED = ("run_id, status, table_id, scale, dataset, spec_version, spec_hash, git_commit, "
           "git_dirty, created, started, ended, host, n_jobs, n_hits, n_computed, n_values, "
           "stamp")


def _digest(row: dict[str, Any]) -> str:
    """sha256 of a run's listed columns: a row whose bytes were edited no longer matches."""
    cols = [c.strip() for c in _LISTED.split(",")]
    text = json.dumps([row.get(c) for c in cols], ensure_ascii=True)
    return hashlib.sha256(text.encode()).hexdigest()


#: what reading a damaged index raises (a text column whose bytes are not UTF-8: the second)
_DAMAGE = (sqlite3.DatabaseError, UnicodeDecodeError)


def _locked(e: Exception) -> bool:
    """A lock timeout (another process writes): not damage, never a reason to rebuild."""
    return isinstance(e, sqlite3.OperationalError) and "locked" in str(e)


#: SQLite's result codes for a damaged file (the low byte of an extended code)
_CORRUPT_CODES = (getattr(sqlite3, "SQLITE_CORRUPT", 11), getattr(sqlite3, "SQLITE_NOTADB", 26))
_CORRUPT_TEXT = ("file is not a database", "database disk image is malformed", "no such table",
                 "no such column", "could not decode to utf-8")


def _is_damage(e: Exception) -> bool:
    """Whether ``e`` (one of ``_DAMAGE``) says the index file itself is damaged (corrupt
    pages, not a database, tables missing or text that is not UTF-8), so moving it aside and
    rebuilding helps.  A read-only store, a disk I/O error or a file that cannot be opened
    are not damage: rebuilding would fail the same way, or lose a good index."""
    if isinstance(e, UnicodeDecodeError):
        return True
    code = getattr(e, "sqlite_errorcode", None)
    if code is not None and (code & 0xFF) in _CORRUPT_CODES:
        return True
    text = str(e).lower()  # sqlite3's "Could not decode to UTF-8 column ..." (an OperationalError)
    return any(t in text for t in _CORRUPT_TEXT)


def _one_line(text: object) -> str:
    """``text`` on one line (SQLite's messages and quick_check rows may hold newlines)."""
    return "; ".join(x.strip() for x in str(text).splitlines() if x.strip())


def _unusable(e: Exception, path: Path) -> ConfigError:
    """The one-line error for an index SQLite cannot use for a reason other than damage."""
    msg = _one_line(e)
    hint = ""
    if "readonly" in msg or "read-only" in msg:
        hint = " (the store is read-only: give REPRO_HOME a writable folder)"
    return ConfigError(f"the run index {path} cannot be used: {msg}{hint}")


def _inode(path: Path) -> int | None:
    try:
        return os.stat(path).st_ino
    except OSError:
        return None


def _text(x: Any) -> str | None:
    return x if isinstance(x, str) or x is None else str(x)


def _delete(con: sqlite3.Connection, rid: str) -> None:
    for t in ("runs", "run_values", "run_keys"):
        con.execute(f"DELETE FROM {t} WHERE run_id=?", (rid,))


def _insert(con: sqlite3.Connection, rid: str, rec, stamp: str) -> None:
    """The rows of one run (fields checked by :mod:`repro.store.run_checks` when read)."""
    r = rec.run
    jobs = r.get("jobs") or []
    git = r.get("git") or {}
    spec = r.get("spec") or {}
    _delete(con, rid)
    row = {"run_id": rid, "status": r["status"], "table_id": _text(r.get("table")),
           "scale": _text(r.get("scale")), "dataset": _text(r.get("dataset")),
           "spec_version": None if spec.get("version") is None else str(spec.get("version")),
           "spec_hash": _text(spec.get("hash")), "git_commit": _text(git.get("commit")),
           "git_dirty": None if not git else int(bool(git.get("dirty"))),
           "created": _text(r.get("created")), "started": _text(r.get("started")),
           "ended": _text(r.get("ended")), "host": _text((r.get("env") or {}).get("host")),
           "n_jobs": len(jobs), "n_hits": sum(1 for j in jobs if j.get("status") == "hit"),
           "n_computed": sum(1 for j in jobs if j.get("status") == "computed"),
           "n_values": len(rec.values), "stamp": stamp}
    con.execute("INSERT INTO runs VALUES (?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?)",
                (*row.values(), json.dumps(r, sort_keys=True), _digest(row)))
    base = {"row", "column", "replicate", "value", "schema"}
    con.executemany(
        "INSERT INTO run_values VALUES (?,?,?,?,?,?,?)",
        [(rid, i, str(v["row"]), str(v["column"]), v.get("replicate"),
          None if v.get("value") is None else float(v["value"]),
          json.dumps({k: x for k, x in v.items() if k not in base}, sort_keys=True))
         for i, v in enumerate(rec.values)])
    keys = r.get("keys") or {}
    con.executemany("INSERT OR IGNORE INTO run_keys VALUES (?,?,?)",
                    [(rid, k, "read") for k in keys.get("read") or []]
                    + [(rid, k, "written") for k in keys.get("written") or []])


def _listed(row: dict[str, Any]) -> dict[str, Any]:
    """A row of :meth:`RunIndex.list`: its stored ``run_json`` replaced by the record's
    ``error`` and ``note`` (text or None)."""
    try:
        rj = json.loads(row.pop("run_json") or "{}")
    except ValueError:
        rj = {}
    rj = rj if isinstance(rj, dict) else {}
    row["error"] = _text(rj.get("error"))
    row["note"] = _text(rj.get("note"))
    return row


class RunIndex:
    def __init__(self, path: str | Path | None = None, runs_dir: str | Path | None = None):
        from repro.paths import runs_root

        self.path = Path(path) if path is not None else index_path()
        self.runs_dir = Path(runs_dir) if runs_dir is not None else runs_root()

    # ------------------------------------------------------------------ plumbing
    @contextmanager
    def _writing(self):
        from filelock import FileLock

        self.path.parent.mkdir(parents=True, exist_ok=True)
        with FileLock(str(self.path) + ".lock"):
            yield

    def _open(self, path: Path) -> sqlite3.Connection:
        con = sqlite3.connect(str(path), timeout=30)
        con.row_factory = sqlite3.Row
        return con

    def _state(self, full: bool = False) -> str | None:
        """None when the index can be used; else why not: ``missing``, ``schema`` (another
        schema: rebuilt in place) or the damage found (the file is then moved aside).
        ``full`` adds SQLite's ``PRAGMA quick_check`` (every page of the file read)."""
        try:
            st = os.stat(self.path)
        except FileNotFoundError:
            return "missing"
        except OSError as e:
            return f"cannot be read ({e.strerror or e})"
        if not stat.S_ISREG(st.st_mode):  # a folder, a pipe (reading it would block), ...
            return "not a regular file"
        try:
            with closing(self._open(self.path)) as con:
                row = con.execute("SELECT value FROM meta WHERE name='schema'").fetchone()
                if row is None or row[0] != str(INDEX_SCHEMA):
                    return "schema"
                con.execute("SELECT count(*) FROM runs").fetchone()
                if full:
                    res = [r[0] for r in con.execute("PRAGMA quick_check")]
                    if res != ["ok"]:
                        return f"quick_check: {'; '.join(map(_one_line, res))[:200]}"
        except _DAMAGE as e:
            if _locked(e):
                raise
            if "no such table" in str(e):
                return "schema"
            if not _is_damage(e):
                raise _unusable(e, self.path) from None
            return _one_line(e)
        return None

    def _ensure(self, full: bool = False) -> None:
        """Rebuild the index if it is missing, damaged or of another schema."""
        if self._state(full) is not None:
            with self._writing():
                why = self._state(full)
                if why is not None:
                    if why not in ("missing", "schema"):
                        self._move_aside(why)
                    self._rebuild_locked()

    def _move_aside(self, why: str) -> None:
        """Rename the damaged index (and its journal) to ``<name>.corrupt-<UTC time>``."""
        stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
        dest = self.path.with_name(f"{self.path.name}.corrupt-{stamp}-{secrets.token_hex(2)}")
        try:
            os.rename(self.path, dest)
        except FileNotFoundError:
            return
        except OSError as e:
            raise DataError(f"the run index is damaged ({why}) and cannot be moved aside "
                            f"({e.strerror or e}); move it away and run `repro runs reindex`",
                            file=self.path) from None
        for suffix in ("-journal", "-wal", "-shm"):
            Path(str(self.path) + suffix).unlink(missing_ok=True)
        log.warning("repro: warning: the run index %s was damaged (%s); moved aside to %s and "
                    "rebuilt from the run folders", self.path, why, dest.name)

    def _healing(self, op):
        """``op()``; on a SQLite error (the index damaged in a way the checks did not see) the
        index is moved aside, rebuilt, and ``op()`` tried once more."""
        ino = _inode(self.path)
        try:
            return op()
        except _DAMAGE as e:
            if _locked(e):
                raise
            if not _is_damage(e):
                raise _unusable(e, self.path) from None
            why = _one_line(e)
        with self._writing():
            if _inode(self.path) == ino:  # else another process rebuilt it meanwhile
                self._move_aside(why)
                self._rebuild_locked()
        return op()

    def _rebuild_locked(self) -> int:
        tmp = self.path.with_name(f".{self.path.name}.tmp-{os.getpid()}-{secrets.token_hex(3)}")
        try:
            with closing(self._open(tmp)) as con:
                # a temp file: journal in memory, no fsync per statement; one before the rename
                con.executescript("PRAGMA journal_mode=MEMORY; PRAGMA synchronous=OFF; BEGIN;"
                                  + _DDL)
                con.execute("INSERT INTO meta VALUES ('schema', ?)", (str(INDEX_SCHEMA),))
                n = 0
                for d in run_dirs(self.runs_dir):
                    if self._upsert(con, d):
                        n += 1
                con.commit()
            fd = os.open(tmp, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
            if os.path.lexists(self.path) and not (os.path.isfile(self.path)
                                                   or os.path.islink(self.path)):
                self._move_aside("not a regular file")  # a folder: os.replace cannot
            os.replace(tmp, self.path)
        finally:
            tmp.unlink(missing_ok=True)
        for suffix in ("-journal", "-wal", "-shm"):
            Path(str(self.path) + suffix).unlink(missing_ok=True)
        return n

    @staticmethod
    def _upsert(con: sqlite3.Connection, run_dir: Path) -> bool:
        """(Re)index one run folder; a damaged record is left out with one warning."""
        stamp = _stamp(run_dir)
        rid = run_dir.name
        try:
            rec = load_run(run_dir)
        except DataError as e:
            log.warning("repro: warning: not indexing run %s: %s", rid, e)
            _delete(con, rid)
            return False
        con.execute("SAVEPOINT one_run")
        try:
            _insert(con, rid, rec, stamp)
        except (sqlite3.InterfaceError, sqlite3.ProgrammingError, sqlite3.DataError,
                OverflowError, ValueError, TypeError, RecursionError) as e:
            con.execute("ROLLBACK TO one_run")
            con.execute("RELEASE one_run")
            log.warning("repro: warning: not indexing run %s: %s", rid, str(e)[:200])
            _delete(con, rid)
            return False
        con.execute("RELEASE one_run")
        return True

    # ------------------------------------------------------------------ API
    def update(self, run_dir: str | Path) -> None:
        """(Re)index one run folder from its files."""
        def op():
            self._ensure()
            with self._writing(), closing(self._open(self.path)) as con:
                self._upsert(con, Path(run_dir))
                con.commit()
        self._healing(op)

    def reindex(self) -> int:
        """Rebuild the index from the run folders; returns the number of runs indexed."""
        with self._writing():
            if os.path.lexists(self.path) and self._state() not in (None, "missing", "schema"):
                self._move_aside(self._state() or "")
            return self._rebuild_locked()

    def sync(self) -> None:
        """Bring the index up to date with the folders (one stat per run; open runs whose
        process died are marked INTERRUPTED); a damaged index is rebuilt first."""
        self._ensure(full=True)
        self._healing(self._sync)

    def _sync(self) -> None:
        dirs = {d.name: d for d in run_dirs(self.runs_dir)}
        have: dict[str, tuple] = {}
        drop = []  # rowids of rows to delete: a run seen twice, a run whose folder is gone
        with closing(self._open(self.path)) as con:
            for r in con.execute(f"SELECT rowid, {_LISTED}, digest FROM runs NOT INDEXED"):
                r = dict(r)
                ok = r.pop("digest") == _digest(r)  # an edited byte SQLite cannot see
                if r["run_id"] in have:
                    drop += [r["rowid"], have[r["run_id"]][2]]
                    ok = False
                have[r["run_id"]] = (r["stamp"] if ok else None, r["status"], r["rowid"])
        open_runs = [d for n, d in dirs.items()
                     if n not in have or have[n][1] in (RUNNING, QUEUED)]
        for d in open_runs:
            try:
                reconcile_stale(d)
            except OSError as e:  # pragma: no cover - read-only media
                log.warning("cannot update %s: %s", d, e)
        stale = [d for n, d in dirs.items() if n not in have or have[n][0] != _stamp(d)]
        gone = [n for n in have if n not in dirs]
        drop += [have[n][2] for n in gone]
        if not stale and not drop:
            return
        with self._writing(), closing(self._open(self.path)) as con:
            for rowid in drop:
                con.execute("DELETE FROM runs WHERE rowid=?", (rowid,))
            for n in gone:
                _delete(con, n)
            for d in stale:
                self._upsert(con, d)
            con.commit()

    def list(self, table: str | None = None, status: str | None = None,
             limit: int | None = None) -> list[dict[str, Any]]:
        """Runs, newest first (after :meth:`sync`); ``error`` / ``note`` from each run's
        record (a FAILED run's error, an INTERRUPTED one's note; None otherwise)."""
        self.sync()
        q = ("SELECT run_id, status, table_id, scale, dataset, spec_version, spec_hash, "
             "git_commit, git_dirty, created, started, ended, host, n_jobs, n_hits, n_computed, "
             "n_values, run_json FROM runs NOT INDEXED")
        cond, args = [], []
        if table:
            cond.append("table_id = ?")
            args.append(table)
        if status:
            cond.append("status = ?")
            args.append(status.upper())
        if cond:
            q += " WHERE " + " AND ".join(cond)
        q += " ORDER BY run_id DESC"
        if limit:
            q += f" LIMIT {int(limit)}"

        def op():
            with closing(self._open(self.path)) as con:
                return [_listed(dict(r)) for r in con.execute(q, args)]
        return self._healing(op)

    def _query(self, q: str, args: tuple = ()) -> list[sqlite3.Row]:
        def op():
            self._ensure()
            with closing(self._open(self.path)) as con:
                return list(con.execute(q, args))
        return self._healing(op)

    def values(self, run_id: str) -> list[dict[str, Any]]:
        return [dict(r) for r in self._query(
            "SELECT row_name, column_name, replicate, value, extra FROM run_values "
            "WHERE run_id=? ORDER BY seq", (run_id,))]

    def runs_using(self, key: str) -> list[str]:
        """Runs that read or wrote store key ``key``."""
        return sorted({r[0] for r in self._query(
            "SELECT run_id FROM run_keys WHERE key=?", (key,))})

    def dump(self) -> dict[str, list[tuple]]:
        """Every row of every table, sorted (to compare two indexes)."""
        return {t: sorted(tuple(r) for r in self._query(f"SELECT * FROM {t}"))
                for t in ("meta", "runs", "run_values", "run_keys")}

