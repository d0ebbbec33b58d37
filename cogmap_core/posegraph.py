"""A 2D pose graph held in flat numpy arrays (cheap for 10^5 vertices)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray


def _default_fixed(n: int) -> NDArray[np.bool_]:
    return np.zeros(n, dtype=bool)


@dataclass
class PoseGraph:
    """Vertices (SE(2) poses) and relative-pose edges with information matrices.

    Attributes:
        vertex_ids: ``(N,)`` user-facing ids (g2o ids, experience ids).
        poses: ``(N, 3)`` x, y, theta.
        edge_from: ``(E,)`` index (not id) of each edge's first vertex.
        edge_to: ``(E,)`` index of each edge's second vertex.
        measurements: ``(E, 3)`` relative pose of ``to`` in the frame of ``from`` (dx, dy, dtheta).
        information: ``(E, 3, 3)`` symmetric positive-definite information matrices.
        fixed: ``(N,)`` vertices held constant by the optimiser.
        loop_closure: ``(E,)`` which edges are loop closures (a robust loop-closure model
            judges only these); None: the edges between vertices whose ids are not consecutive
            (:meth:`loop_closures`).

    """

    vertex_ids: NDArray[np.int64]
    poses: NDArray[np.float64]
    edge_from: NDArray[np.int64]
    edge_to: NDArray[np.int64]
    measurements: NDArray[np.float64]
    information: NDArray[np.float64]
    fixed: NDArray[np.bool_] = field(default_factory=lambda: _default_fixed(0))
    loop_closure: NDArray[np.bool_] | None = None

    def __post_init__(self) -> None:
        """Normalise dtypes and shapes."""
        self.vertex_ids = np.asarray(self.vertex_ids, dtype=np.int64).reshape(-1)
        self.poses = np.asarray(self.poses, dtype=np.float64).reshape(-1, 3)
        self.edge_from = np.asarray(self.edge_from, dtype=np.int64).reshape(-1)
        self.edge_to = np.asarray(self.edge_to, dtype=np.int64).reshape(-1)
        self.measurements = np.asarray(self.measurements, dtype=np.float64).reshape(-1, 3)
        self.information = np.asarray(self.information, dtype=np.float64).reshape(-1, 3, 3)
        if self.fixed.shape != (len(self.poses),):
            self.fixed = _default_fixed(len(self.poses))
        if self.loop_closure is not None:
            self.loop_closure = np.asarray(self.loop_closure, dtype=bool).reshape(-1)

    @property
    def num_vertices(self) -> int:
        """Number of vertices."""
        return int(self.poses.shape[0])

    @property
    def num_edges(self) -> int:
        """Number of edges."""
        return int(self.edge_from.shape[0])

    def copy(self) -> PoseGraph:
        """Deep copy."""
        return PoseGraph(
            self.vertex_ids.copy(),
            self.poses.copy(),
            self.edge_from.copy(),
            self.edge_to.copy(),
            self.measurements.copy(),
            self.information.copy(),
            self.fixed.copy(),
            None if self.loop_closure is None else self.loop_closure.copy(),
        )

    def loop_closures(self) -> NDArray[np.bool_]:
        """Which edges are loop closures: as set, else those joining non-consecutive vertex ids.

        The second is how g2o benchmark files mark them: odometry joins ``i`` and ``i + 1``.
        """
        if self.loop_closure is not None:
            return self.loop_closure
        ids = self.vertex_ids
        return np.abs(ids[self.edge_to] - ids[self.edge_from]) != 1

    def with_poses(self, poses: NDArray[np.float64]) -> PoseGraph:
        """Same graph with other vertex poses."""
        g = self.copy()
        g.poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3).copy()
        return g
