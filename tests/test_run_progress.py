"""Issue 28, item 9: a run whose output is redirected is not silent (progress lines on stderr,
one per finished job with the time since the run started, and one per evaluator / real rows /
gate step); ``--quiet`` keeps CI's log short; emcee's RuntimeWarnings no longer leak."""

from __future__ import annotations

import re
import warnings

from test_tables_engine import _repro, tiny_tables  # noqa: F401 (a fixture)

from repro.paths import repo_root

LINE = re.compile(r"^repro: \[ *(\d+\.\d s|\d+m\d\ds|\d+h\d\dm)\] ", re.M)


def test_a_redirected_run_prints_progress_lines_and_quiet_prints_none(tiny_tables, _repro_home):  # noqa: F811
    out = _repro("run", "marionette/table1", "--scale", "quick", env_home=_repro_home,
                 tables=tiny_tables)  # stdout is a pipe here, as in `repro run ... > log`
    err = out.stderr
    lines = [ln for ln in err.splitlines() if LINE.match(ln)]
    assert len(lines) >= 10, err
    assert any("evaluator transformer on bandai2-mini: training or loading" in ln
               for ln in lines), err
    assert any("evaluator transformer on bandai2-mini trained" in ln for ln in lines), err
    assert any("real rows of transformer" in ln and "real accuracy" in ln for ln in lines), err
    assert any("Real-data gate: standard" in ln for ln in lines), err
    assert any(re.search(r"jobs: 0 cached, \d+ to run", ln) for ln in lines), err
    # one line per finished job: kind, row, replicate, its seconds, done of to-run
    measured = [ln for ln in lines if "computed measure_real real (replicate" in ln]
    assert len(measured) == 3, err
    assert all(re.search(r"in \d+\.\d s \(\d+/\d+\)$", ln) for ln in measured), measured
    assert any("computed train nearest_clip (seed 0)" in ln for ln in lines), err
    assert any(ln.split("] ", 1)[1].startswith("jobs finished:") for ln in lines), err
    assert "RuntimeWarning" not in err
    assert "Real Test Data" in out.stdout  # the table still goes to stdout, alone

    quiet = _repro("run", "marionette/table1", "--scale", "quick", "--quiet",
                   env_home=_repro_home, tables=tiny_tables)
    assert not LINE.search(quiet.stderr), quiet.stderr


def test_ci_runs_tables_quietly():
    """The CI log stays short: the table regression run is ``--quiet``."""
    make = (repo_root() / "Makefile").read_text()
    ci = make[make.index("ci-tables:"):]
    assert "--quiet" in ci.splitlines()[1], ci.splitlines()[1]


def test_line_hook_says_kind_row_replicate_and_skips_planned_hits():
    import io

    from repro.engine.executor import JobResult
    from repro.engine.job_run import COMPUTED, HIT
    from repro.engine.job import Job
    from repro.engine.progress import LineProgressHook, job_words

    def job(label, kind="measure", seed=0):
        return Job(kind=kind, impl="repro.engine.steps:measure", config={"x": label},
                   seed=seed, label=label)

    m, t, h = job("real/measure/r2"), job("marionet/train", "train", 7), job("real/real/r0")
    assert job_words(m) == "measure real (replicate 2)"
    assert job_words(t) == "train marionet (seed 7)"
    buf = io.StringIO()
    hook = LineProgressHook(stream=buf, t0=0.0)
    hook.graph_started([(m, m.key(), "run"), (t, t.key(), "run"), (h, h.key(), "hit")])
    for j in (t, m):
        hook.job_started(j, j.key())
    hook.job_finished(JobResult(t, t.key(), COMPUTED, 12.25))
    hook.job_finished(JobResult(h, h.key(), HIT, 0.0))  # found before the graph ran: counted
    hook.job_finished(JobResult(m, m.key(), "failed", 1.0, error="loss is nan"))
    text = buf.getvalue()
    assert "3 jobs: 1 cached, 2 to run" in text
    assert "computed train marionet (seed 7) in 12.2 s (1/2)" in text
    assert "failed measure real (replicate 2) in 1.0 s (2/2): loss is nan" in text
    assert "real/real" not in text and text.count("\n") == 3
    assert all(LINE.match(ln) for ln in text.splitlines())


def test_claims_on_rows_far_apart_emit_no_runtime_warning():
    """Rows 10^6 pooled sds apart put every walker outside the prior: emcee computed
    -inf - (-inf) and the chain's autocorrelation 0/0, and numpy warned on stderr in the
    middle of a run.  The case is understood (the verdict says the sampler did not mix); its
    warnings are silenced there only."""
    from repro.stats.claims import claim_probability

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        r = claim_probability([0.0, 0.0, 0.0], [1e9, 1e9 + 1, 1e9 + 2], seed=1)
    assert r.verdict == "inconclusive" and r.reason == "the sampler did not mix (acceptance 0)"
    assert r.acceptance == 0.0
