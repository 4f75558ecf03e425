"""One module per command group; each exposes ``register(subparsers)``.

Modules must import only the standard library at import time (``repro --help`` answers in
well under half a second); heavy imports (torch, numpy, ...) go inside the handlers.
"""


def command_group(subparsers, name: str, help: str, description: str, dest: str):
    """The subparsers of a new command group ``name`` whose subcommand goes to ``args.<dest>``;
    the group alone prints its help (exit 0)."""
    p = subparsers.add_parser(name, help=help, description=description)
    sub = p.add_subparsers(dest=dest, metavar="SUBCOMMAND")
    p.set_defaults(func=lambda args: (p.print_help(), 0)[1])
    return sub


def int_at_least(minimum: int, rule: str | None = None):
    """An argparse ``type``: an integer >= ``minimum``; ``rule`` (with ``{v}``) words the refusal
    (default: "must be at least <minimum>, got <v>")."""
    import argparse

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
        if v < minimum:
            raise argparse.ArgumentTypeError((rule or f"must be at least {minimum}, got {{v}}")
                                             .format(v=v))
        return v

    return parse


def run_ref(text: str) -> str:
    """An argparse ``type`` for ``--run``: a run id, a prefix of one or ``latest``; an empty
    one is refused (it would silently mean the newest run, or every run's prefix)."""
    import argparse

    if not text.strip():
        raise argparse.ArgumentTypeError("the run id is empty (give a run id, a unique prefix "
                                         "of one, or 'latest'; `repro runs ls` lists them)")
    return text


def gate_options(p) -> None:
    """``--gate-margin X`` and ``--no-gate``: the real-data gate of a run (``repro run``,
    ``sweep``, ``rescore``, ``eval real``), one definition so each command reads them alike
    (:func:`repro.eval.gate.resolve_gate`: they win over the data-set spec's ``[gate]``, which
    wins over the profile's ``real.gate_margin``)."""
    p.add_argument("--gate-margin", type=gate_margin, default=None, metavar="X",
                   help="real accuracy may fall X (0 to 1) below the classifier's test "
                   "accuracy (default: the data-set spec's [gate] margin, else the profile's "
                   "0.05); a wider margin marks the run NON-STANDARD in its record, footer "
                   "and report")
    p.add_argument("--no-gate", action="store_true",
                   help="report the real-data gate, never stop on it (the run is marked "
                   "NON-STANDARD)")


def gate_margin(text: str) -> float:
    """An argparse ``type``: a number in [0, 1]."""
    import argparse
    import math

    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(v) or not 0 <= v <= 1:
        raise argparse.ArgumentTypeError(f"must be a number in [0, 1], got {text!r}")
    return v
