"""The cognitive (experience) map of the paper: standard, scene-integration and compact forms.

A :class:`CognitiveMap` consumes the front end's events (:mod:`cogmap_core.events`) and composes
the paper's mechanisms, one module each:

- :mod:`~cogmap_core.map_graph` -- the graph store (vertices, edges, aliases, adjacency);
- :mod:`~cogmap_core.neighborhood_fields` -- "Adding Sparse vertices through Neighborhood
  Fields" (compact map only);
- :mod:`~cogmap_core.clustering` -- "Clustering Loop Closure Edges": one batch optimisation
  (:mod:`~cogmap_core.optimizer`, Huber loss on Ceres) per cluster and at the end of the data;
- :mod:`~cogmap_core.scene_integration` -- "Scene Integration" after each optimisation
  (scene_integration and compact maps);
- :mod:`~cogmap_core.short_edges` -- "Removing Short Edges" after each optimisation (compact);
- :mod:`~cogmap_core.relocalisation` -- the consistency test a relocalisation must pass before
  the map follows it (all maps; the paper's open problem of false loop closures).

The three modes:

- ``standard``: OpenRatSLAM's experience map with the paper's batch optimisation instead of
  graph relaxation. Every proposed vertex is added. A link adds a loop-closure edge unless the two
  vertices are already joined (either direction, any edge kind): like OpenRatSLAM's
  ``ExperienceMap::on_create_link``, the map keeps one edge per pair, so re-walking a known route
  -- which links consecutive old vertices that a sequential edge already joins -- does not pile
  up parallel edges. The refused link's evidence (its relative pose) is dropped: the existing
  edge already constrains the pair, and the robot is still re-localised by the set-current event
  that follows. Every link still joins the time clustering, so the three maps share one schedule
  of batch optimisations.
- ``scene_integration``: the standard map plus scene integration.
- ``compact``: neighborhood fields decline proposed vertices whose movement since the current
  vertex is not novel and merge the sequential edges; plus scene integration; plus removal of
  short edges.

Vertex ids are the front end's experience ids; a vertex the map declined or removed is an alias
of the vertex that absorbed it, so later links and relocalisations on it land where the evidence
says.
"""

from __future__ import annotations

import math
import time as wallclock
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cogmap_core.clustering import Cluster, LoopClosureClusterer, joins
from cogmap_core.config import MapParams
from cogmap_core.errors import EventError, StateError
from cogmap_core.events import CreateVertex, LinkToVertex, MapEvent, Odometry, SetCurrentVertex
from cogmap_core.geometry import TWO_PI, compose, compose_scalar, inverse_scalar, wrap_scalar
from cogmap_core.map_graph import EdgeKind, MapGraph, MapSnapshot
from cogmap_core.map_modes import ALL_MODES, MapMode
from cogmap_core.neighborhood_fields import is_novel, neighborhood_field
from cogmap_core.optimizer import (
    OptimizationResult,
    OptimizerOptions,
    optimize_pose_graph,
    rejected_loop_closures,
)
from cogmap_core.posegraph import PoseGraph
from cogmap_core.relocalisation import (
    RelocalisationCheck,
    RelocalisationGate,
    RobotInMap,
)
from cogmap_core.scene_integration import SceneIntegration
from cogmap_core.short_edges import remove_short_edges

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
_ZERO = (0.0, 0.0, 0.0)


@dataclass(frozen=True, slots=True)
class OptimizationRecord:
    """What one batch optimisation did.

    Attributes:
        cluster_id: the cluster whose closing triggered it (-1 outside the cluster schedule).
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

    def state_dict(self) -> dict[str, Any]:
        """The record as plain data (every attribute)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> OptimizationRecord:
        """The record :meth:`state_dict` described."""
        return cls(**state)


@dataclass(slots=True)
class MapCounters:
    """What happened to the front end's proposals (explains the map's size).

    Attributes:
        proposed: vertices the front end proposed (CreateVertex events).
        declined: proposals declined by neighborhood fields (compact).
        integrated: vertices removed by scene integration.
        short_edges: vertices removed by short-edge removal.
        split: vertices made live again because a link their merge rested on was rejected
            (:mod:`~cogmap_core.merge_records`; no longer counted in ``integrated``).
        links: links (loop closures) the front end emitted.
        duplicate_links: links that added no edge (the pair was already joined, or the link
            closed on the vertex the robot is at).
        refused_relocalisations: links and set-current events refused by the consistency test.

    """

    proposed: int = 0
    declined: int = 0
    integrated: int = 0
    short_edges: int = 0
    split: int = 0
    links: int = 0
    duplicate_links: int = 0
    refused_relocalisations: int = 0


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
        self.graph = MapGraph()
        self.integration = SceneIntegration(keeps_evidence=self.mode is MapMode.SCENE_INTEGRATION)
        self.counters = MapCounters()
        self.gate = RelocalisationGate()
        # robot state: current vertex, motion accumulated in its frame, distance driven since
        self._current = -1
        self._accum = [0.0, 0.0, 0.0]
        self._travelled = 0.0
        self._last_rotation = 0.0  # of the latest odometry event (timing term of the gate)
        self._last_time = -math.inf
        # the last link: (time, target, accepted), so its set-current event follows its fate
        self._last_link: tuple[float, int, bool] | None = None
        self._edges_at_last_optimization = 0
        self._optimized_once = False
        self.optimizations: list[OptimizationRecord] = []
        self.refused: list[RelocalisationCheck] = []
        self._hist_time: list[float] = []
        self._hist_vertices: list[int] = []
        self._hist_edges: list[int] = []

    # ----------------------------------------------------------------------------------------
    # public API
    # ----------------------------------------------------------------------------------------

    @property
    def num_vertices(self) -> int:
        """Live vertices."""
        return self.graph.num_vertices

    @property
    def num_edges(self) -> int:
        """Live edges, evidence edges included (those the optimisation weighs)."""
        return self.graph.num_edges

    @property
    def num_loop_edges(self) -> int:
        """Live loop-closure edges."""
        return self.graph.num_loop_edges

    def rejected_loop_edges(self) -> NDArray[np.bool_]:
        """Per edge of :meth:`snapshot` (in its order), whether the loop model rejects it now.

        (:func:`~cogmap_core.optimizer.rejected_loop_closures` at the map's current estimate;
        the evidence edges, which the snapshot leaves out, are left out here too.)
        """
        rejected = rejected_loop_closures(self.to_pose_graph(), self.params.loop_closure_model())
        return rejected[self.graph.path_rows()]

    @property
    def declined_vertices(self) -> int:
        """Proposed vertices declined by neighborhood fields."""
        return self.counters.declined

    @property
    def integrated_vertices(self) -> int:
        """Vertices removed by scene integration."""
        return self.counters.integrated

    @property
    def short_edge_vertices(self) -> int:
        """Vertices removed by short-edge removal."""
        return self.counters.short_edges

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
        kind = type(event)
        if kind is Odometry:
            self._on_odometry(event)  # type: ignore[arg-type]
            return  # odometry never changes the map's size
        if kind is CreateVertex:
            self._on_create(event)  # type: ignore[arg-type]
        elif kind is LinkToVertex:
            self._on_link(event)  # type: ignore[arg-type]
        elif kind is SetCurrentVertex:
            self._on_set(event)  # type: ignore[arg-type]
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
            trans, rot = event.translation, event.rotation  # type: ignore[union-attr]
            if not (t >= self._last_time and t != math.inf and isfinite(trans) and isfinite(rot)):
                self.apply(event)  # raises the contract error
                continue
            cluster = clusterer.open_cluster
            if cluster is not None and not joins(
                cluster.start_time, cluster.last_time, t, clusterer.t_interval, clusterer.t_total
            ):
                self.apply(event)  # closes the cluster: optimisation and integration
                continue
            self._last_time = t
            acc = self._accum
            heading = (acc[2] + rot + pi) % TWO_PI - pi
            acc[2] = heading
            acc[0] += trans * cos(heading)
            acc[1] += trans * sin(heading)
            self._travelled += abs(trans)
            self._last_rotation = rot

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
        return np.array(compose_scalar(self.graph.pose[self._current].tolist(), self._accum))

    def resolve(self, vertex_id: int) -> tuple[int, FloatArray]:
        """The live vertex standing for ``vertex_id`` and the pose of the latter in its frame."""
        target, offset = self.graph.resolve(vertex_id)
        return target, np.array(offset)

    def vertex_pose(self, vertex_id: int) -> FloatArray:
        """Current estimate of the pose of ``vertex_id`` (through its alias if removed)."""
        target, offset = self.resolve(vertex_id)
        return compose(self.graph.pose[target], offset)

    def snapshot(self) -> MapSnapshot:
        """Copy of the live vertices and edges (no evidence edge: :class:`MapSnapshot`)."""
        return self.graph.snapshot(self._current, self.current_pose())

    def to_pose_graph(self) -> PoseGraph:
        """The live map as the pose graph its optimisation uses (first live vertex fixed)."""
        return self.graph.to_pose_graph(self.params.link_sigmas(), self.params.odometry_noise())

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
        self._travelled += abs(trans)
        self._last_rotation = rot

    def _on_create(self, event: CreateVertex) -> None:
        graph = self.graph
        vid = int(event.vertex)
        graph.new_id(vid, event.time, int(event.view_template))
        self.counters.proposed += 1
        rel = (self._accum[0], self._accum[1], self._accum[2])
        if self._current < 0:
            graph.add_vertex(vid, rel)
            self._set_current(vid, _ZERO)
            return
        p = self.params
        if self._declines and not is_novel(rel, p.alpha, p.beta, p.delta):
            # Not novel: decline the vertex; the sequential edges keep merging.
            graph.add_alias(vid, self._current, rel)
            self.counters.declined += 1
            return
        parent = self._current
        graph.add_vertex(vid, compose_scalar(graph.pose[parent].tolist(), rel))
        graph.add_edge(parent, vid, rel, event.time, EdgeKind.SEQUENTIAL, -1)
        if self._integrates:
            self.integration.on_vertex(vid, parent, event.time)
        self._set_current(vid, _ZERO)

    def _relocalisation_ok(self, target: int, relative_rad: float, time: float) -> bool:
        robot = RobotInMap(
            self._current,
            (self._accum[0], self._accum[1], self._accum[2]),
            self._travelled,
            self._last_rotation,
        )
        check = self.gate.check(self.graph, robot, target, relative_rad, time, self.params)
        if not check.accepted:
            self.refused.append(check)
            self.counters.refused_relocalisations += 1
        return check.accepted

    def _on_link(self, event: LinkToVertex) -> None:
        if self._current < 0:
            raise EventError(f"LinkToVertex at {event.time:.3f} s before any vertex was created")
        target, offset = self.graph.resolve(int(event.target))
        if not math.isfinite(event.relative_rad):
            raise EventError(f"LinkToVertex at {event.time:.3f} s has a non-finite relative angle")
        self.counters.links += 1
        # Every loop closure the front end detects joins the time clustering, so the three maps
        # share one schedule of batch optimisations, whatever each map makes of it.
        cluster_id, _ = self.clusterer.add_edge(event.time)  # apply() already closed a due one
        accepted = self._relocalisation_ok(int(event.target), event.relative_rad, event.time)
        self._last_link = (event.time, int(event.target), accepted)
        if not accepted:
            return
        acc = self._accum
        to_place = (acc[0], acc[1], acc[2] - event.relative_rad)
        if target == self._current or self.graph.edge_between(self._current, target) >= 0:
            self.counters.duplicate_links += 1
        else:
            rel = compose_scalar(to_place, inverse_scalar(offset))
            self.graph.add_edge(
                self._current, target, rel, event.time, EdgeKind.LOOP_CLOSURE, cluster_id
            )
        self._relocalised(int(event.target), to_place, event.time)

    def _on_set(self, event: SetCurrentVertex) -> None:
        target, offset = self.graph.resolve(int(event.target))
        if not math.isfinite(event.relative_rad):
            raise EventError(
                f"SetCurrentVertex at {event.time:.3f} s has a non-finite relative angle"
            )
        link, self._last_link = self._last_link, None
        if link is not None and link[:2] == (event.time, int(event.target)):
            if not link[2]:
                return  # its link was refused: the robot stays where the map has it
        elif self._current >= 0:  # a relocalisation without a link: test it the same way
            if not self._relocalisation_ok(int(event.target), event.relative_rad, event.time):
                return
            acc = self._accum
            self._relocalised(
                int(event.target), (acc[0], acc[1], acc[2] - event.relative_rad), event.time
            )
            target, offset = self.graph.resolve(int(event.target))
        self._set_current(target, (offset[0], offset[1], offset[2] + event.relative_rad))

    def _relocalised(self, target: int, to_place: tuple[float, float, float], t: float) -> None:
        """An accepted relocalisation: a revisit run may close (and be integrated) here."""
        if self._integrates:
            merged = self.integration.on_relocalised(
                self.graph, target, to_place, t, self.params, self._current
            )
            if merged:
                self.counters.integrated += merged
                self._follow_merges()

    def _follow_merges(self) -> None:
        """Keep the robot where it is when its current vertex was merged into another."""
        if self._current >= 0 and not self.graph.alive[self._current]:
            kept, offset = self.graph.resolve(self._current)
            travelled = self._travelled
            self._set_current(kept, compose_scalar(offset, self._accum))
            self._travelled = travelled

    # ----------------------------------------------------------------------------------------
    # state
    # ----------------------------------------------------------------------------------------

    def state_dict(self) -> dict[str, Any]:
        """Everything that decides what the map does next, as plain data (copies).

        ``mode`` and ``params`` (:meth:`MapParams.to_dict`), the parts' own state (``graph``,
        ``clusterer``, ``integration``, ``gate``: their ``state_dict()``), the records
        (``optimizations``, ``refused``: lists of their ``state_dict()``), ``counters``, the
        robot's state (``robot``: ``current`` vertex, ``accum``-ulated motion in its frame,
        distance ``travelled`` since, ``last_rotation``, ``last_time``, ``last_link`` as
        ``[time, target, accepted]`` or None), when it last optimised, and its ``size_history``
        (``time``, ``vertices``, ``edges`` arrays). :meth:`from_state` builds the map again.
        """
        times, vertices, edges = self.size_history()
        link = self._last_link
        return {
            "mode": self.mode.value,
            "params": self.params.to_dict(),
            "graph": self.graph.state_dict(),
            "clusterer": self.clusterer.state_dict(),
            "integration": self.integration.state_dict(),
            "gate": self.gate.state_dict(),
            "optimizations": [r.state_dict() for r in self.optimizations],
            "refused": [c.state_dict() for c in self.refused],
            "counters": asdict(self.counters),
            "robot": {
                "current": self._current,
                "accum": list(self._accum),
                "travelled": self._travelled,
                "last_rotation": self._last_rotation,
                "last_time": self._last_time,
                "last_link": None if link is None else list(link),
            },
            "edges_at_last_optimization": self._edges_at_last_optimization,
            "optimized_once": self._optimized_once,
            "size_history": {"time": times, "vertices": vertices, "edges": edges},
        }

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> CognitiveMap:
        """The map :meth:`state_dict` described.

        Raises:
            StateError: parts that do not fit together (:meth:`load_state`).

        """
        cmap = cls(MapMode(state["mode"]), MapParams.from_dict(state["params"]))
        cmap.load_state(state)
        return cmap

    def load_state(self, state: dict[str, Any]) -> None:
        """Become the map :meth:`state_dict` described (a map of the same mode).

        Raises:
            StateError: another mode, or parts that do not fit together: the graph's
                (:meth:`MapGraph.load_state`), or counters that do not add up with the graph
                (they are shown as they were saved, never derived).

        """
        if MapMode(state["mode"]) is not self.mode:
            raise StateError(f"a {state['mode']} map's state cannot make a {self.mode} map")
        self.set_params(MapParams.from_dict(state["params"]))
        self.graph.load_state(state["graph"])
        self.clusterer.load_state(state["clusterer"])
        self.integration.load_state(state["integration"])
        self.gate.load_state(state["gate"])
        self.optimizations = [OptimizationRecord.from_state(r) for r in state["optimizations"]]
        self.refused = [RelocalisationCheck.from_state(c) for c in state["refused"]]
        self.counters = MapCounters(**state["counters"])
        self._check_counters()
        robot = state["robot"]
        self._current = int(robot["current"])
        self._accum = [float(v) for v in robot["accum"]]
        self._travelled = float(robot["travelled"])
        self._last_rotation = float(robot["last_rotation"])
        self._last_time = float(robot["last_time"])
        link = robot["last_link"]
        self._last_link = None if link is None else (float(link[0]), int(link[1]), bool(link[2]))
        self._edges_at_last_optimization = int(state["edges_at_last_optimization"])
        self._optimized_once = bool(state["optimized_once"])
        history = state["size_history"]
        self._hist_time = np.asarray(history["time"]).tolist()
        self._hist_vertices = np.asarray(history["vertices"]).tolist()
        self._hist_edges = np.asarray(history["edges"]).tolist()

    def _check_counters(self) -> None:
        """Refuse counters that do not add up with the graph (:meth:`load_state`).

        Every proposal made an id; every id that is not a live vertex was declined, integrated or
        removed as a short edge; every refused relocalisation is on record.
        """
        counters, graph = self.counters, self.graph
        removed = counters.declined + counters.integrated + counters.short_edges
        if (
            counters.proposed != graph.num_ids
            or removed != graph.num_ids - graph.num_vertices
            or counters.refused_relocalisations != len(self.refused)
        ):
            raise StateError("counters do not match the graph")

    def place_robot(self, vid: int, offset: tuple[float, float, float]) -> None:
        """Put the robot at ``offset`` in the frame of live vertex ``vid`` (a map made by hand)."""
        self._set_current(vid, offset)

    def _set_current(self, vid: int, offset: tuple[float, float, float] | list[float]) -> None:
        self._current = vid
        self._accum = [float(offset[0]), float(offset[1]), wrap_scalar(float(offset[2]))]
        self._travelled = 0.0

    def _record_size(self, t: float) -> None:
        n_v, n_e = self.graph.num_vertices, self.graph.num_edges
        if self._hist_vertices and self._hist_vertices[-1] == n_v and self._hist_edges[-1] == n_e:
            return
        if self._hist_time and self._hist_time[-1] == t:
            self._hist_vertices[-1] = n_v
            self._hist_edges[-1] = n_e
            return
        self._hist_time.append(t)
        self._hist_vertices.append(n_v)
        self._hist_edges.append(n_e)

    # ----------------------------------------------------------------------------------------
    # optimisation, scene integration, short edges
    # ----------------------------------------------------------------------------------------

    def optimize_now(self, time: float | None = None) -> OptimizationRecord | None:
        """Run one batch optimisation (and, per mode, integration) outside the cluster schedule."""
        t = self._last_time if time is None else float(time)
        return self._optimize(-1, t)

    def _optimize(self, cluster_id: int, t: float) -> OptimizationRecord | None:
        graph = self.graph
        if self._edges_at_last_optimization == graph.num_edges_total and self._optimized_once:
            return None  # no edge added since the last optimisation: it would change nothing
        # the edges added since the last optimisation: the robust loop model weighs the
        # hypothesis that its new links are true against the one that they are false
        live = graph.live_edges()
        new_edges = live >= self._edges_at_last_optimization
        self._edges_at_last_optimization = graph.num_edges_total
        self._optimized_once = True
        pose_graph = self.to_pose_graph()
        if pose_graph.num_edges == 0:
            return None
        started = wallclock.perf_counter()
        result = self._solve(pose_graph, live, new_edges)
        wall = wallclock.perf_counter() - started
        integrated = short = 0
        if self._integrates:
            # a merge that rests on a link the solution rejects is split (merge_records), and
            # the map solved again with its vertices and edges back
            rejected = set(live[result.rejected & graph.edge_held[live]].tolist())
            revived = self.integration.split_merges_on(graph, rejected)
            if revived:
                self.counters.integrated -= revived
                self.counters.split += revived
                started = wallclock.perf_counter()
                more = self._solve(self.to_pose_graph(), graph.live_edges(), None)
                wall += wallclock.perf_counter() - started
                result = replace(
                    more,
                    initial_cost=result.initial_cost,
                    iterations=result.iterations + more.iterations,
                )
            integrated = self.integration.after_optimisation(graph, self.params)
            self.counters.integrated += integrated
        if self._removes_short:
            short = remove_short_edges(
                graph, self.params.short_edge_threshold, self.params.short_edge_loops >= 0.5
            )
            self.counters.short_edges += short
        self._follow_merges()
        record = OptimizationRecord(
            cluster_id=cluster_id,
            time=t,
            vertices=pose_graph.num_vertices,
            edges=pose_graph.num_edges,
            iterations=result.iterations,
            initial_cost=result.initial_cost,
            final_cost=result.final_cost,
            wall_s=wall,
            integrated=integrated,
            short_edges_removed=short,
        )
        self.optimizations.append(record)
        return record

    def _solve(
        self, pose_graph: PoseGraph, live: IntArray, new_edges: NDArray[np.bool_] | None
    ) -> OptimizationResult:
        """One batch optimisation of ``pose_graph`` (the live edges ``live``), its poses kept.

        ``new_edges``: the edges added since the last optimisation (the robust loop model weighs
        the hypothesis that its new links are true); None: none.
        """
        graph = self.graph
        result = optimize_pose_graph(
            pose_graph,
            OptimizerOptions(
                huber_scale=self.params.huber_scale,
                initialization="none",
                function_tolerance=1e-5,
                loop_model=self.params.loop_closure_model(),
            ),
            new_loops=new_edges,
            clusters=graph.edge_cluster[live],  # one cluster cannot overrule several
            merged_on=graph.edge_held[live],  # ... nor a merge
        )
        graph.pose[pose_graph.vertex_ids] = result.poses
        return result


class MapSet:
    """The three maps of the paper built side by side from one event stream."""

    def __init__(
        self, params: MapParams | None = None, modes: tuple[MapMode, ...] | None = None
    ) -> None:
        """Create one :class:`CognitiveMap` per mode (default: all three)."""
        if modes is None:
            modes = ALL_MODES
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
    "MapCounters",
    "MapMode",
    "MapSet",
    "MapSnapshot",
    "OptimizationRecord",
    "neighborhood_field",
]
