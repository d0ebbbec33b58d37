"""Event files: the front end's output saved once, replayed into maps any number of times.

The front end's events do not depend on map parameters, so a bag needs the front end only
once; the maps can then be rebuilt from the event file (tests, parameter sweeps, benchmarks).

Format (version 1): a NumPy ``.npz`` archive (no pickle; ``allow_pickle=False`` on reading) with

- ``header``: a 0-d unicode array holding JSON: ``{"format": "cogmap-events", "version": 1,
  "source": ..., "frontend": {...}, "meta": {...}}``;
- one row per event: ``kind`` (uint8: 0 odometry, 1 create vertex, 2 link, 3 set current),
  ``time`` (float64, s), ``ref`` (int64: the vertex id created, or the link/set target; -1 for
  odometry), ``view`` (int64: view template of a created vertex, else -1), ``value0``
  (float64: odometry translation (m), or the link/set relative angle (rad)), ``value1``
  (float64: odometry rotation (rad), else 0);
- one row per camera frame: ``frame_end`` (int64, events of frames ``0..k`` are
  ``events[:frame_end[k]]``), ``frame_time`` (float64, s), and, when the data has ground truth,
  ``ground_truth`` (float64 ``(F, 3)``: x, y, theta at the frame's time).

Files are written to a temporary name beside the target and renamed when complete.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cogmap_core.errors import InputFileError
from cogmap_core.events import CreateVertex, LinkToVertex, MapEvent, Odometry, SetCurrentVertex
from cogmap_core.fileio import atomic_writer, load_archive

FORMAT_NAME = "cogmap-events"
FORMAT_VERSION = 1

KIND_ODOMETRY, KIND_CREATE, KIND_LINK, KIND_SET = 0, 1, 2, 3
_COLUMNS_REQUIRED = ("kind", "time", "ref", "view", "value0", "value1", "frame_end", "frame_time")


@dataclass
class EventRecording:
    """Events of a run with their frame boundaries and, when known, the ground truth.

    Attributes:
        events: the front end's events in time order.
        frame_end: per camera frame, the number of events up to and including that frame.
        frame_time: per frame, its data time (s).
        ground_truth: ``(F, 3)`` true pose per frame, or ``None``.
        source: where the events came from (e.g. the bag's path).
        frontend: the front-end settings that produced them.
        meta: anything else worth keeping (JSON-serialisable).

    """

    events: list[MapEvent]
    frame_end: NDArray[np.int64]
    frame_time: NDArray[np.float64]
    ground_truth: NDArray[np.float64] | None = None
    source: str = ""
    frontend: dict[str, Any] = field(default_factory=dict)
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def frames(self) -> int:
        """Number of camera frames."""
        return int(self.frame_end.shape[0])


def events_to_columns(events: Sequence[MapEvent]) -> dict[str, NDArray[Any]]:
    """Column arrays (``kind``, ``time``, ``ref``, ``view``, ``value0``, ``value1``) of events."""
    n = len(events)
    kind = np.zeros(n, dtype=np.uint8)
    time = np.zeros(n)
    ref = np.full(n, -1, dtype=np.int64)
    view = np.full(n, -1, dtype=np.int64)
    value0 = np.zeros(n)
    value1 = np.zeros(n)
    for k, event in enumerate(events):
        time[k] = event.time
        cls = type(event)
        if cls is Odometry:
            value0[k], value1[k] = event.translation, event.rotation  # type: ignore[union-attr]
        elif cls is CreateVertex:
            kind[k], ref[k], view[k] = KIND_CREATE, event.vertex, event.view_template  # type: ignore[union-attr]
        elif cls is LinkToVertex:
            kind[k], ref[k], value0[k] = KIND_LINK, event.target, event.relative_rad  # type: ignore[union-attr]
        elif cls is SetCurrentVertex:
            kind[k], ref[k], value0[k] = KIND_SET, event.target, event.relative_rad  # type: ignore[union-attr]
        else:
            raise TypeError(f"not a map event: {event!r}")
    return {
        "kind": kind,
        "time": time,
        "ref": ref,
        "view": view,
        "value0": value0,
        "value1": value1,
    }


def columns_to_events(columns: dict[str, NDArray[Any]]) -> list[MapEvent]:
    """The events described by column arrays (inverse of :func:`events_to_columns`)."""
    kind = columns["kind"].tolist()
    time = columns["time"].tolist()
    ref = columns["ref"].tolist()
    view = columns["view"].tolist()
    value0 = columns["value0"].tolist()
    value1 = columns["value1"].tolist()
    out: list[MapEvent] = []
    append = out.append
    for k, t, r, v, a, b in zip(kind, time, ref, view, value0, value1, strict=True):
        if k == KIND_ODOMETRY:
            append(Odometry(t, a, b))
        elif k == KIND_CREATE:
            append(CreateVertex(t, r, v))
        elif k == KIND_LINK:
            append(LinkToVertex(t, r, a))
        elif k == KIND_SET:
            append(SetCurrentVertex(t, r, a))
        else:
            raise ValueError(f"unknown event kind {k}")
    return out


def save_event_file(path: Path | str, recording: EventRecording) -> Path:
    """Write ``recording`` to ``path`` (atomically: a temporary file, then a rename)."""
    path = Path(path)
    header = {
        "format": FORMAT_NAME,
        "version": FORMAT_VERSION,
        "source": recording.source,
        "frontend": recording.frontend,
        "meta": recording.meta,
    }
    arrays: dict[str, NDArray[Any]] = dict(events_to_columns(recording.events))
    arrays["frame_end"] = np.asarray(recording.frame_end, dtype=np.int64)
    arrays["frame_time"] = np.asarray(recording.frame_time, dtype=np.float64)
    if recording.ground_truth is not None:
        arrays["ground_truth"] = np.asarray(recording.ground_truth, dtype=np.float64)
    arrays["header"] = np.array(json.dumps(header, sort_keys=True))
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_writer(path, binary=True) as handle:
        np.savez_compressed(handle, **arrays)
    return path


def load_event_file(path: Path | str) -> EventRecording:
    """Read an event file written by :func:`save_event_file`.

    Raises:
        InputFileError: missing, truncated or corrupt file, another format or version, or
            inconsistent arrays (one line naming the problem).

    """
    header, arrays = load_archive(
        Path(path),
        "event",
        FORMAT_NAME,
        FORMAT_VERSION,
        InputFileError,
        required=_COLUMNS_REQUIRED,
        advice="re-create it from the bag",
        version_advice="re-create it from the bag",
    )
    n = arrays["kind"].shape[0]
    if any(arrays[c].shape != (n,) for c in ("time", "ref", "view", "value0", "value1")):
        raise InputFileError(f"{path}: event columns have different lengths; the file is corrupt")
    frame_end = arrays["frame_end"].astype(np.int64)
    frame_time = arrays["frame_time"].astype(np.float64)
    if frame_end.shape != frame_time.shape or (frame_end.size and frame_end[-1] != n):
        raise InputFileError(f"{path}: frame table does not match the events; the file is corrupt")
    truth = arrays.get("ground_truth")
    if truth is not None and truth.shape != (frame_end.shape[0], 3):
        raise InputFileError(f"{path}: ground truth does not match the frames; the file is corrupt")
    try:
        events = columns_to_events(arrays)
    except ValueError as exc:
        raise InputFileError(f"{path}: {exc}; the file is corrupt") from None
    return EventRecording(
        events=events,
        frame_end=frame_end,
        frame_time=frame_time,
        ground_truth=None if truth is None else truth.astype(np.float64),
        source=str(header.get("source", "")),
        frontend=dict(header.get("frontend") or {}),
        meta=dict(header.get("meta") or {}),
    )
