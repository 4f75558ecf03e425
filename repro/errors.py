"""Errors that end a command with one clear line and exit code 2 (bad input, never a bug).

Every error a user can cause (a malformed file, a typo in a spec, a missing data set) is a
:class:`ReproError`.  The CLI prints ``repro: error: <message>`` and exits with
:data:`EXIT_BAD_INPUT`; nothing already cached is touched.  Anything else is a bug and keeps
its traceback.
"""

from __future__ import annotations

from pathlib import Path

EXIT_BAD_INPUT = 2


class ReproError(Exception):
    """Base class of every user-facing error."""

    exit_code = EXIT_BAD_INPUT


def _where(file: str | Path | None, line: int | None) -> str:
    if file is None:
        return ""
    return f"{file}:{line}: " if line is not None else f"{file}: "


class DataError(ReproError):
    """A data file is malformed or disagrees with what is expected of it.

    The message names the file, the line when known, and the problem.
    """

    def __init__(self, problem: str, file: str | Path | None = None, line: int | None = None):
        self.problem = problem
        self.file = None if file is None else str(file)
        self.line = line
        super().__init__(f"{_where(file, line)}{problem}")


class MissingDataError(DataError):
    """A data set or file the command needs is absent; the message says where to put it."""


class SpecError(ReproError):
    """A table spec or scale profile is invalid; the message names file, location and field."""

    def __init__(self, problem: str, file: str | Path | None = None, location: str | None = None):
        self.problem = problem
        self.file = None if file is None else str(file)
        self.location = location
        loc = f"{location}: " if location else ""
        super().__init__(f"{_where(file, None)}{loc}{problem}")


class ConfigError(ReproError):
    """A command-line or configuration value is invalid (unknown table, bad scale, ...)."""
