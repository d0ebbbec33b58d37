"""How much each edge of the cognitive map is trusted in the batch optimisation.

The paper weighs every residual alike, ``rho(||e_j - e_i - e_ij||^2)``: identity information.
That treats a 7 cm odometry step, a 0.27 m compact edge and a loop closure found by view matching
as equally precise, and lets the optimiser trade a degree of heading for a centimetre of position
anywhere. On RatSLAM's dense experience maps it bends the map: loop closures' heading errors (a
few degrees; more while the robot spins) are spread over long chains of sequential edges, and a
corridor that is only reached through one junction (a dead end) rotates about it.

The default weighs each residual by its expected precision instead (a diagonal information
matrix), scaled so that a loop-closure edge keeps unit weight -- the Huber scale still reads in
metres of loop-closure error, as in the paper:

- loop closure: sigma_xy and sigma_theta = the front end's link precision
  (``MapParams.link_sigma_position`` and ``link_sigma_heading``: by default RatSLAM's view
  matching, which places the robot within a few cm of the vertex, 3 cm, with its relative angle
  good to a few degrees, 0.1 rad; for a log of place recognition its keyframe-level precision,
  :data:`~cogmap_core.sources.odometry_log.LOG_MAP_CHANGES`);
- sequential (odometry) edge of length ``d`` turning ``dtheta``: sigma_xy = ``ODOMETRY_SIGMA_0``
  + ``ODOMETRY_SIGMA_PER_METRE`` d, sigma_theta = ``ODOMETRY_SIGMA_0`` +
  ``ODOMETRY_SIGMA_PER_RADIAN`` |dtheta| + ``ODOMETRY_HEADING_PER_METRE`` d: wheel odometry's
  error grows with the motion it measures.

``MapParams.odometry_scale`` multiplies the sequential edges' sigmas: a log's odometry is
measured by its own loop candidates (:mod:`cogmap_core.odometry_scale`); 1 for camera inputs.
``MapParams.edge_noise_model = 0`` restores the paper's identity weighting.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

ODOMETRY_SIGMA_0 = 0.005  # m and rad: the floor of any odometry step
ODOMETRY_SIGMA_PER_METRE = 0.05  # m of position error per metre driven
ODOMETRY_SIGMA_PER_RADIAN = 0.05  # rad of heading error per radian turned
ODOMETRY_HEADING_PER_METRE = 0.03  # rad of heading error per metre driven


def link_heading_weight(link_sigmas: tuple[float, float] | None) -> float:
    """Metres of loop-closure error one radian of a loop closure's heading error weighs.

    The ratio :func:`edge_information` gives a loop-closure edge's heading residual against its
    position residual (1 with identity information).
    """
    if link_sigmas is None:
        return 1.0
    return link_sigmas[0] / link_sigmas[1]


def edge_information(
    kinds: NDArray[np.int8],
    relative_poses: NDArray[np.float64],
    link_sigmas: tuple[float, float] | None,
    odometry_scale: float = 1.0,
) -> NDArray[np.float64]:
    """``(E, 3, 3)`` information matrices of edges (see the module doc).

    Args:
        kinds: per edge, 0 sequential or 1 loop closure.
        relative_poses: ``(E, 3)`` measured relative poses (dx, dy, dtheta).
        link_sigmas: a loop-closure link's precision (position m, heading rad); None gives
            the paper's identity information.
        odometry_scale: the factor on the sequential edges' sigmas (``MapParams.odometry_scale``,
            :mod:`~cogmap_core.odometry_scale`); not used with identity information.

    """
    n = kinds.shape[0]
    info = np.zeros((n, 3, 3))
    if link_sigmas is None:
        info[:, 0, 0] = info[:, 1, 1] = info[:, 2, 2] = 1.0
        return info
    link_position, link_heading = link_sigmas
    d = np.hypot(relative_poses[:, 0], relative_poses[:, 1])
    turn = np.abs(relative_poses[:, 2])
    sequential = kinds == 0
    sigma_xy = np.where(sequential, ODOMETRY_SIGMA_0 + ODOMETRY_SIGMA_PER_METRE * d, link_position)
    sigma_th = np.where(
        sequential,
        ODOMETRY_SIGMA_0 + ODOMETRY_SIGMA_PER_RADIAN * turn + ODOMETRY_HEADING_PER_METRE * d,
        link_heading,
    )
    if odometry_scale != 1.0:
        factor = np.where(sequential, odometry_scale, 1.0)
        sigma_xy, sigma_th = sigma_xy * factor, sigma_th * factor
    info[:, 0, 0] = info[:, 1, 1] = (link_position / sigma_xy) ** 2
    info[:, 2, 2] = (link_position / sigma_th) ** 2
    return info
