"""The front end's output, kept: every frame's map events and ground truth, in column arrays.

:class:`EventLog` is the storage a :class:`~cogmap_core.slam.SlamSession` fills as frames come
in, and what every map is rebuilt from (:meth:`EventLog.columns`, replayed by
:func:`cogmap_core.compiled_replay.replay`). It also judges what it holds against its ground truth
(dead reckoning, loop-closure precision, a map's ATE and layout fidelity) and converts to and from
the event file's :class:`~cogmap_core.event_file.EventRecording`. No I/O happens here.
"""

from __future__ import annotations

import operator
from collections.abc import Iterator, Mapping, Sequence
from typing import TYPE_CHECKING, Any, overload

import numpy as np
from numpy.typing import NDArray

from cogmap_core.evaluation import (
    LAYOUT_RADIUS,
    TRUE_LOOP_CLOSURE_DISTANCE,
    TRUE_LOOP_CLOSURE_HEADING,
    LayoutFidelity,
    LoopClosureScore,
    MapAccuracy,
    SizeChange,
    absolute_trajectory_error,
    dead_reckoning,
    interpolate_poses,
    layout_fidelity,
    map_accuracy,
    score_loop_closures,
    size_change,
)
from cogmap_core.event_file import (
    KIND_CREATE,
    KIND_LINK,
    KIND_ODOMETRY,
    KIND_SET,
    EventRecording,
    columns_to_events,
    events_to_columns,
)
from cogmap_core.events import CreateVertex, LinkToVertex, MapEvent, Odometry, SetCurrentVertex
from cogmap_core.map_graph import MapSnapshot, grow_array

if TYPE_CHECKING:
    from cogmap_core.cognitive_map import CognitiveMap

FloatArray = NDArray[np.float64]
_EVENT_COLUMNS = ("kind", "time", "ref", "view", "value0", "value1")
_LOG_COLUMNS = (*_EVENT_COLUMNS, "score")
"""The log's per-event columns: the event file's, plus ``score`` (a link's place-recognition
score; NaN for other events and for links without one)."""


class EventView(Sequence[MapEvent]):
    """The events of an :class:`EventLog` (or its first ``stop`` ones), read-only.

    The log keeps events as columns; indexing gives an event object, slicing a list of them,
    and iteration makes them a chunk at a time, so no list of every event is ever held.
    """

    _CHUNK = 4096

    def __init__(self, log: EventLog, stop: int | None = None) -> None:
        """View the first ``stop`` events of ``log`` (default: all, as the log grows)."""
        self._log = log
        self._stop = stop

    def __len__(self) -> int:
        """Number of events."""
        n = self._log.event_count
        return n if self._stop is None else min(self._stop, n)

    @overload
    def __getitem__(self, index: int) -> MapEvent: ...

    @overload
    def __getitem__(self, index: slice) -> list[MapEvent]: ...

    def __getitem__(self, index: int | slice) -> MapEvent | list[MapEvent]:
        """One event, or a list of the events of a slice."""
        n = len(self)
        if isinstance(index, slice):
            start, stop, step = index.indices(n)
            if step != 1:
                return [self[k] for k in range(start, stop, step)]
            return self._log.events_between(start, max(start, stop))
        k = operator.index(index)
        if k < 0:
            k += n
        if not 0 <= k < n:
            raise IndexError(f"event {index} out of range ({n} events)")
        return self._log.events_between(k, k + 1)[0]

    def __iter__(self) -> Iterator[MapEvent]:
        """The events in order, made a chunk at a time."""
        n = len(self)
        for lo in range(0, n, self._CHUNK):
            yield from self._log.events_between(lo, min(lo + self._CHUNK, n))


class EventLog:
    """Front-end events of every frame processed so far, with the ground truth per frame.

    Everything is kept in column arrays grown by doubling (about 49 bytes per event and 41 per
    frame), in the layout of :mod:`cogmap_core.event_file` plus a ``score`` column (each link's
    place-recognition score, NaN where there is none): a long run costs a few megabytes, not a
    Python object per event. :attr:`events` gives them back as event objects.
    """

    def __init__(self) -> None:
        """An empty log."""
        self._n_events = 0
        self._n_frames = 0
        self._truth_frames = 0
        cap = 1024
        self._kind = np.zeros(cap, dtype=np.uint8)
        self._time = np.zeros(cap)
        self._ref = np.zeros(cap, dtype=np.int64)
        self._view = np.zeros(cap, dtype=np.int64)
        self._value0 = np.zeros(cap)
        self._value1 = np.zeros(cap)
        self._score = np.full(cap, np.nan)
        self._frame_end = np.zeros(cap, dtype=np.int64)
        self._frame_time = np.zeros(cap)
        self._truth = np.zeros((cap, 3))
        self._has_truth = np.zeros(cap, dtype=bool)

    # ------------------------------------------------------------------ building
    @classmethod
    def from_columns(
        cls,
        columns: Mapping[str, NDArray[Any]],
        frame_end: NDArray[np.int64] | Sequence[int],
        frame_time: NDArray[np.float64] | Sequence[float],
        ground_truth: NDArray[np.float64] | None = None,
        has_truth: NDArray[np.bool_] | None = None,
    ) -> EventLog:
        """A log holding event columns (as :func:`~cogmap_core.event_file.events_to_columns`).

        ``columns`` may hold a ``score`` column (per event; NaN: none); without it no link has a
        score. ``ground_truth`` is ``(F, 3)``; ``has_truth`` marks the frames that have it
        (default: all when ``ground_truth`` is given). Built by :meth:`extend`, which refuses
        frame ends that do not match the events (``ValueError``).
        """
        log = cls()
        log.extend(columns, frame_end, frame_time)
        f = log._n_frames
        if ground_truth is not None:
            log._truth[:f] = np.asarray(ground_truth, dtype=np.float64).reshape(f, 3)
            mask = np.ones(f, dtype=bool) if has_truth is None else np.asarray(has_truth, bool)
            log._has_truth[:f] = mask
            log._truth_frames = int(np.count_nonzero(mask))
        return log

    def append_frame(
        self,
        events: Sequence[MapEvent],
        time: float,
        ground_truth: tuple[float, float, float] | None = None,
        link_scores: Sequence[float | None] = (),
    ) -> None:
        """Log one frame: its events, its data time and (when known) its true pose.

        ``link_scores``: the place-recognition score of each link in ``events``, in order (links
        beyond them, or given None, have none).
        """
        n = self._n_events
        self._reserve_events(n + len(events))
        kind, ref, view = self._kind, self._ref, self._view
        value0, value1 = self._value0, self._value1
        self._score[n : n + len(events)] = np.nan
        link = 0
        for k, event in enumerate(events, n):
            self._time[k] = event.time
            cls = type(event)
            if cls is Odometry:
                kind[k], ref[k], view[k] = KIND_ODOMETRY, -1, -1
                value0[k], value1[k] = event.translation, event.rotation  # type: ignore[union-attr]
            elif cls is CreateVertex:
                kind[k], ref[k], view[k] = KIND_CREATE, event.vertex, event.view_template  # type: ignore[union-attr]
                value0[k] = value1[k] = 0.0
            elif cls is LinkToVertex or cls is SetCurrentVertex:
                kind[k] = KIND_LINK if cls is LinkToVertex else KIND_SET
                ref[k], view[k] = event.target, -1  # type: ignore[union-attr]
                value0[k], value1[k] = event.relative_rad, 0.0  # type: ignore[union-attr]
                if cls is LinkToVertex:
                    if link < len(link_scores) and link_scores[link] is not None:
                        self._score[k] = link_scores[link]
                    link += 1
            else:
                raise TypeError(f"not a map event: {event!r}")
        self._n_events = n + len(events)
        f = self._n_frames
        self._reserve_frames(f + 1)
        self._frame_end[f] = self._n_events
        self._frame_time[f] = float(time)
        if ground_truth is not None:
            self._truth[f] = ground_truth
            self._has_truth[f] = True
            self._truth_frames += 1
        self._n_frames = f + 1

    def extend(
        self,
        columns: Mapping[str, NDArray[Any]],
        frame_end: NDArray[np.int64] | Sequence[int],
        frame_time: NDArray[np.float64] | Sequence[float],
    ) -> None:
        """Append frames given as event columns (as :meth:`columns` gives them), no truth.

        ``frame_end`` counts events from the start of the log (as :attr:`frame_end` does); what
        is appended is what another log holds after this one's events and frames (a copy kept
        in step, e.g. in a worker process).
        """
        n = self._n_events
        m = int(np.asarray(columns["kind"]).shape[0])
        self._reserve_events(n + m)
        for name in _EVENT_COLUMNS:
            getattr(self, "_" + name)[n : n + m] = np.asarray(columns[name])
        self._score[n : n + m] = np.asarray(columns["score"]) if "score" in columns else np.nan
        ends = np.asarray(frame_end, dtype=np.int64)
        f, g = self._n_frames, int(ends.shape[0])
        if g and (ends[0] < n or ends[-1] != n + m or np.any(np.diff(ends) < 0)):
            raise ValueError("frame ends do not match the events appended")
        self._reserve_frames(f + g)
        self._frame_end[f : f + g] = ends
        self._frame_time[f : f + g] = np.asarray(frame_time, dtype=np.float64)
        self._has_truth[f : f + g] = False
        self._n_events, self._n_frames = n + m, f + g

    def _reserve_events(self, n: int) -> None:
        cap = self._kind.shape[0]
        if n > cap:
            new = max(n, 2 * cap)
            for name in _LOG_COLUMNS:
                fill = np.nan if name == "score" else 0  # (NaN: no score)
                setattr(self, "_" + name, grow_array(getattr(self, "_" + name), new, fill))

    def _reserve_frames(self, n: int) -> None:
        cap = self._frame_end.shape[0]
        if n > cap:
            new = max(n, 2 * cap)
            for name in ("_frame_end", "_frame_time", "_truth", "_has_truth"):
                setattr(self, name, grow_array(getattr(self, name), new))

    def truncated(self, frames: int) -> EventLog:
        """A copy of the first ``frames`` frames."""
        frames = max(0, min(frames, self._n_frames))
        end = int(self._frame_end[frames - 1]) if frames else 0
        truth = self._truth[:frames] if self._truth_frames else None
        return EventLog.from_columns(
            self.columns(end),
            self._frame_end[:frames],
            self._frame_time[:frames],
            truth,
            self._has_truth[:frames] if truth is not None else None,
        )

    # ------------------------------------------------------------------ access
    @property
    def frames(self) -> int:
        """Number of frames logged."""
        return self._n_frames

    @property
    def event_count(self) -> int:
        """Number of events logged."""
        return self._n_events

    @property
    def events(self) -> EventView:
        """Every event logged, as event objects (a read-only sequence view)."""
        return EventView(self)

    @property
    def frame_end(self) -> NDArray[np.int64]:
        """Per frame, the number of events up to and including it (a read-only view)."""
        return _read_only(self._frame_end[: self._n_frames])

    @property
    def frame_time(self) -> NDArray[np.float64]:
        """Per frame, its data time (s) (a read-only view)."""
        return _read_only(self._frame_time[: self._n_frames])

    @property
    def end_time(self) -> float:
        """Data time (s) of the last frame logged (0.0 when there are no frames)."""
        return float(self._frame_time[self._n_frames - 1]) if self._n_frames else 0.0

    @property
    def ground_truth(self) -> NDArray[np.float64]:
        """``(n, 3)`` true poses of the frames that have one, in order (a read-only view)."""
        truth = self._truth[: self._n_frames]
        if self._truth_frames != self._n_frames:
            truth = truth[self._has_truth[: self._n_frames]]
        return _read_only(truth)

    @property
    def has_truth(self) -> NDArray[np.bool_]:
        """Per frame, whether it came with ground truth (a read-only view)."""
        return _read_only(self._has_truth[: self._n_frames])

    @property
    def link_scores(self) -> list[float | None]:
        """Per loop closure (link event), its place-recognition score (None where unknown)."""
        n = self._n_events
        scores = self._score[:n][self._kind[:n] == KIND_LINK].tolist()
        return [None if s != s else s for s in scores]  # NaN: no score

    def columns(self, stop: int | None = None) -> dict[str, NDArray[Any]]:
        """The columns of the first ``stop`` events (default all), as read-only views.

        The event file's (``kind``, ``time``, ``ref``, ``view``, ``value0``, ``value1``) and
        ``score`` (each link's place-recognition score; NaN: none).
        """
        stop = self._n_events if stop is None else max(0, min(stop, self._n_events))
        return {name: _read_only(getattr(self, "_" + name)[:stop]) for name in _LOG_COLUMNS}

    def events_between(self, start: int, stop: int) -> list[MapEvent]:
        """Events ``start .. stop - 1`` as event objects."""
        stop = min(stop, self._n_events)
        start = max(0, min(start, stop))
        return columns_to_events(
            {name: getattr(self, "_" + name)[start:stop] for name in _EVENT_COLUMNS}
        )

    def events_until(self, frames: int | None = None) -> list[MapEvent]:
        """Events of the first ``frames`` frames (all by default), as a list."""
        if frames is None or frames >= self._n_frames:
            return self.events_between(0, self._n_events)
        return self.events_between(0, int(self._frame_end[frames - 1])) if frames > 0 else []

    def has_ground_truth(self) -> bool:
        """True when every frame so far came with ground truth."""
        return self._n_frames > 0 and self._truth_frames == self._n_frames

    # ------------------------------------------------------------------ evaluation
    def truth_at(self, times: FloatArray) -> FloatArray | None:
        """Ground-truth poses at data ``times`` (interpolated; None without ground truth)."""
        if not self.has_ground_truth():
            return None
        return interpolate_poses(
            np.asarray(self.frame_time), np.asarray(self.ground_truth), np.asarray(times)
        )

    def vertex_ground_truth(self, cmap: CognitiveMap) -> FloatArray | None:
        """Ground-truth pose at each live vertex's creation time (None without ground truth)."""
        return self.truth_at(cmap.snapshot().vertex_time)

    def map_ate(self, cmap: CognitiveMap) -> float | None:
        """RMSE of a map's vertex positions against ground truth after rigid alignment (m)."""
        if cmap.num_vertices == 0:
            return None
        snap = cmap.snapshot()
        truth = self.truth_at(snap.vertex_time)
        return None if truth is None else absolute_trajectory_error(snap.poses, truth)

    def dead_reckoning(self) -> FloatArray:
        """``(F, 3)`` pose after each frame from the odometry events alone (from the origin)."""
        kind = self._kind[: self._n_events]
        is_odometry = kind == KIND_ODOMETRY
        ends = self._frame_end[: self._n_frames]
        out = np.zeros((ends.size, 3))
        if not is_odometry.any():
            return out
        poses = dead_reckoning(
            self._value0[: self._n_events][is_odometry],
            self._value1[: self._n_events][is_odometry],
        )
        # the pose after the last odometry event of each frame
        count = np.cumsum(is_odometry)
        index = np.where(ends > 0, count[np.maximum(ends - 1, 0)] - 1, -1)
        out[index >= 0] = poses[index[index >= 0]]
        return out

    def dead_reckoning_ate(self) -> float | None:
        """ATE (m) of the odometry alone at every frame: the baseline a map must beat."""
        if not self.has_ground_truth():
            return None
        return absolute_trajectory_error(self.dead_reckoning(), np.asarray(self.ground_truth))

    def layout_fidelity(
        self, cmap: CognitiveMap, radius: float = LAYOUT_RADIUS
    ) -> LayoutFidelity | None:
        """Completeness and correctness of a map against the dense true path (per frame)."""
        snap = cmap.snapshot()
        truth = self.truth_at(snap.vertex_time)
        if truth is None:
            return None
        return layout_fidelity(
            snap.poses, truth, *snap.edge_ends(), np.asarray(self.ground_truth), radius
        )

    def map_accuracy(self, snap: MapSnapshot, radius: float = LAYOUT_RADIUS) -> MapAccuracy | None:
        """ATE and layout fidelity of a map's snapshot against ground truth (None without)."""
        truth = self.truth_at(snap.vertex_time)
        if truth is None:
            return None
        return map_accuracy(snap, truth, np.asarray(self.ground_truth), radius)

    def size_change(
        self, cmap: CognitiveMap, start: float, end: float, radius: float = LAYOUT_RADIUS
    ) -> SizeChange | None:
        """A map's size change between two data times, exploration set apart (needs truth).

        ``cmap`` must be the map as it was at ``end`` (or later, when no vertex made after
        ``end`` is alive: then the vertices alive at the end of the data stand for those at
        ``end``).
        """
        if not self.has_ground_truth():
            return None
        times, vertices, _ = cmap.size_history()
        snap = cmap.snapshot()
        return size_change(
            times,
            vertices,
            snap.vertex_time[snap.vertex_time <= end],
            np.asarray(self.frame_time),
            np.asarray(self.ground_truth),
            start,
            end,
            radius,
        )

    def link_table(self) -> list[tuple[float, int, float]]:
        """Every loop closure the front end emitted: (time, target, relative_rad)."""
        links = self._kind[: self._n_events] == KIND_LINK
        return list(
            zip(
                self._time[: self._n_events][links].tolist(),
                self._ref[: self._n_events][links].tolist(),
                self._value0[: self._n_events][links].tolist(),
                strict=True,
            )
        )

    def loop_closure_score(
        self,
        distance: float = TRUE_LOOP_CLOSURE_DISTANCE,
        heading: float | None = TRUE_LOOP_CLOSURE_HEADING,
    ) -> LoopClosureScore | None:
        """Front-end loop closures judged by ground truth, position and heading.

        A link is true when the robot's true position is within ``distance`` of the target
        vertex's true position (at its creation) and the heading the link claims (target heading
        plus the link's relative angle) is within ``heading`` of the robot's true heading
        (``heading=None``: position only). ``false_indices`` index :meth:`link_table`.
        """
        judged = self._judge_links(distance, heading)
        return None if judged is None else judged[1]

    def false_links(
        self,
        distance: float = TRUE_LOOP_CLOSURE_DISTANCE,
        heading: float | None = TRUE_LOOP_CLOSURE_HEADING,
    ) -> NDArray[np.bool_] | None:
        """Per link (:meth:`link_table` order), whether the ground truth calls it false.

        Judged as :meth:`loop_closure_score` judges (a link it cannot judge is not false); None
        without ground truth.
        """
        judged = self._judge_links(distance, heading)
        if judged is None:
            return None
        known, score = judged
        out = np.zeros(known.shape[0], dtype=bool)
        out[np.flatnonzero(known)[list(score.false_indices)]] = True
        return out

    def _judge_links(
        self, distance: float, heading: float | None
    ) -> tuple[NDArray[np.bool_], LoopClosureScore] | None:
        """The links the truth can judge (mask over :meth:`link_table`) and their score."""
        if not self.has_ground_truth():
            return None
        n = self._n_events
        kind, time, ref = self._kind[:n], self._time[:n], self._ref[:n]
        created = np.flatnonzero(kind == KIND_CREATE)
        made_at = np.full(int(ref[created].max()) + 1 if created.size else 0, n)  # event index
        made_at[ref[created]] = created
        links = np.flatnonzero(kind == KIND_LINK)
        frame = np.searchsorted(self._frame_end[: self._n_frames], links, side="right")
        target = ref[links]
        # links with ground truth at their frame, to a vertex made before them
        known = self._has_truth[frame] & (target >= 0) & (target < made_at.size)
        known[known] &= made_at[target[known]] < links[known]
        robot = self._truth[frame[known]]
        target_time = time[made_at[target[known]]]
        relative = self._value0[links[known]]
        if not robot.shape[0]:
            return known, score_loop_closures(np.zeros((0, 3)), np.zeros((0, 3)))
        target_truth = self.truth_at(target_time)
        if heading is None:
            return known, score_loop_closures(robot, target_truth, None, distance)
        return known, score_loop_closures(robot, target_truth, relative, distance, heading)

    def state_dict(self) -> dict[str, NDArray[Any]]:
        """The log as arrays (copies), what :meth:`from_state` restores.

        The per-event columns (:meth:`columns`: ``kind``, ``time``, ``ref``, ``view``,
        ``value0``, ``value1``, ``score``) and, per frame, ``frame_end``, ``frame_time``,
        ``has_truth`` and ``truth`` (``(F, 3)``, zeros where a frame has none).
        """
        state = {name: np.array(column) for name, column in self.columns().items()}
        state["frame_end"] = np.array(self.frame_end)
        state["frame_time"] = np.array(self.frame_time)
        state["has_truth"] = np.array(self.has_truth)
        truth = np.zeros((self._n_frames, 3))
        truth[self.has_truth] = self.ground_truth
        state["truth"] = truth
        return state

    @classmethod
    def from_state(cls, state: Mapping[str, NDArray[Any]]) -> EventLog:
        """The log :meth:`state_dict` described; without ``score``, no link has a score.

        Raises:
            ValueError: the frame ends do not match the events (:meth:`from_columns`).

        """
        columns = {name: state[name] for name in _EVENT_COLUMNS}
        if "score" in state:
            columns["score"] = state["score"]
        return cls.from_columns(
            columns, state["frame_end"], state["frame_time"], state["truth"], state["has_truth"]
        )

    def recording(self, source: str = "", frontend: dict[str, Any] | None = None) -> EventRecording:
        """The log as an :class:`~cogmap_core.event_file.EventRecording` (to save or replay)."""
        return EventRecording(
            events=self.events_until(),
            frame_end=self.frame_end.copy(),
            frame_time=self.frame_time.copy(),
            ground_truth=self.ground_truth.copy() if self.has_ground_truth() else None,
            source=source,
            frontend=dict(frontend or {}),
        )

    @classmethod
    def from_recording(cls, recording: EventRecording) -> EventLog:
        """A log holding a recording's events and frames."""
        return cls.from_columns(
            events_to_columns(recording.events),
            recording.frame_end,
            recording.frame_time,
            recording.ground_truth,
        )


def _read_only(array: NDArray[Any]) -> NDArray[Any]:
    view = array.view()
    view.flags.writeable = False
    return view
