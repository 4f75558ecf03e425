"""One page of claims (issue 32, item 6): ``repro claims`` and the top of the report's index.

The runs read are committed records: the seven Neural Marionette medium runs of
``docs/results/medium/`` copied into a temporary ``REPRO_HOME``; Table 1's copy is given the
``evidence.converged`` the runs record now (True on one claim, False on another, absent on the
rest, as in a record made before it was kept), one claim training-seed variance and one no
trained row.  MultiAct and ODMO have no run there: their claims must read "not run".
"""

from __future__ import annotations

import csv
import io
import json
import shutil
from pathlib import Path

import pytest

from repro.paths import repo_root

MEDIUM = repo_root() / "docs" / "results" / "medium"
KEYS = ["paper", "table", "claim", "verdict", "p", "converged", "variance", "budget"]


def _copy_records(home: Path) -> dict[str, Path]:
    """The medium records copied into ``home/runs`` (writable), by table id."""
    out = {}
    for src in sorted(MEDIUM.iterdir()):
        dst = home / "runs" / src.name
        shutil.copytree(src, dst)
        for f in [dst, *dst.iterdir()]:
            f.chmod(0o755 if f.is_dir() else 0o644)
        out[json.loads((dst / "run.json").read_text())["table"]] = dst
    return out


@pytest.fixture
def home(_repro_home) -> dict[str, Path]:
    runs = _copy_records(_repro_home)
    f = runs["marionette/table1"] / "summary.json"
    summary = json.loads(f.read_text())
    claims = {c["id"]: c for c in summary["claims"]}
    claims["fid_best"]["evidence"]["converged"] = True
    claims["acc_best"]["evidence"]["converged"] = False
    claims["acc_best"]["evidence"]["variance"] = "training"
    claims["traj_best"]["evidence"]["budgets"] = {}
    claims["traj_best"]["evidence"]["trained_rows"] = []
    f.write_text(json.dumps(summary))
    return runs


def _repro(capsys, *argv) -> tuple[int, str, str]:
    from cli.main import main

    rc = main(list(argv))
    out = capsys.readouterr()
    return rc, out.out, out.err


def _all_claims() -> list[tuple[str, str]]:
    from repro.engine.table_view import claim_text
    from repro.specs.load import load_all

    return [(s.id, claim_text(s, c)) for s in load_all().values() for c in s.claims]


def test_json_lists_every_claim_of_every_spec_with_exactly_the_keys(home, capsys):
    rc, out, _ = _repro(capsys, "claims", "--format", "json")
    assert rc == 0
    entries = json.loads(out)
    assert all(list(e) == KEYS for e in entries)
    want = _all_claims()
    assert len(want) >= 60 and [(e["table"], e["claim"]) for e in entries] == want
    assert {e["paper"] for e in entries} == {"marionette", "multiact", "odmo"}


def test_a_table_without_a_run_lists_its_claims_as_not_run(home, capsys):
    entries = json.loads(_repro(capsys, "claims", "--format", "json")[1])
    not_run = [e for e in entries if e["verdict"] == "not run"]
    assert {e["paper"] for e in not_run} == {"multiact", "odmo"}
    assert all(e["p"] is None and e["converged"] is None and e["variance"] is None
               and e["budget"] is None for e in not_run)
    ran = [e for e in entries if e["paper"] == "marionette"]
    assert ran and all(e["verdict"] != "not run" and e["variance"] == "sampling"
                       for e in ran if e["table"] != "marionette/table1")


def test_verdict_p_converged_variance_budget_come_from_the_run(home, capsys):
    from repro.engine.claims_list import list_claims

    entries = list_claims(["marionette/table1"])
    summary = json.loads((home["marionette/table1"] / "summary.json").read_text())
    assert [e["verdict"] for e in entries] == [c["verdict"] for c in summary["claims"]]
    assert [e["p"] for e in entries] == [c["probability"] for c in summary["claims"]]
    fid, acc, div = entries[0], entries[1], entries[2]
    assert (fid["converged"], acc["converged"], div["converged"]) == (True, False, None)
    assert (fid["variance"], acc["variance"]) == ("sampling", "training seeds")
    # the trained rows involved, in the claim's order, as the evidence line words them
    assert fid["budget"] == "marionet 1%, mann 1.2%*, a2m 0.84%*, actor 0.5%*"
    assert entries[-1]["claim"].startswith("marionet better than mann, actor on traj_err")
    assert entries[-1]["budget"] == "no trained row"


def test_csv_and_markdown_parse_and_print_converged_as_yes_no_dash(home, capsys):
    rc, out, _ = _repro(capsys, "claims", "marionette/table1", "--format", "csv")
    assert rc == 0
    rows = list(csv.DictReader(io.StringIO(out)))
    assert list(rows[0]) == KEYS and len(rows) == 7
    assert [r["converged"] for r in rows[:3]] == ["yes", "no", "—"]
    assert float(rows[0]["p"]) == 0.0 and rows[0]["budget"].startswith("marionet 1%")
    rc, out, _ = _repro(capsys, "claims", "marionette/table1", "odmo/table1", "--format", "md")
    lines = out.strip().splitlines()
    assert rc == 0 and lines[0] == "| " + " | ".join(["paper", "table", "claim", "verdict",
                                                       "P", "converged", "variance",
                                                       "budget"]) + " |"
    body = [ln.strip("|").split(" | ") for ln in lines[2:]]
    n_odmo = sum(1 for t, _ in _all_claims() if t == "odmo/table1")
    assert len(body) == 7 + n_odmo and all(len(cells) == 8 for cells in body)
    assert [c[5].strip() for c in body[:3]] == ["yes", "no", "—"]
    assert all(c[3].strip() == "not run" for c in body[7:])


def test_tables_and_scale_choose_what_is_listed(home, capsys):
    # in the order given, each once (an alias of a table already named adds nothing)
    entries = json.loads(_repro(capsys, "claims", "odmo/table1", "marionette/table1",
                                "marionette-table1", "--format", "json")[1])
    tables = [e["table"] for e in entries]
    assert list(dict.fromkeys(tables)) == ["odmo/table1", "marionette/table1"]
    assert tables.count("marionette/table1") == 7
    # the medium runs are not quick runs: at --scale quick every claim is "not run"
    entries = json.loads(_repro(capsys, "claims", "marionette/table1", "--scale", "quick",
                                "--format", "json")[1])
    assert {e["verdict"] for e in entries} == {"not run"}
    entries = json.loads(_repro(capsys, "claims", "marionette/table1", "--scale", "medium",
                                "--format", "json")[1])
    assert entries[0]["converged"] is True


def test_term_lists_the_claims_and_says_which_runs(home, capsys):
    rc, out, _ = _repro(capsys, "claims", "marionette/table2", "multiact/table1")
    assert rc == 0
    assert "inconclusive" in out and "not run" in out
    assert "claims of 2 tables, from the newest finished run of each at any scale; tables " \
        "not run: 1" in out


@pytest.mark.parametrize("argv, needle", [
    (["claims", "marionette/tabel1"], "did you mean 'marionette/table1'"),
    (["claims", "table3"], "is ambiguous"),
    (["claims", "--scale", "huge"], "unknown scale 'huge'"),
])
def test_an_unknown_table_or_scale_is_one_line_and_exit_2(home, capsys, argv, needle):
    rc, out, err = _repro(capsys, *argv)
    assert rc == 2 and out == ""
    assert needle in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_no_run_at_all_lists_every_claim_as_not_run(capsys):
    rc, out, _ = _repro(capsys, "claims", "--format", "json")
    entries = json.loads(out)
    assert rc == 0 and len(entries) == len(_all_claims())
    assert {e["verdict"] for e in entries} == {"not run"}


def test_report_index_opens_with_the_claims(home, tmp_path):
    from repro.report.html_report import claims_index, write_report

    # a verdict is data: escaped on the page
    f = home["marionette/table2"] / "summary.json"
    summary = json.loads(f.read_text())
    summary["claims"][0]["verdict"] = "<b>supported</b> & more"
    f.write_text(json.dumps(summary))
    top = claims_index("medium")
    assert top[0] == "<h2>Claims</h2>"
    assert sum(1 for x in top if x.startswith("<tr><td>")) == len(_all_claims())
    page = "\n".join(top)
    assert "&lt;b&gt;supported&lt;/b&gt; &amp; more" in page and "<b>supported" not in page
    assert "<td>yes</td>" in page and "<td>no</td>" in page
    index = write_report(["marionette/table1"], tmp_path / "r", scale="medium", strips=False)
    html = index.read_text()
    assert html.index("<h2>Claims</h2>") < html.index("<table") < html.index("<h2>Tables</h2>")
    first = html[html.index("<table"):html.index("</table>")]
    assert "marionet better than mann, a2m, actor on fid" in first
