"""Fingerprints of upstream files: sha256 of their bytes, cached by (path, size, mtime).

A dataset's fingerprint enters every downstream cache key, so it must change whenever a file
the reader consumes changes.  Hashing gigabytes on every ``repro doctor`` would be slow, so
each file's digest is cached in ``REPRO_HOME/cache/file-digests.json`` keyed by its absolute
path, size and modification time (nanoseconds); a changed size or mtime forces a re-hash.  The
cache is an accelerator only: deleting it changes nothing but speed.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Iterable

from repro.keys import content_key, sha256_file
from repro.paths import repro_home


def _cache_path() -> Path:
    return repro_home() / "cache" / "file-digests.json"


def _load_cache() -> dict:
    p = _cache_path()
    try:
        with open(p, encoding="utf-8") as f:
            data = json.load(f)
        return data if isinstance(data, dict) else {}
    except (OSError, ValueError):
        return {}


def _save_cache(cache: dict) -> None:
    from filelock import FileLock

    p = _cache_path()
    p.parent.mkdir(parents=True, exist_ok=True)
    with FileLock(str(p) + ".lock"):
        merged = _load_cache()
        merged.update(cache)
        tmp = p.with_suffix(f".{os.getpid()}.tmp")
        with open(tmp, "w", encoding="utf-8") as f:
            json.dump(merged, f, sort_keys=True)
        os.replace(tmp, p)


def file_digests(paths: Iterable[str | Path]) -> list[str]:
    """sha256 hex digests of the files, in order (stat-cached, see module docstring)."""
    cache = _load_cache()
    fresh: dict = {}
    out = []
    for path in paths:
        p = Path(path).resolve()
        st = p.stat()
        key = str(p)
        stamp = [st.st_size, st.st_mtime_ns]
        hit = cache.get(key)
        if (isinstance(hit, dict) and hit.get("stat") == stamp
                and isinstance(hit.get("sha256"), str)):
            out.append(hit["sha256"])
            continue
        digest = sha256_file(p)
        fresh[key] = {"stat": stamp, "sha256": digest}
        out.append(digest)
    if fresh:
        _save_cache(fresh)
    return out


def tree_fingerprint(root: str | Path, relpaths: Iterable[str], *, content: bool = True) -> str:
    """Content key of the named files under ``root`` (relative paths and digests).

    With ``content=False`` only (relative path, size) pairs are hashed: used for AMASS motion
    trees, whose tens of gigabytes would make a first ``repro doctor`` take minutes (the BABEL
    annotations themselves are always hashed by content).
    """
    root = Path(root)
    rels = sorted(set(relpaths))
    if content:
        digests = file_digests(root / r for r in rels)
        items = [[r, d] for r, d in zip(rels, digests)]
    else:
        items = [[r, (root / r).stat().st_size] for r in rels]
    return content_key({"files": items, "content": content})
