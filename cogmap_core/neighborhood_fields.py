"""Neighborhood fields (paper, "Adding Sparse vertices through Neighborhood Fields").

Movement since the last vertex -- translation ``d`` and rotation ``theta`` -- forms a
neighborhood field ``g(d, theta) = (1 + alpha d)(1 + beta |theta|)``. A vertex proposed by the
front end is added only when the field is novel enough, ``g > delta``; otherwise it is declined
and the consecutive sequential edges merge into one (the declined vertex becomes an alias of the
last vertex, at its relative pose). With the paper's alpha = beta = 10 and delta = 3.746, a
straight run adds a vertex every 0.2746 m and a turn on the spot one every 0.2746 rad.
"""

from __future__ import annotations

import math


def neighborhood_field(d: float, theta: float, alpha: float, beta: float) -> float:
    """The paper's neighborhood field g(d, theta) = (1 + alpha d)(1 + beta |theta|)."""
    return (1.0 + alpha * d) * (1.0 + beta * abs(theta))


def is_novel(
    movement: tuple[float, float, float] | list[float], alpha: float, beta: float, delta: float
) -> bool:
    """Whether a movement ``(dx, dy, dtheta)`` since the last vertex earns a new vertex."""
    d = math.hypot(movement[0], movement[1])
    return neighborhood_field(d, movement[2], alpha, beta) > delta
