"""Where the papers' own datasets are looked for.

Each dataset lives in its own folder ``$REPRO_PAPER_DATA/<name>/`` (default
``REPRO_HOME/paper-data/<name>/``), laid out exactly as its upstream distribution (file names in
``docs/datasets.md`` and in each reader's docstring).  Nothing is downloaded: these datasets are
not redistributable, so the user puts them there.
"""

from __future__ import annotations

import os
from pathlib import Path

from repro.paths import repro_home

PAPER_DATA_ENV = "REPRO_PAPER_DATA"


def paper_data_root() -> Path:
    """The folder holding one sub-folder per paper dataset (not created here)."""
    env = os.environ.get(PAPER_DATA_ENV)
    return Path(env).expanduser() if env else repro_home() / "paper-data"


def paper_data_dir(name: str) -> Path:
    """``paper_data_root() / name`` (e.g. ``humanact12``, ``uestc``, ``cmu-mocap``, ``babel``)."""
    return paper_data_root() / name
