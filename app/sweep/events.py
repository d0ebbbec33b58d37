"""Each bag's events in the sweep folder (``DIR/events``), and the figures the sweep keeps of them.

:func:`prepare_events` finds a bag's events in the folder, copies them from the user-wide cache
(:mod:`app.events_cache`) or runs the front end once; :class:`BagEvents` is what the sweep then
knows of the bag (and records in ``sweep.json``, so a finished sweep resumes without loading it).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from app.events_cache import (
    EVENTS_DIR,
    BagSource,
    EventsError,
    FrameProgress,
    record_bag_events,
    shared_events_dir,
)
from app.sweep.errors import SweepError
from cogmap_core.errors import InputFileError
from cogmap_core.event_file import load_event_file, save_event_file
from cogmap_core.event_log import EventLog
from cogmap_core.fileio import write_bytes_atomic


@dataclass(frozen=True, slots=True)
class BagEvents:
    """A bag's recorded events, ready for the cells.

    Attributes:
        source: the bag.
        events_path: its event file in ``DIR/events``.
        frames: camera frames.
        duration_s: data duration.
        events: number of events.
        dead_reckoning_ate_m: ATE of the odometry alone (the baseline).
        origin: where the events came from this time: ``front end``, ``cache``, ``folder``,
            ``event file``, or ``manifest`` (not loaded: the figures of the bag's record in
            ``sweep.json``, see :meth:`from_manifest_record`).

    """

    source: BagSource
    events_path: Path
    frames: int
    duration_s: float
    events: int
    dead_reckoning_ate_m: float
    origin: str

    def to_dict(self) -> dict[str, Any]:
        """JSON form (for ``sweep.json``)."""
        return {
            "bag": str(self.source.path),
            "label": self.source.label,
            "key": self.source.key,
            "events_file": str(Path(EVENTS_DIR) / self.events_path.name),
            "frames": self.frames,
            "duration_s": self.duration_s,
            "events": self.events,
            "dead_reckoning_ate_m": self.dead_reckoning_ate_m,
            "frontend": None if self.source.frontend is None else self.source.frontend.to_dict(),
        }

    @classmethod
    def from_manifest_record(
        cls, source: BagSource, out_dir: Path, record: Mapping[str, Any]
    ) -> BagEvents | None:
        """The bag's figures as an earlier run recorded them in ``sweep.json``, events unread.

        For a sweep with nothing left to compute, whose analysis needs only these figures.

        Args:
            source: the bag.
            out_dir: the sweep folder.
            record: the bag's entry in ``sweep.json``'s ``bags`` (see :meth:`to_dict`).

        Returns:
            The figures (``origin`` ``"manifest"``), or ``None`` when the record is not of these
            events, lacks a figure (an older or cut-short manifest) or its event file is gone:
            then the events must be loaded (:func:`prepare_events`).

        """
        events_path = out_dir / EVENTS_DIR / source.events_name
        figures = ("frames", "duration_s", "events", "dead_reckoning_ate_m")
        if record.get("key") != source.key or any(name not in record for name in figures):
            return None
        if not events_path.is_file():
            return None
        dead_reckoning = record["dead_reckoning_ate_m"]  # None: NaN, written as strict JSON
        try:
            return cls(
                source=source,
                events_path=events_path,
                frames=int(record["frames"]),
                duration_s=float(record["duration_s"]),
                events=int(record["events"]),
                dead_reckoning_ate_m=float("nan")
                if dead_reckoning is None
                else float(dead_reckoning),
                origin="manifest",
            )
        except (TypeError, ValueError):  # a hand-edited record: load the events instead
            return None


def prepare_events(
    source: BagSource,
    out_dir: Path,
    progress: Callable[[str], FrameProgress | None] | None = None,
    say: Callable[[str], None] | None = None,
) -> BagEvents:
    """The bag's events in ``out_dir/events``: found there, copied from the cache, or recorded.

    Recording runs the front end over the whole bag once and saves its events (atomically) in
    ``out_dir/events`` and in :func:`shared_events_dir`.

    Raises:
        CogmapError: the bag cannot be read, or has no ground truth (one line naming the bag).

    """
    target = out_dir / EVENTS_DIR / source.events_name
    target.parent.mkdir(parents=True, exist_ok=True)
    recording = None
    origin = "folder"
    if target.exists():
        with contextlib.suppress(InputFileError):  # a damaged copy is recorded again
            recording = load_event_file(target)
    if recording is None:
        shared = source.path if source.is_event_file else shared_events_dir() / source.events_name
        if shared.exists():
            try:
                recording = load_event_file(shared)
            except InputFileError:
                if source.is_event_file:
                    raise
            else:
                write_bytes_atomic(target, shared.read_bytes())
                origin = "cache" if not source.is_event_file else "event file"
    if recording is None:
        if say is not None:
            say(f"{source.label}: running the front end once (its events are then cached)")
        bar = progress("front end " + source.label) if progress else None
        try:
            recording = record_bag_events(source, bar)
        except EventsError as exc:
            raise SweepError(str(exc)) from None
        finally:
            close = getattr(bar, "close", None)
            if callable(close):
                close()
        save_event_file(target, recording)
        with contextlib.suppress(OSError):  # the cache is a convenience
            shared_events_dir().mkdir(parents=True, exist_ok=True)
            write_bytes_atomic(shared_events_dir() / source.events_name, target.read_bytes())
        origin = "front end"
    recorded_from = recording.meta.get("input_format", "bag")
    if recorded_from != "bag":
        raise SweepError(
            f"{source.path}: these events were recorded from a {recorded_from} odometry log, "
            "whose maps are set and judged differently; a sweep takes bags and their event files"
        )
    if recording.ground_truth is None:
        raise SweepError(
            f"{source.path}: the data has no ground truth; a sweep measures every map against it "
            "(check --gt-topic)"
        )
    log = EventLog.from_recording(recording)
    dead_reckoning = log.dead_reckoning_ate()
    return BagEvents(
        source=source,
        events_path=target,
        frames=recording.frames,
        duration_s=float(recording.frame_time[-1] - recording.frame_time[0])
        if recording.frames
        else 0.0,
        events=len(recording.events),
        dead_reckoning_ate_m=float("nan") if dead_reckoning is None else dead_reckoning,
        origin=origin,
    )
