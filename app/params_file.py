"""Map parameters from a JSON file: a flat ``{parameter: value}`` table or a sweep's ``best.json``.

``cogmap serve --params FILE`` (and ``cogmap run``) start from the parameters in ``FILE``:

- a flat table, ``{"delta": 5.0, "t_interval": 1.5}`` (parameters not named keep their
  defaults: the input kind's, the paper's for bags), or ``{"params": {...}}``;
- a sweep's ``best.json``: its ``smallest_complete`` entry by default, or another entry named
  after ``#``: ``best.json#paper``, ``best.json#front_ate/0`` (the first, smallest, setting of
  the vertices-vs-ATE front), ``best.json#front_completeness/2``, ``best.json#beat_paper/0``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from cogmap_core.config import MapParams
from cogmap_core.errors import CogmapError, InputFileError
from cogmap_core.fileio import read_json

BEST_FORMAT = "cogmap-sweep-best"
DEFAULT_ENTRY = "smallest_complete"
SINGLE_ENTRIES = ("smallest_complete", "paper")
LIST_ENTRIES = ("front_ate", "front_completeness", "beat_paper")
_JSON_TYPES = {"list": "list", "str": "string", "int": "number", "float": "number",
               "bool": "boolean", "dict": "object", "null": "null"}  # fmt: skip


def split_entry(text: str) -> tuple[Path, str | None]:
    """``FILE#ENTRY`` -> (FILE, ENTRY); no ``#``: (FILE, None)."""
    path, sep, entry = text.partition("#")
    return Path(path), (entry if sep else None)


def load_params_changes(text: str) -> dict[str, float]:
    """The map parameters ``FILE`` or ``FILE#ENTRY`` names (see the module docstring), validated.

    Raises:
        InputFileError: missing or unreadable file, not JSON, an unknown entry or an empty one,
            an unknown parameter or a value out of range (one line naming the file).

    """
    path, entry = split_entry(text)
    if not path.is_file():
        raise InputFileError(f"{path}: no such parameter file; give a JSON file, e.g. best.json")
    data = read_json(path, "parameter file", InputFileError)
    if not isinstance(data, dict):
        raise InputFileError(f"{path}: expected a JSON object of map parameters")
    if data.get("format") == BEST_FORMAT:
        data = _best_entry(path, data, entry or DEFAULT_ENTRY)
    elif entry is not None:
        raise InputFileError(
            f"{path}: #{entry} names an entry, but this is not a sweep's best.json"
        )
    values = data.get("params", data)
    if not isinstance(values, dict):
        raise InputFileError(f"{path}: 'params' must be an object of parameter: value")
    try:
        MapParams.from_dict(values)  # unknown names, values that are not numbers or out of range
    except (CogmapError, TypeError) as exc:  # TypeError: a value of the wrong type
        raise InputFileError(f"{path}: {exc}") from None
    return dict(values)


def _entry_object(path: Path, entry: str, chosen: object) -> dict[str, Any]:
    """A best.json entry, which must be a JSON object (a setting), as a dict."""
    if not isinstance(chosen, dict):
        kind = type(chosen).__name__ if chosen is not None else "null"
        raise InputFileError(
            f"{path}#{entry}: the entry is a {_JSON_TYPES.get(kind, kind)}, not a setting "
            "(an object of parameters); the file is not a sweep's best.json as cogmap writes it"
        )
    return dict(chosen)


def _best_entry(path: Path, best: dict[str, Any], entry: str) -> dict[str, Any]:
    name, _, index_text = entry.partition("/")
    choices = ", ".join(SINGLE_ENTRIES + tuple(f"{n}/K" for n in LIST_ENTRIES))
    if name in SINGLE_ENTRIES and not index_text:
        chosen = best.get(name)
        if chosen is None or chosen == {}:
            raise InputFileError(
                f"{path}: the sweep has no {name} setting; pick another entry ({choices})"
            )
        return _entry_object(path, entry, chosen)
    if name in LIST_ENTRIES:
        items = best.get(name) or []
        if not isinstance(items, list):
            raise InputFileError(
                f"{path}#{entry}: {name} is a {_JSON_TYPES.get(type(items).__name__, 'value')}, "
                "not a list of settings; the file is not a sweep's best.json as cogmap writes it"
            )
        try:
            index = int(index_text or "0")
        except ValueError:
            raise InputFileError(f"{path}#{entry}: {index_text!r} is not an index") from None
        if not 0 <= index < len(items):
            raise InputFileError(
                f"{path}#{entry}: {name} has {len(items)} settings (0..{len(items) - 1})"
            )
        return _entry_object(path, entry, items[index])
    raise InputFileError(f"{path}: no entry {entry!r}; entries: {choices}")
