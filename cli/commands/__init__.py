"""One module per command group; each exposes ``register(subparsers)``.

Modules must import only the standard library at import time (``repro --help`` answers in
well under half a second); heavy imports (torch, numpy, ...) go inside the handlers.
"""


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
