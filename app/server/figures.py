"""Figures the page shows beside the maps: ATE, layout fidelity, truth alignment, false links.

All are computed from the session's event log (ground truth per frame) and a map, the same way
``cogmap run``'s report computes them (:class:`~cogmap_core.slam.EventLog`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from cogmap_core.cognitive_map import CognitiveMap
from cogmap_core.evaluation import (
    EvaluationSettings,
    LayoutFidelity,
    align_rigid_2d,
    map_accuracy,
)
from cogmap_core.map_graph import MapSnapshot
from cogmap_core.slam import EventLog

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class MapFigures:
    """A map's accuracy figures (None: no ground truth, or no vertex yet)."""

    ate: float | None
    fidelity: LayoutFidelity | None
    truth_transform: tuple[float, float, float] | None


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

    """

    map: MapSnapshot
    vertex_truth: FloatArray | None
    path: FloatArray | None


def figure_inputs(log: EventLog, cmap: CognitiveMap) -> FigureInputs:
    """Take what the figures of ``cmap`` need (hold the replay's lock while calling)."""
    snap = cmap.snapshot()
    if not log.has_ground_truth():
        return FigureInputs(snap, None, None)
    return FigureInputs(snap, log.truth_at(snap.vertex_time), log.ground_truth)


def compute_figures(inputs: FigureInputs, judging: EvaluationSettings | None = None) -> MapFigures:
    """ATE, layout fidelity (at ``judging``'s radius) and the truth's alignment of a map.

    The same computation as ``cogmap run``'s report (:func:`~cogmap_core.evaluation.map_accuracy`).
    """
    snap, truth, path = inputs.map, inputs.vertex_truth, inputs.path
    if truth is None or path is None:
        return MapFigures(None, None, None)
    radius = (judging or EvaluationSettings()).layout_radius
    accuracy = map_accuracy(snap, truth, path, radius)
    return MapFigures(accuracy.ate, accuracy.fidelity, _alignment(snap, truth, path))


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
    """Copy what :func:`false_link_times` reads from ``log`` (hold the replay's lock while calling).

    The copy (a few milliseconds) can then be judged without the lock while the replay goes on;
    without ground truth nothing is judged, so nothing is copied (an empty log).
    """
    return log.truncated(log.frames) if log.has_ground_truth() else EventLog()


def false_link_times(log: EventLog, judging: EvaluationSettings | None = None) -> FloatArray:
    """Times of the links the ground truth calls false (with ``judging``'s tolerances).

    The default tolerances are a bag's: position 0.1 m, heading 10 degrees.
    """
    judging = judging or EvaluationSettings()
    score = log.loop_closure_score(judging.loop_distance, judging.loop_heading)
    if score is None or not score.false_indices:
        return np.zeros(0)
    table = log.link_table()
    return np.array([table[k][0] for k in score.false_indices], dtype=np.float64)
