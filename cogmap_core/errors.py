"""One base exception for everything a user can get wrong; the CLI turns it into a clean message."""

from __future__ import annotations


class CogmapError(Exception):
    """Base of every expected error: bad input, bad parameter, unreadable data.

    The message is one line that names the problem and what to do about it. The command-line
    interface prints it (no traceback) and exits with :attr:`exit_code`.
    """

    exit_code: int = 2


class InputFileError(CogmapError):
    """A file given by the user is missing, unreadable or malformed."""


class G2oFormatError(InputFileError):
    """A g2o file has a line that cannot be parsed (the message names file and line)."""


class ParameterError(CogmapError):
    """A parameter is outside its valid range (the message gives the range)."""


class EventError(CogmapError):
    """The event stream given to the cognitive map breaks the event contract."""


class OptimizationError(CogmapError):
    """Ceres could not solve the problem (for example non-finite values)."""


class OutputError(CogmapError):
    """An output cannot be written: read-only or missing folder, full disk, a folder in the way.

    Raised before any work when the target is found unwritable, or when writing fails; either way
    the previous output (if any) is left intact.
    """


class StateError(ValueError):
    """Saved state does not fit the object it is loaded into (``load_state``, ``from_state``).

    The message names the part that does not fit (``"adjacency does not match the graph"``);
    a file format reading the state prefixes it with where the part came from.
    """
