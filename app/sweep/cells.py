"""A sweep's cells (one setting on one bag's events) and the task that builds one.

:func:`compute_cell` is what a Dask worker runs (:mod:`app.sweep.dask_backend`), or this process
for :func:`run_serially`: it builds one map from the bag's events (loaded once per worker and
kept) and returns its figures (:func:`cogmap_core.sweep.evaluate_cell`) or its error.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
import threading
from collections import OrderedDict
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from app.events_cache import BagSource
from app.sweep.events import BagEvents
from cogmap_core import __version__
from cogmap_core.cognitive_map import MapMode
from cogmap_core.config import MapParams
from cogmap_core.evaluation import LAYOUT_RADIUS
from cogmap_core.event_file import FORMAT_VERSION, load_event_file
from cogmap_core.event_log import EventLog
from cogmap_core.sweep import GROWTH_FRACTION, evaluate_cell

CELL_VERSION = 1  # bump when a cell's figures change meaning: old rows are then not reused


@dataclass(frozen=True, slots=True)
class Cell:
    """One map to build: a bag's events with one setting.

    Attributes:
        key: identity of the cell (events, map, setting, measure settings).
        bag: the bag's source.
        params: the setting.
        mode: which map.

    """

    key: str
    bag: BagSource
    params: MapParams
    mode: MapMode


def cell_key(bag_key: str, params: MapParams, mode: MapMode) -> str:
    """Identity of a cell: the same events, map, setting and measures give the same key."""
    identity = {
        "version": CELL_VERSION,
        "events": bag_key,
        "map": mode.value,
        "params": params.to_dict(),
        "layout_radius": LAYOUT_RADIUS,
        "growth_fraction": GROWTH_FRACTION,
    }
    return hashlib.sha1(json.dumps(identity, sort_keys=True).encode()).hexdigest()[:16]


def plan_cells(
    bags: Sequence[BagSource], settings: Sequence[MapParams], mode: MapMode
) -> list[Cell]:
    """Every (bag, setting) cell, bag by bag, settings in order."""
    return [Cell(cell_key(b.key, p, mode), b, p, mode) for b in bags for p in settings]


def cells_digest(cells: Sequence[Cell]) -> str:
    """Identity of a whole sweep (its set of cells)."""
    return hashlib.sha1("\n".join(sorted(c.key for c in cells)).encode()).hexdigest()[:16]


# --------------------------------------------------------------------------- the task
_LOGS: OrderedDict[str, EventLog] = OrderedDict()
_LOGS_LOCK = threading.Lock()
_LOGS_KEEP = 4


def worker_event_log(key: str, data: bytes | str) -> EventLog:
    """The event log of ``key`` in this process, loaded once from a path or shipped bytes."""
    with _LOGS_LOCK:
        log = _LOGS.get(key)
        if log is not None:
            _LOGS.move_to_end(key)
            return log
        if isinstance(data, bytes):
            with tempfile.TemporaryDirectory(prefix="cogmap-events-") as tmp:
                path = Path(tmp) / f"{key}.events.npz"
                path.write_bytes(data)
                recording = load_event_file(path)
        else:
            recording = load_event_file(data)
        log = EventLog.from_recording(recording)
        _LOGS[key] = log
        while len(_LOGS) > _LOGS_KEEP:
            _LOGS.popitem(last=False)
        return log


def _worker_name() -> str:
    try:
        from distributed import get_worker

        return str(get_worker().name)
    except (ImportError, ValueError):
        return f"pid {os.getpid()}"


def compute_cell(
    events_key: str, data: bytes | str, mode: str, params: Mapping[str, float]
) -> dict[str, Any]:
    """The task: build one map from a bag's events and return its figures (or its error).

    ``data`` is the event file's path (readable where the task runs) or its content. Errors are
    returned, not raised: a failed cell is recorded and the sweep goes on.
    """
    try:
        log = worker_event_log(events_key, data)
        figures: dict[str, Any] = evaluate_cell(log, MapParams(**params), MapMode(mode))
        figures["status"] = "ok"
        figures["error"] = ""
    except Exception as exc:
        message = " ".join(f"{type(exc).__name__}: {exc}".split())
        figures = {"status": "error", "error": message[:500]}
    figures["worker"] = _worker_name()
    return figures


def worker_check(paths: Sequence[str] = ()) -> dict[str, Any]:
    """What a worker reports before a sweep: cogmap's version and which event files it sees."""
    return {
        "cogmap": __version__,
        "event_format": FORMAT_VERSION,
        "missing": [p for p in paths if not os.path.isfile(p)],
    }


def result_row(cell: Cell, run: int, outcome: Mapping[str, Any]) -> dict[str, Any]:
    """A results-table row: the cell's identity and setting, then the task's outcome."""
    row: dict[str, Any] = {
        "key": cell.key,
        "run": run,
        "bag": cell.bag.label,
        "bag_key": cell.bag.key,
        "map": cell.mode.value,
    }
    row.update(cell.params.to_dict())
    row.update(outcome)
    return row


# --------------------------------------------------------------------------- in this process
Record = Callable[[Cell, dict[str, Any]], None]


def run_serially(cells: Sequence[Cell], events: Mapping[str, BagEvents], record: Record) -> None:
    """Build every cell in this process, one after the other (the reference for the speed-up)."""
    for cell in cells:
        path = str(events[cell.bag.key].events_path)
        record(cell, compute_cell(cell.bag.key, path, cell.mode.value, cell.params.to_dict()))
