"""Generative methods, one module each, all behind :class:`repro.models.base.Generator`."""
