"""The graph store of the cognitive map: vertices, edges, aliases and adjacency.

Vertices are indexed by the front end's experience ids (``0, 1, 2, ...``); edges by an edge
index in creation order. Both live in flat numpy arrays grown by doubling, so 10^5 vertices stay
cheap; adjacency is one small dict per vertex (neighbour -> edge index), so the edges of a vertex
are found without scanning the map. Between two vertices there is at most one live edge.

A vertex the map declined or removed stays addressable as an *alias*: the live vertex that
absorbed it plus its relative pose in that vertex's frame, so later links to it land exactly where
the evidence says.

An edge is weighed by the noise model (:mod:`~cogmap_core.edge_noise`) unless it carries its own
covariance (``edge_cov``): a merged revisit run's chain, marginalised onto the two vertices it
joined (:mod:`~cogmap_core.marginalisation`). Such an *evidence edge* (``edge_evidence``) is a
measurement, not a corridor -- its two vertices can lie metres apart along a bend -- so it is in
the optimisation (:meth:`MapGraph.to_pose_graph`) but not in what is drawn, exported as the
layout or searched as ground (:meth:`MapGraph.path_edges`, :meth:`MapGraph.snapshot`).

This module knows nothing of the paper's mechanisms; they live in
:mod:`~cogmap_core.neighborhood_fields`, :mod:`~cogmap_core.scene_integration`,
:mod:`~cogmap_core.short_edges` and :mod:`~cogmap_core.relocalisation`.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import IntEnum
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from cogmap_core.edge_noise import OdometryNoise, edge_information, information_unit
from cogmap_core.errors import EventError, StateError
from cogmap_core.geometry import (
    between_scalar,
    compose,
    compose_covariance,
    compose_scalar,
    inverse_scalar,
    relative_to_polar,
    wrap_scalar,
)
from cogmap_core.posegraph import PoseGraph

if TYPE_CHECKING:
    from scipy.spatial import cKDTree

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
Pose = tuple[float, float, float]


class EdgeKind(IntEnum):
    """Kinds of edges."""

    SEQUENTIAL = 0
    LOOP_CLOSURE = 1


@dataclass(frozen=True, slots=True)
class MapSnapshot:
    """A copy of the live part of the map (for viewers, exporters and reports).

    Its edges are the ground driven (:meth:`MapGraph.path_edges`): the evidence edges, which the
    optimisation weighs but which are no corridor, are left out.

    Edge fields follow OpenRatSLAM: ``d``, ``heading_rad`` and ``facing_rad`` give the relative
    pose of ``edge_to`` in the frame of ``edge_from``; ``edge_rel`` is the same as (dx, dy, dtheta).
    ``edge_from``/``edge_to`` are vertex ids.
    """

    vertex_ids: IntArray
    poses: FloatArray
    vertex_time: FloatArray
    vertex_view: IntArray
    edge_from: IntArray
    edge_to: IntArray
    edge_rel: FloatArray
    edge_time: FloatArray
    edge_kind: NDArray[np.int8]
    edge_cluster: IntArray
    current_vertex: int
    current_pose: FloatArray

    @property
    def edge_d(self) -> FloatArray:
        """Edge lengths ``d`` (m)."""
        return relative_to_polar(self.edge_rel)[0]

    @property
    def edge_heading_rad(self) -> FloatArray:
        """Direction of travel relative to the source vertex's heading."""
        return relative_to_polar(self.edge_rel)[1]

    @property
    def edge_facing_rad(self) -> FloatArray:
        """Heading change from source to target."""
        return relative_to_polar(self.edge_rel)[2]

    def edge_ends(self) -> tuple[IntArray, IntArray]:
        """Per edge, the row (in this snapshot's vertex arrays) of its first and second vertex."""
        return _edge_rows(self.vertex_ids, self.edge_from, self.edge_to)


def _edge_rows(
    vertex_ids: IntArray, edge_from: IntArray, edge_to: IntArray
) -> tuple[IntArray, IntArray]:
    """Per edge, the row in ascending ``vertex_ids`` of its first and second vertex."""
    rows = np.searchsorted(vertex_ids, np.r_[edge_from, edge_to])
    m = edge_from.shape[0]
    return rows[:m], rows[m:]


#: The graph's per-vertex arrays (one row per vertex id) and per-edge arrays (one per edge index).
VERTEX_ARRAYS = ("pose", "vertex_time", "view", "alive", "alias", "alias_offset")
EDGE_ARRAYS = (
    "edge_from", "edge_to", "edge_rel", "edge_time", "edge_kind", "edge_cluster", "edge_alive",
    "edge_held", "edge_cov",
)  # fmt: skip
#: What a new graph's arrays hold past the rows in use.
_FILL = {"alias": -1, "edge_cluster": -1}
#: Arrays a state written before they existed lacks (``load_state`` fills them with zeros):
#: ``edge_held``, the links merges rest on -- none held; ``edge_cov``, the merged runs' evidence
#: -- none kept.
_ADDED_LATER = ("edge_held", "edge_cov")
_INITIAL_CAPACITY = 256


def nearest_vertex(
    poses: FloatArray, point: Sequence[float] | FloatArray, tree: cKDTree | None = None
) -> tuple[int, float] | None:
    """The row of ``poses`` nearest to place ``point`` and its distance (m); None when empty.

    The one rule for picking a map's vertex by a place -- the vertex a click inspects, the map a
    route's click lies on, the vertex a route's end snaps to: the distance in x, y (``np.hypot``
    over ``poses[:, :2]`` to ``point[:2]``), the first row on a tie (``argmin``).

    ``tree``: a :class:`scipy.spatial.cKDTree` of ``poses[:, :2]``, for many look-ups on one
    large map (:meth:`cogmap_core.routes.RouteMap.snap`). The tree's query is used instead: its
    distance is the square root of the summed squares, which can differ from ``np.hypot`` in
    the last bit, and on an exact tie it takes the row it reaches first.
    """
    if poses.shape[0] == 0:
        return None
    if tree is not None:
        distance, row = tree.query(np.asarray(point, dtype=np.float64)[:2])
        return int(row), float(distance)
    d = np.hypot(poses[:, 0] - point[0], poses[:, 1] - point[1])
    k = int(np.argmin(d))
    return k, float(d[k])


def grow_array(array: NDArray, size: int, fill: float = 0) -> NDArray:
    """A copy of ``array`` with ``size`` rows; the new rows hold ``fill``."""
    out = np.full((size,) + array.shape[1:], fill, dtype=array.dtype)
    out[: array.shape[0]] = array
    return out


class MapGraph:
    """Vertices, edges, aliases and adjacency of one cognitive map."""

    def __init__(self) -> None:
        """An empty graph."""
        cap = _INITIAL_CAPACITY
        self.pose = np.zeros((cap, 3))
        self.vertex_time = np.zeros(cap)
        self.view = np.zeros(cap, dtype=np.int64)
        self.alive = np.zeros(cap, dtype=bool)
        self.alias = np.full(cap, -1, dtype=np.int64)
        self.alias_offset = np.zeros((cap, 3))
        self.num_ids = 0
        self.edge_from = np.zeros(cap, dtype=np.int64)
        self.edge_to = np.zeros(cap, dtype=np.int64)
        self.edge_rel = np.zeros((cap, 3))
        self.edge_time = np.zeros(cap)
        self.edge_kind = np.zeros(cap, dtype=np.int8)
        self.edge_cluster = np.full(cap, -1, dtype=np.int64)
        self.edge_alive = np.zeros(cap, dtype=bool)
        # edge_held[k]: loop closure k is one a merge rests on (hold_edge)
        self.edge_held = np.zeros(cap, dtype=bool)
        # edge_cov[k]: the covariance of edge k's measurement (m, rad) where it is an evidence
        # edge (module doc; its variances are positive), else zeros (the noise model weighs it)
        self.edge_cov = np.zeros((cap, 3, 3))
        self.num_edges_total = 0
        self.adjacency: list[dict[int, int]] = []
        # absorbed[v]: ids whose alias is v (besides v itself), to re-point them on a merge
        self._absorbed: list[list[int]] = []
        self.num_vertices = 0
        self.num_edges = 0
        self.num_loop_edges = 0
        #: bumped whenever an edge's ends change (a merge, a state loaded): what an index of the
        #: graph's structure checks to know it must be rebuilt (not saved with the graph)
        self.revision = 0
        #: an exact, faster :meth:`graph_distance_below` (the compiled replay installs
        #: :class:`~cogmap_core.compiled_search.PathSearch` while it replays), or None
        self.path_search: Callable[[int, int, float], bool] | None = None

    # ------------------------------------------------------------------ vertices
    def new_id(self, vertex_id: int, time: float, view: int) -> None:
        """Register the next experience id (alive or not is decided by the caller)."""
        if vertex_id != self.num_ids:
            raise EventError(
                f"CreateVertex({vertex_id}) at {time:.3f} s: the next vertex id must be "
                f"{self.num_ids} (ids are 0, 1, 2, ... in creation order)"
            )
        n = vertex_id + 1
        cap = self.pose.shape[0]
        if n > cap:
            new = max(n, 2 * cap)
            self.pose = grow_array(self.pose, new)
            self.vertex_time = grow_array(self.vertex_time, new)
            self.view = grow_array(self.view, new)
            self.alive = grow_array(self.alive, new)
            self.alias = grow_array(self.alias, new, fill=-1)
            self.alias_offset = grow_array(self.alias_offset, new)
        self.num_ids = n
        self.vertex_time[vertex_id] = time
        self.view[vertex_id] = view
        self.adjacency.append({})
        self._absorbed.append([])

    def add_vertex(self, vertex_id: int, pose: Pose | list[float]) -> None:
        """Make a registered id a live vertex at ``pose``."""
        self.pose[vertex_id] = (pose[0], pose[1], wrap_scalar(pose[2]))
        self.alive[vertex_id] = True
        self.alias[vertex_id] = vertex_id
        self.alias_offset[vertex_id] = 0.0
        self.num_vertices += 1

    def add_alias(self, vertex_id: int, target: int, offset: Pose | list[float]) -> None:
        """Make a registered id an alias of the live vertex ``target`` (pose ``offset`` in it)."""
        self.alias[vertex_id] = target
        self.alias_offset[vertex_id] = offset
        self._absorbed[target].append(vertex_id)

    def resolve(self, vertex_id: int) -> tuple[int, list[float]]:
        """The live vertex standing for ``vertex_id`` and the pose of the latter in its frame."""
        if not 0 <= vertex_id < self.num_ids:
            raise EventError(
                f"vertex {vertex_id} does not exist (known ids: 0..{self.num_ids - 1}); "
                "the front end referred to a vertex it never created"
            )
        return int(self.alias[vertex_id]), self.alias_offset[vertex_id].tolist()

    def pose_of(self, vertex_id: int) -> Pose:
        """Map pose of ``vertex_id`` (through its alias if it was declined or removed)."""
        target, offset = self.resolve(vertex_id)
        return compose_scalar(self.pose[target].tolist(), offset)

    def live_ids(self) -> IntArray:
        """Ids of the live vertices, ascending."""
        return np.flatnonzero(self.alive[: self.num_ids]).astype(np.int64)

    def first_live(self) -> int:
        """The oldest live vertex (the map's anchor), or -1."""
        live = np.flatnonzero(self.alive[: self.num_ids])
        return int(live[0]) if live.size else -1

    # ------------------------------------------------------------------ edges
    def edge_between(self, a: int, b: int) -> int:
        """Index of the live edge joining ``a`` and ``b`` (either direction), or -1."""
        return self.adjacency[a].get(b, -1)

    def add_edge(
        self, src: int, dst: int, rel: Pose | list[float], t: float, kind: EdgeKind, cluster: int
    ) -> int:
        """Add an edge ``src -> dst`` with relative pose ``rel`` (of dst in src's frame)."""
        k = self.num_edges_total
        cap = self.edge_from.shape[0]
        if k + 1 > cap:
            new = 2 * cap
            self.edge_from = grow_array(self.edge_from, new)
            self.edge_to = grow_array(self.edge_to, new)
            self.edge_rel = grow_array(self.edge_rel, new)
            self.edge_time = grow_array(self.edge_time, new)
            self.edge_kind = grow_array(self.edge_kind, new)
            self.edge_cluster = grow_array(self.edge_cluster, new, fill=-1)
            self.edge_alive = grow_array(self.edge_alive, new)
            self.edge_held = grow_array(self.edge_held, new)
            self.edge_cov = grow_array(self.edge_cov, new)
        self.edge_from[k], self.edge_to[k] = src, dst
        self.edge_rel[k] = (rel[0], rel[1], wrap_scalar(rel[2]))
        self.edge_time[k] = t
        self.edge_kind[k] = kind
        self.edge_cluster[k] = cluster
        self.edge_cov[k] = 0.0
        self.num_edges_total += 1
        self._attach(k)
        return k

    def _attach(self, k: int) -> None:
        """Make edge ``k`` a live edge between its two vertices (adjacency and counts)."""
        a, b = int(self.edge_from[k]), int(self.edge_to[k])
        self.edge_alive[k] = True
        self.adjacency[a][b] = k
        self.adjacency[b][a] = k
        self.num_edges += 1
        if self.edge_kind[k] == EdgeKind.LOOP_CLOSURE:
            self.num_loop_edges += 1

    def _reexpress(
        self, k: int, to_src: Pose | list[float] | None, to_dst: Pose | list[float] | None
    ) -> None:
        """Edge ``k``'s measurement (and own covariance) for ends moved into other frames.

        ``to_src``, ``to_dst``: the pose of its old first / second vertex in the frame of the
        vertex that now stands for it; None where that end stays. The covariance is in the
        measurement's own frame, so only a change at the second end changes it.
        """
        rel = self.edge_rel[k].tolist()
        if to_src is not None:
            rel = compose_scalar(to_src, rel)
        if to_dst is not None:
            from_dst = inverse_scalar(to_dst)
            if self.edge_cov[k, 0, 0] > 0:  # evidence; the offset is exact: only its frame
                cov = compose_covariance(self.edge_cov[k], from_dst, np.zeros((3, 3)))
                self.edge_cov[k] = cov
            rel = compose_scalar(rel, from_dst)
        self.edge_rel[k] = rel

    def remove_edge(self, k: int) -> None:
        """Remove edge ``k`` (no-op if already removed)."""
        if not self.edge_alive[k]:
            return
        self.edge_alive[k] = False
        a, b = int(self.edge_from[k]), int(self.edge_to[k])
        if self.adjacency[a].get(b) == k:
            del self.adjacency[a][b]
        if self.adjacency[b].get(a) == k:
            del self.adjacency[b][a]
        self.num_edges -= 1
        if self.edge_kind[k] == EdgeKind.LOOP_CLOSURE:
            self.num_loop_edges -= 1

    def add_evidence_edge(
        self, src: int, dst: int, rel: Pose | list[float], cov: FloatArray, t: float, cluster: int
    ) -> int:
        """Add an evidence edge ``src -> dst`` (module doc): a loop closure of covariance ``cov``.

        ``cov``: of ``rel`` in its own frame (:func:`~cogmap_core.geometry.compose_covariance`),
        in metres and radians.
        """
        k = self.add_edge(src, dst, rel, t, EdgeKind.LOOP_CLOSURE, cluster)
        self.edge_cov[k] = cov
        return k

    def hold_edge(self, k: int) -> None:
        """Mark loop closure ``k`` as one a merge rests on (it stays marked if re-attached).

        Scene integration merges a revisit run only when the links that bracket it are kept by
        the loop model; a later optimisation must not then reject them while the merge stands
        (:func:`~cogmap_core.cluster_consistency.overrules_a_merge`).
        """
        if self.edge_kind[k] == EdgeKind.LOOP_CLOSURE:
            self.edge_held[k] = True

    def live_edges(self) -> IntArray:
        """Indices of the live edges, in creation order."""
        return np.flatnonzero(self.edge_alive[: self.num_edges_total]).astype(np.int64)

    @property
    def edge_evidence(self) -> NDArray[np.bool_]:
        """Per edge index (the arrays' capacity), whether it is an evidence edge (module doc)."""
        return self.edge_cov[:, 0, 0] > 0

    def path_edges(self) -> IntArray:
        """Indices of the live edges that are ground the robot drove (no evidence edge)."""
        m = self.num_edges_total
        return np.flatnonzero(self.edge_alive[:m] & (self.edge_cov[:m, 0, 0] <= 0)).astype(np.int64)

    def path_rows(self) -> NDArray[np.bool_]:
        """Per edge of :meth:`to_pose_graph` (in its order), whether :meth:`snapshot` has it.

        For figures computed on the pose graph and shown on the snapshot's edges.
        """
        return self.edge_cov[self.live_edges(), 0, 0] <= 0

    # ------------------------------------------------------------------ merging
    def merge_vertex(self, removed: int, kept: int, offset: Pose | list[float]) -> None:
        """Remove vertex ``removed`` and re-attach its edges to ``kept``.

        ``offset`` is the pose of ``removed`` in the frame of ``kept``. An edge that would join
        ``kept`` to itself is dropped; an edge that would duplicate an existing connection of
        ``kept`` to the same vertex is dropped as redundant (the existing edge stays). Every id
        that stood for ``removed`` stands for ``kept`` afterwards.
        """
        self.revision += 1
        kept_adjacency = self.adjacency[kept]
        for other, k in list(self.adjacency[removed].items()):
            del self.adjacency[removed][other]
            del self.adjacency[other][removed]
            if other == kept or other in kept_adjacency:
                self.remove_edge(k)
                continue
            if self.edge_from[k] == removed:
                self.edge_from[k] = kept
                self._reexpress(k, offset, None)
            else:
                self.edge_to[k] = kept
                self._reexpress(k, None, offset)
            kept_adjacency[other] = k
            self.adjacency[other][kept] = k
        moved = [removed, *self._absorbed[removed]]
        self._absorbed[removed] = []
        index = np.asarray(moved, dtype=np.int64)
        self.alias_offset[index] = compose(np.asarray(offset), self.alias_offset[index])
        self.alias[index] = kept
        self._absorbed[kept].extend(moved)
        self.alive[removed] = False
        self.num_vertices -= 1

    def standing_for(self, vertex_id: int) -> list[int]:
        """The ids whose alias live vertex ``vertex_id`` is, besides itself (a copy)."""
        return list(self._absorbed[vertex_id])

    def revive_vertex(self, vertex_id: int, moved: Sequence[int]) -> None:
        """Make a merged vertex live again where the map now places it (a merge split again).

        Its pose is the one its alias gives it now. ``moved``: the ids that stood for it,
        besides itself, when it was merged (:meth:`standing_for`); they stand for it again, at
        the poses the map gives them now. Its edges are put back by :meth:`restore_edge`.
        """
        if self.alive[vertex_id]:
            raise StateError(f"vertex {vertex_id} is live: there is no merge to split")
        pose = self.pose_of(vertex_id)
        offsets = [between_scalar(pose, self.pose_of(i)) for i in moved]
        self.revision += 1
        for i in (vertex_id, *moved):
            self._absorbed[int(self.alias[i])].remove(i)
        self.pose[vertex_id] = pose
        self.alias[vertex_id] = vertex_id
        self.alias_offset[vertex_id] = 0.0
        for i, offset in zip(moved, offsets, strict=True):
            self.alias[i] = vertex_id
            self.alias_offset[i] = offset
        self._absorbed[vertex_id] = list(moved)
        self.alive[vertex_id] = True
        self.num_vertices += 1

    def restore_edge(
        self, k: int, src: int, dst: int, rel: Pose | list[float], cov: FloatArray
    ) -> bool:
        """Put edge ``k`` back as it was measured, ``src -> dst`` with ``rel`` and ``cov``.

        The ids stand for the live vertices they resolve to now, the measurement re-expressed as
        :meth:`merge_vertex` re-expresses it. Where that would join a vertex to itself or
        duplicate a connection, the edge stays removed (False). A live edge ``k`` is taken off
        its ends first.
        """
        self.remove_edge(k)
        self.revision += 1
        a, to_src = self.resolve(src)
        b, to_dst = self.resolve(dst)
        if a == b or b in self.adjacency[a]:
            return False
        self.edge_from[k], self.edge_to[k] = a, b
        self.edge_rel[k], self.edge_cov[k] = rel, cov
        self._reexpress(k, to_src, to_dst)
        self._attach(k)
        return True

    # ------------------------------------------------------------------ state
    def state_dict(self) -> dict[str, Any]:
        """The graph as plain data (copies), what :meth:`load_state` restores.

        The rows in use of every array (:data:`VERTEX_ARRAYS`: ``num_ids`` rows,
        :data:`EDGE_ARRAYS`: ``num_edges_total``), ``adjacency`` (per vertex id, neighbour ->
        edge index, in the dict's own order: merges and short-edge removal iterate it),
        ``absorbed`` (per vertex id, the ids whose alias it is besides itself) and the counts.
        """
        n, m = self.num_ids, self.num_edges_total
        state: dict[str, Any] = {name: getattr(self, name)[:n].copy() for name in VERTEX_ARRAYS}
        state.update({name: getattr(self, name)[:m].copy() for name in EDGE_ARRAYS})
        state["adjacency"] = [dict(a) for a in self.adjacency]
        state["absorbed"] = [list(a) for a in self._absorbed]
        state["num_ids"], state["num_edges_total"] = n, m
        state["num_vertices"] = self.num_vertices
        state["num_edges"] = self.num_edges
        state["num_loop_edges"] = self.num_loop_edges
        return state

    def load_state(self, state: dict[str, Any]) -> None:
        """Become the graph :meth:`state_dict` described (its arrays grown as a new graph's).

        A state written before an array of ``_ADDED_LATER`` existed loads with it all zeros.

        Raises:
            StateError: parts that do not fit together (an array or the adjacency of another
                size than the counts, live vertices other than ``num_vertices``).

        """
        n, m = int(state["num_ids"]), int(state["num_edges_total"])
        self.revision += 1
        for name in (*VERTEX_ARRAYS, *EDGE_ARRAYS):
            like = getattr(self, name)  # dtype and row shape
            rows = n if name in VERTEX_ARRAYS else m
            if name in _ADDED_LATER and name not in state:
                saved = np.zeros((rows, *like.shape[1:]), dtype=like.dtype)
            else:
                saved = np.asarray(state[name])
            if saved.shape != (rows, *like.shape[1:]):
                raise StateError(f"graph.{name} does not match the graph")
            saved = saved.astype(like.dtype, copy=False)
            setattr(self, name, grow_array(saved, max(_INITIAL_CAPACITY, rows), _FILL.get(name, 0)))
        self.num_ids, self.num_edges_total = n, m
        self.num_vertices = int(state["num_vertices"])
        self.num_edges = int(state["num_edges"])
        self.num_loop_edges = int(state["num_loop_edges"])
        if len(state["adjacency"]) != n:
            raise StateError("adjacency does not match the graph")
        self.adjacency = [dict(a) for a in state["adjacency"]]
        if len(state["absorbed"]) != n:
            raise StateError("aliases do not match the graph")
        self._absorbed = [list(a) for a in state["absorbed"]]
        if int(np.count_nonzero(self.alive[:n])) != self.num_vertices:
            raise StateError("graph's live vertices do not match its header")

    # ------------------------------------------------------------------ queries
    def graph_distance_below(self, source: int, target: int, limit: float) -> bool:
        """Whether a path of edges from ``source`` to ``target`` is shorter than ``limit`` (m).

        Dijkstra over measured edge lengths, stopped at ``limit``: cheap when the answer is no
        path that short, which is what a consistency test needs to know. With a
        :attr:`path_search` installed, that answers (the same answer, compiled); else
        :meth:`python_distance_below`.
        """
        if self.path_search is not None:
            return self.path_search(source, target, limit)
        return self.python_distance_below(source, target, limit)

    def python_distance_below(self, source: int, target: int, limit: float) -> bool:
        """:meth:`graph_distance_below` in Python over the adjacency: the reference search."""
        if source == target:
            return limit > 0
        best = {source: 0.0}
        heap = [(0.0, source)]
        rel = self.edge_rel
        while heap:
            dist, v = heapq.heappop(heap)
            if dist >= limit:
                return False
            if v == target:
                return True
            if dist > best.get(v, math.inf):
                continue
            for w, k in self.adjacency[v].items():
                nd = dist + math.hypot(rel[k, 0], rel[k, 1])
                if nd < best.get(w, math.inf) and nd < limit:
                    best[w] = nd
                    heapq.heappush(heap, (nd, w))
        return False

    # ------------------------------------------------------------------ views
    def snapshot(self, current_vertex: int, current_pose: FloatArray) -> MapSnapshot:
        """Copy of the live vertices and the edges of ground driven (:meth:`path_edges`)."""
        ids = self.live_ids()
        e = self.path_edges()
        return MapSnapshot(
            vertex_ids=ids,
            poses=self.pose[ids].copy(),
            vertex_time=self.vertex_time[ids].copy(),
            vertex_view=self.view[ids].copy(),
            edge_from=self.edge_from[e].copy(),
            edge_to=self.edge_to[e].copy(),
            edge_rel=self.edge_rel[e].copy(),
            edge_time=self.edge_time[e].copy(),
            edge_kind=self.edge_kind[e].copy(),
            edge_cluster=self.edge_cluster[e].copy(),
            current_vertex=current_vertex,
            current_pose=current_pose,
        )

    def edge_information(
        self,
        edges: IntArray,
        link_sigmas: tuple[float, float] | None = None,
        odometry: OdometryNoise | None = None,
    ) -> FloatArray:
        """``(len(edges), 3, 3)`` information of edges, as :meth:`to_pose_graph` weighs them."""
        info = edge_information(self.edge_kind[edges], self.edge_rel[edges], link_sigmas, odometry)
        own = np.flatnonzero(self.edge_cov[edges, 0, 0] > 0)
        if own.size:
            info[own] = information_unit(link_sigmas) * np.linalg.inv(self.edge_cov[edges[own]])
        return info

    def edge_covariances(
        self,
        edges: IntArray,
        link_sigmas: tuple[float, float] | None = None,
        odometry: OdometryNoise | None = None,
    ) -> FloatArray:
        """``(len(edges), 3, 3)`` covariances (m, rad) of edges, as the pose graph weighs them.

        An evidence edge's own; else the inverse of the noise model's information.
        """
        info = edge_information(self.edge_kind[edges], self.edge_rel[edges], link_sigmas, odometry)
        cov = information_unit(link_sigmas) * np.linalg.inv(info)
        own = self.edge_cov[edges, 0, 0] > 0
        cov[own] = self.edge_cov[edges[own]]
        return cov

    def to_pose_graph(
        self,
        link_sigmas: tuple[float, float] | None = None,
        odometry: OdometryNoise | None = None,
    ) -> PoseGraph:
        """The live map as a pose graph, first live vertex fixed.

        Information is the identity (the paper), or with ``link_sigmas`` (a loop closure's
        position and heading precision) each edge's expected precision, the odometry edges' as
        ``odometry`` says (:func:`~cogmap_core.edge_noise.edge_information`). An edge with its
        own covariance weighs as its inverse, in the same unit.
        """
        ids = self.live_ids()
        e = self.live_edges()
        edge_from, edge_to = _edge_rows(ids, self.edge_from[e], self.edge_to[e])
        fixed = np.zeros(ids.shape[0], dtype=bool)
        if fixed.size:
            fixed[0] = True
        information = self.edge_information(e, link_sigmas, odometry)
        return PoseGraph(
            vertex_ids=ids,
            poses=self.pose[ids].copy(),
            edge_from=edge_from,
            edge_to=edge_to,
            measurements=self.edge_rel[e].copy(),
            information=information,
            fixed=fixed,
            loop_closure=self.edge_kind[e] == EdgeKind.LOOP_CLOSURE,
        )
