"""One module per command group; each exposes ``register(subparsers)``.

Modules must import only the standard library at import time (``repro --help`` answers in
well under half a second); heavy imports (torch, numpy, ...) go inside the handlers.
"""
