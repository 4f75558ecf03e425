"""The committed results (docs/results.md): the medium-scale run records of every Neural
Marionette spec under docs/results/medium/ (context from composed sequences, verdicts with their
evidence, harness columns, learning curves), the baselines made from them
(tables/baselines/medium/) and the tables the page prints all agree, so the page cannot drift
from the records nor the records be edited.  The quick records under docs/results/quick/ are
CI's baselines (tables/baselines/quick/).  The sweeps (docs/results/sweeps/) are printed as
their records render, and their points are ordinary run records.  The earlier records (before
verdicts carried their evidence: docs/results/*-pre-evidence/; before the context came from
sequences: docs/results/*-same-clip/ and the cross-host rerun docs/results/medium-rerun/) are
kept as history: each is consistent with its own raw values; the page describes them without
re-printing their bare verdicts."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from repro.engine.baselines import compare, load_baseline, make_baseline
from repro.paths import repo_root

RESULTS = repo_root() / "docs" / "results"


def _records(folder: str) -> list[Path]:
    d = RESULTS / folder
    return sorted(p for p in d.iterdir() if (p / "summary.json").is_file()) if d.is_dir() else []


RUNS = _records("medium")
QUICK = _records("quick")
OLD = _records("medium-same-clip")
OLD_QUICK = _records("quick-same-clip")
RERUN = _records("medium-rerun")
PRE = _records("medium-pre-evidence") + _records("quick-pre-evidence")
SWEEPS = sorted(p for p in (RESULTS / "sweeps").iterdir() if (p / "sweep.json").is_file()) \
    if (RESULTS / "sweeps").is_dir() else []
MARIONETTE = {f"marionette/{t}" for t in
              ("table1", "table2", "table3", "table4", "table5", "fig8", "fig10")}


def _run(path: Path) -> tuple[dict, dict]:
    return (json.loads((path / "run.json").read_text()),
            json.loads((path / "summary.json").read_text()))


def test_there_are_records_for_every_marionette_spec():
    for records, scale in ((RUNS, "medium"), (QUICK, "quick")):
        assert {_run(p)[0]["table"] for p in records} == MARIONETTE, scale
    assert {_run(p)[0]["table"] for p in OLD} == {"marionette/table1", "marionette/table2",
                                                  "marionette/table4"}


def _cells_are_their_values(path: Path, summary: dict, n: int) -> None:
    """Every cell mean is the mean of the raw replicate values recorded beside it."""
    values: dict[tuple[str, str], list[float]] = {}
    for line in (path / "values.jsonl").read_text().splitlines():
        v = json.loads(line)
        if v["value"] is not None:
            values.setdefault((v["row"], v["column"]), []).append(v["value"])
    for row, cols in summary["cells"].items():
        for col, cell in cols.items():
            got = values[(row, col)]
            assert len(got) == cell["n"] == n
            assert sum(got) / len(got) == pytest.approx(cell["mean"], rel=1e-12, abs=1e-12)


@pytest.mark.parametrize("path", RUNS + QUICK, ids=[p.parent.name + "/" + p.name
                                                    for p in RUNS + QUICK])
def test_record_matches_its_baseline_and_its_values(path):
    rj, summary = _run(path)
    scale = path.parent.name
    dataset = {"medium": "bandai2", "quick": "bandai2-mini"}[scale]
    assert rj["status"] == "FINISHED" and rj["scale"] == scale and rj["dataset"] == dataset
    assert not rj["config"].get("retrain")
    base = load_baseline(repo_root() / "tables" / "baselines" / scale, rj["table"])
    assert base["run"] == rj["run_id"]
    assert compare(base, summary) == []  # checksum intact, every cell and verdict equal
    made = make_baseline(summary, scale=scale, dataset=dataset, run_id=rj["run_id"])
    assert made["checksum"] == base["checksum"]
    _cells_are_their_values(path, summary, {"medium": 5, "quick": 3}[scale])


@pytest.mark.parametrize("path", OLD, ids=[p.name for p in OLD])
def test_same_clip_records_are_their_values(path):
    rj, summary = _run(path)
    assert rj["status"] == "FINISHED" and rj["scale"] == "medium" and rj["dataset"] == "bandai2"
    _cells_are_their_values(path, summary, 5)


@pytest.mark.parametrize("path", PRE, ids=[p.parent.name + "/" + p.name for p in PRE])
def test_pre_evidence_records_are_their_values(path):
    rj, summary = _run(path)
    assert rj["status"] == "FINISHED"
    assert not any("evidence" in c for c in summary["claims"])
    _cells_are_their_values(path, summary, {"medium": 5, "quick": 3}[rj["scale"]])


def test_current_records_carry_evidence_curves_and_harness_columns():
    """Issue 11's done-when on the records: every evaluated claim has its evidence line; the
    trained models' learning curves are recorded; Tables 1 and 2 have the harness columns, and
    the nearest-clip copier sits at (near) zero nearest-training distance in joint space."""
    for path in RUNS + QUICK:
        rj, summary = _run(path)
        for c in summary["claims"]:
            if c["verdict"] != "not evaluated":
                assert c["evidence"]["text"].startswith("variance:"), (rj["table"], c["id"])
        trainings = json.loads((path / "trainings.json").read_text())["trainings"]
        for t in trainings:
            if t["method"] != "nearest_clip":
                hist = t["training"]["history"]
                assert hist and all("loss" in h and "batches" in h for h in hist)
                assert all("val_loss" in h for h in hist), (rj["table"], t["row"])
                if t["method"] == "marionet":
                    assert all("ss_active" in h and "xi" in h for h in hist)
        if rj["table"] in ("marionette/table1", "marionette/table2"):
            cells = summary["cells"]
            for row, cols in cells.items():
                for m in ("nn_train_feat", "nn_train_joint", "precision", "recall", "density",
                          "coverage"):
                    if row != "real":
                        assert m in cols, (rj["table"], row, m)
            if rj["table"] == "marionette/table1":
                assert cells["nearest_clip"]["nn_train_joint"]["mean"] < 1e-5
                assert cells["real"]["nn_train_joint"]["mean"] > 0.05


def test_results_page_prints_the_records(tmp_path, monkeypatch):
    from repro.engine.runner import table_view
    from repro.report import render

    from repro.engine.sweep import render_sweep
    from repro.report.curves import format_learning_curve

    home = tmp_path / "home"
    for p in RUNS + QUICK:
        shutil.copytree(p, home / "runs" / p.name)
    monkeypatch.setenv("REPRO_HOME", str(home))
    page = [ln.rstrip() for ln in (repo_root() / "docs" / "results.md").read_text().splitlines()]
    text = "\n".join(page)
    for p in RUNS + QUICK:
        rj, _ = _run(p)
        md = render(table_view(rj["table"], scale=rj["scale"], run=rj["run_id"]), "md")
        block = "\n".join(ln.rstrip() for ln in md.strip().splitlines())
        assert block in text, f"docs/results.md does not show run {rj['run_id']} as rendered"
    # the medium models' learning curves (Tables 1, 2 and 4 train every model of the page)
    for p in RUNS:
        if _run(p)[0]["table"] in ("marionette/table1", "marionette/table2", "marionette/table4"):
            for t in json.loads((p / "trainings.json").read_text())["trainings"]:
                if (t["training"] or {}).get("history"):
                    curve = "\n".join(ln.rstrip() for ln in format_learning_curve(t["training"]))
                    assert curve in text, f"learning curve of {t['row']} missing"
    for d in SWEEPS:
        rec = json.loads((d / "sweep.json").read_text())
        block = "\n".join(ln.rstrip() for ln in render_sweep(rec, "md").strip().splitlines())
        assert block in text, f"docs/results.md does not show sweep {d.name} as rendered"
    # no bare verdict: every claim line on the page carries what decided it
    for ln in page:
        if ln.startswith("- ") and any(ln[2:].startswith(v) for v in
                                       ("SUPPORTED", "CONTRADICTED", "NOT REPRODUCED")):
            assert "[decided by: variance:" in ln, ln


@pytest.mark.parametrize("path", SWEEPS, ids=[p.name for p in SWEEPS])
def test_sweep_records_are_their_runs(path):
    """A sweep's cells and verdicts are those of the point runs recorded beside it."""
    rec = json.loads((path / "sweep.json").read_text())
    runs = {p.name: p for p in path.iterdir() if (p / "summary.json").is_file()}
    assert sorted(runs) == sorted(rec["runs"])
    for i, run_id in enumerate(rec["runs"]):
        rj, summary = _run(runs[run_id])
        assert rj["table"] == rec["table"] and rj["scale"] == rec["scale"]
        key = "budget" if rec["axis"] == "budget" else "evaluator_seed"
        assert rj["config"][key] == rec["points"][i]
        for row, cols in summary["cells"].items():
            for col, cell in cols.items():
                got = rec["cells"][row][col]
                got = got["points"] if isinstance(got, dict) and "points" in got else got
                assert got[i]["mean"] == cell["mean"]
        for c in summary["claims"]:
            assert rec["claims"][c["id"]]["verdict"][i] == c["verdict"]


def test_quick_records_one_model_per_row_and_retrain():
    """The two earlier quick Table 1 records (same-clip context): the then CI baseline's run
    (sampling replicates) and a --retrain run whose replicates are separate trainings, the
    first one shared."""
    (plain, ps), (retrain, rs) = sorted((_run(p) for p in OLD_QUICK),
                                        key=lambda r: bool(r[0]["config"].get("retrain")))
    assert {plain["table"], retrain["table"]} == {"marionette/table1"}
    assert not plain["config"].get("retrain") and retrain["config"]["retrain"] is True
    assert any("independent trainings" in line for line in rs["footer"])
    trains = {j["label"]: j["key"] for r in (plain, retrain) for j in r["jobs"]
              if j["kind"] == "train"}
    assert "marionet/train/s1" in trains and "marionet/train/s2" in trains
    # replicate 0 is the same computation in both (training seed 0, sampling seed 0): its
    # values are bitwise equal (the keys differ: a refactor of spec validation came between)
    def values(run):
        path = RESULTS / "quick-same-clip" / run["run_id"] / "values.jsonl"
        return {(v["row"], v["column"], v["replicate"]): v["value"]
                for v in map(json.loads, path.read_text().splitlines())}

    a, b = values(plain), values(retrain)
    first = [k for k in a if k[2] == 0]
    assert len(first) == 29 and all(a[k] == b[k] for k in first)
    assert any(a[k] != b[k] for k in a if k[2] > 0 and k[0] == "marionet")


def test_medium_rerun_is_a_second_sample_of_the_same_tables():
    """The session-3 rerun: same tables, data and seeds as the reference records, its cells the
    means of its raw values; the nearest-clip reference, which trains nothing, has the same
    evaluator-free Δtraj values bit for bit (what differs between the two hosts is float
    rounding in training)."""
    ref = {_run(p)[0]["table"]: p for p in OLD}
    assert {_run(p)[0]["table"] for p in RERUN} == set(ref)
    for path in RERUN:
        rj, summary = _run(path)
        old, _ = _run(ref[rj["table"]])
        assert rj["status"] == "FINISHED" and rj["scale"] == "medium"
        assert rj["config"]["data_fingerprint"] == old["config"]["data_fingerprint"]
        assert rj["config"]["seeds"] == old["config"]["seeds"] == [0, 1, 2, 3, 4]
        if rj["table"] == "marionette/table1":
            def traj(p):
                return [v["value"] for v in map(json.loads, (p / "values.jsonl").read_text()
                                                .splitlines())
                        if v["row"] == "nearest_clip" and v["column"] == "traj_err"]
            assert traj(path) == traj(ref[rj["table"]]) and len(traj(path)) == 5
        raw = {}
        for v in map(json.loads, (path / "values.jsonl").read_text().splitlines()):
            raw.setdefault((v["row"], v["column"]), []).append(v["value"])
        for row, cols in summary["cells"].items():
            for col, cell in cols.items():
                assert sum(raw[(row, col)]) / cell["n"] == pytest.approx(cell["mean"], rel=1e-12)


# -- MultiAct (issue 13): its records sit in their own folders --------------------------------
MULTIACT = {f"multiact/{t}" for t in ("table1", "table2", "table3", "tableA", "tableB", "fig6")}
MA_RUNS = {"medium": _records("multiact-medium"), "quick": _records("multiact-quick")}
MA_ALL = [(s, p) for s, ps in MA_RUNS.items() for p in ps]


def test_there_are_multiact_records_for_every_spec():
    for scale, records in MA_RUNS.items():
        assert {_run(p)[0]["table"] for p in records} == MULTIACT, scale


def _family_record_checks(scale: str, path: Path) -> dict:
    """A paper family's record (its own folders): finished, its scale's data set, equal to
    its committed baseline, every cell the mean of its raw values; returns the summary."""
    rj, summary = _run(path)
    assert rj["status"] == "FINISHED" and rj["scale"] == scale
    assert rj["dataset"] == {"medium": "bandai2", "quick": "bandai2-mini"}[scale]
    base = load_baseline(repo_root() / "tables" / "baselines" / scale, rj["table"])
    assert base["run"] == rj["run_id"]
    assert compare(base, summary) == []
    _cells_are_their_values(path, summary, len(rj["config"]["seeds"]))
    return summary


def _page_prints(records, tmp_path, monkeypatch) -> None:
    """docs/results.md shows every record of ``records`` exactly as it renders."""
    from repro.engine.runner import table_view
    from repro.report import render

    home = tmp_path / "home"
    for _, p in records:
        shutil.copytree(p, home / "runs" / p.name)
    monkeypatch.setenv("REPRO_HOME", str(home))
    text = "\n".join(ln.rstrip() for ln in
                     (repo_root() / "docs" / "results.md").read_text().splitlines())
    for _, p in records:
        rj, _ = _run(p)
        md = render(table_view(rj["table"], scale=rj["scale"], run=rj["run_id"]), "md")
        block = "\n".join(ln.rstrip() for ln in md.strip().splitlines())
        assert block in text, f"docs/results.md does not show run {rj['run_id']} as rendered"


@pytest.mark.parametrize("scale, path", MA_ALL, ids=[f"{s}/{p.name}" for s, p in MA_ALL])
def test_multiact_record_matches_its_baseline_and_its_values(scale, path):
    _family_record_checks(scale, path)


def test_results_page_prints_the_multiact_records(tmp_path, monkeypatch):
    _page_prints(MA_ALL, tmp_path, monkeypatch)


# -- ODMO (issue 14): its records sit in their own folders --------------------------------------
ODMO = {f"odmo/{t}" for t in ("table1", "table2", "table3", "table4", "tableS1")}
OD_RUNS = {"medium": _records("odmo-medium"), "quick": _records("odmo-quick")}
OD_ALL = [(s, p) for s, ps in OD_RUNS.items() for p in ps]


def test_there_are_odmo_records_for_every_spec():
    for scale, records in OD_RUNS.items():
        assert {_run(p)[0]["table"] for p in records} == ODMO, scale


@pytest.mark.parametrize("scale, path", OD_ALL, ids=[f"{s}/{p.name}" for s, p in OD_ALL])
def test_odmo_record_matches_its_baseline_and_its_values(scale, path):
    summary = _family_record_checks(scale, path)
    # no ODMO cell is "not implemented": every row of every spec has values
    assert all(v["status"] == "ok" for v in summary["rows"].values()), summary["rows"]


def test_odmo_table3_has_the_style_columns():
    for scale, records in OD_RUNS.items():
        (t3,) = [p for p in records if _run(p)[0]["table"] == "odmo/table3"]
        cells = _run(t3)[1]["cells"]
        for row in ("odmo", "actor", "random_codes", "pca_lmp"):  # issue 27: AMI, ARI, calibration
            assert {"humanact12.style_ami", "humanact12.style_ari",
                    "humanact12_paper_rule.mode_homogeneity"} <= set(cells[row]), (scale, row)
            assert not {"humanact12.style_nmi", "humanact12.style_coverage"} & set(cells[row])


def test_results_page_prints_the_odmo_records(tmp_path, monkeypatch):
    _page_prints(OD_ALL, tmp_path, monkeypatch)


PIN_HISTORY = (_records("quick-before-pin") + _records("multiact-quick-before-pin")
               + _records("odmo-quick-before-pin"))


@pytest.mark.parametrize("path", PIN_HISTORY, ids=[p.parent.name + "/" + p.name
                                                   for p in PIN_HISTORY])
def test_quick_records_before_the_kernel_pin_are_their_values(path):
    """The quick records CI compared with until issue 25 (made on an Intel Xeon without the
    kernel pin): kept as history, each consistent with its own raw values, none made under
    the pin."""
    rj, summary = _run(path)
    assert rj["status"] == "FINISHED" and rj["scale"] == "quick"
    assert "kernels" not in (rj.get("env") or {})
    _cells_are_their_values(path, summary, 3)


BEFORE_31 = (_records("quick-before-31") + _records("multiact-quick-before-31")
             + _records("odmo-quick-before-31"))


@pytest.mark.parametrize("path", BEFORE_31, ids=[p.parent.name + "/" + p.name for p in BEFORE_31])
def test_quick_records_before_issue_31_are_their_values(path):
    """The quick records CI compared with until issue 31 (kernel pin v1, the training paths
    before its speed-ups; docs/results.md, "Earlier records"): kept as history, one per spec,
    each consistent with its own raw values and made under pin v1."""
    rj, summary = _run(path)
    assert rj["status"] == "FINISHED" and rj["scale"] == "quick"
    assert rj["env"]["kernels"]["version"] == 1
    _cells_are_their_values(path, summary, 3)


def test_before_31_history_covers_every_quick_spec():
    tables = [_run(p)[0]["table"] for p in BEFORE_31]
    assert len(tables) == len(set(tables)) == 18


UNPACKED = _records("quick-unpacked")


@pytest.mark.parametrize("path", UNPACKED, ids=[p.name for p in UNPACKED])
def test_quick_records_before_marionets_packed_frames_are_their_values(path):
    """The Neural Marionette quick records of issue 31's first re-make (code 1a39184: pin v2,
    MarioNet still trained on padded frames; docs/results.md, "Quick scale"): kept as history,
    one per spec, each consistent with its own raw values and made under pin v2."""
    rj, summary = _run(path)
    assert rj["status"] == "FINISHED" and rj["scale"] == "quick"
    assert rj["env"]["kernels"]["version"] == 2 and rj["git"]["commit"].startswith("1a39184")
    _cells_are_their_values(path, summary, 3)


def test_unpacked_history_covers_every_marionette_spec():
    tables = sorted(_run(p)[0]["table"] for p in UNPACKED)
    assert tables == sorted(_run(p)[0]["table"] for p in QUICK)


BEFORE_26 = _records("quick-before-26") + _records("multiact-quick-before-26")


@pytest.mark.parametrize("path", BEFORE_26, ids=[p.parent.name + "/" + p.name for p in BEFORE_26])
def test_quick_records_before_issue_26_are_their_values(path):
    """The quick records CI compared with until issue 26 (composer version 1: chains falling into
    the arm classes, truncated actions, blended junctions; docs/results.md, "Earlier records"):
    kept as history, each consistent with its own raw values."""
    rj, summary = _run(path)
    assert rj["status"] == "FINISHED" and rj["scale"] == "quick"
    assert rj["env"]["kernels"]["mode"] == "pinned"
    _cells_are_their_values(path, summary, 3)


def test_before_26_history_covers_the_marionette_and_multiact_specs():
    assert {_run(p)[0]["table"] for p in BEFORE_26} == MARIONETTE | MULTIACT


MEDIUM_BEFORE_26 = _records("medium-before-26")


@pytest.mark.parametrize("path", MEDIUM_BEFORE_26, ids=[p.name for p in MEDIUM_BEFORE_26])
def test_medium_records_before_issue_26_are_their_values(path):
    """The Neural Marionette medium records until issue 26 (composer version 1, unpinned,
    2026-12-01; replaced 2026-12-05 by records of composer version 2 under the kernel pin):
    kept as history, each consistent with its own raw values."""
    rj, summary = _run(path)
    assert rj["status"] == "FINISHED" and rj["scale"] == "medium" and rj["dataset"] == "bandai2"
    _cells_are_their_values(path, summary, 5)


def test_medium_before_26_history_covers_the_marionette_specs():
    assert {_run(p)[0]["table"] for p in MEDIUM_BEFORE_26} == MARIONETTE


MA_MEDIUM_BEFORE_26 = _records("multiact-medium-before-26")


@pytest.mark.parametrize("path", MA_MEDIUM_BEFORE_26, ids=[p.name for p in MA_MEDIUM_BEFORE_26])
def test_multiact_medium_records_before_issue_26_are_their_values(path):
    """The MultiAct medium records until issue 26 (composer version 1, unpinned, 2026-12-01;
    replaced by records of composer version 2 under the kernel pin): kept as history, each
    consistent with its own raw values."""
    rj, summary = _run(path)
    assert rj["status"] == "FINISHED" and rj["scale"] == "medium" and rj["dataset"] == "bandai2"
    _cells_are_their_values(path, summary, len(rj["config"]["seeds"]))


def test_multiact_medium_before_26_history_covers_the_multiact_specs():
    assert {_run(p)[0]["table"] for p in MA_MEDIUM_BEFORE_26} == MULTIACT


BEFORE_27 = {"quick": _records("odmo-quick-before-27"), "medium": _records("odmo-medium-before-27")}
BEFORE_27_ALL = [(s, p) for s, ps in BEFORE_27.items() for p in ps]


@pytest.mark.parametrize("scale, path", BEFORE_27_ALL,
                         ids=[f"{s}/{p.name}" for s, p in BEFORE_27_ALL])
def test_odmo_records_before_issue_27_are_their_values(scale, path):
    """The ODMO records until issue 27 (a model that was neither the paper's nor the released
    code's: r̂_t fed to the decoder, no time input, one-FC encoder head, a repeated trajectory
    input, the paper's sums; Table 3 under the sampler's K rule without calibration rows;
    docs/results.md, "Earlier records"): kept as history, each consistent with its raw values."""
    rj, summary = _run(path)
    assert rj["status"] == "FINISHED" and rj["scale"] == scale
    assert rj["table"] in ODMO
    _cells_are_their_values(path, summary, len(rj["config"]["seeds"]))


def test_before_27_history_covers_the_odmo_specs():
    for scale, records in BEFORE_27.items():
        assert {_run(p)[0]["table"] for p in records} == ODMO, scale


def test_current_quick_records_were_made_under_the_pin():
    for path in QUICK + MA_RUNS["quick"] + OD_RUNS["quick"]:
        rj, _ = _run(path)
        k = rj["env"]["kernels"]
        assert k["mode"] == "pinned" and k["version"] >= 2, rj["run_id"]
        base = load_baseline(repo_root() / "tables" / "baselines" / "quick", rj["table"])
        assert base["kernels"] == k  # the baseline names the run's pin and CPU


# -- at convergence (issue 32): the page opens with the claims of the converged run -------------
CONVERGED = _records("converged")
#: the specs the converged run covers (the others are named on the page as not run)
CONVERGED_TABLES = {"marionette/table1", "marionette/table4", "multiact/table2", "multiact/tableB",
                    "odmo/table3", "odmo/table4"}


def test_there_are_converged_records_one_table_per_paper():
    assert {_run(p)[0]["table"] for p in CONVERGED} == CONVERGED_TABLES
    assert {t.split("/")[0] for t in CONVERGED_TABLES} == {"marionette", "multiact", "odmo"}


@pytest.mark.parametrize("path", CONVERGED, ids=[p.name for p in CONVERGED])
def test_converged_record_is_its_values_and_trained_until_the_plateau(path):
    rj, summary = _run(path)
    assert rj["status"] == "FINISHED" and rj["scale"] == "converged"
    assert rj["dataset"] == "bandai2"
    _cells_are_their_values(path, summary, len(rj["config"]["seeds"]))
    for t in json.loads((path / "trainings.json").read_text())["trainings"]:
        rec = t["training"] or {}
        if rec.get("epochs") is None:
            continue  # the retrieval reference indexes, it does not train
        conv = rec["convergence"]
        assert rec["until"] == "plateau" and rec["schema"] == 3, t["row"]
        # converged exactly when the rule stopped it, at the epoch it first fired
        assert conv["converged"] == (conv["stopped_by"] == "plateau"), t["row"]
        if conv["converged"]:
            assert len(rec["history"]) == conv["converged_epoch"] + 1 < rec["epochs"] + 1


def _converged_home(tmp_path, monkeypatch) -> None:
    from cli.main import main

    home = tmp_path / "home"
    for p in CONVERGED:
        shutil.copytree(p, home / "runs" / p.name)
    monkeypatch.setenv("REPRO_HOME", str(home))
    assert main(["runs", "reindex"]) == 0


def test_results_page_opens_with_the_claims_at_convergence(tmp_path, monkeypatch, capsys):
    from repro.engine.claims_list import list_claims, render_claims

    _converged_home(tmp_path, monkeypatch)
    capsys.readouterr()
    entries = list_claims(scale="converged")
    page = "\n".join(ln.rstrip() for ln in
                     (repo_root() / "docs" / "results.md").read_text().splitlines())
    block = "\n".join(ln.rstrip() for ln in render_claims(entries, "md").strip().splitlines())
    assert block in page
    first_section = page.index("\n## ")
    assert page.index(block) < page.index("\n## ", first_section + 1), \
        "the claims page is not the page's first section"
    # every claim of every spec is listed; those of the specs not run read "not run", and the
    # page names those specs
    ran = [e for e in entries if e["table"] in CONVERGED_TABLES]
    assert ran and all(e["verdict"] != "not run" for e in ran)
    for e in entries:
        if e["table"] not in CONVERGED_TABLES:
            assert e["verdict"] == "not run" and f"`{e['table']}`" in page


def test_converged_tables_and_curves_are_on_the_page(tmp_path, monkeypatch):
    from repro.report.curves import format_learning_curve

    _page_prints([("converged", p) for p in CONVERGED], tmp_path, monkeypatch)
    page = "\n".join(ln.rstrip() for ln in
                     (repo_root() / "docs" / "results.md").read_text().splitlines())
    for p in CONVERGED:
        rj = _run(p)[0]
        table = rj["table"]
        # a table's first converged record has <table>.png, a later one <table>-<run id>.png
        names = [table.replace("/", "-") + ".png",
                 table.replace("/", "-") + f"-{rj['run_id']}.png"]
        assert any((RESULTS / "converged" / "curves" / n).is_file()
                   and f"results/converged/curves/{n}" in page for n in names), table
        for t in json.loads((p / "trainings.json").read_text())["trainings"]:
            if (t["training"] or {}).get("history"):
                curve = "\n".join(ln.rstrip() for ln in format_learning_curve(t["training"]))
                assert curve in page, f"learning curve of {table} {t['row']} missing"


def _holds_now(rec: dict) -> str:
    """Whether today's rule (window means *and* medians) holds at the training's last epoch,
    read on its recorded history with its recorded settings: 'yes' / 'no'."""
    from repro.train.plateau import PlateauRule, fires_at

    rule = dict(rec["convergence"]["rule"])
    rule["also"] = tuple(rule["also"])
    rule["statistic"] = "both"
    return "yes" if fires_at(rec["history"], PlateauRule(**rule), len(rec["history"]) - 1) \
        else "no"


def _converged_trainings_table() -> str:
    """The page's table of every training of the converged records, as the records say, with
    whether today's rule would hold where each stopped."""
    rows = ["| spec | row | method | epochs run (cap) | training time | stopped by | converged "
            "(as recorded) | rule holds there (means and medians) |",
            "|---|---|---|---|---|---|---|---|"]
    for p in CONVERGED:
        table = _run(p)[0]["table"]
        for t in json.loads((p / "trainings.json").read_text())["trainings"]:
            rec = t["training"] or {}
            if rec.get("epochs") is None:
                continue
            conv = rec["convergence"]
            rows.append(f"| `{table}` | {t['row']} | {t['method']} | {len(rec['history'])} "
                        f"({rec['epochs']}) | {rec['seconds']:.0f} s | {conv['stopped_by']} | "
                        f"{'yes' if conv['converged'] else 'no'} | {_holds_now(rec)} |")
    return "\n".join(rows)


def test_converged_page_lists_every_training_and_its_verdicts_follow_it():
    page = "\n".join(ln.rstrip() for ln in
                     (repo_root() / "docs" / "results.md").read_text().splitlines())
    assert _converged_trainings_table() in page
    # a claim reads "at convergence" exactly when its evidence says every compared training
    # converged (none does in this run: the page says which did not and why)
    for p in CONVERGED:
        for c in _run(p)[1]["claims"]:
            ev = c.get("evidence") or {}
            assert ("at convergence" in c["verdict"]) == bool(ev.get("converged")), c["id"]
            if ev.get("converged") is False:
                assert "not every training reached its plateau" in ev["text"]


def test_converged_history_record_with_actors_old_cap():
    """The first multiact/table2 record at converged (ACTOR's cap 100, before it was raised):
    kept as history, consistent with its values; ACTOR ran into that cap."""
    (path,) = _records("converged-actor-cap-100")
    rj, summary = _run(path)
    assert rj["status"] == "FINISHED" and rj["scale"] == "converged"
    assert rj["table"] == "multiact/table2"
    _cells_are_their_values(path, summary, len(rj["config"]["seeds"]))
    actor = [t["training"] for t in json.loads((path / "trainings.json").read_text())["trainings"]
             if t["method"] == "actor"][0]
    assert actor["epochs"] == 100 and len(actor["history"]) == 100
    assert actor["convergence"]["stopped_by"] == "epochs" and actor["seconds"] < 120


def test_converged_backbones_transformer_is_table2s_macvae_and_stopped_in_a_spike():
    """multiact/tableB at converged (2026-12-07, under the rule's means-only reading): its
    transformer row is multiact/table2's MACVAE training, bitwise (same items, seed, config),
    and stopped in the same KL spike, where today's rule (means and medians) does not hold."""
    (path,) = [p for p in CONVERGED if _run(p)[0]["table"] == "multiact/tableB"]
    (table2,) = [p for p in CONVERGED if _run(p)[0]["table"] == "multiact/table2"]
    trainings = {t["row"]: t["training"]
                 for t in json.loads((path / "trainings.json").read_text())["trainings"]}
    assert set(trainings) == {"transformer", "lstm", "gru", "mlp"}
    tr = trainings["transformer"]
    macvae = [t["training"] for t in json.loads((table2 / "trainings.json").read_text())
              ["trainings"] if t["method"] == "macvae"][0]
    assert tr["history"] == macvae["history"]
    assert tr["convergence"]["converged_epoch"] == 63 and _holds_now(tr) == "no"
