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

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from cogmap_core.cognitive_map import CognitiveMap, MapMode, MapSet
from cogmap_core.config import MapParams
from cogmap_core.evaluation import (
    LAYOUT_RADIUS,
    EvaluationSettings,
    LayoutFidelity,
    LoopClosureScore,
    false_loop_edges,
    loop_edge_links,
)
from cogmap_core.event_log import EventLog
from cogmap_core.events import MapEvent
from cogmap_core.frames import EventStep, Frame
from cogmap_core.frontend import FrontEnd, FrontEndConfig
from cogmap_core.map_build import BuildTask, build_map
from cogmap_core.map_graph import MapSnapshot
from cogmap_core.map_modes import ALL_MODES

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class FrameOutput:
    """What one frame produced (for live displays)."""

    index: int
    time: float
    events: tuple[MapEvent, ...]
    view_template: int | None
    template_count: int


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
            events: Sequence[MapEvent] = frame.events
            scores: Sequence[float | None] = frame.link_scores
            view_template = None
        else:
            events = self.frontend.process(frame)
            scores = ()
            view_template = self.frontend.current_template
        truth = frame.ground_truth
        self.log.append_frame(
            events,
            frame.time,
            None if truth is None else (float(truth[0]), float(truth[1]), float(truth[2])),
            scores,
        )
        for event in events:
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
        self.maps.finish(self.log.end_time)
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

        Each map is built by :func:`cogmap_core.map_build.build_map` (the events replayed by
        the compiled replay when numba is available; the same maps as
        :meth:`CognitiveMap.apply_all`); the end-of-data optimisation runs at the time of the
        session's last frame, whatever ``frames``.

        Args:
            params: the new map parameters.
            frames: rebuild up to this many frames (default: all processed so far).
            modes: which maps (default: all of the session's).
            finish: run the end-of-data optimisation (default: when the session had finished and
                all frames are replayed).

        """
        modes = modes or self.modes
        log = self.log
        if finish is None:
            finish = self.finished and (frames is None or frames >= log.frames)
        count = log.frames if frames is None or frames >= log.frames else max(frames, 0)
        return {
            mode: build_map(log, BuildTask(mode, params, count, finish), finish_time=log.end_time)[
                0
            ]
            for mode in modes
        }

    def adopt(self, params: MapParams, maps: dict[MapMode, CognitiveMap]) -> None:
        """Make rebuilt maps (and their parameters) the session's current ones."""
        self.params = params
        for mode, cmap in maps.items():
            self.maps.maps[mode] = cmap

    # ------------------------------------------------------------------ evaluation
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


def link_resolution(cmap: CognitiveMap) -> tuple[NDArray[np.int64], frozenset[tuple[float, int]]]:
    """A copy of what ties a map's loop-closure edges to the links that made them.

    The map's alias table (every vertex id to the live vertex standing for it) and the
    ``(time, target)`` of the relocalisations it refused, for
    :func:`~cogmap_core.evaluation.loop_edge_links` (a copy: it can be read while the map grows).
    """
    alias = np.array(cmap.graph.alias[: cmap.graph.num_ids], dtype=np.int64)
    refused = frozenset((float(c.time), int(c.target)) for c in cmap.refused)
    return alias, refused


def map_false_loop_edge_mask(
    log: EventLog,
    cmap: CognitiveMap,
    judging: EvaluationSettings | None = None,
    snapshot: MapSnapshot | None = None,
) -> NDArray[np.bool_] | None:
    """Per edge of the map's snapshot, whether it is a loop-closure edge made from a false link.

    "False loop closures in the map" on the page and in ``summary.json``: a live loop-closure
    edge is false when the link that made it (:func:`~cogmap_core.evaluation.loop_edge_links`) is
    false (``judging``'s tolerances, a bag's by default). None without ground truth.
    ``snapshot``: the map's snapshot when the caller has taken one.
    """
    judging = judging or EvaluationSettings()
    false = log.false_links(judging.loop_distance, judging.loop_heading)
    if false is None:
        return None
    snap = cmap.snapshot() if snapshot is None else snapshot
    alias, refused = link_resolution(cmap)
    links = log.link_table()
    edge_links = loop_edge_links(
        np.array([t for t, _, _ in links]), np.array([g for _, g, _ in links], dtype=np.int64),
        snap, alias, refused,
    )  # fmt: skip
    return false_loop_edges(edge_links, false)


def map_false_loop_edges(
    log: EventLog,
    cmap: CognitiveMap,
    judging: EvaluationSettings | None = None,
    snapshot: MapSnapshot | None = None,
) -> int | None:
    """How many of a map's loop-closure edges were made from links the ground truth calls false.

    (:func:`map_false_loop_edge_mask`, counted; None without ground truth.)
    """
    mask = map_false_loop_edge_mask(log, cmap, judging, snapshot)
    return None if mask is None else int(np.count_nonzero(mask))


def map_rejected_loop_edges(
    log: EventLog,
    cmap: CognitiveMap,
    judging: EvaluationSettings | None = None,
    snapshot: MapSnapshot | None = None,
    false_edges: NDArray[np.bool_] | None = None,
) -> tuple[int, int | None]:
    """How many of a map's loop-closure edges its loop model rejects, and how many of them true.

    Rejected: :meth:`~cogmap_core.cognitive_map.CognitiveMap.rejected_loop_edges`. True: not made
    from a link the ground truth calls false (:func:`map_false_loop_edge_mask`, or
    ``false_edges`` when the caller has it; None without ground truth).
    """
    rejected = cmap.rejected_loop_edges()
    if false_edges is None:
        false_edges = map_false_loop_edge_mask(log, cmap, judging, snapshot)
    true = None if false_edges is None else int(np.count_nonzero(rejected & ~false_edges))
    return int(np.count_nonzero(rejected)), true


def optimisation_summary(cmap: CognitiveMap) -> dict[str, float | int]:
    """Counts and timing of a map's optimisations and loop closures."""
    return {
        "vertices": cmap.num_vertices,
        "edges": cmap.num_edges,
        "loop_edges": cmap.num_loop_edges,
        "clusters": len(cmap.clusters),
        "optimizations": len(cmap.optimizations),
        "optimize_wall_s": float(sum(o.wall_s for o in cmap.optimizations)),
    }
