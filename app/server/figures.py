"""Figures the page shows beside the maps: ATE, layout fidelity, truth alignment, false links.

A loop closure (link) is false when the ground truth puts its two places apart (a bag's: 0.1 m
and 10 degrees; a log's: 1 m); a map's *false loop closures* are its loop-closure edges made from
a false link -- one definition for the page, ``summary.json`` and the HTML replay
(:func:`~cogmap_core.slam.map_false_loop_edges`).

All are computed from the session's event log (ground truth per frame) and a map, the same way
``cogmap run``'s report computes them (:class:`~cogmap_core.event_log.EventLog`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from cogmap_core.cognitive_map import CognitiveMap, EdgeKind
from cogmap_core.evaluation import (
    EvaluationSettings,
    LayoutFidelity,
    align_rigid_2d,
    false_loop_edges,
    loop_edge_links,
    map_accuracy,
)
from cogmap_core.event_log import EventLog
from cogmap_core.map_graph import MapSnapshot
from cogmap_core.slam import link_resolution

FloatArray = NDArray[np.float64]
#: Loop-closure edges of a map, each as ``(time, end vertex)``.
FalseEdges = frozenset[tuple[float, int]]


@dataclass(frozen=True, slots=True)
class LinkCounts:
    """Where a map's links (the loop closures the front end detected) went.

    Attributes:
        links: links the map received.
        duplicates: links that joined a pair already joined (or the vertex the robot is at).
        refused: links its relocalisation test refused.
        made: loop-closure edges it made of them (``links - duplicates - refused``).
        removed: edges of those it holds no more as drawn edges (merged by scene integration,
            or folded into a merged run's evidence edge, or removed with a short edge's vertex).

    """

    links: int
    duplicates: int
    refused: int
    made: int
    removed: int


@dataclass(frozen=True, slots=True)
class MapFigures:
    """A map's accuracy figures (None: no ground truth, or no vertex yet) and link counts.

    ``false_edges`` are the map's loop-closure edges made from a link the ground truth calls
    false, as ``(time, end vertex)`` pairs (:func:`~cogmap_core.evaluation.loop_edge_links`);
    ``false_count`` how many (None without ground truth).
    """

    ate: float | None
    fidelity: LayoutFidelity | None
    truth_transform: tuple[float, float, float] | None
    false_edges: FalseEdges = frozenset()
    false_count: int | None = None
    links: LinkCounts | None = None


@dataclass(frozen=True, slots=True)
class LinkJudgement:
    """Every link of a log (:meth:`~cogmap_core.event_log.EventLog.link_table` order), judged.

    Attributes:
        time: per link, its data time.
        target: per link, the vertex id it links to.
        false: per link, whether the ground truth calls it false (None without ground truth).

    """

    time: FloatArray
    target: NDArray[np.int64]
    false: NDArray[np.bool_] | None

    def false_before(self, count: int) -> int | None:
        """How many of the first ``count`` links are false (None without ground truth)."""
        return None if self.false is None else int(np.count_nonzero(self.false[:count]))


NO_LINKS = LinkJudgement(np.zeros(0), np.zeros(0, dtype=np.int64), None)


@dataclass(frozen=True, slots=True)
class FigureInputs:
    """What a map's figures are computed from, taken out of a running replay.

    Taken while the replay's lock is held (:func:`figure_inputs`, a few milliseconds); the
    figures are then computed from it without the lock (:func:`compute_figures`), so the replay
    does not wait for them.

    Attributes:
        map: the map's live part (a copy).
        vertex_truth: the true pose at each vertex's creation time (None without truth).
        path: the dense true path, one pose per frame (None without truth): a read-only view
            of the log's, not a copy. The log only appends (rows already logged are never
            written again; growing it moves them to a new buffer), so the view stays as taken.
        alias: the map's alias table and ``refused`` its refused relocalisations (copies:
            :func:`~cogmap_core.slam.link_resolution`), to trace its loop-closure edges to links.
        links: links the map received; ``duplicates``: those that joined a joined pair.

    """

    map: MapSnapshot
    vertex_truth: FloatArray | None
    path: FloatArray | None
    alias: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    refused: frozenset[tuple[float, int]] = frozenset()
    links: int = 0
    duplicates: int = 0


def figure_inputs(log: EventLog, cmap: CognitiveMap) -> FigureInputs:
    """Take what the figures of ``cmap`` need (hold the replay's lock while calling)."""
    snap = cmap.snapshot()
    alias, refused = link_resolution(cmap)
    c = cmap.counters
    if not log.has_ground_truth():
        return FigureInputs(snap, None, None, alias, refused, c.links, c.duplicate_links)
    return FigureInputs(
        snap, log.truth_at(snap.vertex_time), log.ground_truth, alias, refused, c.links,
        c.duplicate_links,
    )  # fmt: skip


def compute_figures(
    inputs: FigureInputs,
    judging: EvaluationSettings | None = None,
    links: LinkJudgement = NO_LINKS,
) -> MapFigures:
    """ATE, layout fidelity (at ``judging``'s radius), the truth's alignment and link counts.

    The same computation as ``cogmap run``'s report (:func:`~cogmap_core.evaluation.map_accuracy`
    and :func:`~cogmap_core.slam.map_false_loop_edges`); ``links``: the log's links judged
    (:func:`judge_links`).
    """
    snap, truth, path = inputs.map, inputs.vertex_truth, inputs.path
    made = loop_edge_links(links.time, links.target, snap, inputs.alias, inputs.refused)
    refused = sum(
        (t, g) in inputs.refused
        for t, g in zip(links.time.tolist(), links.target.tolist(), strict=True)
    )
    made_count = inputs.links - inputs.duplicates - refused
    loop_edges = int(np.count_nonzero(snap.edge_kind == EdgeKind.LOOP_CLOSURE))
    counts = LinkCounts(
        inputs.links, inputs.duplicates, refused, made_count, made_count - loop_edges
    )
    false_edges: FalseEdges = frozenset()
    false_count = None
    if links.false is not None:
        false = false_loop_edges(made, links.false)
        false_edges = _pairs(snap, false)
        false_count = len(false_edges)
    if truth is None or path is None:
        return MapFigures(None, None, None, false_edges, false_count, counts)
    radius = (judging or EvaluationSettings()).layout_radius
    accuracy = map_accuracy(snap, truth, path, radius)
    return MapFigures(
        accuracy.ate, accuracy.fidelity, _alignment(snap, truth, path), false_edges, false_count,
        counts,
    )  # fmt: skip


def _alignment(
    snap: MapSnapshot, truth: FloatArray, path: FloatArray
) -> tuple[float, float, float]:
    if snap.vertex_ids.shape[0] >= 2:
        t = align_rigid_2d(truth, snap.poses)
        return (t.theta, t.tx, t.ty)
    x0, y0, theta0 = path[0]
    c, s = math.cos(-theta0), math.sin(-theta0)
    return (-theta0, -(c * x0 - s * y0), -(s * x0 + c * y0))


def truth_transform(log: EventLog, cmap: CognitiveMap) -> tuple[float, float, float] | None:
    """(theta, tx, ty) taking the ground truth onto the map: the rigid alignment of the ATE.

    With fewer than two vertices, the truth is placed so that its first pose is the map's
    origin (where the first vertex is made). None without ground truth.
    """
    inputs = figure_inputs(log, cmap)
    if inputs.vertex_truth is None or inputs.path is None:
        return None
    return _alignment(inputs.map, inputs.vertex_truth, inputs.path)


def layout_radius_label(judging: EvaluationSettings) -> str:
    """The layout fidelity radius as the page writes it ("8 cm", "50 cm")."""
    return f"{judging.layout_radius * 100:g} cm"


def false_link_label(judging: EvaluationSettings) -> str:
    """When a loop closure counts as false, as the page writes it."""
    text = f"position {judging.loop_distance:g} m"
    if judging.loop_heading is not None:
        text += f", heading {math.degrees(judging.loop_heading):.0f}°"
    return text


def false_link_inputs(log: EventLog) -> EventLog:
    """Copy what :func:`judge_links` reads from ``log`` (hold the replay's lock while calling).

    The copy (a few milliseconds) can then be judged without the lock while the replay goes on.
    """
    return log.truncated(log.frames)


def judge_links(log: EventLog, judging: EvaluationSettings | None = None) -> LinkJudgement:
    """Every link of ``log`` and whether the ground truth calls it false (``judging``'s tolerances).

    The default tolerances are a bag's: position 0.1 m, heading 10 degrees.
    """
    judging = judging or EvaluationSettings()
    table = log.link_table()
    return LinkJudgement(
        np.array([t for t, _, _ in table], dtype=np.float64),
        np.array([g for _, g, _ in table], dtype=np.int64),
        log.false_links(judging.loop_distance, judging.loop_heading),
    )


def _pairs(snap: MapSnapshot, mask: NDArray[np.bool_]) -> FalseEdges:
    return frozenset(zip(snap.edge_time[mask].tolist(), snap.edge_to[mask].tolist(), strict=True))


def map_false_edges(cmap: CognitiveMap, links: LinkJudgement) -> FalseEdges:
    """``(time, end vertex)`` of the loop-closure edges of ``cmap`` made from false links."""
    if links.false is None:
        return frozenset()
    snap = cmap.snapshot()
    alias, refused = link_resolution(cmap)
    made = loop_edge_links(links.time, links.target, snap, alias, refused)
    return _pairs(snap, false_loop_edges(made, links.false))


def false_edge_mask(snap: MapSnapshot, false_edges: FalseEdges) -> NDArray[np.bool_]:
    """Per edge of ``snap``, whether it is one of ``false_edges``."""
    if not false_edges or snap.edge_from.shape[0] == 0:
        return np.zeros(snap.edge_from.shape[0], dtype=bool)
    return np.array(
        [
            kind == EdgeKind.LOOP_CLOSURE and (t, v) in false_edges
            for kind, t, v in zip(
                snap.edge_kind.tolist(), snap.edge_time.tolist(), snap.edge_to.tolist(), strict=True
            )
        ],
        dtype=bool,
    )
