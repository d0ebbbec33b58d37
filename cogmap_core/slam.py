"""A SLAM session: front end + the three cognitive maps, with the front-end output cached.

The front end (view templates, pose cells) is the expensive, parameter-independent part: its
events depend only on the data. The session keeps them, so the maps can be rebuilt for other
map parameters (alpha, beta, delta, T_interval, T_total, ...) up to any frame without touching
the bag again -- what the web app's sliders do. No I/O happens here.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from cogmap_core.cognitive_map import CognitiveMap, EdgeKind, MapMode, MapSet
from cogmap_core.config import MapParams
from cogmap_core.evaluation import (
    LoopClosureScore,
    absolute_trajectory_error,
    interpolate_poses,
    score_loop_closures,
)
from cogmap_core.events import CreateVertex, LinkToVertex, MapEvent
from cogmap_core.frames import Frame
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


class SlamSession:
    """Frames in; front-end events logged; standard, scene-integration and compact maps out."""

    def __init__(
        self,
        params: MapParams | None = None,
        frontend_config: FrontEndConfig | None = None,
        modes: tuple[MapMode, ...] = ALL_MODES,
    ) -> None:
        """Start an empty session."""
        self.params = params or MapParams()
        self.frontend = FrontEnd(frontend_config)
        self.modes = modes
        self.maps = MapSet(self.params, modes)
        self.log = EventLog()
        self.finished = False

    # ------------------------------------------------------------------ processing
    def process(self, frame: Frame) -> FrameOutput:
        """Run the front end on one frame and apply its events to every map."""
        events = self.frontend.process(frame)
        log = self.log
        log.events.extend(events)
        log.frame_end.append(len(log.events))
        log.frame_time.append(float(frame.time))
        if frame.ground_truth is not None:
            log.ground_truth.append(tuple(float(v) for v in frame.ground_truth))  # type: ignore[arg-type]
        for event in events:
            if isinstance(event, LinkToVertex):
                log.link_robot_truth.append(frame.ground_truth)
            self.maps.apply(event)
        return FrameOutput(
            index=frame.index,
            time=float(frame.time),
            events=tuple(events),
            view_template=self.frontend.current_template,
            template_count=self.frontend.template_count,
        )

    def run(self, frames: Iterable[Frame]) -> None:
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
        if not self.log.has_ground_truth():
            return None
        snap = cmap.snapshot()
        return interpolate_poses(
            np.asarray(self.log.frame_time), np.asarray(self.log.ground_truth), snap.vertex_time
        )

    def ate(self, cmap: CognitiveMap) -> float | None:
        """RMSE of vertex positions against ground truth after rigid alignment (m)."""
        truth = self.vertex_ground_truth(cmap)
        if truth is None or cmap.num_vertices == 0:
            return None
        return absolute_trajectory_error(cmap.snapshot().poses, truth)

    def loop_closure_score(self) -> LoopClosureScore | None:
        """Front-end loop closures judged by ground truth (robot vs. target vertex position)."""
        if not self.log.has_ground_truth():
            return None
        times = np.asarray(self.log.frame_time)
        truth = np.asarray(self.log.ground_truth)
        vertex_time: dict[int, float] = {}
        robot, target = [], []
        link_index = 0
        for event in self.log.events:
            if isinstance(event, CreateVertex):
                vertex_time[event.vertex] = event.time
            elif isinstance(event, LinkToVertex):
                robot_truth = self.log.link_robot_truth[link_index]
                link_index += 1
                if robot_truth is None or event.target not in vertex_time:
                    continue
                robot.append(robot_truth)
                target.append(
                    interpolate_poses(times, truth, np.array([vertex_time[event.target]]))[0]
                )
        if not robot:
            return score_loop_closures(np.zeros((0, 2)), np.zeros((0, 2)))
        return score_loop_closures(np.asarray(robot), np.asarray(target))


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
