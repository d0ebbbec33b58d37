"""The array packing a session file uses (:mod:`cogmap_core.session_file`), and its error.

A session file is a header of JSON (:data:`Json`) and named arrays (:data:`Arrays`); flat
records (a dataclass's ``state_dict()``: one value per field) are kept as one array per field,
lists of integer lists as their counts and items.
"""

from __future__ import annotations

from dataclasses import fields
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cogmap_core.errors import InputFileError

Arrays = dict[str, NDArray[Any]]
Json = dict[str, Any]


class SessionError(InputFileError):
    """A session file cannot be used: unreadable, corrupt, another version, other settings."""


def save_records(arrays: Arrays, prefix: str, records: list[Json], kind: type) -> None:
    """Flat records (dicts of ``kind``'s fields) as one array per field.

    The fields' types give the arrays' types; ``correction`` (three floats) is ``(n, 3)``.
    """
    for f in fields(kind):
        values = [r[f.name] for r in records]
        if f.name == "correction":
            arrays[prefix + f.name] = np.array(values, dtype=np.float64).reshape(-1, 3)
        elif f.type in ("int", "bool"):
            arrays[prefix + f.name] = np.array(values, dtype=np.int64 if f.type == "int" else bool)
        else:
            arrays[prefix + f.name] = np.array(values, dtype=np.float64)


def save_lists(arrays: Arrays, prefix: str, lists: list[list[int]]) -> None:
    """Lists of integers as their counts (``prefix.count``) and items (``prefix.items``)."""
    counts = np.array([len(x) for x in lists], dtype=np.int64)
    arrays[prefix + ".count"] = counts
    arrays[prefix + ".items"] = np.fromiter(
        (v for x in lists for v in x), dtype=np.int64, count=int(counts.sum())
    )


def load_records(arrays: Arrays, prefix: str, kind: type) -> list[Json]:
    """The records :func:`save_records` saved under ``prefix`` (dicts of ``kind``'s fields)."""
    columns = {f.name: arrays[prefix + f.name].tolist() for f in fields(kind)}
    count = len(next(iter(columns.values())))
    if any(len(v) != count for v in columns.values()):
        raise SessionError(f"{prefix[:-1]} records have columns of different lengths")
    return [{name: values[k] for name, values in columns.items()} for k in range(count)]


def load_lists(arrays: Arrays, prefix: str) -> list[list[int]]:
    """The lists :func:`save_lists` saved under ``prefix``."""
    counts = arrays[prefix + ".count"].tolist()
    items = arrays[prefix + ".items"].tolist()
    if sum(counts) != len(items):
        raise SessionError(f"{prefix} lists do not match their counts")
    out = []
    start = 0
    for c in counts:
        out.append(items[start : start + c])
        start += c
    return out


__all__ = [
    "Arrays",
    "Json",
    "SessionError",
    "load_lists",
    "load_records",
    "save_lists",
    "save_records",
]
