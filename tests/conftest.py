"""Shared test set-up: a temporary REPRO_HOME for every test, and the `data` marker.

Tests marked ``data`` need the Bandai-Namco-2 archive; they are skipped (with the reason) when
it is absent, so ``make test`` runs them exactly when the stand-in data is there.
"""

from __future__ import annotations

import pytest

from repro.paths import find_bandai_archive


@pytest.fixture(autouse=True)
def _repro_home(tmp_path_factory, monkeypatch):
    home = tmp_path_factory.mktemp("repro-home")
    monkeypatch.setenv("REPRO_HOME", str(home))
    yield home


@pytest.fixture
def paper_data(tmp_path, monkeypatch):
    """An empty $REPRO_PAPER_DATA (the upstream data sets' root), no SMPL folder set."""
    root = tmp_path / "paper-data"
    monkeypatch.setenv("REPRO_PAPER_DATA", str(root))
    monkeypatch.delenv("REPRO_SMPL_DIR", raising=False)
    return root


@pytest.fixture(scope="session")
def bandai_archive():
    path = find_bandai_archive()
    if path is None:
        pytest.skip("Bandai-Namco-2 archive not found (../shared/data/bandai-namco-2 or $REPRO_DATA)")
    return path


def pytest_collection_modifyitems(config, items):
    if find_bandai_archive() is not None:
        return
    skip = pytest.mark.skip(reason="needs the Bandai-Namco-2 stand-in archive")
    for item in items:
        if "data" in item.keywords:
            item.add_marker(skip)
