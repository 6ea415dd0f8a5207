"""The one exception family of tpos; the CLI maps it to exit codes (2 invalid input, 1 processing)."""

from __future__ import annotations


class TposError(Exception):
    """Base of every error tpos raises on purpose; exit code 1 unless a subclass says otherwise."""

    exit_code = 1


class InvalidInputError(TposError):
    """A session, pipeline file or argument is not valid; the message names file, column, row."""

    exit_code = 2

    def __init__(self, message: str, problems: list | None = None):
        super().__init__(message)
        self.problems = list(problems or [])


class ProcessingError(TposError):
    """Processing could not complete on valid input (e.g. a filter diverged)."""

    exit_code = 1
