"""The optimiser's Ceres problem: chunked parameter blocks, grouped edges, one snapshot.

(:mod:`~cogmap_core.optimizer` explains the layout: vertices in chunks, edges grouped by the
pair of chunks they join, and one zero-valued snapshot block that evaluates every edge in one
numpy pass before the groups copy their slices.)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyceres
from numpy.typing import NDArray

from cogmap_core.edge_residuals import EdgeLosses, EdgeModel, edge_terms, subset_loss

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


@dataclass(frozen=True, slots=True)
class Plan:
    """How the edges are split into residual blocks and where their Jacobians go.

    Edges are sorted by the pair of chunks they join; each run of one pair is a *group* (one
    residual block). ``dense`` (owned by :class:`Snapshot`) holds every group's Jacobian blocks
    as Ceres lays them out -- per group and parameter block, row-major ``(3 edges, 3 n_block)``
    -- one after the other; ``target[e, end, a, b]`` is where the derivative of residual ``a`` of
    edge ``e`` with respect to component ``b`` of its ``end`` (0 from, 1 to) goes. Positions that
    are not targets are structural zeros and stay zero.

    Attributes:
        group_start: ``(G + 1,)`` first edge of each group (and the number of edges).
        group_chunks: the chunks (parameter blocks) of each group, one or two.
        spans: per group and parameter block, the ``(start, end)`` of its block in ``dense``.
        target: ``(E * 18,)`` flat targets in ``dense`` (-1: none, the edge is a self-loop).
        local_from, local_to: per edge, its vertices' indices in the concatenation of its
            group's chunks (for a group evaluated away from the snapshot).
        dense_size: length of ``dense``.

    """

    group_start: IntArray
    group_chunks: list[list[int]]
    spans: list[list[tuple[int, int]]]
    target: IntArray
    local_from: IntArray
    local_to: IntArray
    dense_size: int


def plan_groups(
    edge_from: IntArray,
    edge_to: IntArray,
    chunk_of: IntArray,
    chunk_start: IntArray,
    chunk_len: IntArray,
) -> Plan:
    """Split edges (already sorted by chunk pair) into groups and plan their Jacobian layout."""
    e = edge_from.shape[0]
    ends = np.stack([edge_from, edge_to], axis=1)  # (E, 2)
    chunk = chunk_of[ends]
    lo = chunk.min(axis=1)
    hi = chunk.max(axis=1)
    key = lo * (int(chunk_of.max()) + 1) + hi
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    g = starts.size
    counts = np.diff(np.r_[starts, e])
    group_of = np.repeat(np.arange(g), counts)
    q = np.arange(e) - starts[group_of]  # edge index within its group
    rows = 3 * counts
    g_lo, g_hi = lo[starts], hi[starts]
    two = g_lo != g_hi
    size0 = rows * 3 * chunk_len[g_lo]
    size1 = np.where(two, rows * 3 * chunk_len[g_hi], 0)
    off0 = np.cumsum(np.r_[0, (size0 + size1)[:-1]]) if g else np.zeros(0, dtype=np.int64)
    off1 = off0 + size0
    block = (chunk != lo[:, None]).astype(np.int64)  # 0: the group's first chunk, 1: its second
    within = ends - chunk_start[chunk]  # vertex index inside its chunk
    cols = 3 * chunk_len[chunk]  # (E, 2) columns of the parameter block of each end
    offset = np.where(block == 0, off0[group_of][:, None], off1[group_of][:, None])
    base = offset + 3 * q[:, None] * cols + 3 * within  # (E, 2)
    a = np.arange(3)[None, None, :, None]
    b = np.arange(3)[None, None, None, :]
    target = base[:, :, None, None] + a * cols[:, :, None, None] + b
    target[edge_from == edge_to] = -1  # a self-loop's two derivatives cancel: no entry
    local = within + block * chunk_len[lo][:, None]
    lo_list, hi_list, two_list = g_lo.tolist(), g_hi.tolist(), two.tolist()
    o0, o1 = off0.tolist(), off1.tolist()
    s0, s1 = size0.tolist(), size1.tolist()
    group_chunks: list[list[int]] = []
    spans: list[list[tuple[int, int]]] = []
    for k in range(g):
        if two_list[k]:
            group_chunks.append([lo_list[k], hi_list[k]])
            spans.append([(o0[k], o0[k] + s0[k]), (o1[k], o1[k] + s1[k])])
        else:
            group_chunks.append([lo_list[k]])
            spans.append([(o0[k], o0[k] + s0[k])])
    return Plan(
        group_start=np.r_[starts, e].astype(np.int64),
        group_chunks=group_chunks,
        spans=spans,
        target=target.reshape(-1),
        local_from=local[:, 0].copy(),
        local_to=local[:, 1].copy(),
        dense_size=int(off1[-1] + s1[-1]) if g else 0,
    )


class Snapshot:
    """All edge residuals and Jacobians at the point Ceres is currently evaluating."""

    def __init__(
        self,
        poses: FloatArray,
        edge_from: IntArray,
        edge_to: IntArray,
        model: EdgeModel,
        losses: EdgeLosses,
        plan: Plan,
        num_chunks: int,
    ) -> None:
        self.poses = poses.copy()
        self.edge_from = edge_from
        self.edge_to = edge_to
        self.model = model
        self.losses = losses  # edges in the snapshot's (sorted) order
        self.chunk_bytes: list[bytes | None] = [None] * num_chunks
        self.residuals = np.zeros(3 * edge_from.shape[0])
        self.dense = np.zeros(plan.dense_size)
        keep = plan.target >= 0
        self.dense_target = plan.target[keep]
        self.dense_source = np.flatnonzero(keep) if not keep.all() else None
        self.has_jacobians = False

    def take(self, chunk_values: list[FloatArray], with_jacobians: bool) -> None:
        """Evaluate every edge at the chunks' values (Jacobians too when asked)."""
        self.poses.reshape(-1)[:] = np.concatenate(chunk_values)
        self.chunk_bytes = [values.tobytes() for values in chunk_values]
        x = self.poses
        res, jac = edge_terms(
            x[self.edge_from], x[self.edge_to], self.model, self.losses, with_jacobians
        )
        self.residuals[:] = res.reshape(-1)
        if jac is not None:
            flat = jac.reshape(-1)
            self.dense[self.dense_target] = (
                flat if self.dense_source is None else flat[self.dense_source]
            )
        self.has_jacobians = with_jacobians


class SnapshotCost(pyceres.CostFunction):
    """A zero residual depending on every chunk: evaluating it takes the snapshot."""

    def __init__(self, snapshot: Snapshot, chunk_sizes: list[int]) -> None:
        super().__init__()
        self.snapshot = snapshot
        self.set_num_residuals(1)
        self.set_parameter_block_sizes(chunk_sizes)

    def Evaluate(  # noqa: N802 (Ceres' name)
        self, parameters: list[FloatArray], residuals: FloatArray, jacobians: list | None
    ) -> bool:
        """Ceres' evaluation of this residual block."""
        self.snapshot.take(parameters, jacobians is not None)
        residuals[0] = 0.0
        if jacobians is not None:
            for block in jacobians:
                if block is not None:
                    block.fill(0.0)
        return True


class EdgeGroupCost(pyceres.CostFunction):
    """The edges joining one chunk to itself or to one other chunk (contiguous in edge order)."""

    def __init__(self, snapshot: Snapshot, plan: Plan, group: int, block_sizes: list[int]) -> None:
        super().__init__()
        first, end = int(plan.group_start[group]), int(plan.group_start[group + 1])
        self.set_num_residuals(3 * (end - first))
        self.set_parameter_block_sizes(block_sizes)
        self.snapshot = snapshot
        self.plan = plan
        self.first, self.end = first, end
        self.chunks = plan.group_chunks[group]
        self.spans = plan.spans[group]
        self.r0, self.r1 = 3 * first, 3 * end
        self.res_view = snapshot.residuals[self.r0 : self.r1]
        self.jac_views = [snapshot.dense[a:b] for a, b in self.spans]
        self.two = len(self.chunks) == 2

    def Evaluate(  # noqa: N802 (Ceres' name)
        self, parameters: list[FloatArray], residuals: FloatArray, jacobians: list | None
    ) -> bool:
        """Ceres' evaluation of this residual block."""
        snap = self.snapshot
        stored = snap.chunk_bytes
        chunks = self.chunks
        if (
            (jacobians is None or snap.has_jacobians)
            and stored[chunks[0]] == parameters[0].tobytes()
            and (not self.two or stored[chunks[1]] == parameters[1].tobytes())
        ):
            residuals[:] = self.res_view
            if jacobians is not None:
                views = self.jac_views
                jacobians[0][:] = views[0]
                if self.two:
                    jacobians[1][:] = views[1]
            return True
        # Ceres evaluated this block at another point than the snapshot: compute it on its own.
        plan = self.plan
        x = np.concatenate(parameters).reshape(-1, 3)
        edges = slice(self.first, self.end)
        res, jac = edge_terms(
            x[plan.local_from[edges]],
            x[plan.local_to[edges]],
            snap.model.subset(edges),
            [subset_loss(rows, kernel, edges) for rows, kernel in snap.losses],
            jacobians is not None,
        )
        residuals[:] = res.reshape(-1)
        if jacobians is not None and jac is not None:
            target = plan.target[18 * self.first : 18 * self.end]
            keep = target >= 0
            values = jac.reshape(-1)[keep]
            target = target[keep]
            for block, (a, b) in zip(jacobians, self.spans, strict=True):
                if block is not None:
                    block.fill(0.0)
                    mine = (target >= a) & (target < b)
                    block[target[mine] - a] = values[mine]
        return True
