"""Declarative table specs (``tables/<paper>/<table>.toml``) and scale profiles
(``tables/scales.toml``): schema, vocabularies, loading.  Format: ``docs/specs.md``."""

from repro.specs import names
from repro.specs.load import SpecValidationError, find_spec, load_all, load_spec, spec_paths
from repro.specs.reported import check_claim_on_reported
from repro.specs.scales import ResolvedScale, load_scales, resolve_scale
from repro.specs.schema import (
    Claim,
    Column,
    ColumnGroup,
    ReportedCell,
    Row,
    TableSpec,
    parse_printed,
)

__all__ = [
    "names", "SpecValidationError", "find_spec", "load_all", "load_spec", "spec_paths",
    "check_claim_on_reported", "ResolvedScale", "load_scales", "resolve_scale",
    "Claim", "Column", "ColumnGroup", "ReportedCell", "Row", "TableSpec", "parse_printed",
]
