"""SQLite index over the run folders (``repro_home()/runs.sqlite``), for fast listing.

The folders are the truth; this file is derived.  :class:`RunIndex` updates one run after each
write of its recorder, :meth:`RunIndex.sync` (run before every listing) adds folders the index
lacks or that changed since (compared by file mtimes), drops rows whose folder is gone and
marks dead RUNNING runs INTERRUPTED, and :meth:`RunIndex.reindex` rebuilds the whole file
(``repro runs reindex``).  A missing, corrupt or older-schema index is rebuilt silently.
Writers serialise on a file lock beside the database; a rebuild is written to a temp file and
swapped in with ``os.replace``.

Tables: ``runs`` (one row per run: status, table, scale, dataset, spec, git, times, job counts,
the full ``run.json`` text), ``run_values`` (run_id, row_name, column_name, replicate, value,
extra JSON), ``run_keys`` (run_id, key, mode = read | written), ``meta`` (schema).
"""

from __future__ import annotations

import json
import logging
import os
import secrets
import sqlite3
from contextlib import closing, contextmanager
from pathlib import Path
from typing import Any

from repro.errors import DataError
from repro.store.runs import (RUN_JSON, RUNNING, QUEUED, VALUES_JSONL, load_run,
                              reconcile_stale, run_dirs)

INDEX_SCHEMA = 1
log = logging.getLogger("repro.runs")

_DDL = """
CREATE TABLE meta (name TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE runs (
  run_id TEXT PRIMARY KEY, status TEXT NOT NULL, table_id TEXT, scale TEXT, dataset TEXT,
  spec_version TEXT, spec_hash TEXT, git_commit TEXT, git_dirty INTEGER,
  created TEXT, started TEXT, ended TEXT, host TEXT,
  n_jobs INTEGER, n_hits INTEGER, n_computed INTEGER, n_values INTEGER,
  stamp TEXT NOT NULL, run_json TEXT NOT NULL);
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

    def _valid(self) -> bool:
        if not self.path.exists():
            return False
        try:
            with closing(self._open(self.path)) as con:
                row = con.execute("SELECT value FROM meta WHERE name='schema'").fetchone()
                con.execute("SELECT count(*) FROM runs").fetchone()
                return row is not None and row[0] == str(INDEX_SCHEMA)
        except sqlite3.DatabaseError:
            return False

    def _ensure(self) -> None:
        """Rebuild the index if it is missing, corrupt or of another schema (silently)."""
        if not self._valid():
            with self._writing():
                if not self._valid():
                    self._rebuild_locked()

    def _rebuild_locked(self) -> int:
        tmp = self.path.with_name(f".{self.path.name}.tmp-{os.getpid()}-{secrets.token_hex(3)}")
        try:
            with closing(self._open(tmp)) as con:
                con.executescript(_DDL)
                con.execute("INSERT INTO meta VALUES ('schema', ?)", (str(INDEX_SCHEMA),))
                n = 0
                for d in run_dirs(self.runs_dir):
                    if self._upsert(con, d):
                        n += 1
                con.commit()
            os.replace(tmp, self.path)
        finally:
            tmp.unlink(missing_ok=True)
        for suffix in ("-journal", "-wal", "-shm"):
            Path(str(self.path) + suffix).unlink(missing_ok=True)
        return n

    @staticmethod
    def _upsert(con: sqlite3.Connection, run_dir: Path) -> bool:
        stamp = _stamp(run_dir)
        try:
            rec = load_run(run_dir)
        except DataError as e:
            log.warning("not indexing %s: %s", run_dir, e)
            con.execute("DELETE FROM runs WHERE run_id=?", (run_dir.name,))
            return False
        r = rec.run
        rid = run_dir.name
        jobs = r.get("jobs") or []
        git = r.get("git") or {}
        spec = r.get("spec") or {}
        con.execute("DELETE FROM runs WHERE run_id=?", (rid,))
        con.execute("DELETE FROM run_values WHERE run_id=?", (rid,))
        con.execute("DELETE FROM run_keys WHERE run_id=?", (rid,))
        con.execute(
            "INSERT INTO runs VALUES (?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?)",
            (rid, r["status"], r.get("table"), r.get("scale"), r.get("dataset"),
             None if spec.get("version") is None else str(spec.get("version")), spec.get("hash"),
             git.get("commit"), None if not git else int(bool(git.get("dirty"))),
             r.get("created"), r.get("started"), r.get("ended"), (r.get("env") or {}).get("host"),
             len(jobs), sum(1 for j in jobs if j.get("status") == "hit"),
             sum(1 for j in jobs if j.get("status") == "computed"), len(rec.values),
             stamp, json.dumps(r, sort_keys=True)))
        base = {"row", "column", "replicate", "value", "schema"}
        con.executemany(
            "INSERT INTO run_values VALUES (?,?,?,?,?,?,?)",
            [(rid, i, str(v["row"]), str(v["column"]), v.get("replicate"), v.get("value"),
              json.dumps({k: x for k, x in v.items() if k not in base}, sort_keys=True))
             for i, v in enumerate(rec.values)])
        keys = r.get("keys") or {}
        con.executemany("INSERT OR IGNORE INTO run_keys VALUES (?,?,?)",
                        [(rid, k, "read") for k in keys.get("read") or []]
                        + [(rid, k, "written") for k in keys.get("written") or []])
        return True

    # ------------------------------------------------------------------ API
    def update(self, run_dir: str | Path) -> None:
        """(Re)index one run folder from its files."""
        self._ensure()
        with self._writing(), closing(self._open(self.path)) as con:
            self._upsert(con, Path(run_dir))
            con.commit()

    def reindex(self) -> int:
        """Rebuild the index from the run folders; returns the number of runs indexed."""
        with self._writing():
            return self._rebuild_locked()

    def sync(self) -> None:
        """Bring the index up to date with the folders (one stat per run; open runs whose
        process died are marked INTERRUPTED)."""
        self._ensure()
        dirs = {d.name: d for d in run_dirs(self.runs_dir)}
        with closing(self._open(self.path)) as con:
            have = {r["run_id"]: (r["stamp"], r["status"])
                    for r in con.execute("SELECT run_id, stamp, status FROM runs")}
        open_runs = [d for n, d in dirs.items()
                     if n not in have or have[n][1] in (RUNNING, QUEUED)]
        for d in open_runs:
            try:
                reconcile_stale(d)
            except OSError as e:  # pragma: no cover - read-only media
                log.warning("cannot update %s: %s", d, e)
        stale = [d for n, d in dirs.items() if n not in have or have[n][0] != _stamp(d)]
        gone = [n for n in have if n not in dirs]
        if not stale and not gone:
            return
        with self._writing(), closing(self._open(self.path)) as con:
            for d in stale:
                self._upsert(con, d)
            for n in gone:
                for t in ("runs", "run_values", "run_keys"):
                    con.execute(f"DELETE FROM {t} WHERE run_id=?", (n,))
            con.commit()

    def list(self, table: str | None = None, status: str | None = None,
             limit: int | None = None) -> list[dict[str, Any]]:
        """Runs, newest first (after :meth:`sync`)."""
        self.sync()
        q = ("SELECT run_id, status, table_id, scale, dataset, spec_version, spec_hash, "
             "git_commit, git_dirty, created, started, ended, host, n_jobs, n_hits, n_computed, "
             "n_values FROM runs")
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
        with closing(self._open(self.path)) as con:
            return [dict(r) for r in con.execute(q, args)]

    def values(self, run_id: str) -> list[dict[str, Any]]:
        self._ensure()
        with closing(self._open(self.path)) as con:
            return [dict(r) for r in con.execute(
                "SELECT row_name, column_name, replicate, value, extra FROM run_values "
                "WHERE run_id=? ORDER BY seq", (run_id,))]

    def runs_using(self, key: str) -> list[str]:
        """Runs that read or wrote store key ``key``."""
        self._ensure()
        with closing(self._open(self.path)) as con:
            return sorted({r[0] for r in con.execute(
                "SELECT run_id FROM run_keys WHERE key=?", (key,))})

    def dump(self) -> dict[str, list[tuple]]:
        """Every row of every table, sorted (to compare two indexes)."""
        self._ensure()
        out = {}
        with closing(self._open(self.path)) as con:
            for t in ("meta", "runs", "run_values", "run_keys"):
                out[t] = sorted(tuple(r) for r in con.execute(f"SELECT * FROM {t}"))
        return out

