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
from cogmap_core.evaluation import EvaluationSettings, LayoutFidelity, align_rigid_2d
from cogmap_core.slam import EventLog

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class MapFigures:
    """A map's accuracy figures (None: no ground truth, or no vertex yet)."""

    ate: float | None
    fidelity: LayoutFidelity | None
    truth_transform: tuple[float, float, float] | None


def truth_transform(log: EventLog, cmap: CognitiveMap) -> tuple[float, float, float] | None:
    """(theta, tx, ty) taking the ground truth onto the map: the rigid alignment of the ATE.

    With fewer than two vertices, the truth is placed so that its first pose is the map's
    origin (where the first vertex is made). None without ground truth.
    """
    if not log.has_ground_truth():
        return None
    snap = cmap.snapshot()
    if snap.vertex_ids.shape[0] >= 2:
        truth = log.truth_at(snap.vertex_time)
        assert truth is not None
        t = align_rigid_2d(truth, snap.poses)
        return (t.theta, t.tx, t.ty)
    x0, y0, theta0 = log.ground_truth[0]
    c, s = math.cos(-theta0), math.sin(-theta0)
    return (-theta0, -(c * x0 - s * y0), -(s * x0 + c * y0))


def map_figures(
    log: EventLog, cmap: CognitiveMap, judging: EvaluationSettings | None = None
) -> MapFigures:
    """ATE, layout fidelity (at ``judging``'s radius) and the truth's alignment of ``cmap``."""
    radius = (judging or EvaluationSettings()).layout_radius
    return MapFigures(
        log.map_ate(cmap), log.layout_fidelity(cmap, radius), truth_transform(log, cmap)
    )


def layout_radius_label(judging: EvaluationSettings) -> str:
    """The layout fidelity radius as the page writes it ("8 cm", "50 cm")."""
    return f"{judging.layout_radius * 100:g} cm"


def false_link_label(judging: EvaluationSettings) -> str:
    """When a loop closure counts as false, as the page writes it."""
    text = f"position {judging.loop_distance:g} m"
    if judging.loop_heading is not None:
        text += f", heading {math.degrees(judging.loop_heading):.0f}°"
    return text


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
