"""LAGO-style linear initialisation of 2D pose graphs.

After Carlone et al., "A fast and accurate approximation for planar pose graph optimization",
IJRR 2014.

Two sparse linear least-squares problems, no iteration: first all headings (with the 2 pi
ambiguity of each edge resolved along a breadth-first spanning tree), then all positions given
the headings. Started from this estimate, Ceres needs only a couple of Gauss-Newton steps.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from numpy.typing import NDArray
from scipy.sparse.csgraph import breadth_first_order

from cogmap_core.posegraph import PoseGraph

TWO_PI = 2.0 * np.pi


def _solve_spd(normal: sp.spmatrix, rhs: NDArray[np.float64]) -> NDArray[np.float64]:
    """Solve a sparse symmetric positive-definite system (symmetric-mode LU, minimum degree)."""
    lu = spla.splu(
        sp.csc_matrix(normal),
        permc_spec="MMD_AT_PLUS_A",
        diag_pivot_thresh=0.0,
        options={"SymmetricMode": True},
    )
    return lu.solve(rhs)


def _spanning_tree_headings(graph: PoseGraph, roots: NDArray[np.int64]) -> NDArray[np.float64]:
    """Headings obtained by chaining edge rotations along breadth-first trees from ``roots``."""
    n = graph.num_vertices
    i, j = graph.edge_from, graph.edge_to
    # One edge per unordered vertex pair (the first in file order), stored in both directions
    # with value +-(edge index + 1) so that the sign tells the direction of travel.
    _, first = np.unique(np.minimum(i, j) * n + np.maximum(i, j), return_index=True)
    ids = first.astype(np.int64) + 1
    adjacency = sp.csr_matrix(
        (np.r_[ids, -ids], (np.r_[i[first], j[first]], np.r_[j[first], i[first]])), shape=(n, n)
    )
    heading = graph.poses[:, 2].copy()
    dtheta = graph.measurements[:, 2]
    for root in roots.tolist():
        order, predecessors = breadth_first_order(adjacency, root, directed=False)
        children = order[1:]
        parents = predecessors[children]
        signed = np.asarray(adjacency[parents, children]).ravel().astype(np.int64)
        step = (np.sign(signed) * dtheta[np.abs(signed) - 1]).tolist()
        h = heading.tolist()
        for parent, child, delta in zip(parents.tolist(), children.tolist(), step, strict=True):
            h[child] = h[parent] + delta
        heading = np.asarray(h)
    return heading


def _weighted_laplacian(
    graph: PoseGraph, weight: NDArray[np.float64], column: NDArray[np.int64], size: int
) -> sp.csc_matrix:
    """Normal matrix of ``sum_k w_k (v_j - v_i)^2`` restricted to the free vertices."""
    i, j = graph.edge_from, graph.edge_to
    rows = np.r_[i, j, i, j]
    cols = np.r_[i, j, j, i]
    vals = np.r_[weight, weight, -weight, -weight]
    keep = (column[rows] >= 0) & (column[cols] >= 0)
    return sp.csc_matrix((vals[keep], (column[rows[keep]], column[cols[keep]])), shape=(size, size))


def _edge_rhs(
    graph: PoseGraph,
    weight: NDArray[np.float64],
    target: NDArray[np.float64],
    known: NDArray[np.float64],
) -> NDArray[np.float64]:
    """Right-hand side of ``sum_k w_k |v_j - v_i - target_k|^2`` given the fixed values ``known``.

    ``known`` holds the values of fixed vertices (zeros elsewhere); returned per vertex.
    """
    i, j = graph.edge_from, graph.edge_to
    shape = (graph.num_vertices,) + target.shape[1:]
    w = weight.reshape((-1,) + (1,) * (target.ndim - 1))
    fixed = graph.fixed.reshape((-1,) + (1,) * (target.ndim - 1))
    # Move fixed endpoints to the right-hand side: residual = v_j - v_i - target.
    adjusted = target - np.where(fixed[j], known[j], 0.0) + np.where(fixed[i], known[i], 0.0)
    rhs = np.zeros(shape)
    np.add.at(rhs, j, w * adjusted)
    np.add.at(rhs, i, -w * adjusted)
    return rhs


def lago_initialization(graph: PoseGraph) -> NDArray[np.float64]:
    """Return LAGO initial poses for ``graph`` (fixed vertices keep their poses).

    Headings: weighted least squares on ``theta_j - theta_i = dtheta + 2 pi k`` (weights: inverse
    heading variance). Positions: ``p_j - p_i = R(theta_i) t`` weighted by the isotropic part of
    the translation information (an initialisation only; Ceres then solves the exact problem).
    Every connected component must contain at least one fixed vertex (the optimiser makes sure).
    """
    n, e = graph.num_vertices, graph.num_edges
    if e == 0:
        return graph.poses.copy()
    i, j = graph.edge_from, graph.edge_to
    fixed = graph.fixed
    free = np.flatnonzero(~fixed)
    column = np.full(n, -1, dtype=np.int64)
    column[free] = np.arange(free.size)
    covariance = np.linalg.inv(graph.information)
    out = graph.poses.copy()
    if free.size == 0:
        return out

    # 1) headings: theta_j - theta_i = dtheta + 2 pi k, k from the spanning-tree estimate.
    tree = _spanning_tree_headings(graph, np.flatnonzero(fixed))
    dtheta = graph.measurements[:, 2]
    regularised = dtheta + TWO_PI * np.round((tree[j] - tree[i] - dtheta) / TWO_PI)
    heading_weight = 1.0 / covariance[:, 2, 2]
    rhs = _edge_rhs(graph, heading_weight, regularised, graph.poses[:, 2])
    out[free, 2] = _solve_spd(
        _weighted_laplacian(graph, heading_weight, column, free.size), rhs[free]
    )

    # 2) positions given headings: p_j - p_i = R(theta_i) t_ij.
    c, s = np.cos(out[i, 2]), np.sin(out[i, 2])
    t = graph.measurements[:, :2]
    world_t = np.stack([c * t[:, 0] - s * t[:, 1], s * t[:, 0] + c * t[:, 1]], axis=1)
    position_weight = 2.0 / (covariance[:, 0, 0] + covariance[:, 1, 1])
    rhs = _edge_rhs(graph, position_weight, world_t, graph.poses[:, :2])
    out[free, :2] = _solve_spd(
        _weighted_laplacian(graph, position_weight, column, free.size), rhs[free]
    )
    return out
