"""``repro doctor``: what data the specs can use, where it is looked for, and what is missing.

One line per registered data set (``repro.data.registry.DATASETS``): name, state, fingerprint
prefix, where it is (or is looked for), and what is missing or damaged; then the body models
and the compute environment.  The state is validated, not just looked up (issue 16: it said
"prepared yes" for any file present): each data set's :meth:`DatasetEntry.validate` opens its
files cheaply (a prepared cache's ``meta.json``, ``.npy`` headers, sizes and per-clip arrays;
the bundle's recorded sha256; the upstream readers' own checks) and the line says

- ``prepared, valid``: present and read back intact;
- ``prepared, damaged``: present but damaged; the next line, ``damaged: <file>: <why>``, names
  the file and the command that rebuilds it;
- ``not prepared``: absent; ``missing:`` says what to put where;
- ``prepared, unchecked``: present, but its entry registers no validation.

It is a report: exit 0 whatever is missing or damaged; exit 2 only when the registry itself
cannot be read (a broken installation).  It reads only: no data is changed or deleted.
"""

from __future__ import annotations

import json
import sys


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "doctor", help="report which data sets are ready and what is missing",
        description="Report each data set the table specs can use: whether it is prepared, "
        "where it is looked for, its fingerprint, and what is missing.")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=_doctor)


def _datasets() -> list[dict]:
    from repro.data.registry import DATASETS
    from repro.errors import ReproError

    rows = []
    for name, entry in DATASETS.items():
        st = entry.status()
        try:
            damaged = entry.validate()
        except ReproError as e:  # a validator that raises instead of answering
            damaged = str(e)
        checked = getattr(entry, "validate_fn", None) is not None
        if damaged:
            state = "prepared, damaged"
        elif st.prepared:
            state = "prepared, valid" if checked else "prepared, unchecked"
        else:
            state = "not prepared"
        rows.append({"name": name, "paper_dataset": bool(entry.is_paper_dataset),
                     "prepared": bool(st.prepared), "state": state,
                     "valid": (not damaged) if (st.prepared or damaged) and checked else None,
                     "damaged": damaged or None, "location": st.location,
                     "fingerprint": st.fingerprint, "missing": st.missing,
                     "description": entry.description})
    return rows


def _body_models() -> list[dict]:
    from repro.data.upstream.smpl import locate_body_model
    from repro.errors import ReproError

    out = []
    for kind, gender, used_by in (("smplh", "male", "BABEL joints (MultiAct)"),
                                  ("smpl", "neutral", "SMPL poses to joints (ACTOR)")):
        try:
            path, missing = str(locate_body_model(kind, gender=gender)), None
        except ReproError as e:
            path, missing = None, str(e)
        out.append({"kind": kind, "gender": gender, "used_by": used_by, "path": path,
                    "missing": missing})
    return out


def _environment() -> dict:
    import platform

    import torch

    from repro import kernels

    kernels.apply_runtime()  # what a job of this process would compute under
    st = kernels.state()
    bad = [] if kernels.fast_requested() else kernels.pinned_in_force(st)
    return {"python": platform.python_version(), "torch": torch.__version__,
            "threads": torch.get_num_threads(), "cuda": bool(torch.cuda.is_available()),
            "kernels": {**kernels.record(), "in_force": st, "not_in_force": bad}}


def _doctor(args) -> int:
    from repro.errors import EXIT_BAD_INPUT

    try:
        rows = _datasets()
    except Exception as e:  # a broken registry is the one failure doctor reports as such
        print(f"repro: error: the data-set registry cannot be read ({type(e).__name__}: {e})",
              file=sys.stderr)
        return EXIT_BAD_INPUT
    models = _body_models()
    env = _environment()
    if args.json:
        print(json.dumps({"datasets": rows, "body_models": models, "environment": env},
                         indent=2))
        return 0
    width = max(len(r["name"]) for r in rows) if rows else 8
    for r in rows:
        fp = r["fingerprint"][:12] if r["fingerprint"] else "-" * 12
        line = f"{r['name']:<{width}}  {r['state']:<19}  {fp}  {r['location']}"
        if r["damaged"]:
            line += f"\n{'':<{width}}  damaged: {r['damaged']}"
        if r["missing"] and not (r["damaged"] and not r["prepared"]):
            line += f"\n{'':<{width}}  missing: {r['missing']}"
        print(line)
    for m in models:
        label = f"{m['kind']} ({m['gender']})"
        print(f"body model {label:<16} {m['path'] or 'not found'}  [{m['used_by']}]"
              + (f"\n{'':<11}missing: {m['missing']}" if m["missing"] else ""))
    print(f"environment: python {env['python']}, torch {env['torch']}, "
          f"{env['threads']} threads, cuda {'yes' if env['cuda'] else 'no'}")
    from repro.kernels import describe

    k = env["kernels"]
    print(f"kernels: {describe(k)}"
          + (f"; NOT in force: {'; '.join(k['not_in_force'])}" if k["not_in_force"] else ""))
    return 0
