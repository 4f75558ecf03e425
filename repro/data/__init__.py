"""Data layer: format readers, the Bandai stand-in, splits, windows, the data-set registry."""
