"""The cognitive (experience) map of the paper: standard, scene-integration and compact forms.

A :class:`CognitiveMap` consumes the front end's events (:mod:`cogmap_core.events`):

- ``standard``: every proposed vertex and every link is kept (OpenRatSLAM's experience map with
  the paper's batch optimisation instead of graph relaxation).
- ``scene_integration``: after each optimisation, revisited vertices that converged onto the
  vertex they revisit are removed and their edges re-attached: the end of a loop-closure edge
  that lies within ``integration_radius`` of the other end (the paper's cases A, B, C), and a
  vertex created while revisiting -- joined by an edge to a vertex at least
  ``integration_min_age`` seconds older -- that lies within that radius of it.
- ``compact``: neighborhood fields decline proposed vertices whose movement since the current
  vertex is not novel (g(d, theta) = (1 + alpha d)(1 + beta |theta|) <= delta) and merge the
  sequential edges; plus scene integration; plus removal of short edges.

Loop-closure edges are clustered by time (:mod:`cogmap_core.clustering`); one batch optimisation
of the whole map runs when a cluster closes and at the end of the data. Sequential edges never
trigger an optimisation.

Storage is flat numpy arrays indexed by vertex id (vertex ids are the front end's experience
ids) and by edge index, grown by doubling, so 10^5 vertices stay cheap. A vertex the map declined
or removed stays addressable as an *alias*: the vertex that absorbed it plus its relative pose in
that vertex's frame, so later links to it land exactly where the evidence says.
"""

from __future__ import annotations

import math
import time as wallclock
from dataclasses import dataclass
from enum import IntEnum, StrEnum

import numpy as np
from numpy.typing import NDArray

from cogmap_core.clustering import Cluster, LoopClosureClusterer
from cogmap_core.config import MapParams
from cogmap_core.errors import EventError
from cogmap_core.events import CreateVertex, LinkToVertex, MapEvent, Odometry, SetCurrentVertex
from cogmap_core.geometry import (
    between,
    compose,
    compose_scalar,
    inverse_scalar,
    relative_to_polar,
    wrap_scalar,
)
from cogmap_core.optimizer import EdgeModel, OptimizerOptions, edge_terms, optimize_pose_graph
from cogmap_core.posegraph import PoseGraph

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
Pose = tuple[float, float, float] | list[float]
_ZERO: Pose = (0.0, 0.0, 0.0)
TWO_PI = 2.0 * math.pi


class MapMode(StrEnum):
    """Which of the paper's three maps to build."""

    STANDARD = "standard"
    SCENE_INTEGRATION = "scene_integration"
    COMPACT = "compact"


class EdgeKind(IntEnum):
    """Kinds of edges."""

    SEQUENTIAL = 0
    LOOP_CLOSURE = 1


def neighborhood_field(d: float, theta: float, alpha: float, beta: float) -> float:
    """The paper's neighborhood field g(d, theta) = (1 + alpha d)(1 + beta |theta|)."""
    return (1.0 + alpha * d) * (1.0 + beta * abs(theta))


@dataclass(frozen=True, slots=True)
class OptimizationRecord:
    """What one batch optimisation did.

    Attributes:
        cluster_id: the cluster whose closing triggered it (-1 for the end-of-data run without
            an open cluster).
        time: data time of the optimisation.
        vertices: vertices in the optimised graph; edges likewise.
        iterations: Ceres iterations.
        initial_cost, final_cost: robust cost before and after.
        wall_s: wall time of the optimisation itself.
        integrated: vertices removed by scene integration afterwards.
        short_edges_removed: vertices removed by short-edge removal afterwards.

    """

    cluster_id: int
    time: float
    vertices: int
    edges: int
    iterations: int
    initial_cost: float
    final_cost: float
    wall_s: float
    integrated: int
    short_edges_removed: int


@dataclass(frozen=True, slots=True)
class MapSnapshot:
    """A copy of the live part of the map (for viewers, exporters and reports).

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


class CognitiveMap:
    """The cognitive map (experience map) built from front-end events.

    Args:
        mode: ``standard``, ``scene_integration`` or ``compact``.
        params: the map parameters (paper values by default); change them with :meth:`set_params`.

    """

    def __init__(self, mode: MapMode | str, params: MapParams | None = None) -> None:
        """Create an empty map."""
        self.mode = MapMode(mode)
        self._declines = self.mode is MapMode.COMPACT  # neighborhood fields
        self._integrates = self.mode is not MapMode.STANDARD  # scene integration
        self._removes_short = self.mode is MapMode.COMPACT
        self.params = params or MapParams()
        self.clusterer = LoopClosureClusterer(self.params.t_interval, self.params.t_total)
        cap = 256
        # vertices, indexed by experience id
        self._pose = np.zeros((cap, 3))
        self._vtime = np.zeros(cap)
        self._view = np.zeros(cap, dtype=np.int64)
        self._alive = np.zeros(cap, dtype=bool)
        self._alias = np.full(cap, -1, dtype=np.int64)
        self._alias_offset = np.zeros((cap, 3))
        self._num_ids = 0
        # edges
        self._efrom = np.zeros(cap, dtype=np.int64)
        self._eto = np.zeros(cap, dtype=np.int64)
        self._erel = np.zeros((cap, 3))
        self._etime = np.zeros(cap)
        self._ekind = np.zeros(cap, dtype=np.int8)
        self._ecluster = np.full(cap, -1, dtype=np.int64)
        self._ealive = np.zeros(cap, dtype=bool)
        self._num_edges_total = 0
        # live counts
        self.num_vertices = 0
        self.num_edges = 0
        self.num_loop_edges = 0
        # robot state: current vertex and motion accumulated in its frame
        self._current = -1
        self._accum = [0.0, 0.0, 0.0]
        self._last_time = -math.inf
        self._integrated_until = -math.inf
        self._edges_at_last_optimization = 0
        self._optimized_once = False
        # records
        self.optimizations: list[OptimizationRecord] = []
        self.declined_vertices = 0
        self.integrated_vertices = 0
        self.short_edge_vertices = 0
        self._hist_time: list[float] = []
        self._hist_vertices: list[int] = []
        self._hist_edges: list[int] = []

    # ----------------------------------------------------------------------------------------
    # public API
    # ----------------------------------------------------------------------------------------

    def set_params(self, params: MapParams) -> None:
        """Change parameters; they apply to the events that follow."""
        self.params = params
        self.clusterer.t_interval = params.t_interval
        self.clusterer.t_total = params.t_total

    def apply(self, event: MapEvent) -> None:
        """Apply one front-end event (see :mod:`cogmap_core.events`).

        Raises:
            EventError: the event breaks the contract (time going backwards, unknown vertex id,
                non-sequential new id, non-finite values, link before any vertex).

        """
        t = event.time
        if not t >= self._last_time:  # also catches NaN
            if not math.isfinite(t):
                raise EventError(f"event time {event.time!r} is not finite; drop or fix the event")
            raise EventError(
                f"event time {t:.6f} s is earlier than the previous event "
                f"({self._last_time:.6f} s); events must come in time order"
            )
        if t == math.inf:
            raise EventError(f"event time {event.time!r} is not finite; drop or fix the event")
        self._last_time = t
        if self.clusterer.open_cluster is not None:
            closed = self.clusterer.due(t)
            if closed is not None:
                self._optimize(closed.cluster_id, t)
                self._record_size(t)
        if type(event) is Odometry:
            self._on_odometry(event)
            return  # odometry never changes the map's size
        if isinstance(event, Odometry):
            self._on_odometry(event)
        elif isinstance(event, CreateVertex):
            self._on_create(event)
        elif isinstance(event, LinkToVertex):
            self._on_link(event)
        elif isinstance(event, SetCurrentVertex):
            self._on_set(event)
        else:
            raise EventError(f"unknown event type {type(event).__name__}")
        self._record_size(t)

    def apply_all(self, events: list[MapEvent] | tuple[MapEvent, ...]) -> None:
        """Apply several events in order (same result as :meth:`apply` on each, faster).

        Runs of odometry events -- most of a replay -- take an inlined path; every other event,
        and any odometry event that could close a cluster or breaks the contract, goes through
        :meth:`apply`.
        """
        odometry = Odometry
        isfinite = math.isfinite
        cos, sin, pi = math.cos, math.sin, math.pi
        clusterer = self.clusterer
        for event in events:
            if type(event) is not odometry:
                self.apply(event)
                continue
            t = event.time
            trans, rot = event.translation, event.rotation
            if not (t >= self._last_time and t != math.inf and isfinite(trans) and isfinite(rot)):
                self.apply(event)  # raises the contract error
                continue
            cluster = clusterer.open_cluster
            if cluster is not None and (
                t - cluster.last_time >= clusterer.t_interval
                or t - cluster.start_time > clusterer.t_total
            ):
                self.apply(event)  # closes the cluster: optimisation and integration
                continue
            self._last_time = t
            acc = self._accum
            heading = (acc[2] + rot + pi) % TWO_PI - pi
            acc[2] = heading
            acc[0] += trans * cos(heading)
            acc[1] += trans * sin(heading)

    def finish(self, time: float | None = None) -> None:
        """End of data: close the open cluster (if any) and run its batch optimisation."""
        t = self._last_time if time is None else float(time)
        closed = self.clusterer.finish(t)
        if closed is not None:
            self._optimize(closed.cluster_id, t)
            self._record_size(t)

    @property
    def clusters(self) -> list[Cluster]:
        """All loop-closure clusters so far."""
        return self.clusterer.clusters

    @property
    def current_vertex(self) -> int:
        """Id of the current vertex (-1 before the first vertex)."""
        return self._current

    def current_pose(self) -> FloatArray:
        """Dead-reckoned robot pose: current vertex pose composed with the accumulated motion."""
        if self._current < 0:
            return np.array(self._accum)
        return np.array(compose_scalar(self._pose[self._current].tolist(), self._accum))

    def resolve(self, vertex_id: int) -> tuple[int, FloatArray]:
        """The live vertex standing for ``vertex_id`` and the pose of the latter in its frame."""
        target, offset = self._resolve(vertex_id)
        return target, np.array(offset)

    def _resolve(self, vertex_id: int) -> tuple[int, list[float]]:
        if not 0 <= vertex_id < self._num_ids:
            raise EventError(
                f"vertex {vertex_id} does not exist (known ids: 0..{self._num_ids - 1}); "
                "the front end referred to a vertex it never created"
            )
        return int(self._alias[vertex_id]), self._alias_offset[vertex_id].tolist()

    def vertex_pose(self, vertex_id: int) -> FloatArray:
        """Current estimate of the pose of ``vertex_id`` (through its alias if removed)."""
        target, offset = self.resolve(vertex_id)
        return compose(self._pose[target], offset)

    def snapshot(self) -> MapSnapshot:
        """Copy of the live vertices and edges."""
        ids = np.flatnonzero(self._alive[: self._num_ids])
        e = np.flatnonzero(self._ealive[: self._num_edges_total])
        return MapSnapshot(
            vertex_ids=ids.astype(np.int64),
            poses=self._pose[ids].copy(),
            vertex_time=self._vtime[ids].copy(),
            vertex_view=self._view[ids].copy(),
            edge_from=self._efrom[e].copy(),
            edge_to=self._eto[e].copy(),
            edge_rel=self._erel[e].copy(),
            edge_time=self._etime[e].copy(),
            edge_kind=self._ekind[e].copy(),
            edge_cluster=self._ecluster[e].copy(),
            current_vertex=self._current,
            current_pose=self.current_pose(),
        )

    def to_pose_graph(self) -> PoseGraph:
        """The live map as a pose graph (identity information, first live vertex fixed)."""
        snap = self.snapshot()
        index = np.searchsorted(snap.vertex_ids, np.r_[snap.edge_from, snap.edge_to])
        m = snap.edge_from.shape[0]
        fixed = np.zeros(snap.vertex_ids.shape[0], dtype=bool)
        if fixed.size:
            fixed[0] = True
        return PoseGraph(
            vertex_ids=snap.vertex_ids,
            poses=snap.poses,
            edge_from=index[:m],
            edge_to=index[m:],
            measurements=snap.edge_rel,
            information=np.broadcast_to(np.eye(3), (m, 3, 3)).copy(),
            fixed=fixed,
        )

    def size_history(self) -> tuple[FloatArray, IntArray, IntArray]:
        """(time, vertices, edges) after every event that changed the map's size."""
        return (
            np.array(self._hist_time),
            np.array(self._hist_vertices, dtype=np.int64),
            np.array(self._hist_edges, dtype=np.int64),
        )

    # ----------------------------------------------------------------------------------------
    # events
    # ----------------------------------------------------------------------------------------

    def _on_odometry(self, event: Odometry) -> None:
        trans, rot = event.translation, event.rotation
        if not (math.isfinite(trans) and math.isfinite(rot)):
            raise EventError(
                f"odometry at {event.time:.3f} s is not finite "
                f"(translation={trans}, rotation={rot}); fix or drop the message"
            )
        acc = self._accum
        heading = (acc[2] + rot + math.pi) % TWO_PI - math.pi
        acc[2] = heading
        acc[0] += trans * math.cos(heading)
        acc[1] += trans * math.sin(heading)

    def _on_create(self, event: CreateVertex) -> None:
        vid = int(event.vertex)
        if vid != self._num_ids:
            raise EventError(
                f"CreateVertex({vid}) at {event.time:.3f} s: the next vertex id must be "
                f"{self._num_ids} (ids are 0, 1, 2, ... in creation order)"
            )
        self._ensure_vertex_capacity(vid + 1)
        self._num_ids += 1
        self._vtime[vid] = event.time
        self._view[vid] = int(event.view_template)
        rel = tuple(self._accum)
        if self._current < 0:
            self._add_vertex(vid, rel)
            self._set_current(vid, _ZERO)
            return
        if self._declines:
            d = math.hypot(rel[0], rel[1])
            g = neighborhood_field(d, rel[2], self.params.alpha, self.params.beta)
            if g <= self.params.delta:
                # Not novel: decline the vertex; the sequential edges keep merging.
                self._alias[vid] = self._current
                self._alias_offset[vid] = rel
                self.declined_vertices += 1
                return
        self._add_vertex(vid, compose_scalar(self._pose[self._current].tolist(), rel))
        self._add_edge(self._current, vid, rel, event.time, EdgeKind.SEQUENTIAL, -1)
        self._set_current(vid, _ZERO)

    def _on_link(self, event: LinkToVertex) -> None:
        if self._current < 0:
            raise EventError(f"LinkToVertex at {event.time:.3f} s before any vertex was created")
        target, offset = self._resolve(int(event.target))
        if not math.isfinite(event.relative_rad):
            raise EventError(f"LinkToVertex at {event.time:.3f} s has a non-finite relative angle")
        acc = self._accum
        to_experience = (acc[0], acc[1], acc[2] - event.relative_rad)
        rel = compose_scalar(to_experience, inverse_scalar(offset))
        # Every loop closure the front end detects joins the time clustering, so the three maps
        # share one schedule of batch optimisations, even when this map needs no new edge.
        cluster_id, _ = self.clusterer.add_edge(event.time)  # apply() already closed a due one
        if target == self._current:
            return  # the link closes on the vertex we are at (after merges): nothing to add
        self._add_edge(self._current, target, rel, event.time, EdgeKind.LOOP_CLOSURE, cluster_id)

    def _on_set(self, event: SetCurrentVertex) -> None:
        target, offset = self._resolve(int(event.target))
        if not math.isfinite(event.relative_rad):
            raise EventError(
                f"SetCurrentVertex at {event.time:.3f} s has a non-finite relative angle"
            )
        self._set_current(target, (offset[0], offset[1], offset[2] + event.relative_rad))

    # ----------------------------------------------------------------------------------------
    # storage
    # ----------------------------------------------------------------------------------------

    def _ensure_vertex_capacity(self, n: int) -> None:
        cap = self._pose.shape[0]
        if n <= cap:
            return
        new = max(n, 2 * cap)
        self._pose = _grow(self._pose, new)
        self._vtime = _grow(self._vtime, new)
        self._view = _grow(self._view, new)
        self._alive = _grow(self._alive, new)
        self._alias = _grow(self._alias, new, fill=-1)
        self._alias_offset = _grow(self._alias_offset, new)

    def _ensure_edge_capacity(self, n: int) -> None:
        cap = self._efrom.shape[0]
        if n <= cap:
            return
        new = max(n, 2 * cap)
        self._efrom = _grow(self._efrom, new)
        self._eto = _grow(self._eto, new)
        self._erel = _grow(self._erel, new)
        self._etime = _grow(self._etime, new)
        self._ekind = _grow(self._ekind, new)
        self._ecluster = _grow(self._ecluster, new, fill=-1)
        self._ealive = _grow(self._ealive, new)

    def _add_vertex(self, vid: int, pose: Pose) -> None:
        self._pose[vid] = (pose[0], pose[1], wrap_scalar(pose[2]))
        self._alive[vid] = True
        self._alias[vid] = vid
        self._alias_offset[vid] = 0.0
        self.num_vertices += 1

    def _add_edge(
        self, src: int, dst: int, rel: Pose, t: float, kind: EdgeKind, cluster: int
    ) -> int:
        k = self._num_edges_total
        self._ensure_edge_capacity(k + 1)
        self._efrom[k], self._eto[k] = src, dst
        self._erel[k] = (rel[0], rel[1], wrap_scalar(rel[2]))
        self._etime[k] = t
        self._ekind[k] = kind
        self._ecluster[k] = cluster
        self._ealive[k] = True
        self._num_edges_total += 1
        self.num_edges += 1
        if kind == EdgeKind.LOOP_CLOSURE:
            self.num_loop_edges += 1
        return k

    def _remove_edge(self, k: int) -> None:
        if self._ealive[k]:
            self._ealive[k] = False
            self.num_edges -= 1
            if self._ekind[k] == EdgeKind.LOOP_CLOSURE:
                self.num_loop_edges -= 1

    def _set_current(self, vid: int, offset: Pose) -> None:
        self._current = vid
        self._accum = [float(offset[0]), float(offset[1]), wrap_scalar(float(offset[2]))]

    def _record_size(self, t: float) -> None:
        if (
            self._hist_vertices
            and self._hist_vertices[-1] == self.num_vertices
            and self._hist_edges[-1] == self.num_edges
        ):
            return
        if self._hist_time and self._hist_time[-1] == t:
            self._hist_vertices[-1] = self.num_vertices
            self._hist_edges[-1] = self.num_edges
            return
        self._hist_time.append(t)
        self._hist_vertices.append(self.num_vertices)
        self._hist_edges.append(self.num_edges)

    # ----------------------------------------------------------------------------------------
    # optimisation, scene integration, short edges
    # ----------------------------------------------------------------------------------------

    def optimize_now(self, time: float | None = None) -> OptimizationRecord | None:
        """Run one batch optimisation (and, per mode, integration) outside the cluster schedule."""
        t = self._last_time if time is None else float(time)
        return self._optimize(-1, t)

    def _optimize(self, cluster_id: int, t: float) -> OptimizationRecord | None:
        if self._edges_at_last_optimization == self._num_edges_total and self._optimized_once:
            return None  # no edge added since the last optimisation: it would change nothing
        self._edges_at_last_optimization = self._num_edges_total
        self._optimized_once = True
        graph = self.to_pose_graph()
        if graph.num_edges == 0:
            return None
        started = wallclock.perf_counter()
        result = optimize_pose_graph(
            graph,
            OptimizerOptions(
                huber_scale=self.params.huber_scale, initialization="none", function_tolerance=1e-5
            ),
        )
        wall = wallclock.perf_counter() - started
        self._pose[graph.vertex_ids] = result.poses
        integrated = short = 0
        if self._integrates:
            integrated = self._integrate_scenes()
        if self._removes_short:
            short = self._remove_short_edges()
        record = OptimizationRecord(
            cluster_id=cluster_id,
            time=t,
            vertices=graph.num_vertices,
            edges=graph.num_edges,
            iterations=result.iterations,
            initial_cost=result.initial_cost,
            final_cost=result.final_cost,
            wall_s=wall,
            integrated=integrated,
            short_edges_removed=short,
        )
        self.optimizations.append(record)
        return record

    def _live_edges(self) -> IntArray:
        return np.flatnonzero(self._ealive[: self._num_edges_total])

    def _integrate_scenes(self) -> int:
        """Merge revisiting vertices that converged onto the vertex they revisit (cases A, B, C)."""
        removed = 0
        loop = self._live_edges()
        loop = loop[self._ekind[loop] == EdgeKind.LOOP_CLOSURE]
        if loop.size == 0:
            return 0
        p = self.params
        residual_norm = self._edge_residual_norms(loop)
        distance = np.hypot(
            *(self._pose[self._efrom[loop], :2] - self._pose[self._eto[loop], :2]).T
        )
        candidates = loop[
            (distance <= p.integration_radius) & (residual_norm <= p.integration_max_residual)
        ]
        for k in candidates.tolist():  # in edge (time) order
            if not self._ealive[k]:
                continue
            a, b = int(self._efrom[k]), int(self._eto[k])
            newer, older = (a, b) if a > b else (b, a)
            # pose of `newer` in the frame of `older`, from the loop-closure measurement
            # the pose of `newer` in the frame of `older`, as the optimisation converged
            offset = tuple(between(self._pose[older], self._pose[newer]).tolist())
            self._remove_edge(k)
            self._merge_vertex(newer, older, offset)
            removed += 1
        removed += self._integrate_revisits()
        self.integrated_vertices += removed
        return removed

    def _integrate_revisits(self) -> int:
        """Merge new vertices that converged onto an older vertex they are connected to.

        A vertex created since the previous integration that is joined by an edge to a vertex
        at least ``integration_min_age`` seconds older was created while the robot revisited
        mapped territory (it continues from, or closes onto, an old place). If after the
        optimisation it lies within ``integration_radius`` of that old vertex, it is merged into
        it (the nearest such neighbour), its edges re-attached with the optimised relative pose.
        """
        p = self.params
        n = self._num_ids
        since = self._integrated_until
        self._integrated_until = self._last_time
        new = np.flatnonzero(self._alive[:n] & (self._vtime[:n] > since))
        if new.size == 0 or p.integration_radius <= 0:
            return 0
        live = self._live_edges()
        adjacency: dict[int, set[int]] = {}
        for a, b in zip(self._efrom[live].tolist(), self._eto[live].tolist(), strict=True):
            adjacency.setdefault(a, set()).add(b)
            adjacency.setdefault(b, set()).add(a)
        removed = 0
        for u in new.tolist():
            if not self._alive[u]:
                continue
            oldest = self._vtime[u] - p.integration_min_age
            old = [v for v in adjacency.get(u, ()) if self._alive[v] and self._vtime[v] <= oldest]
            if not old:
                continue
            candidates = np.array(old, dtype=np.int64)
            distance = np.hypot(*(self._pose[candidates, :2] - self._pose[u, :2]).T)
            best = int(np.argmin(distance))
            if distance[best] > p.integration_radius:
                continue
            v = int(candidates[best])
            self._merge_vertex(u, v, tuple(between(self._pose[v], self._pose[u]).tolist()))
            removed += 1
            neighbours = adjacency.pop(u, set()) - {u, v}
            adjacency.setdefault(v, set()).update(neighbours)
            adjacency[v].discard(u)
            for w in neighbours:
                adjacency[w].discard(u)
                adjacency[w].add(v)
        return removed

    def _remove_short_edges(self) -> int:
        """Contract edges shorter than the threshold (paper figure "Removing short edges")."""
        removed = 0
        threshold = self.params.short_edge_threshold
        if threshold <= 0:
            return 0
        while True:
            live = self._live_edges()
            if live.size == 0:
                return removed
            delta = self._pose[self._efrom[live], :2] - self._pose[self._eto[live], :2]
            short = live[np.hypot(delta[:, 0], delta[:, 1]) < threshold]
            if short.size == 0:
                self.short_edge_vertices += removed
                return removed
            k = int(short[0])
            src, dst = int(self._efrom[k]), int(self._eto[k])
            rel = tuple(self._erel[k].tolist())
            self._remove_edge(k)
            anchor = int(np.argmax(self._alive))  # the first live vertex is the map's anchor
            if src != anchor:  # the figure removes the edge's first vertex ...
                self._merge_vertex(src, dst, inverse_scalar(rel))
            else:  # ... unless it anchors the map
                self._merge_vertex(dst, src, rel)
            removed += 1

    def _edge_residual_norms(self, edges: IntArray) -> FloatArray:
        model = EdgeModel(self._erel[edges], np.broadcast_to(np.eye(3), (edges.size, 3, 3)))
        res, _ = edge_terms(
            self._pose[self._efrom[edges]], self._pose[self._eto[edges]], model, None, False
        )
        return np.sqrt(np.einsum("ka,ka->k", res, res))

    def _merge_vertex(self, removed: int, kept: int, offset: Pose) -> None:
        """Remove vertex ``removed`` and re-attach its edges to ``kept``.

        ``offset`` is the pose of ``removed`` in the frame of ``kept``. Edges that would join
        ``kept`` to itself are dropped; an edge that would duplicate an existing connection
        between the same two vertices is dropped as redundant.
        """
        live = self._live_edges()
        incident = live[(self._efrom[live] == removed) | (self._eto[live] == removed)]
        neighbours_of_kept = set(
            self._eto[live[self._efrom[live] == kept]].tolist()
            + self._efrom[live[self._eto[live] == kept]].tolist()
        )
        inv_offset = inverse_scalar(offset)
        for k in incident.tolist():
            src, dst = int(self._efrom[k]), int(self._eto[k])
            if src == removed:
                src = kept
                self._erel[k] = compose_scalar(offset, self._erel[k].tolist())
            if dst == removed:
                dst = kept
                self._erel[k] = compose_scalar(self._erel[k].tolist(), inv_offset)
            other = dst if src == kept else src
            if src == dst or other in neighbours_of_kept:
                self._remove_edge(k)
                continue
            self._efrom[k], self._eto[k] = src, dst
            neighbours_of_kept.add(other)
        # Everything that stood for `removed` now stands for `kept`.
        n = self._num_ids
        moved = np.flatnonzero(self._alias[:n] == removed)
        self._alias_offset[moved] = compose(np.array(offset), self._alias_offset[moved])
        self._alias[moved] = kept
        self._alive[removed] = False
        self.num_vertices -= 1
        if self._current == removed:
            self._set_current(kept, compose_scalar(offset, self._accum))


def _grow(array: NDArray, size: int, fill: float = 0) -> NDArray:
    out = np.full((size,) + array.shape[1:], fill, dtype=array.dtype)
    out[: array.shape[0]] = array
    return out


class MapSet:
    """The three maps of the paper built side by side from one event stream."""

    def __init__(
        self, params: MapParams | None = None, modes: tuple[MapMode, ...] | None = None
    ) -> None:
        """Create one :class:`CognitiveMap` per mode (default: all three)."""
        modes = modes or (MapMode.STANDARD, MapMode.SCENE_INTEGRATION, MapMode.COMPACT)
        self.maps: dict[MapMode, CognitiveMap] = {m: CognitiveMap(m, params) for m in modes}

    def apply(self, event: MapEvent) -> None:
        """Apply one event to every map."""
        for cmap in self.maps.values():
            cmap.apply(event)

    def apply_all(self, events: list[MapEvent] | tuple[MapEvent, ...]) -> None:
        """Apply several events to every map."""
        for event in events:
            self.apply(event)

    def finish(self, time: float | None = None) -> None:
        """End of data for every map."""
        for cmap in self.maps.values():
            cmap.finish(time)

    def __getitem__(self, mode: MapMode | str) -> CognitiveMap:
        """The map of one mode."""
        return self.maps[MapMode(mode)]


__all__ = [
    "CognitiveMap",
    "EdgeKind",
    "MapMode",
    "MapSet",
    "MapSnapshot",
    "OptimizationRecord",
    "neighborhood_field",
]
