"""Small SE(2) helpers, vectorised over leading dimensions (poses ``(..., 3)``: x, y, theta)."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]
TWO_PI = 2.0 * math.pi


def wrap_angle(angle: ArrayLike) -> FloatArray:
    """Wrap angles to ``[-pi, pi)``, the range the paper constrains vertex headings to."""
    a = np.asarray(angle, dtype=np.float64)
    return (a + np.pi) % (2.0 * np.pi) - np.pi


def wrap_scalar(angle: float) -> float:
    """Wrap one angle to ``[-pi, pi)`` (a fast path for plain floats)."""
    return (angle + math.pi) % TWO_PI - math.pi


def compose_scalar(
    a: tuple[float, float, float] | list[float], b: tuple[float, float, float] | list[float]
) -> tuple[float, float, float]:
    """:func:`compose` for one pair of poses given as plain floats (no numpy overhead)."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return (
        a[0] + c * b[0] - s * b[1],
        a[1] + s * b[0] + c * b[1],
        (a[2] + b[2] + math.pi) % TWO_PI - math.pi,
    )


def inverse_scalar(a: tuple[float, float, float] | list[float]) -> tuple[float, float, float]:
    """:func:`inverse` for one pose given as plain floats."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return (-(c * a[0] + s * a[1]), s * a[0] - c * a[1], (math.pi - a[2]) % TWO_PI - math.pi)


def compose(a: ArrayLike, b: ArrayLike) -> FloatArray:
    """Compose poses: ``a (+) b``, pose ``b`` (given in frame ``a``) expressed in a's parent."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    out = np.empty(np.broadcast_shapes(a.shape, b.shape), dtype=np.float64)
    out[..., 0] = a[..., 0] + c * b[..., 0] - s * b[..., 1]
    out[..., 1] = a[..., 1] + s * b[..., 0] + c * b[..., 1]
    out[..., 2] = wrap_angle(a[..., 2] + b[..., 2])
    return out


def inverse(a: ArrayLike) -> FloatArray:
    """Invert poses: ``a (+) inverse(a) = identity``."""
    a = np.asarray(a, dtype=np.float64)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    out = np.empty_like(a)
    out[..., 0] = -(c * a[..., 0] + s * a[..., 1])
    out[..., 1] = s * a[..., 0] - c * a[..., 1]
    out[..., 2] = wrap_angle(-a[..., 2])
    return out


def between_scalar(
    a: tuple[float, float, float] | list[float], b: tuple[float, float, float] | list[float]
) -> tuple[float, float, float]:
    """:func:`between` of two single poses, in plain floats."""
    return compose_scalar(inverse_scalar(a), b)


def between(a: ArrayLike, b: ArrayLike) -> FloatArray:
    """Relative pose of ``b`` in the frame of ``a``: ``inverse(a) (+) b``."""
    return compose(inverse(a), b)


def polar_to_relative(d: ArrayLike, heading_rad: ArrayLike, facing_rad: ArrayLike) -> FloatArray:
    """Turn OpenRatSLAM link fields (d, heading_rad, facing_rad) into relative poses.

    The paper's residual predicts ``x_j = x_i + d cos(theta_i + heading_rad)`` (likewise y) and
    ``theta_j = theta_i + facing_rad``: the relative pose in frame ``i`` is therefore
    ``(d cos heading, d sin heading, facing)``.
    """
    d = np.asarray(d, dtype=np.float64)
    h = np.asarray(heading_rad, dtype=np.float64)
    f = np.asarray(facing_rad, dtype=np.float64)
    return np.stack([d * np.cos(h), d * np.sin(h), wrap_angle(f)], axis=-1)


def relative_to_polar(rel: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Inverse of :func:`polar_to_relative`: ``(d, heading_rad, facing_rad)`` of relative poses."""
    rel = np.asarray(rel, dtype=np.float64)
    d = np.hypot(rel[..., 0], rel[..., 1])
    heading = np.arctan2(rel[..., 1], rel[..., 0])
    return d, heading, wrap_angle(rel[..., 2])


def compose_covariance(
    cov_a: FloatArray, b: tuple[float, float, float] | list[float], cov_b: FloatArray
) -> FloatArray:
    """Covariance of ``a (+) b`` for independent measurements ``a`` and ``b``, to first order.

    Each covariance is in its measurement's own frame, the frame the optimiser's residual uses
    (:mod:`cogmap_core.optimizer`): a measurement ``(t, theta)`` is perturbed to ``(t +
    R(theta) dt, theta + dtheta)``. Then ``a (+) b``'s perturbation is ``A da + db`` with ``A =
    [[R_b^T, R_b^T J t_b], [0, 1]]`` (``J`` the rotation by 90 degrees): ``A cov_a A^T + cov_b``.
    ``a`` itself does not enter (its frame cancels).
    """
    jac = _carry_jacobian(b)
    return jac @ cov_a @ jac.T + cov_b


def inverse_covariance(
    a: tuple[float, float, float] | list[float], cov_a: FloatArray
) -> FloatArray:
    """Covariance of ``inverse(a)`` in its own frame (:func:`compose_covariance`'s frames).

    ``inverse(a)``'s perturbation is ``[[-R_a, J t_a], [0, -1]] da``.
    """
    c, s = math.cos(a[2]), math.sin(a[2])
    jac = np.array([[-c, s, -a[1]], [-s, -c, a[0]], [0.0, 0.0, -1.0]])
    return jac @ cov_a @ jac.T


def _carry_jacobian(b: tuple[float, float, float] | list[float]) -> FloatArray:
    """How a perturbation of ``a`` shows in ``a (+) b``'s frame (:func:`compose_covariance`)."""
    c, s = math.cos(b[2]), math.sin(b[2])
    # R_b^T = [[c, s], [-s, c]]; J t_b = (-t_y, t_x)
    return np.array(
        [
            [c, s, -c * b[1] + s * b[0]],
            [-s, c, s * b[1] + c * b[0]],
            [0.0, 0.0, 1.0],
        ]
    )
