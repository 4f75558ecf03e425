"""Where things live: ``REPRO_HOME`` (store, run records, prepared data) and the stand-in data.

``REPRO_HOME`` defaults to the user cache directory given by :mod:`platformdirs`; tests always
point it at a temporary folder.  The real-mocap stand-in archive is looked for at
``$REPRO_DATA`` (the archive itself or the folder holding it), else at
``../shared/data/bandai-namco-2/`` beside the repository checkout.
"""

from __future__ import annotations

import os
from pathlib import Path

BANDAI_ARCHIVE_NAME = "bandai-namco-research-motiondataset-2.tar.xz"


def repro_home() -> Path:
    """The root of everything ``repro`` writes (created on demand)."""
    env = os.environ.get("REPRO_HOME")
    if env:
        home = Path(env).expanduser()
    else:
        import platformdirs

        home = Path(platformdirs.user_cache_dir("repro"))
    home.mkdir(parents=True, exist_ok=True)
    return home


def store_root() -> Path:
    """Content-addressed objects (checkpoints, samples, features, prepared data)."""
    return repro_home() / "store"


def runs_root() -> Path:
    """One folder per run; the SQLite index beside it is derived from these folders."""
    return repro_home() / "runs"


def datasets_root() -> Path:
    """Prepared data-set caches, one folder per data set and source fingerprint."""
    return repro_home() / "datasets"


def repo_root() -> Path:
    """The checkout (or install prefix) that holds the ``repro`` package."""
    return Path(__file__).resolve().parent.parent


def tables_root() -> Path:
    """The declarative table specs (``tables/<paper>/<table>.toml``)."""
    env = os.environ.get("REPRO_TABLES")
    return Path(env) if env else repo_root() / "tables"


def shared_data_dir() -> Path:
    """The folder that should hold the Bandai-Namco-2 archive (it may not exist)."""
    env = os.environ.get("REPRO_DATA")
    if env:
        p = Path(env).expanduser()
        return p.parent if p.is_file() else p
    return repo_root().parent / "shared" / "data" / "bandai-namco-2"


def find_bandai_archive() -> Path | None:
    """The stand-in archive if it is present, else ``None``."""
    env = os.environ.get("REPRO_DATA")
    if env and Path(env).expanduser().is_file():
        return Path(env).expanduser()
    cand = shared_data_dir() / BANDAI_ARCHIVE_NAME
    return cand if cand.is_file() else None
