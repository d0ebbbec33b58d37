"""How precise a log's odometry is, measured by its own loop candidates (no ground truth).

The odometry edges' noise model (:mod:`cogmap_core.edge_noise`) is one for every input: wheel
odometry whose error grows by a few centimetres and degrees per metre. It has to be loose enough
for the worst odometry cogmap meets, and on a log whose odometry is ten times better it is ten
times too loose: a cluster of place-recognition links that all point to a look-alike corridor
13 m away then costs the odometry little to satisfy, and the robust loop model keeps it
(``parallel_corridors`` of ``cogmap make-log``; issue 28).

Each loop candidate says that the robot is where it was at an earlier time. Dead reckoning says
where it is relative to that place: the displacement ``e`` between the two times along the
odometry. The model predicts that displacement's variance ``v``: the position error of every
step, the heading error of every step swung over the distance still to go, and the link's own
``link_sigma_position``. For true candidates ``|e|^2 / (2 v)`` is about the ratio of the real
odometry's variance to the model's; a false candidate gives a random value, usually a larger
one. The median over the candidates (robust to up to half of them false) is the estimate: on
the 18 generated logs it is 0.01-0.13 for medium drift, 0.3-1.1 for high, 1.5-4 for extreme,
with true candidates alone within 30 % of it, and 0.20 on Lecture Hall.

The odometry edges' sigmas are then multiplied by ``sqrt(ratio)``, clipped to
[:data:`MIN_SCALE`, 1]: never looser than the model (the loop model's kernel was designed with
it), never stiffer than a third of it (a few lucky candidates must not freeze the odometry).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from cogmap_core.edge_noise import (
    ODOMETRY_HEADING_PER_METRE,
    ODOMETRY_SIGMA_PER_METRE,
    ODOMETRY_SIGMA_PER_RADIAN,
)
from cogmap_core.evaluation import dead_reckoning

#: The stiffest odometry the estimate may give: sigmas x 0.3 (variance x 0.09).
MIN_SCALE = 0.3
#: Fewer usable candidates than this: no estimate (the model's sigmas, scale 1).
MIN_CANDIDATES = 10
#: A candidate is usable when its two times are at least this many odometry samples apart.
MIN_SAMPLES_APART = 10


@dataclass(frozen=True)
class OdometryScale:
    """The estimate for one log.

    Attributes:
        scale: the factor on the odometry edges' sigmas (``MapParams.odometry_scale``).
        median_ratio: the median of ``|e|^2 / (2 v)`` over the usable candidates (NaN: none).
        candidates: how many candidates it was taken over.

    """

    scale: float
    median_ratio: float
    candidates: int


def innovation_ratios(
    odometry: NDArray[np.float64],
    candidates: NDArray[np.float64],
    link_sigma_position: float,
) -> NDArray[np.float64]:
    """``|e|^2 / (2 v)`` of each usable candidate (module doc), in candidate order.

    Args:
        odometry: ``(N, 3)`` time, forward velocity (m/s), yaw rate (rad/s), times increasing.
        candidates: ``(M, 2+)`` time, matched (earlier) time, ... -- the candidates to use.
        link_sigma_position: a link's position precision (m).

    """
    t, v, w = odometry[:, 0], odometry[:, 1], odometry[:, 2]
    dt = np.diff(t, prepend=t[0])
    poses = dead_reckoning(v * dt, w * dt)  # as the map integrates odometry
    x, y = poses[:, 0], poses[:, 1]
    ds, dth = np.abs(v * dt), np.abs(w * dt)
    # the model's variances per step: heading (per metre driven and per radian turned), position
    heading_var = ODOMETRY_HEADING_PER_METRE**2 * ds + ODOMETRY_SIGMA_PER_RADIAN**2 * dth
    position_var = np.cumsum(ODOMETRY_SIGMA_PER_METRE**2 * ds)
    # sum_k h_k |p_j - p_k|^2 = |p_j|^2 H - 2 p_j . sum h_k p_k + sum h_k |p_k|^2 (prefix sums)
    h = np.cumsum(heading_var)
    hx, hy = np.cumsum(heading_var * x), np.cumsum(heading_var * y)
    hr = np.cumsum(heading_var * (x * x + y * y))
    if candidates.size == 0:
        return np.zeros(0)
    now = np.minimum(np.searchsorted(t, candidates[:, 0]), len(t) - 1)
    then = np.minimum(np.searchsorted(t, candidates[:, 1]), len(t) - 1)
    usable = now - then >= MIN_SAMPLES_APART
    j, i = now[usable], then[usable]
    xj, yj = x[j], y[j]
    swing = (
        (xj * xj + yj * yj) * (h[j] - h[i])
        - 2 * (xj * (hx[j] - hx[i]) + yj * (hy[j] - hy[i]))
        + (hr[j] - hr[i])
    )
    predicted = np.maximum(swing, 0.0) + position_var[j] - position_var[i]
    predicted += link_sigma_position**2
    displacement = (xj - x[i]) ** 2 + (yj - y[i]) ** 2
    return displacement / (2.0 * predicted)


def estimate_odometry_scale(
    odometry: NDArray[np.float64],
    candidates: NDArray[np.float64],
    link_sigma_position: float,
) -> OdometryScale:
    """The factor on the odometry edges' sigmas for a log (module doc).

    ``candidates``: the loop candidates the map will be given (score and travel thresholds
    applied); see :func:`innovation_ratios` for the arguments.
    """
    ratios = innovation_ratios(odometry, candidates, link_sigma_position)
    if ratios.size < MIN_CANDIDATES:
        median = float(np.median(ratios)) if ratios.size else math.nan
        return OdometryScale(1.0, median, int(ratios.size))
    median = float(np.median(ratios))
    scale = math.sqrt(min(1.0, max(MIN_SCALE**2, median)))
    return OdometryScale(scale, median, int(ratios.size))


__all__ = [
    "MIN_CANDIDATES",
    "MIN_SAMPLES_APART",
    "MIN_SCALE",
    "OdometryScale",
    "estimate_odometry_scale",
    "innovation_ratios",
]
