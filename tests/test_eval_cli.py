"""`repro eval classifier | real` end to end on the bundled bandai2-mini, with a tiny evaluator
profile given through a temporary tables/scales.toml (REPRO_TABLES); plus the real-data
accuracy check on the full stand-in (slow, data)."""

from __future__ import annotations

import json

import pytest

from test_tables_engine import UNUSED_PROFILES

SCALES = """
schema = 1
version = 1
[quick]
description = "test profile"
replicates = 2
bootstrap_resamples = 200
[quick.evaluator]
window = 30
[quick.evaluator.train]
epochs = 3
windows_per_epoch = 128
batch_size = 64
[quick.evaluator.real]
per_class = 6
replicates = 3
"""
SCALES += UNUSED_PROFILES


@pytest.fixture
def tiny_profile(tmp_path, monkeypatch):
    (tmp_path / "scales.toml").write_text(SCALES)
    monkeypatch.setenv("REPRO_TABLES", str(tmp_path))
    from repro.eval import provider

    provider._LOADED.clear()
    yield
    provider._LOADED.clear()


def test_cli_classifier_then_real(tiny_profile, capsys):
    from cli.main import main

    assert main(["eval", "classifier", "--dataset", "bandai2-mini", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["scale"] == "quick" and out["kind"] == "a2m_gru" and out["store_hit"] is False
    assert out["input"]["window"] == 30 and out["input"]["heading"] == "raw"
    test = out["test"]
    assert 0.0 <= test["top1"] <= test["top5"] <= 1.0 and len(test["confusion"]) == 10
    assert sum(map(sum, test["confusion"])) == test["n_windows"]

    # the second call loads it from the store: same fingerprint, no training
    assert main(["eval", "classifier", "--dataset", "bandai2-mini", "--json"]) == 0
    again = json.loads(capsys.readouterr().out)
    assert again["fingerprint"] == out["fingerprint"]

    rc = main(["eval", "real", "--dataset", "bandai2-mini", "--json", "--no-gate"])
    assert rc == 0
    rows = json.loads(capsys.readouterr().out)
    assert rows["evaluator"]["fingerprint"] == out["fingerprint"]
    assert rows["replicates"] == 3 and rows["per_class"] == 6
    real = rows["rows"]["real"]
    assert real["n_apd"]["mean"] == 100.0
    assert len(real["fid_train"]["values"]) == 3 and len(real["fid_train"]["ci"]) == 2
    assert isinstance(rows["gate"]["passed"], bool)

    # text output names the fingerprint and the gate verdict; a failed gate exits 2
    rc = main(["eval", "real", "--dataset", "bandai2-mini"])
    cap = capsys.readouterr()
    assert out["fingerprint"] in cap.out and "gate:" in cap.out
    assert rc == (0 if rows["gate"]["passed"] else 2)


def test_cli_errors_are_one_line(tiny_profile, capsys):
    from cli.main import main

    assert main(["eval", "classifier", "--dataset", "bandai3"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("repro: error:") and "bandai3" in err and err.count("\n") == 1


@pytest.mark.data
@pytest.mark.slow
def test_medium_gru_reaches_90_percent_on_real_bandai2(bandai_archive, capsys):
    """Issue 3 item 1: at the medium scale on bandai2 the GRU recogniser reaches ≥ 90% top-1 on
    the real test split, and the real rows pass the gate."""
    from cli.main import main

    assert main(["data", "prepare", "bandai2", "--source", str(bandai_archive)]) == 0
    capsys.readouterr()
    assert main(["eval", "classifier", "--dataset", "bandai2", "--scale", "medium", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["test"]["top1"] >= 0.90, out["test"]
    assert main(["eval", "real", "--dataset", "bandai2", "--scale", "medium", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert rows["gate"]["passed"] and rows["evaluator"]["fingerprint"] == out["fingerprint"]
