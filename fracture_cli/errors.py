"""The exception hierarchy and its exit codes, defined in one place.

Every error the library raises on purpose is a :class:`FractureError`; the CLI
turns it into one line on stderr and the exit code below. Anything else is a bug
and is shown with a traceback only under ``--debug``.
"""

from __future__ import annotations

import os

EXIT_OK = 0
EXIT_FAILURE = 1  # bad input or a stage that could not finish
EXIT_USAGE = 2  # wrong command line (click's own convention)


def printable(path: str | os.PathLike) -> str:
    """``path`` for a message: a file name that is not UTF-8 (surrogate-escaped by Python) gets ``\\xNN`` escapes."""
    return os.fsencode(path).decode("utf-8", "backslashreplace")


class FractureError(Exception):
    """Base class of every error the tool reports to its user.

    Parameters
    ----------
    message : str
        One line that says what went wrong and, where possible, what would work.
    path : str, optional (default None)
        The file the problem is about; it prefixes the message.
    stage : str, optional (default None)
        The pipeline stage that raised; it prefixes the message.
    """

    exit_code = EXIT_FAILURE

    def __init__(self, message: str, *, path: str | None = None, stage: str | None = None):
        super().__init__(message)
        self.message = message
        self.path = path
        self.stage = stage

    def __str__(self) -> str:
        prefix = ""
        if self.stage:
            prefix += f"{self.stage}: "
        if self.path:
            prefix += printable(self.path) + ": "
        return prefix + self.message


class InputError(FractureError):
    """An input file (mesh, recipe, runtime file) is missing, unreadable or unusable."""


class RuntimeFileError(InputError, ValueError):
    """A runtime file (``.fracture.json`` + ``.bin``) is missing, damaged, of another version or inconsistent.

    Also a :class:`ValueError`, so code that reads runtime files without the
    rest of the tool can catch it as one.
    """


class ImpactArgumentError(InputError, ValueError):
    """:func:`~fracture_cli.runtime.impact.project_impact` got an unusable argument.

    A point or impulse that is not three finite numbers, or a threshold that
    is NaN or negative. Also a :class:`ValueError`.
    """


class OutputError(FractureError):
    """The outputs cannot be written: folder not writable, disk full, would overwrite an input, locked."""


class RecipeError(InputError):
    """A recipe or a ``--set`` override has an unknown key, a wrong type or a value out of range."""


class StageError(FractureError):
    """A pipeline stage could not produce a valid result."""


class UsageError(FractureError):
    """The command line asks for something impossible (e.g. a stage without its input)."""

    exit_code = EXIT_USAGE


def exit_code_for(error: BaseException) -> int:
    """Return the process exit code for ``error``."""
    if isinstance(error, FractureError):
        return error.exit_code
    return EXIT_FAILURE
