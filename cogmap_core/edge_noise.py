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
``MapParams.odometry_step_length`` and ``odometry_step_turn`` say how long the odometry steps
were that the map's edges are made of (a log's vertex step): a compact edge that replaced five
steps then weighs as the chain of five it replaced (five times one step's variance), not as one
step five times as long (25 times). Without them (0, camera inputs) every edge is one step.
``MapParams.edge_noise_model = 0`` restores the paper's identity weighting.
"""

from __future__ import annotations

from dataclasses import dataclass

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


def information_unit(link_sigmas: tuple[float, float] | None) -> float:
    """The variance (m²) that weighs 1: a loop closure's position variance (1 for identity).

    An edge of covariance ``C`` (m, rad) weighs ``information_unit * C^-1``, in the unit of
    :func:`edge_information`.
    """
    return 1.0 if link_sigmas is None else link_sigmas[0] ** 2


@dataclass(frozen=True)
class OdometryNoise:
    """How the odometry edges' sigmas are set beyond the model's rates (module doc).

    Attributes:
        scale: the factor on their sigmas (``MapParams.odometry_scale``, measured for a log by
            :mod:`~cogmap_core.odometry_scale`).
        step_length: the odometry steps an edge is made of (m): an edge of length ``d`` turning
            ``dtheta`` is the chain of ``n = max(1, d / step_length, |dtheta| / step_turn)``
            equal steps it replaced, and its variance that chain's, ``n`` times one step's; 0:
            every edge is one step (``MapParams.odometry_step_length``).
        step_turn: ... and their turn (rad; ``MapParams.odometry_step_turn``).

    """

    scale: float = 1.0
    step_length: float = 0.0
    step_turn: float = 0.0


def edge_information(
    kinds: NDArray[np.int8],
    relative_poses: NDArray[np.float64],
    link_sigmas: tuple[float, float] | None,
    odometry: OdometryNoise | None = None,
) -> NDArray[np.float64]:
    """``(E, 3, 3)`` information matrices of edges (see the module doc).

    Args:
        kinds: per edge, 0 sequential or 1 loop closure.
        relative_poses: ``(E, 3)`` measured relative poses (dx, dy, dtheta).
        link_sigmas: a loop-closure link's precision (position m, heading rad); None gives
            the paper's identity information.
        odometry: the odometry edges' scale and steps (default: the model as it is); not used
            with identity information.

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
    odometry = odometry or OdometryNoise()
    steps = np.ones(n)
    if odometry.step_length > 0:
        steps = np.maximum(steps, d / odometry.step_length)
    if odometry.step_turn > 0:
        steps = np.maximum(steps, turn / odometry.step_turn)
    # a chain of n steps of d / n and turn / n: n x one step's variance (sqrt(n) x its sigma)
    chain = np.sqrt(steps) * odometry.scale
    step_xy = ODOMETRY_SIGMA_0 + ODOMETRY_SIGMA_PER_METRE * d / steps
    step_th = (
        ODOMETRY_SIGMA_0
        + ODOMETRY_SIGMA_PER_RADIAN * turn / steps
        + ODOMETRY_HEADING_PER_METRE * d / steps
    )
    sigma_xy = np.where(sequential, chain * step_xy, link_position)
    sigma_th = np.where(sequential, chain * step_th, link_heading)
    info[:, 0, 0] = info[:, 1, 1] = (link_position / sigma_xy) ** 2
    info[:, 2, 2] = (link_position / sigma_th) ** 2
    return info
