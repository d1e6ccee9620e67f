"""Errors that the command line turns into a one-line message and exit code 2."""

from __future__ import annotations

from os import PathLike


class GyrolabError(Exception):
    """Bad input or bad arguments: reported as one line, exit code 2, nothing written."""

    exit_code = 2


class InputError(GyrolabError):
    """A problem with a named file (or argument): ``"<path>: <problem>"``."""

    def __init__(self, path: str | PathLike[str] | None, problem: str) -> None:
        self.path = None if path is None else str(path)
        self.problem = problem
        super().__init__(problem if self.path is None else f"{self.path}: {problem}")
