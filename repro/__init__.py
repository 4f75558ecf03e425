"""repro: a reproducibility harness for human-motion generation papers.

Neural Marionette, MultiAct and ODMO tables are rebuilt from declarative specs in
``tables/``; see ``README.md`` and ``docs/``.
"""

__version__ = "0.1.0"
