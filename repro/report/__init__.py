"""Reported-vs-reproduced tables: the neutral view and its renderers."""

from repro.report.render import FORMATS, render
from repro.report.view import CellView, ClaimView, ColumnView, RowView, TableView

__all__ = ["FORMATS", "render", "CellView", "ClaimView", "ColumnView", "RowView", "TableView"]
