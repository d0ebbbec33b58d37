"""A SLAM session: front end + the three cognitive maps, with the front-end output cached.

The front end (view templates, pose cells) is the expensive, parameter-independent part: its
events depend only on the data. The session keeps them, so the maps can be rebuilt for other
map parameters (alpha, beta, delta, T_interval, T_total, ...) up to any frame without touching
the bag again -- what the web app's sliders do. No I/O happens here.

A session takes camera :class:`~cogmap_core.frames.Frame` objects (run through the RatSLAM front
end) or :class:`~cogmap_core.frames.EventStep` objects whose events are already known (a log of
odometry and place recognition, :mod:`cogmap_core.sources.odometry_log`); both are logged the
same way, one "frame" per item.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cogmap_core.cognitive_map import CognitiveMap, EdgeKind, MapMode, MapSet
from cogmap_core.config import MapParams
from cogmap_core.evaluation import (
    LAYOUT_RADIUS,
    TRUE_LOOP_CLOSURE_DISTANCE,
    TRUE_LOOP_CLOSURE_HEADING,
    EvaluationSettings,
    LayoutFidelity,
    LoopClosureScore,
    SizeChange,
    absolute_trajectory_error,
    dead_reckoning,
    interpolate_poses,
    layout_fidelity,
    score_loop_closures,
    size_change,
)
from cogmap_core.event_file import EventRecording
from cogmap_core.events import CreateVertex, LinkToVertex, MapEvent, Odometry
from cogmap_core.frames import EventStep, Frame
from cogmap_core.frontend import FrontEnd, FrontEndConfig

FloatArray = NDArray[np.float64]
ALL_MODES: tuple[MapMode, ...] = (MapMode.STANDARD, MapMode.SCENE_INTEGRATION, MapMode.COMPACT)


@dataclass(frozen=True, slots=True)
class FrameOutput:
    """What one frame produced (for live displays)."""

    index: int
    time: float
    events: tuple[MapEvent, ...]
    view_template: int | None
    template_count: int


@dataclass
class EventLog:
    """Front-end events of every frame processed so far, with the ground truth per frame."""

    events: list[MapEvent] = field(default_factory=list)
    frame_end: list[int] = field(default_factory=list)  # events[: frame_end[k]] up to frame k
    frame_time: list[float] = field(default_factory=list)
    ground_truth: list[tuple[float, float, float]] = field(default_factory=list)
    link_robot_truth: list[tuple[float, float, float] | None] = field(default_factory=list)
    link_scores: list[float | None] = field(default_factory=list)  # per link; None: no score

    @property
    def frames(self) -> int:
        """Number of frames logged."""
        return len(self.frame_end)

    def events_until(self, frames: int | None = None) -> list[MapEvent]:
        """Events of the first ``frames`` frames (all by default)."""
        if frames is None or frames >= len(self.frame_end):
            return self.events
        return self.events[: self.frame_end[frames - 1]] if frames > 0 else []

    def has_ground_truth(self) -> bool:
        """True when every frame so far came with ground truth."""
        return bool(self.ground_truth) and len(self.ground_truth) == len(self.frame_end)

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
        truth = self.vertex_ground_truth(cmap)
        if truth is None or cmap.num_vertices == 0:
            return None
        return absolute_trajectory_error(cmap.snapshot().poses, truth)

    def dead_reckoning(self) -> FloatArray:
        """``(F, 3)`` pose after each frame from the odometry events alone (from the origin)."""
        is_odometry = np.fromiter((type(e) is Odometry for e in self.events), dtype=bool)
        odometry = [e for e in self.events if type(e) is Odometry]
        ends = np.asarray(self.frame_end, dtype=np.int64)
        out = np.zeros((ends.size, 3))
        if not odometry:
            return out
        poses = dead_reckoning(
            np.array([e.time for e in odometry]),
            np.array([e.translation for e in odometry]),
            np.array([e.rotation for e in odometry]),
        )
        # the pose after the last odometry event of each frame
        count = np.cumsum(is_odometry)
        index = np.where(ends > 0, count[np.maximum(ends - 1, 0)] - 1, -1)
        out[index >= 0] = poses[index[index >= 0]]
        return out

    def dead_reckoning_ate(self) -> float | None:
        """ATE (m) of the odometry alone at every frame: the baseline a map must beat."""
        if not self.has_ground_truth() or not self.frame_end:
            return None
        return absolute_trajectory_error(self.dead_reckoning(), np.asarray(self.ground_truth))

    def layout_fidelity(
        self, cmap: CognitiveMap, radius: float = LAYOUT_RADIUS
    ) -> LayoutFidelity | None:
        """Completeness and correctness of a map against the dense true path (per frame)."""
        if not self.has_ground_truth():
            return None
        snap = cmap.snapshot()
        truth = self.truth_at(snap.vertex_time)
        assert truth is not None
        index = np.searchsorted(snap.vertex_ids, np.r_[snap.edge_from, snap.edge_to])
        m = snap.edge_from.shape[0]
        return layout_fidelity(
            snap.poses, truth, index[:m], index[m:], np.asarray(self.ground_truth), radius
        )

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
        keep = snap.vertex_time <= end
        truth = self.truth_at(snap.vertex_time[keep])
        assert truth is not None
        return size_change(
            times,
            vertices,
            snap.vertex_time[keep],
            truth,
            np.asarray(self.frame_time),
            np.asarray(self.ground_truth),
            start,
            end,
            radius,
        )

    def link_table(self) -> list[tuple[float, int, float]]:
        """Every loop closure the front end emitted: (time, target, relative_rad)."""
        return [
            (event.time, event.target, event.relative_rad)
            for event in self.events
            if type(event) is LinkToVertex
        ]

    def link_score(self, k: int) -> float | None:
        """Place-recognition score of link ``k`` of :meth:`link_table` (None when unknown)."""
        return self.link_scores[k] if k < len(self.link_scores) else None

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
        if not self.has_ground_truth():
            return None
        vertex_time: dict[int, float] = {}
        robot, target_time, relative = [], [], []
        link_index = 0
        for event in self.events:
            if type(event) is CreateVertex:
                vertex_time[event.vertex] = event.time
            elif type(event) is LinkToVertex:
                robot_truth = self.link_robot_truth[link_index]
                link_index += 1
                if robot_truth is None or event.target not in vertex_time:
                    continue
                robot.append(robot_truth)
                target_time.append(vertex_time[event.target])
                relative.append(event.relative_rad)
        if not robot:
            return score_loop_closures(np.zeros((0, 3)), np.zeros((0, 3)))
        target = self.truth_at(np.asarray(target_time))
        if heading is None:
            return score_loop_closures(np.asarray(robot), target, None, distance)
        return score_loop_closures(
            np.asarray(robot), target, np.asarray(relative), distance, heading
        )

    def recording(self, source: str = "", frontend: dict[str, Any] | None = None) -> EventRecording:
        """The log as an :class:`~cogmap_core.event_file.EventRecording` (to save or replay)."""
        return EventRecording(
            events=list(self.events),
            frame_end=np.asarray(self.frame_end, dtype=np.int64),
            frame_time=np.asarray(self.frame_time, dtype=np.float64),
            ground_truth=np.asarray(self.ground_truth) if self.has_ground_truth() else None,
            source=source,
            frontend=dict(frontend or {}),
        )

    @classmethod
    def from_recording(cls, recording: EventRecording) -> EventLog:
        """A log holding a recording's events (link truths rebuilt from the frames)."""
        log = cls(
            events=list(recording.events),
            frame_end=recording.frame_end.tolist(),
            frame_time=recording.frame_time.tolist(),
        )
        if recording.ground_truth is not None:
            truth = [tuple(row) for row in recording.ground_truth.tolist()]
            log.ground_truth = truth  # type: ignore[assignment]
            frame = 0
            for k, event in enumerate(log.events):
                while log.frame_end[frame] <= k:
                    frame += 1
                if isinstance(event, LinkToVertex):
                    log.link_robot_truth.append(truth[frame])  # type: ignore[arg-type]
        return log


class SlamSession:
    """Frames in; front-end events logged; standard, scene-integration and compact maps out."""

    def __init__(
        self,
        params: MapParams | None = None,
        frontend_config: FrontEndConfig | None = None,
        modes: tuple[MapMode, ...] = ALL_MODES,
        evaluation: EvaluationSettings | None = None,
    ) -> None:
        """Start an empty session (``evaluation``: tolerances of the accuracy figures)."""
        self.params = params or MapParams()
        self.frontend = FrontEnd(frontend_config)
        self.modes = modes
        self.maps = MapSet(self.params, modes)
        self.log = EventLog()
        self.finished = False
        self.evaluation = evaluation or EvaluationSettings()

    # ------------------------------------------------------------------ processing
    def process(self, frame: Frame | EventStep) -> FrameOutput:
        """Log one frame's events (the front end's, or a step's own) and apply them to every map."""
        if isinstance(frame, EventStep):
            events: list[MapEvent] = list(frame.events)
            scores: list[float | None] = list(frame.link_scores)
            view_template = None
        else:
            events = self.frontend.process(frame)
            scores = []
            view_template = self.frontend.current_template
        log = self.log
        log.events.extend(events)
        log.frame_end.append(len(log.events))
        log.frame_time.append(float(frame.time))
        if frame.ground_truth is not None:
            log.ground_truth.append(tuple(float(v) for v in frame.ground_truth))  # type: ignore[arg-type]
        for event in events:
            if isinstance(event, LinkToVertex):
                log.link_robot_truth.append(frame.ground_truth)
                log.link_scores.append(scores.pop(0) if scores else None)
            self.maps.apply(event)
        return FrameOutput(
            index=frame.index,
            time=float(frame.time),
            events=tuple(events),
            view_template=view_template,
            template_count=self.frontend.template_count,
        )

    def run(self, frames: Iterable[Frame | EventStep]) -> None:
        """Process every frame, then finish."""
        for frame in frames:
            self.process(frame)
        self.finish()

    def finish(self) -> None:
        """End of data: run the final optimisation of every map (closes open clusters)."""
        end = self.log.frame_time[-1] if self.log.frame_time else 0.0
        self.maps.finish(end)
        self.finished = True

    # ------------------------------------------------------------------ rebuilding
    def rebuild(
        self,
        params: MapParams,
        frames: int | None = None,
        modes: tuple[MapMode, ...] | None = None,
        finish: bool | None = None,
    ) -> dict[MapMode, CognitiveMap]:
        """Rebuild maps from the cached events with other parameters (the bag is not re-read).

        Args:
            params: the new map parameters.
            frames: rebuild up to this many frames (default: all processed so far).
            modes: which maps (default: all of the session's).
            finish: run the end-of-data optimisation (default: when the session had finished and
                all frames are replayed).

        """
        modes = modes or self.modes
        events = self.log.events_until(frames)
        if finish is None:
            finish = self.finished and (frames is None or frames >= self.log.frames)
        rebuilt: dict[MapMode, CognitiveMap] = {}
        for mode in modes:
            cmap = CognitiveMap(mode, params)
            cmap.apply_all(events)
            if finish:
                end = self.log.frame_time[-1] if self.log.frame_time else 0.0
                cmap.finish(end)
            rebuilt[mode] = cmap
        return rebuilt

    def adopt(self, params: MapParams, maps: dict[MapMode, CognitiveMap]) -> None:
        """Make rebuilt maps (and their parameters) the session's current ones."""
        self.params = params
        for mode, cmap in maps.items():
            self.maps.maps[mode] = cmap

    # ------------------------------------------------------------------ evaluation
    def vertex_ground_truth(self, cmap: CognitiveMap) -> FloatArray | None:
        """Ground-truth pose at each live vertex's creation time (None without ground truth)."""
        return self.log.vertex_ground_truth(cmap)

    def ate(self, cmap: CognitiveMap) -> float | None:
        """RMSE of vertex positions against ground truth after rigid alignment (m)."""
        return self.log.map_ate(cmap)

    def layout_fidelity(
        self, cmap: CognitiveMap, radius: float = LAYOUT_RADIUS
    ) -> LayoutFidelity | None:
        """Completeness and correctness of a map against the true path (None without truth)."""
        return self.log.layout_fidelity(cmap, radius)

    def loop_closure_score(self) -> LoopClosureScore | None:
        """Front-end loop closures judged by ground truth, with the session's tolerances."""
        judging = self.evaluation
        return self.log.loop_closure_score(judging.loop_distance, judging.loop_heading)


def optimisation_summary(cmap: CognitiveMap) -> dict[str, float | int]:
    """Counts and timing of a map's optimisations and loop closures."""
    snap = cmap.snapshot()
    return {
        "vertices": cmap.num_vertices,
        "edges": cmap.num_edges,
        "loop_edges": int(np.count_nonzero(snap.edge_kind == EdgeKind.LOOP_CLOSURE)),
        "clusters": len(cmap.clusters),
        "optimizations": len(cmap.optimizations),
        "optimize_wall_s": float(sum(o.wall_s for o in cmap.optimizations)),
    }
