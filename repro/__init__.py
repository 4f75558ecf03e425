"""repro: a reproducibility harness for human-motion generation papers.

Neural Marionette, MultiAct and ODMO tables are rebuilt from declarative specs in
``tables/``; see ``README.md`` and ``docs/``.

Importing ``repro`` pins the numeric libraries' kernel paths (:mod:`repro.kernels`) before
torch or numpy is loaded, so that the same seed gives the same bytes on every x86-64 CPU with
AVX2; ``REPRO_FAST_KERNELS=1`` (the CLI's ``--fast-kernels``) keeps the host's own paths.
"""

from repro.kernels import pin_environment as _pin_environment

__version__ = "0.1.0"

_pin_environment()
