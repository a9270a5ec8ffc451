"""One exception tree for usvlog.

Every error a user can cause (bad input, a missing file, an existing output) is a
:class:`UsvlogError`.  The CLI turns it into one line on stderr and exit code 2.
Subclasses also inherit the matching builtin so library callers can catch
``ValueError`` / ``OSError`` as usual.
"""

from __future__ import annotations


class UsvlogError(Exception):
    """Base class of every error usvlog raises on purpose."""


class InputError(UsvlogError, ValueError):
    """Input data is malformed: names the file, the channel and the row or time."""


class FormatError(InputError):
    """A file is not in the expected format at all (e.g. not MCAP)."""


class ConfigError(UsvlogError, ValueError):
    """A parameter, scenario or settings value is invalid."""


class OutputExistsError(UsvlogError, FileExistsError):
    """An output exists and ``force`` was not given."""


class StorageError(UsvlogError, OSError):
    """The file system refused: missing input, unwritable output, disk full."""


class UnusableResultError(UsvlogError, ArithmeticError):
    """A computation ran but its result cannot be trusted (diverged, non-finite): nothing
    is written, and the CLI exits 1 (not 2: the input was readable, the answer is no)."""

    exit_code = 1


class FitFailed(UnusableResultError):
    """A numerical fit could not proceed on this data from this start: its simulation
    diverged, its numbers left the finite range, or its equations were singular.

    Raised by the identification's numerical functions (output error, the surge fit, the
    extended model's output error, equation error, filter error, the smoothers) instead of a
    raw numpy/scipy exception. An identification catches it per candidate (that candidate
    failed, with this message as the reason); one that escapes is an unusable result
    (exit 1). ``reasons`` holds the message, as the identifier's unusable errors do."""

    def __init__(self, message: str):
        super().__init__(message)
        self.reasons = [message]


def where(path: object = None, channel: str | None = None, at: str | None = None) -> str:
    """Format the 'file, channel, row/time' prefix used by every error message.

    Parameters
    ----------
    path : object, optional
        File (or other source) name.
    channel : str, optional
        Channel (topic).
    at : str, optional
        Row, line or time.

    Returns
    -------
    str
        The given parts joined by spaces (empty or None ones left out).
    """
    parts = [str(p) for p in (path, channel, at) if p not in (None, "")]
    return " ".join(parts)
