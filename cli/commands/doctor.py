"""``repro doctor``: what data the specs can use, where it is looked for, and what is missing.

One line per registered data set (``repro.data.registry.DATASETS``): name, prepared yes/no,
where it is (or is looked for), fingerprint prefix, and what is missing; then the body models
and the compute environment.  It is a report: exit 0 whatever is missing; exit 2 only when the
registry itself cannot be read (a broken installation).
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

    rows = []
    for name, entry in DATASETS.items():
        st = entry.status()
        rows.append({"name": name, "paper_dataset": bool(entry.is_paper_dataset),
                     "prepared": bool(st.prepared), "location": st.location,
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

    return {"python": platform.python_version(), "torch": torch.__version__,
            "threads": torch.get_num_threads(), "cuda": bool(torch.cuda.is_available())}


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
        state = "yes" if r["prepared"] else "no "
        line = f"{r['name']:<{width}}  prepared {state}  {fp}  {r['location']}"
        if r["missing"]:
            line += f"\n{'':<{width}}  missing: {r['missing']}"
        print(line)
    for m in models:
        label = f"{m['kind']} ({m['gender']})"
        print(f"body model {label:<16} {m['path'] or 'not found'}  [{m['used_by']}]"
              + (f"\n{'':<11}missing: {m['missing']}" if m["missing"] else ""))
    print(f"environment: python {env['python']}, torch {env['torch']}, "
          f"{env['threads']} threads, cuda {'yes' if env['cuda'] else 'no'}")
    return 0
