"""``repro report``: a self-contained HTML report, one page per table, that opens from disk.

``write_report(tables, out)`` writes into ``out``:

- ``index.html``: every claim of every spec, one line each (:func:`claims_index`, as
  ``repro claims --scale <scale>`` lists them; issue 32, item 6), then every registered table
  with its state (reported in this folder, last run, not run, not implemented), linking the
  pages written;
- ``<paper>-<table>.html`` per table: the paper-vs-ours table with intervals (the same view
  every other format renders, :mod:`repro.report.render`), every claim with its verdict and
  what decided it, the comparison strips of every row for the same items
  (:mod:`repro.report.strip_sets`; PNG shown, EXR linked), the plots (a figure's curves with
  interval bands, a table's cells against the paper's, the learning curves of the run's
  trainings: :mod:`repro.render.plots`, each beside its data as CSV), and the provenance (run
  id, code commit, data fingerprint, evaluator fingerprints, scale, machine, packages);
- ``<paper>-<table>/``: that page's images and data files.

Every file is written beside its name and renamed over it (:mod:`repro.store.atomic`), so a
link already in ``out`` (``index.html -> ~/notes.txt``, a linked ``<paper>-<table>/``) is
replaced, never written through; an ``out`` that is a file, a device or cannot be made is one
error line.

No server, no network: styles are inline, images are relative files.  Each page carries a
small script that, once loaded, checks that every image decoded and records the result on
``<body data-images-ok data-images-failed data-script-errors>``; a failure also shows a
red banner, so a broken report says so to its reader (and the browser test reads it).
"""

from __future__ import annotations

import html
import json
from pathlib import Path

from repro.report.render import html_table
from repro.report.view import FigureView, data_mark
from repro.store.atomic import output_dir, output_subdir, write_output

E = html.escape

CSS = """
body{font-family:DejaVu Sans,Helvetica,Arial,sans-serif;margin:24px;color:#222;max-width:1500px}
h1{font-size:22px;margin:0 0 6px}h2{font-size:18px;margin:26px 0 8px;border-bottom:1px solid #ccc}
h3{font-size:15px}table{border-collapse:collapse;font-size:12px;margin:8px 0}
td,th{border:1px solid #ccc;padding:3px 6px;text-align:left;vertical-align:top}
th{background:#f1f1f1}.standin{background:#fff3cd;border:1px solid #e0c36c;padding:6px 10px}
.verdict{font-weight:bold}.v-supported{color:#1b7a1b}.v-contradicted{color:#b00020}
.v-other{color:#8a5a00}.strip img,.plot img{max-width:100%;border:1px solid #ddd}
.muted{color:#666;font-size:12px}#report-check{display:none;background:#b00020;color:#fff;
padding:6px 10px}dl{display:grid;grid-template-columns:max-content auto;gap:2px 14px;font-size:12px}
dt{font-weight:bold}dd{margin:0;word-break:break-all}
"""

CHECK_JS = """
window.__reproErrors = 0;
window.addEventListener('error', function () { window.__reproErrors += 1; }, true);
window.addEventListener('load', function () {
  var imgs = document.images, ok = 0, bad = 0;
  for (var i = 0; i < imgs.length; i++) {
    if (imgs[i].complete && imgs[i].naturalWidth > 0) { ok += 1; } else { bad += 1; }
  }
  document.body.setAttribute('data-images-ok', ok);
  document.body.setAttribute('data-images-failed', bad);
  document.body.setAttribute('data-script-errors', window.__reproErrors);
  if (bad || window.__reproErrors) {
    var b = document.getElementById('report-check');
    b.textContent = 'This report is damaged: ' + bad + ' image(s) did not load, '
      + window.__reproErrors + ' error(s).';
    b.style.display = 'block';
  }
});
"""


def page_name(table_id: str) -> str:
    return table_id.replace("/", "-") + ".html"


def _page(title: str, body: list[str]) -> str:
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>{E(title)}</title><style>{CSS}</style><script>{CHECK_JS}</script>"
            "</head><body>\n<div id=\"report-check\"></div>\n" + "\n".join(body)
            + "\n</body></html>\n")


def _verdict_class(v: str) -> str:
    from repro.engine.claims_list import verdict_kind

    kind = verdict_kind(v)
    return f"v-{kind}" if kind in ("supported", "contradicted") else "v-other"


def _claims_html(view) -> list[str]:
    if not view.claims:
        return ["<p class=\"muted\">The spec states no claim for this table.</p>"]
    out = ["<table><tr><th>claim</th><th>verdict</th><th>P</th><th>why / what decided it</th>"
           "</tr>"]
    for cl in view.claims:
        p = "" if cl.probability is None else f"{cl.probability:.3f}"
        why = " — ".join(x for x in (cl.reason, f"decided by: {cl.evidence}" if cl.evidence
                                     else None) if x)
        out.append(f"<tr><td>{E(cl.text)}<div class=\"muted\">{E(cl.source or '')}</div></td>"
                   f"<td class=\"verdict {_verdict_class(cl.verdict)}\">{E(cl.verdict)}</td>"
                   f"<td>{E(p)}</td><td>{E(why)}</td></tr>")
    out.append("</table>")
    return out


def provenance(rj: dict | None, view) -> list[tuple[str, str]]:
    """(field, value) pairs saying what made the numbers."""
    if rj is None:
        failed = getattr(view, "failed_run", None)
        if failed:
            from repro.engine.footer import failure_line

            return [("run", "none finished at this scale; " + failure_line(failed, None))]
        return [("run", "none: this table has not been run at this scale")]
    cfg = rj.get("config") or {}
    git = rj.get("git") or {}
    env = rj.get("env") or {}
    cpu = env.get("cpu") or {}
    evs = sorted({b.get("evaluator_key") or "" for b in cfg.get("bands", [])} - {""})
    pk = rj.get("packages") or {}
    commit = git.get("commit") or "unknown (not a git checkout)"
    if git.get("dirty"):
        commit += f" + uncommitted changes (diff sha256 {git.get('diff_sha256')})"
    return [("run", f"{rj.get('run_id')} ({rj.get('status')}, {rj.get('started')} → "
                    f"{rj.get('ended')})"),
            ("command", " ".join(rj.get("command") or [])),
            ("code commit", commit),
            ("spec", f"{rj.get('table')} v{(rj.get('spec') or {}).get('version')} "
                     f"[{((rj.get('spec') or {}).get('hash') or '')[:12]}]"),
            ("scale", f"{rj.get('scale')}; seeds {cfg.get('seeds')}; retrain "
                      f"{bool(cfg.get('retrain'))}; budget ×{cfg.get('budget', 1.0)}; "
                      f"evaluator seed {cfg.get('evaluator_seed', 0)}"),
            ("data set", f"{rj.get('dataset')} (fingerprint {cfg.get('data_fingerprint')})"
                         + (f" — not the paper's data ({data_mark(view.standin)})"
                            if view.standin else "")),
            ("evaluator fingerprints", ", ".join(evs) or "none"),
            ("machine", f"{env.get('host')}: {cpu.get('model')} ({cpu.get('cpus')} cpus), "
                        f"{env.get('platform')}, device {env.get('device')}, "
                        f"{env.get('threads')} threads"),
            ("packages", ", ".join(f"{k} {v}" for k, v in sorted(pk.items()))),
            ("pictures drawn by", _drawn_by())]


def _drawn_by() -> str:
    """The code that drew this report (it may be newer than the run's)."""
    from repro.store.runs import git_state

    g = git_state() or {}
    return (g.get("commit") or "unknown (not a git checkout)") + (
        " + uncommitted changes" if g.get("dirty") else "")


def _page_top(spec, view, path) -> tuple[list[str], str]:
    """The top of a table's page (a link back, the title, the notes on stand-in data, marks,
    a failed newest run, a figure not reproduced yet) and the table's state for the index."""
    body = [f"<p><a href=\"index.html\">← all tables</a></p>",
            f"<h1>{E(spec.id)}: {E(spec.title)}</h1>"]
    if view.standin:
        body.append(f"<p class=\"standin\">{E(data_mark(view.standin))} — the paper used "
                    f"{E(spec.paper_dataset)}; absolute values are not comparable, only "
                    "orderings and gaps.</p>")
    for m in view.marks:  # a non-standard gate, a newest run that failed (the footer says more)
        body.append(f"<p class=\"standin\">{E(m)}</p>")
    failed = view.failed_run
    if failed:
        from repro.engine.footer import failure_line

        body.append(f"<p class=\"standin\">{E(failure_line(failed, path.name if path else None))}"
                    "</p>")
    state = "run " + path.name if path else "not run"
    if failed:
        state = (f"newest run {failed.get('run_id')} {failed.get('status')}; "
                 + (f"showing run {path.name}" if path else "no finished run"))
    if view.marks and not failed:
        state += " [" + "; ".join(view.marks) + "]"
    if isinstance(view, FigureView) and not (view.x is not None and view.x.values):
        why = "; ".join(sorted({f"{r.label}: {r.status}" for r in view.rows}))
        body.append(f"<p class=\"standin\">Not reproduced yet — {E(why)}.</p>")
        state = "not reproduced yet" if path is None else state
    return body, state


def _plots_html(spec, view, path, assets: Path) -> list[str]:
    """The page's plots section: the figure (or the cells against the paper's) and the run's
    learning curves, each drawn into ``assets`` beside its data as CSV."""
    from repro.render.plots import figure_plot, learning_curve_plot, table_plot
    from repro.store.runs import read_trainings

    body = ["<h2>Plots</h2>"]
    plots = []
    if isinstance(view, FigureView):
        note = "" if view.x is not None and view.x.values else " (not reproduced yet)"
        figure_plot(view, assets / "figure.png", data_path=assets / "figure.csv")
        plots.append(("figure.png", "figure.csv", f"{spec.id} as a plot{note}: our means with "
                      "interval bands; the paper prints no values for a figure."))
    else:
        table_plot(view, assets / "cells.png", data_path=assets / "cells.csv")
        plots.append(("cells.png", "cells.csv", "our mean and interval per cell; the paper's "
                      "printed value as a black x"))
    if path is not None:
        trainings = read_trainings(path)
        if trainings:
            learning_curve_plot(trainings, assets / "curves.png", data_path=assets / "curves.csv")
            plots.append(("curves.png", "curves.csv", "learning curves of the run's trainings "
                          "(validation dashed)"))
    rel = assets.name
    for png, data, cap in plots:
        body.append(f"<div class=\"plot\"><img src=\"{rel}/{png}\" alt=\"{E(cap)}\">"
                    f"<p class=\"muted\">{E(cap)} — data: <a href=\"{rel}/{data}\">{data}</a>"
                    "</p></div>")
    return body


def _strips_html(spec, view, path, assets: Path, *, items: int,
                 strips: bool) -> tuple[list[str], int]:
    """The page's strips section (drawn into ``assets`` from the run's samples, when there is
    a finished run and strips are asked for) and how many strips it shows."""
    body = ["<h2>Strips: the motions behind the numbers</h2>"]
    n_strips = 0
    if path is None:
        body.append("<p class=\"muted\">" + ("No finished run: no samples to draw."
                                             if view.failed_run
                                             else "Not run yet: no samples to draw.") + "</p>")
    elif not strips:
        body.append("<p class=\"muted\">Strips were not asked for (--no-strips).</p>")
    else:
        from repro.engine.run_samples import run_samples
        from repro.report.strip_sets import write_strips

        rel = assets.name
        rec = write_strips(run_samples(spec.id, run=path), assets, items=items)
        n_strips = len(rec["strips"])
        for st in rec["strips"]:
            f = st["files"]
            body.append(f"<div class=\"strip\"><h3>{E(st['title'])}</h3>"
                        f"<img src=\"{rel}/{f['png']}\" alt=\"{E(st['title'])}\">"
                        f"<p class=\"muted\">{E(st['band_label'])}; replicate "
                        f"{st['replicate']}; rows: "
                        f"{E(', '.join(st['rows']))}. Multi-channel OpenEXR (R, G, B, A, Z, "
                        f"JointIndex): <a href=\"{rel}/{f['exr']}\">{f['exr']}</a></p></div>")
        for n in rec["notes"]:
            body.append(f"<p class=\"muted\">No strip: {E(n)}</p>")
        if not rec["strips"] and not rec["notes"]:
            why = ("its data set is not available" if any(
                r.status == "data unavailable" for r in view.rows) else
                "no row of this table generated samples")
            body.append(f"<p class=\"muted\">No strips: {E(why)}.</p>")
    return body, n_strips


def table_page(table_id: str, out: Path, *, scale: str = "quick", dataset: str | None = None,
               run: str | None = None, items: int = 2, strips: bool = True) -> dict:
    """Write one table's page and its assets; returns what it holds (for the index)."""
    from repro.engine.runner import table_run, table_spec, table_view
    from repro.store.runs import read_run_json

    spec = table_spec(table_id)
    path = table_run(spec, scale, dataset, run)
    rj = read_run_json(path) if path is not None else None
    # the run asked for, else the newest finished one (the view then says when a newer run
    # failed): the same folder as ``path``
    view = table_view(spec.id, scale=scale, dataset=dataset, run=run)
    name = page_name(spec.id)
    assets = output_subdir(out, name[:-5])  # a link planted there is replaced, not followed
    body, state = _page_top(spec, view, path)
    body += ["<h2>Paper vs reproduced</h2>", html_table(view), "<h2>Claims</h2>",
             *_claims_html(view)]
    body += _plots_html(spec, view, path, assets)
    strip_body, n_strips = _strips_html(spec, view, path, assets, items=items, strips=strips)
    body += strip_body
    body.append("<h2>Provenance</h2><dl>" + "".join(
        f"<dt>{E(k)}</dt><dd>{E(v)}</dd>" for k, v in provenance(rj, view)) + "</dl>")
    body += [f"<p class=\"muted\">{E(x)}</p>" for x in view.footer]
    write_output(out / name, _page(f"{spec.id} — repro report", body))
    return {"table": spec.id, "page": name, "state": state, "strips": n_strips,
            "claims": [(c.verdict, c.text) for c in view.claims], "title": spec.title}


def claims_index(scale: str, dataset: str | None = None,
                 runs: dict[str, Path | None] | None = None) -> list[str]:
    """The top of the index page (issue 32, item 6): every claim of every spec, one line each,
    as ``repro claims --scale <scale>`` lists them (:mod:`repro.engine.claims_list`; ``runs``:
    the run of a table given by ``--run``); the verdicts coloured as on a table's page, every
    cell escaped."""
    from repro.engine.claims_list import HEADINGS, NOT_RUN, claim_cells, list_claims

    entries = list_claims(scale=scale, dataset=dataset, runs=runs)
    tables = {e["table"] for e in entries}
    n_run = len(tables - {e["table"] for e in entries if e["verdict"] == NOT_RUN})
    out = ["<h2>Claims</h2>",
           f"<p class=\"muted\">Every claim of every spec ({len(entries)}), with the verdict "
           f"of its table's newest finished run at scale {E(scale)} (tables with one: "
           f"{n_run} of {len(tables)}; the others' claims read \"not run\"). P: the "
           "probability that the claim holds; "
           "converged: whether every trained row it involves trained to a plateau; budget: "
           "the trained rows' training against the paper's schedule (*: assumed).</p>",
           "<table class=\"claims\"><tr>" + "".join(
               f"<th>{h}</th>" for h in HEADINGS) + "</tr>"]
    for e in entries:
        cells = [f"<td>{E(c)}</td>" for c in claim_cells(e)]
        cells[3] = f"<td class=\"verdict {_verdict_class(e['verdict'])}\">{E(e['verdict'])}</td>"
        out.append("<tr>" + "".join(cells) + "</tr>")
    out.append("</table>")
    return out


def write_report(tables: list[str], out: str | Path, *, scale: str = "quick",
                 dataset: str | None = None, run: str | None = None, items: int = 2,
                 strips: bool = True) -> Path:
    """Write the report of ``tables`` into ``out``; returns the index page's path."""
    from repro.engine.runner import latest_run, table_run, table_spec
    from repro.specs.load import load_all

    from repro.errors import ConfigError

    if run is not None and len(set(tables)) > 1:
        raise ConfigError("--run names one run, of one table; give one table with it")
    ids = list(dict.fromkeys(table_spec(t).id for t in tables))
    out = output_dir(out)
    done = {t: table_page(t, out, scale=scale, dataset=dataset,
                          run=run if len(ids) == 1 else None, items=items, strips=strips)
            for t in ids}
    rows = []
    for sid, spec in sorted(load_all().items()):
        if sid in done:
            d = done[sid]
            verdicts = "; ".join(f"{v}" for v, _ in d["claims"]) or "-"
            rows.append(f"<tr><td><a href=\"{d['page']}\">{E(sid)}</a></td><td>{E(spec.title)}"
                        f"</td><td>{E(d['state'])}</td><td>{d['strips']}</td>"
                        f"<td>{E(verdicts)}</td></tr>")
        else:
            last = latest_run(sid, scale)
            st = f"not in this report (last run {last.name})" if last else "not in this report"
            rows.append(f"<tr><td>{E(sid)}</td><td>{E(spec.title)}</td><td>{E(st)}</td>"
                        "<td>-</td><td>-</td></tr>")
    runs = {ids[0]: table_run(table_spec(ids[0]), scale, dataset, run)} if run else None
    body = ["<h1>repro report</h1>", *claims_index(scale, dataset, runs),
            "<h2>Tables</h2>",
            f"<p class=\"muted\">Scale {E(scale)}; {len(done)} of {len(rows)} tables reported "
            "here. Each page: the paper's table beside ours, the claims with their verdicts, "
            "plots, strips of the motions, provenance.</p>",
            "<table><tr><th>table</th><th>title</th><th>state</th><th>strips</th>"
            "<th>claim verdicts</th></tr>", *rows, "</table>"]
    index = out / "index.html"
    write_output(index, _page("repro report", body))
    write_output(out / "report.json", json.dumps({"schema": 1, "scale": scale,
                                                  "tables": list(done.values())}, indent=1,
                                                 sort_keys=True) + "\n")
    return index
