"""Errors that the command line turns into a one-line message and exit code 2."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from os import PathLike
from pathlib import Path


class GyrolabError(Exception):
    """Bad input or bad arguments: reported as one line, exit code 2, nothing written."""

    exit_code = 2


class InputError(GyrolabError):
    """A problem with a named file (or argument): ``"<path>: <problem>"``."""

    def __init__(self, path: str | PathLike[str] | None, problem: str) -> None:
        self.path = None if path is None else str(path)
        self.problem = problem
        super().__init__(problem if self.path is None else f"{self.path}: {problem}")


def existing_file(path: str | PathLike[str], what: str = "recording") -> Path:
    """``path`` when it names a file; otherwise the :class:`InputError` that says what it
    names instead (a directory — a model directory given as the run, say — or nothing)."""
    p = Path(path)
    if p.is_dir():
        raise InputError(p, f"is a directory, not a {what} file")
    if not p.is_file():
        raise InputError(p, "file not found" if not p.exists() else f"is not a {what} file")
    return p


@contextlib.contextmanager
def named(path: str | PathLike[str]) -> Iterator[None]:
    """Give an :class:`InputError` raised deep in the numerics (no file attached) the name
    of the file it came from."""
    try:
        yield
    except InputError as err:
        if err.path is None:
            raise InputError(path, err.problem) from None
        raise
