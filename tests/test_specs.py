"""Table specs and scale profiles: schema, vocabularies, loader errors, `repro spec`."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from cli.main import main
from repro.errors import ConfigError, SpecError
from repro.paths import tables_root
from repro.specs import (
    SpecValidationError,
    check_claim_on_reported,
    find_spec,
    load_all,
    load_spec,
    names,
    parse_printed,
    resolve_scale,
)
from repro.specs.scales import load_scales

EXPECTED_IDS = {
    "marionette/table1", "marionette/table2", "marionette/table3", "marionette/table4",
    "marionette/table5", "marionette/fig8", "marionette/fig10",
    "multiact/table1", "multiact/table2", "multiact/table3", "multiact/tableA", "multiact/tableB",
    "multiact/fig6",
    "odmo/table1", "odmo/table2", "odmo/table3", "odmo/table4", "odmo/tableS1",
}


@pytest.fixture(scope="module")
def specs():
    return load_all()


@pytest.fixture
def tables_copy(tmp_path, monkeypatch):
    """A writable copy of tables/ that the loader and the CLI use."""
    dst = tmp_path / "tables"
    shutil.copytree(tables_root(), dst)
    monkeypatch.setenv("REPRO_TABLES", str(dst))
    return dst


def _edit(path: Path, old: str, new: str, count: int = 1) -> None:
    text = path.read_text(encoding="utf-8")
    assert old in text, f"{old!r} not in {path}"
    path.write_text(text.replace(old, new, count), encoding="utf-8")


def _edit_re(path: Path, pattern: str, repl: str) -> None:
    """Replace the first match of the regular expression ``pattern`` (which must match)."""
    text = path.read_text(encoding="utf-8")
    new, n = re.subn(pattern, repl, text, count=1)
    assert n == 1, f"{pattern!r} not in {path}"
    path.write_text(new, encoding="utf-8")


def _problems(path: Path) -> list[str]:
    with pytest.raises(SpecValidationError) as ei:
        load_spec(path)
    return [str(p) for p in ei.value.problems]


# -- the 18 specs -------------------------------------------------------------------------------


def test_all_eighteen_specs_load(specs):
    assert set(specs) == EXPECTED_IDS
    for sid, spec in specs.items():
        assert spec.version >= 1 and spec.schema_version == 1
        assert spec.paper.file == names.PAPERS[spec.paper.key].file
        assert names.DATASETS[spec.standin_dataset].standin
        assert not names.DATASETS[spec.paper_dataset].standin
        if spec.kind == "table":
            assert spec.n_reported() > 0, sid
        else:
            assert spec.x is not None and spec.n_reported() == 0
        assert spec.claims, f"{sid} records no claim"
        for claim in spec.claims:
            assert len(claim.source) >= 10


def test_interval_conventions_per_paper(specs):
    want = {"marionette": "none", "multiact": "t_sem", "odmo": "z_sd_sqrt_nm1"}
    for spec in specs.values():
        assert spec.interval == want[spec.paper.key]
        for row in spec.rows:
            assert spec.interval_for(row.id) in names.INTERVALS


def test_every_claim_agrees_with_the_printed_numbers(specs):
    """holds_on_reported is true exactly where the paper's certain numbers support the claim."""
    evaluated = 0
    for spec in specs.values():
        for claim in spec.claims:
            res = check_claim_on_reported(spec, claim)
            if res.result is not None:
                evaluated += 1
                assert res.result == claim.holds_on_reported, (spec.id, claim.id, res.per_column)
    assert evaluated >= 40
    assert [c.id for c in specs["odmo/tableS1"].claims if not c.holds_on_reported] == \
        ["fid_rises_as_sigma2_grows_humanact12"]


def test_known_inconsistencies_are_recorded_not_guessed(specs):
    t5 = specs["marionette/table5"]
    cell = t5.reported("neural_marionette", "pose_gap")
    assert cell.printed == "0.265" and cell.certain is False and "2.65" in cell.note
    t2 = specs["marionette/table2"]
    for row in ("no_tu_no_ti", "no_tu", "no_ti"):
        assert "acc" not in t2.row(row).reported and "div" not in t2.row(row).reported
    assert "9.867" in t2.note
    t3 = specs["marionette/table3"]
    assert "overall.acc" not in t3.row("mann").reported
    assert not t3.reported("a2m", "overall.pose_gap").certain
    assert "0.775" in t3.note and "0.830" in t3.note


def test_spec_lookups(specs):
    t3 = specs["marionette/table3"]
    assert t3.protocol_for("overall.acc") == "multi_action"
    assert t3.protocol_params_for("sufficient.fid")["test_set"] == "sufficient"
    assert t3.column("overall.fid").direction == "lower"
    t4 = specs["marionette/table4"]
    assert t4.protocol_for("single.acc") == "single_action"
    assert t4.protocol_for("overall.acc") == "multi_action"
    o1 = specs["odmo/table1"]
    assert o1.paper_dataset_for("uestc.acc") == "uestc"
    assert o1.reference_row("humanact12.div") == "real"
    assert o1.column("uestc.acc").unit == "%"
    m1 = specs["multiact/table1"]
    assert m1.reference_row("multimod") == "real_test"
    assert m1.reference_row("fid_train") is None


# -- parsing printed values ------------------------------------------------------------------------


@pytest.mark.parametrize("printed,expected", [
    ("0.74±0.019", (0.74, 0.019, False)),
    ("99.70±.06", (99.70, 0.06, False)),
    ("197.1±1.1", (197.1, 1.1, False)),
    ("15.22%±.92", (15.22, 0.92, True)),
    ("0.00%±.00", (0.0, 0.0, True)),
    ("3.406", (3.406, None, False)),
    ("/", (None, None, False)),
    ("-", (None, None, False)),
])
def test_parse_printed(printed, expected):
    assert parse_printed(printed) == expected


@pytest.mark.parametrize("bad", ["0.7a", "±.06", "1.2±", "1,2", "0.5 ± 0.1 ± 0.2"])
def test_parse_printed_refuses_garbage(bad):
    with pytest.raises(ValueError):
        parse_printed(bad)


# -- errors name file, row and field -------------------------------------------------------------


def test_unknown_method_gets_did_you_mean(tables_copy):
    p = tables_copy / "marionette" / "table1.toml"
    _edit(p, 'method = "mann"', 'method = "man"')
    probs = _problems(p)
    assert len(probs) == 1
    msg = probs[0]
    assert "table1.toml" in msg and "rows[1] (id 'mann').method" in msg
    assert "unknown method 'man'" in msg and "did you mean 'mann'" in msg


def test_unknown_metric_dataset_protocol_interval(tables_copy):
    p = tables_copy / "odmo" / "table2.toml"
    _edit(p, 'metric = "multimod"', 'metric = "multimodality"')
    _edit(p, 'paper_dataset = "cmu-mocap"', 'paper_dataset = "cmu_mocap"')
    _edit(p, 'protocol = "odmo_generation"', 'protocol = "odmo_generate"')
    _edit(p, 'interval = "z_sd_sqrt_nm1"', 'interval = "z_sd_sqrt_n"')
    text = "\n".join(_problems(p))
    assert "unknown metric 'multimodality' (did you mean 'multimod'?)" in text
    assert "unknown dataset 'cmu_mocap' (did you mean 'cmu-mocap'?)" in text
    assert "unknown protocol 'odmo_generate' (did you mean 'odmo_generation'?)" in text
    assert "unknown interval 'z_sd_sqrt_n' (did you mean 'z_sd_sqrt_nm1'?)" in text
    assert "columns[3] (id 'multimod').metric" in text


def test_unknown_key_is_an_error_with_suggestion(tables_copy):
    p = tables_copy / "multiact" / "table3.toml"
    _edit(p, 'label = "ACTOR + Interpolation"\nmethod', 'lable = "ACTOR + Interpolation"\nmethod')
    _edit_re(p, r"\nversion = (\d+)\n", r"\nversion = \1\nverison = 2\n")
    text = "\n".join(_problems(p))
    assert "rows[4] (id 'interpolation'): unknown field 'lable' (did you mean 'label'?)" in text
    assert "unknown field 'verison' (did you mean 'version'?)" in text
    assert "missing required field 'label'" in text


#: one edit of a spec (file, text, replacement) -> phrases of the one problem it makes
ONE_EDIT_ONE_PROBLEM = {
    "reported_cell_for_unknown_column": (
        "marionette/table3.toml", 'overall.fid = "12.785"', 'overall.fd = "12.785"',
        ["rows[0] (id 'mann').reported",
         "unknown column 'overall.fd' (did you mean 'overall.fid'?)"]),
    "unparseable_printed_value": (
        "odmo/table3.toml", '"15.22%±.92"', '"15.22%+-.92"',
        ["rows[2] (id 'odmo').reported.humanact12.mode_homogeneity.printed",
         "cannot parse printed value"]),
    "claim_fields_must_match_kind": (
        "multiact/tableB.toml", 'kind = "order"', 'kind = "gap"',
        ["a gap claim needs 'a', 'b' and 'delta'", "'better' is not used by a gap claim"]),
    "transcription_slip_that_flips_a_claim_is_caught": (
        "multiact/tableB.toml", 'fid_train = "2.00±0.122"', 'fid_train = "0.70±0.122"',
        ["claims[0] (id 'transformer_best')", "fid_train", "holds_on_reported = false"]),
    "closer_to_real_needs_a_reference": (
        "multiact/table2.toml", 'reference = "real_test"\n', "",
        ["columns[4] (id 'div')", "needs a reference row", "real_train, real_test"]),
    "uncertain_cell_needs_a_note": (
        "marionette/table5.toml",
        'pose_gap = { printed = "0.265", certain = false, note = "printed 0.265; likely a typo '
        'for 2.65 (see the table note)" }',
        'pose_gap = { printed = "0.265", certain = false }', ["needs a note", "pose_gap"]),
    "id_must_match_path": ("odmo/table4.toml", 'id = "odmo/table4"', 'id = "odmo/table5"',
                           ["does not match its path", "odmo/table4"]),
}


@pytest.mark.parametrize("case", list(ONE_EDIT_ONE_PROBLEM))
def test_one_edit_makes_one_problem(tables_copy, case):
    file, old, new, phrases = ONE_EDIT_ONE_PROBLEM[case]
    p = tables_copy / file
    _edit(p, old, new)
    (msg,) = _problems(p)
    for phrase in phrases:
        assert phrase in msg, (phrase, msg)


def test_claim_naming_unknown_row_and_column(tables_copy):
    p = tables_copy / "multiact" / "table2.toml"
    _edit(p, 'than = ["actor"]', 'than = ["actr"]')
    _edit(p, 'column = ["fid_train", "fid_test"', 'column = ["fid_trian", "fid_test"')
    text = "\n".join(_problems(p))
    assert "claims[0] (id 'macvae_beats_actor_everywhere').than: unknown row 'actr' (did you mean 'actor'?)" in text
    assert "unknown column 'fid_trian' (did you mean 'fid_train'?)" in text


def test_toml_syntax_error_names_the_line(tables_copy):
    p = tables_copy / "marionette" / "table4.toml"
    lines = p.read_text(encoding="utf-8").splitlines()
    lines[6] = 'protocol = "single_action'  # unterminated string on line 7
    p.write_text("\n".join(lines) + "\n", encoding="utf-8")
    with pytest.raises(SpecError) as ei:
        load_spec(p)
    assert "line 7" in str(ei.value) and "table4.toml" in str(ei.value)


def test_stand_in_must_be_a_stand_in(tables_copy):
    p = tables_copy / "odmo" / "table3.toml"
    _edit(p, 'standin_dataset = "bandai2"', 'standin_dataset = "uestc"')
    (msg,) = _problems(p)
    assert "is a paper data set, not a stand-in" in msg


# -- identity --------------------------------------------------------------------------------------


def test_spec_hash_is_content_not_layout(tables_copy):
    p = tables_copy / "marionette" / "table4.toml"
    h0 = load_spec(p).spec_hash
    p.write_text("# a new comment\n\n" + p.read_text(encoding="utf-8"), encoding="utf-8")
    assert load_spec(p).spec_hash == h0
    _edit(p, 'overall.acc = "0.770"', 'overall.acc = "0.77"')
    assert load_spec(p).spec_hash != h0  # the printed precision is part of the spec


def test_find_spec_aliases(specs):
    assert find_spec("marionette/table3").id == "marionette/table3"
    assert find_spec("fig8").id == "marionette/fig8"
    assert find_spec("tables/odmo/tableS1.toml").id == "odmo/tableS1"
    assert find_spec("tables1").id == "odmo/tableS1"
    assert find_spec("multiact-tablea").id == "multiact/tableA"
    with pytest.raises(ConfigError, match="ambiguous: marionette/table1, multiact/table1, odmo/table1"):
        find_spec("table1")
    with pytest.raises(ConfigError, match="did you mean 'fig6'"):
        find_spec("fgi6")


# -- scale profiles --------------------------------------------------------------------------------


def test_scales_resolve_and_paper_values():
    q, m, p = resolve_scale("quick"), resolve_scale("medium"), resolve_scale("paper")
    assert (q.dataset, m.dataset, p.dataset) == ("bandai2-mini", "bandai2", None)
    assert q.replicates < m.replicates < p.replicates
    assert p.seeds_for("odmo_generation") == tuple(range(10))
    assert p.replicates_for("multiact_conditioned") == 20
    mn = p.method_config("marionet")
    assert (mn["batch_size"], mn["lr"], mn["epochs"], mn["ss_activate_epoch"],
            mn["ss_accomplish_epoch"]) == (30, 1e-4, 1000, 250, 750)
    mv = p.method_config("macvae")
    assert (mv["d_model"], mv["layers"], mv["heads"], mv["lr"], mv["batch_size"], mv["epochs"],
            mv["lambda_acc"], mv["lambda_kl"]) == (512, 8, 4, 5e-5, 16, 1200, 1.0, 1e-5)
    od = p.method_config("odmo")
    assert (od["latent_dim"], od["lr"], od["margin"], od["sigma2"], od["tf_start"],
            od["tf_end"], od["tf_decay_epochs"], od["batch_size"], od["windows_per_epoch"],
            od["epochs"]) == (20, 1e-3, 5.0, 0.05, 1.0, 0.3, 4000, 512, 2048, 100_000)
    from repro.models.odmo import ODMOConfig  # every paper-scale field is a real config field
    ODMOConfig(**od)
    assert p.protocol_config("multi_action")["sequences"] == 764


def test_dataset_is_orthogonal_to_the_profile(specs):
    spec = specs["odmo/table1"]
    assert resolve_scale("paper").dataset_for(spec) == "bandai2"
    assert resolve_scale("quick").dataset_for(spec) == "bandai2-mini"
    assert resolve_scale("quick", dataset="bandai2").dataset_for(spec) == "bandai2"
    with pytest.raises(ConfigError, match="did you mean 'bandai2'"):
        resolve_scale("quick", dataset="bandai")
    with pytest.raises(ConfigError, match="did you mean 'medium'"):
        resolve_scale("meduim")


def test_resolved_scale_is_frozen():
    q = resolve_scale("quick")
    h = q.scale_hash
    with pytest.raises(AttributeError):
        q.replicates = 99  # type: ignore[misc]
    q.methods["marionet"]["epochs"] = 10**6  # a copy: the profile does not change
    assert q.method_config("marionet")["epochs"] != 10**6
    assert q.scale_hash == h == resolve_scale("quick").scale_hash
    assert resolve_scale("quick", dataset="bandai2").scale_hash != h


def test_scales_file_errors_name_profile_and_field(tables_copy):
    p = tables_copy / "scales.toml"
    _edit(p, "[quick.methods.marionet]", "[quick.methods.marionett]")
    _edit(p, "[medium.protocols.ss_ar]", "[medium.protocols.ss_arr]")
    _edit(p, "replicates = 3", "replicate = 3")
    with pytest.raises(SpecValidationError) as ei:
        load_scales(p)
    text = "\n".join(str(x) for x in ei.value.problems)
    assert "scales.toml" in text
    assert "quick.methods: unknown method 'marionett' (did you mean 'marionet'?)" in text
    assert "medium.protocols: unknown protocol 'ss_arr' (did you mean 'ss_ar'?)" in text
    assert "quick: unknown field 'replicate' (did you mean 'replicates'?)" in text


# -- CLI ---------------------------------------------------------------------------------------------


def test_cli_spec_check_all(capsys):
    assert main(["spec", "check"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert len(out) == 19 and all(line.startswith("ok  ") for line in out)
    assert any("scales" in line for line in out)


def test_cli_spec_check_reports_every_problem(tables_copy, capsys):
    _edit(tables_copy / "marionette" / "table2.toml", 'method = "marionet"', 'method = "marionete"')
    _edit(tables_copy / "odmo" / "table3.toml", 'better = "odmo"', 'better = "odm"')
    assert main(["spec", "check"]) == 2
    cap = capsys.readouterr()
    err = cap.err.splitlines()
    assert any("tables/marionette/table2.toml: rows[0] (id 'marionet').method: unknown method "
               "'marionete' (did you mean 'marionet'?)" in e for e in err)
    assert any("tables/odmo/table3.toml: claims[0] (id 'odmo_modes_purer').better: unknown row "
               "'odm' (did you mean 'odmo'?)" in e for e in err)
    assert err[-1] == "repro: error: 2 of 19 file(s) invalid"
    assert len(cap.out.splitlines()) == 17


def test_cli_spec_check_json_and_files(capsys):
    path = str(tables_root() / "multiact" / "table3.toml")
    assert main(["spec", "check", "--json", path]) == 0
    rec = json.loads(capsys.readouterr().out)
    assert rec["id"] == "multiact/table3" and rec["ok"] and rec["reported"] == 10
    assert len(rec["spec_hash"]) == 64


def test_cli_spec_schema_is_json_schema():
    out = subprocess.run([sys.executable, "-m", "cli.main", "spec", "schema"],
                         capture_output=True, text=True, check=True).stdout
    schema = json.loads(out)
    assert schema["title"] == "TableSpec" and schema["additionalProperties"] is False
    for key in ("schema", "id", "version", "columns", "rows", "claims", "interval"):
        assert key in schema["properties"]
    assert {"Row", "Column", "Claim", "ReportedCell"} <= set(schema["$defs"])
    scales = json.loads(subprocess.run([sys.executable, "-m", "cli.main", "spec", "schema", "--scales"],
                                       capture_output=True, text=True, check=True).stdout)
    assert "quick" in scales["properties"]


def test_protocol_settings_layer_spec_group_and_scale(specs):
    t3 = specs["marionette/table3"]
    quick, paper = resolve_scale("quick"), resolve_scale("paper")
    sq = quick.protocol_settings(t3, "sufficient.acc")
    assert sq["test_set"] == "sufficient" and sq["sufficient_top_k"] == 4   # spec group
    assert sq["actions_per_sequence"] == 10 and sq["sequences"] == 12        # quick shrinks
    sp = paper.protocol_settings(t3, "overall.acc")
    assert (sp["test_set"], sp["sequences"], sp["actions_per_sequence"]) == ("overall", 764, 20)
