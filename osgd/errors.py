"""Errors a person can act on, and how any error becomes one line.

:class:`InputError` is raised for a problem with a file a person supplied
(a mesh, a sidecar, an annotation file): it carries the file and the cause
separately, so that the command line can list failed items as a table of
item, file and cause. :func:`describe` turns any exception into such a
(file, cause) pair, for the errors that are not ours.
"""

from __future__ import annotations

import os


class InputError(ValueError):
    """A file that cannot be used; names the file and what is wrong.

    Parameters
    ----------
    file : str or path
        The file at fault.
    cause : str
        What is wrong with it and, where it helps, what is allowed.
    """

    def __init__(self, file: str | os.PathLike[str], cause: str) -> None:
        super().__init__(f"{file}: {cause}")
        self.file = str(file)
        self.cause = cause

    def __reduce__(self) -> tuple[type[InputError], tuple[str, str]]:
        # Exceptions pickle their ``args`` (the joined message) by default;
        # keep the two parts apart across processes.
        return type(self), (self.file, self.cause)


def one_line(text: str) -> str:
    """``text`` with its lines joined by ``"; "`` (a table cell, a log line)."""
    return "; ".join(line.strip() for line in str(text).splitlines() if line.strip())


def describe(error: BaseException) -> tuple[str, str]:
    """The file an exception is about (empty when unknown) and its cause, one line.

    Parameters
    ----------
    error : BaseException

    Returns
    -------
    file : str
    cause : str
        The message of an :class:`InputError` or an ``OSError``; for other
        exceptions the type name and the message, e.g.
        ``"IndexError: index 6448 is out of bounds ..."``.
    """
    if isinstance(error, InputError):
        return error.file, one_line(error.cause)
    if isinstance(error, OSError) and error.filename:
        return str(error.filename), one_line(error.strerror or type(error).__name__)
    message = one_line(str(error))
    return "", f"{type(error).__name__}: {message}" if message else type(error).__name__
