"""SE(2) pose-graph edges: whitened residuals and Jacobians of all edges in one numpy pass.

The optimiser's Ceres problem (:mod:`~cogmap_core.ceres_blocks`), its reweighting of loop
closures and the maps' costs all evaluate edges here.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from cogmap_core.errors import OptimizationError
from cogmap_core.geometry import wrap_angle
from cogmap_core.posegraph import PoseGraph
from cogmap_core.robust import Kernel, Weights, apply_kernel

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


class EdgeModel:
    """Per-edge constants: the measurement and the whitening ``W = S blockdiag(R_z^T, 1)``."""

    def __init__(self, measurements: FloatArray, information: FloatArray) -> None:
        """Precompute whitening from measurements ``(E, 3)`` and information ``(E, 3, 3)``."""
        cz, sz = np.cos(measurements[:, 2]), np.sin(measurements[:, 2])
        rz_t = np.zeros_like(information)
        rz_t[:, 0, 0], rz_t[:, 0, 1], rz_t[:, 1, 0], rz_t[:, 1, 1] = cz, sz, -sz, cz
        rz_t[:, 2, 2] = 1.0
        off_diagonal = information[:, [0, 0, 1, 1, 2, 2], [1, 2, 0, 2, 0, 1]]
        scale = information[:, [0, 1, 2], [0, 1, 2]]
        if not off_diagonal.any() and (scale > 0).all() and np.isfinite(scale).all():
            # Diagonal information (the map's noise model; the paper's identity): the Cholesky
            # factor is the square root of the diagonal (sqrt(1) * x == x exactly), and this
            # product is exactly the general one below.
            self.whitening = np.sqrt(scale)[:, :, None] * rz_t
        else:
            try:
                lower = np.linalg.cholesky(information)  # Omega = L L^T, so S = L^T
            except np.linalg.LinAlgError:
                raise OptimizationError(
                    "an edge information matrix is not positive definite; fix the edge weights"
                ) from None
            self.whitening = lower.transpose(0, 2, 1) @ rz_t
        self.tx = measurements[:, 0].copy()
        self.ty = measurements[:, 1].copy()
        self.ttheta = measurements[:, 2].copy()

    def subset(self, index: IntArray | slice) -> EdgeModel:
        """The model of some of the edges."""
        out = EdgeModel.__new__(EdgeModel)
        out.whitening = self.whitening[index]
        out.tx, out.ty, out.ttheta = self.tx[index], self.ty[index], self.ttheta[index]
        return out


EdgeLosses = Sequence[tuple[NDArray[np.bool_] | None, Kernel | Weights]]
"""Robust kernels and the edges (a mask; None: all) each applies to; the masks are disjoint."""


def edge_losses(huber_scale: float | None) -> EdgeLosses:
    """The paper's loss: Huber on every edge (none for plain least squares)."""
    return () if huber_scale is None else ((None, Kernel("huber", huber_scale)),)


def edge_terms(
    pose_i: FloatArray,
    pose_j: FloatArray,
    model: EdgeModel,
    losses: EdgeLosses | None,
    with_jacobians: bool,
) -> tuple[FloatArray, FloatArray | None]:
    """Whitened (and robustified) residuals ``(E, 3)`` and Jacobians ``(E, 2, 3, 3)``.

    ``jac[:, 0]`` is d r / d pose_i and ``jac[:, 1]`` is d r / d pose_j. ``losses`` is None
    (plain least squares) or kernels per edge
    (:func:`~cogmap_core.robust.apply_kernel`): a robust residual is ``sqrt(rho(s)/s) r`` so
    that its squared norm is ``rho(s)``.
    """
    theta = pose_i[:, 2]
    c, s = np.cos(theta), np.sin(theta)
    dx = pose_j[:, 0] - pose_i[:, 0]
    dy = pose_j[:, 1] - pose_i[:, 1]
    u = c * dx + s * dy
    v = c * dy - s * dx
    err = np.empty((theta.shape[0], 3))
    err[:, 0] = u - model.tx
    err[:, 1] = v - model.ty
    err[:, 2] = wrap_angle(pose_j[:, 2] - theta - model.ttheta)
    w = model.whitening
    res = np.einsum("kab,kb->ka", w, err)
    jac = None
    if with_jacobians:
        # W times d err / d pose_j = [[c, s, 0], [-s, c, 0], [0, 0, 1]] and d err / d pose_i =
        # [[-c, -s, v], [s, -c, -u], [0, 0, -1]], written out (a batched 3x3 matmul is slower)
        w0, w1, w2 = w[:, :, 0], w[:, :, 1], w[:, :, 2]
        c1, s1 = c[:, None], s[:, None]
        jac = np.empty((theta.shape[0], 2, 3, 3))
        jac[:, 1, :, 0] = w0 * c1 - w1 * s1
        jac[:, 1, :, 1] = w0 * s1 + w1 * c1
        jac[:, 1, :, 2] = w2
        jac[:, 0, :, :2] = -jac[:, 1, :, :2]
        jac[:, 0, :, 2] = w0 * v[:, None] - w1 * u[:, None] - w2
    for rows, kernel in losses or ():
        res, jac = apply_kernel(res, jac, kernel, rows)
    return res, jac


def graph_cost(
    graph: PoseGraph,
    poses: FloatArray | None = None,
    losses: EdgeLosses | None = None,
) -> float:
    """g2o cost ``1/2 sum rho(|S r|^2)`` of ``graph`` at ``poses`` (default: its own poses).

    ``rho`` is the kernels of ``losses`` (:func:`edge_losses`), the identity without them.
    """
    if graph.num_edges == 0:
        return 0.0
    x = graph.poses if poses is None else poses
    model = EdgeModel(graph.measurements, graph.information)
    res, _ = edge_terms(x[graph.edge_from], x[graph.edge_to], model, losses, False)
    return 0.5 * float(np.einsum("ka,ka->", res, res))


def chi2(graph: PoseGraph, poses: FloatArray | None = None) -> FloatArray:
    """``(E,)`` squared whitened residual of every edge (no kernel) at ``poses``."""
    x = graph.poses if poses is None else poses
    model = EdgeModel(graph.measurements, graph.information)
    res, _ = edge_terms(x[graph.edge_from], x[graph.edge_to], model, None, False)
    return np.einsum("ka,ka->k", res, res)


def subset_loss(
    rows: NDArray[np.bool_] | None, kernel: Kernel | Weights, index: IntArray | slice
) -> tuple[NDArray[np.bool_] | None, Kernel | Weights]:
    """A loss restricted (and reordered) to the edges ``index``."""
    if isinstance(kernel, Weights):
        kernel = Weights(kernel.values[index])
    return (None if rows is None else rows[index], kernel)
