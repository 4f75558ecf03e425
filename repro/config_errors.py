"""Configuration models validated into one clear :class:`~repro.errors.ConfigError`.

Every configuration model of the harness (a method's ``Config``, a protocol's ``Params``, the
item construction, the sequence composition, the item and pair sources) is a frozen pydantic
model with ``extra="forbid"``.  A bad value must end the command with one line naming the field
(exit code 2, no traceback; DESIGN.md "Conventions"), so each of them turns pydantic's
``ValidationError`` into a ConfigError the same way:

- :func:`first_problem` ``(error) -> (field, message)``: the dotted location of the first
  problem pydantic reports and its message;
- :func:`config_error` ``(error, lead) -> ConfigError``: ``"<lead> '<field>': <message>"``;
- :func:`resolve_config` ``(cls, value, lead)``: ``value`` (``None``: the defaults; an instance
  of ``cls``: itself; another pydantic model: its fields; a mapping: overrides) validated as
  ``cls``, a ConfigError from :func:`config_error` when it is not valid.

Each caller keeps its own wording in ``lead`` (tests and users match on it).
"""

from __future__ import annotations

from typing import Any, Mapping, TypeVar

from pydantic import BaseModel, ValidationError

from repro.errors import ConfigError

M = TypeVar("M", bound=BaseModel)


def first_problem(error: ValidationError, unnamed: str = "?") -> tuple[str, str]:
    """``(field, message)`` of the first problem in ``error``: the field as its dotted
    location (``unnamed`` when pydantic gives none, e.g. a model-level validator)."""
    err = error.errors()[0]
    field = ".".join(str(p) for p in err.get("loc", ())) or unnamed
    return field, str(err["msg"])


def config_error(error: ValidationError, lead: str, *, unnamed: str = "?",
                 quote: bool = True) -> ConfigError:
    """The ConfigError for ``error``: ``"<lead> '<field>': <message>"`` (``quote=False``:
    ``"<lead> <field>: <message>"``), the field and message of :func:`first_problem`."""
    field, msg = first_problem(error, unnamed)
    return ConfigError(f"{lead} {field!r}: {msg}" if quote else f"{lead} {field}: {msg}")


def resolve_config(cls: type[M], value: "M | BaseModel | Mapping[str, Any] | None", lead: str,
                   *, unnamed: str = "?", quote: bool = True,
                   type_lead: str | None = None) -> M:
    """``value`` validated as ``cls`` over its defaults (module docstring).

    ``None`` gives ``cls()``; an instance of ``cls`` (or of a subclass) is returned as it is;
    another pydantic model is read through ``model_dump()``; anything else is taken as a
    mapping of field overrides.  A ValidationError becomes :func:`config_error` ``(error,
    lead, unnamed=..., quote=...)``.  With ``type_lead``, a TypeError (``value`` is not a
    mapping, a key is not a string) becomes ``ConfigError("<type_lead>: <error>")``; without
    it, it propagates (a caller's bug, not bad input).
    """
    if value is None:
        return cls()
    if isinstance(value, cls):
        return value
    if isinstance(value, BaseModel):
        value = value.model_dump()
    try:
        return cls(**dict(value))
    except ValidationError as e:
        raise config_error(e, lead, unnamed=unnamed, quote=quote) from None
    except TypeError as e:
        if type_lead is None:
            raise
        raise ConfigError(f"{type_lead}: {e}") from None
