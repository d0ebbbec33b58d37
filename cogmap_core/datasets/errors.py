"""Errors of the dataset layer: unreadable bags, bad layouts, a broken dataset cache.

Every message is one line that names the problem and what to do about it; the command line
prints it without a traceback and exits with code 2.
"""

from __future__ import annotations

from cogmap_core.errors import CogmapError, InputFileError


class BagError(InputFileError):
    """A bag is missing, is not a bag, is truncated or corrupt, or cannot be read."""


class BagTopicError(BagError):
    """A required topic is missing from a bag (the message lists the topics it has)."""


class BagMessageTypeError(BagError):
    """A topic carries a message type the reader cannot use (the message names both types)."""


class LayoutError(InputFileError):
    """A maze layout cannot be used: bad characters, no waypoints, unreachable waypoints..."""


class DatasetCacheError(CogmapError):
    """The dataset cache directory cannot be created or written."""
