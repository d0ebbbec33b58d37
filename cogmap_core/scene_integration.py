"""Scene integration (paper, "Scene Integration"): revisited vertices merged into the old ones.

"When the robot revisits familiar image views, redundant vertices should not be added and the
same scenes are integrated." Vertices are added while revisiting and removed once the map shows
where they belong (paper: "we remove revisited vertices after optimization, not avoid adding
redundant vertices to begin with").

**Which vertices are redundant because of a revisit.** While the robot re-walks a known route, the
front end re-localises it on old vertices (link + set current); the map only gets a new vertex
there when the front end proposes one (the view changed, the pose cells drifted). Such vertices
come in *revisit runs*: the vertices created after the robot was re-localised on known ground
(``start``) until it is re-localised on known ground again (``end``, joined to the run's last
vertex by the loop-closure edge of that relocalisation). Known ground is a vertex made at least
``integration_min_age`` seconds before; a relocalisation on a vertex the robot just made (while it
spins on the spot, or closes a small loop of new ground) does not end a run. A run is redundant --
the paper's cases A (one vertex), B (several vertices onto one) and C (several vertices and their
edges just removed) -- when

1. ``start`` and ``end`` are known ground for the whole run (at least ``integration_min_age``
   older than its first vertex; neither belongs to the run);
2. the links that bracket the run agree with the map: their residuals, weighed as the
   optimiser weighs them, are at most ``integration_max_residual`` (an edge the optimisation
   could not satisfy is no evidence). That is the closing link, judged in the frame it was
   measured in: the vertex the robot was at, the run's last one unless the robot spun back
   onto a young vertex of the run before it closed; and, when a link alone
   re-localised the robot where the run began (below), that link must be one the loop-closure
   model keeps (:func:`~cogmap_core.optimizer.rejected_loop_closures`' rule: its residual
   within the model's scale) -- a false match that opened a run says nothing about where its
   vertices belong; and
3. every vertex of the run lies within ``integration_radius`` of an edge of known ground (an
   edge whose vertices are at least ``integration_min_age`` older than the run): the run
   re-walked mapped corridors.

Each vertex of a redundant run is merged into the nearer end of that edge, its edges re-attached
with the current (optimised) relative pose. The links that bracket a merged run are then *held*
(``MapGraph.hold_edge``): the merge rests on them, so no later optimisation's hypothesis may
reject them while it stands (:func:`~cogmap_core.cluster_consistency.overrules_a_merge`).
Should the solution an optimisation keeps reject one all the same, the merge is split again
(:mod:`~cogmap_core.merge_records`; beyond the paper): its vertices and edges come back as they
were measured, and the map is solved again (:class:`~cogmap_core.cognitive_map.CognitiveMap`).

**Keeping what the run measured** (``MapParams.integration_keeps_evidence``, the
scene-integration map; beyond the paper). The run's chain from ``start`` to ``end`` is
marginalised onto those two vertices (:mod:`~cogmap_core.marginalisation`) and replaces its
re-attached edges: an evidence edge, held in the links' place. The compact map merges its runs
the paper's way: there the chain runs through its declined vertices' fixed offsets, and keeping
it made the compact map less accurate (``docs/maps.md``).

Nothing else is ever removed: a first-visit vertex belongs to no run that starts on known ground
and passes 3 -- not even the last one before a loop closes, a few centimetres short of the place
the robot then recognises -- and the vertex where the robot leaves known ground begins a run
that does not stay on known ground.

**Re-localised by a link alone.** A front end may report a recognised place as a link without
moving the robot onto the old vertex (a log of odometry and place recognition,
:mod:`cogmap_core.sources.odometry_log`: its matches are too coarse to restart odometry from).
The robot is then on known ground all the same -- its current vertex is joined to the old one by
the accepted link -- so a run opened at the vertex where that happened starts at the place it
was re-localised on, as it would have after a set-current event. For front ends that follow
every link with set current (RatSLAM) this changes nothing: the run's first vertex then hangs
off the re-localised vertex itself.

**When.** A run is judged when it closes if its links already agree with the map (2 holds
before any optimisation: the optimisation would not move them), otherwise after the next
batch optimisation -- the paper's order, which lets the optimisation decide where the run
converges. Runs are judged one after the other against the map as the merges before left it;
``start`` and ``end`` are resolved to the vertices that absorbed them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from cogmap_core.config import MapParams
from cogmap_core.edge_noise import link_heading_weight
from cogmap_core.geometry import between, compose_scalar, wrap_scalar
from cogmap_core.map_graph import MapGraph
from cogmap_core.marginalisation import ChainMeasurement, chain_measurement, keep_chain_evidence
from cogmap_core.merge_records import MergeRecord, split_merge


@dataclass(slots=True)
class RevisitRun:
    """Vertices created between two relocalisations on known ground.

    Attributes:
        start: vertex id the robot was at when the run began (or, when a link alone
            re-localised it there, the vertex that link joined it to).
        opened_from: when a link alone re-localised the robot where the run began, the vertex
            that link came from (its loop-closure edge joins it to ``start``); -1 otherwise.
        vertices: the vertices created, in order.
        created: data time of the first vertex.
        end: vertex id the robot re-localised on when the run closed (-1 while open).
        closing: the closing link's measurement: the pose of ``end``'s place in the frame of
            ``closed_at``.
        closed: data time of the closing relocalisation.
        closed_at: the vertex id the robot was at when the closing link was measured (the frame
            of ``closing``): the run's last vertex, or one the robot was re-localised on since
            (a young vertex of the run while it spun back, or one that absorbed it); -1: the
            run's last vertex.

    """

    start: int
    opened_from: int = -1
    vertices: list[int] = field(default_factory=list)
    created: float = 0.0
    end: int = -1
    closing: tuple[float, float, float] = (0.0, 0.0, 0.0)
    closed: float = math.nan
    closed_at: int = -1

    def closer(self) -> int:
        """The vertex id the closing link was measured from (``closed_at``, or the last vertex)."""
        return self.closed_at if self.closed_at >= 0 else self.vertices[-1]

    def state_dict(self) -> dict[str, Any]:
        """The run as plain data (every attribute; ``vertices`` and ``closing`` as lists)."""
        return {
            "start": self.start,
            "opened_from": self.opened_from,
            "vertices": list(self.vertices),
            "created": self.created,
            "end": self.end,
            "closing": list(self.closing),
            "closed": self.closed,
            "closed_at": self.closed_at,
        }

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> RevisitRun:
        """The run :meth:`state_dict` described."""
        return cls(
            start=int(state["start"]),
            opened_from=int(state["opened_from"]),
            vertices=[int(v) for v in state["vertices"]],
            created=float(state["created"]),
            end=int(state["end"]),
            closing=tuple(float(v) for v in state["closing"]),  # type: ignore[arg-type]
            closed=float(state["closed"]),
            closed_at=int(state["closed_at"]),
        )


class KnownEdges:
    """Spatial index of the map's live edges, as they were when it was built.

    Built when a run is first judged and kept until the next batch optimisation moves the poses
    (new edges and merges since are not in it; when it is built is part of the map's result and
    is saved with sessions).

    Each edge is cut into pieces no longer than the integration radius; a KD-tree over the piece
    midpoints answers "which edges pass within ``radius`` of this point", exactly. Each edge
    remembers when its newer vertex was made, so a run only counts edges of ground known before
    it. Edges removed since the index was built still stand for ground between two real places.
    """

    def __init__(self, graph: MapGraph, radius: float) -> None:
        """Index every edge of driven ground of ``graph`` (:meth:`MapGraph.path_edges`)."""
        edges = graph.path_edges()
        a_id, b_id = graph.edge_from[edges], graph.edge_to[edges]
        a, b = graph.pose[a_id, :2], graph.pose[b_id, :2]
        piece = max(radius, 1e-3)
        counts = np.maximum(np.ceil(np.hypot(*(b - a).T) / piece).astype(np.int64), 1)
        owner = np.repeat(np.arange(edges.size), counts)
        first = np.cumsum(counts) - counts
        index = np.arange(owner.size) - first[owner]
        direction = b[owner] - a[owner]
        self.start = a[owner] + direction * (index / counts[owner])[:, None]
        self.end = a[owner] + direction * ((index + 1) / counts[owner])[:, None]
        self.ends = np.stack([a_id[owner], b_id[owner]], axis=1)
        self.newest = np.maximum(graph.vertex_time[a_id], graph.vertex_time[b_id])[owner]
        self.tree = cKDTree(0.5 * (self.start + self.end)) if owner.size else None
        longest = float(np.max(np.hypot(*(self.end - self.start).T))) if owner.size else 0.0
        self.reach = radius + 0.5 * longest
        self.radius = radius

    def state_dict(self) -> dict[str, Any]:
        """The index as plain data, what :meth:`from_state` restores.

        Its pieces' arrays (copies), ``reach``, ``radius``, and whether it has a tree (the same
        midpoints build the same tree again).
        """
        state: dict[str, Any] = {
            name: getattr(self, name).copy() for name in ("start", "end", "ends", "newest")
        }
        state.update(reach=self.reach, radius=self.radius, tree=self.tree is not None)
        return state

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> KnownEdges:
        """The index :meth:`state_dict` described, as it was when it was built."""
        known = cls.__new__(cls)
        for name in ("start", "end", "ends", "newest"):
            setattr(known, name, state[name])
        known.reach = float(state["reach"])
        known.radius = float(state["radius"])
        known.tree = cKDTree(0.5 * (known.start + known.end)) if state["tree"] else None
        return known

    def nearest(self, point: np.ndarray, known_before: float) -> tuple[int, int] | None:
        """The closest edge of ground known before ``known_before`` within the radius of ``point``.

        Returns its two vertex ids, or None when no such edge passes within the radius.
        """
        if self.tree is None:
            return None
        candidates = np.asarray(self.tree.query_ball_point(point, self.reach), dtype=np.int64)
        if candidates.size:
            candidates = candidates[self.newest[candidates] <= known_before]
        if candidates.size == 0:
            return None
        a, b = self.start[candidates], self.end[candidates]
        ab = b - a
        denom = np.einsum("ij,ij->i", ab, ab)
        t = np.clip(np.einsum("ij,ij->i", point - a, ab) / np.where(denom > 0, denom, 1.0), 0, 1)
        gap = np.hypot(*(point - (a + ab * t[:, None])).T)
        best = int(np.argmin(gap))
        if gap[best] > self.radius:
            return None
        u, v = self.ends[candidates[best]]
        return int(u), int(v)


class SceneIntegration:
    """Collects revisit runs as events arrive and merges the redundant ones (module doc)."""

    def __init__(self, keeps_evidence: bool = False) -> None:
        """No run yet.

        ``keeps_evidence``: this map keeps a merged run's chain when
        ``MapParams.integration_keeps_evidence`` says so (module doc).
        """
        self.keeps_evidence = keeps_evidence
        self.open: RevisitRun | None = None
        self.pending: list[RevisitRun] = []
        #: the merges made, oldest first, each as it can be split again
        self.merges: list[MergeRecord] = []
        self._known: KnownEdges | None = None
        # (robot's vertex, vertex id it was re-localised on) of the latest relocalisation on
        # known ground, until the next vertex is added
        self._relocalised_at: tuple[int, int] | None = None

    def state_dict(self) -> dict[str, Any]:
        """The runs and the index as plain data, what :meth:`load_state` restores.

        ``open`` and ``pending`` runs (:meth:`RevisitRun.state_dict`), ``merges``
        (:meth:`MergeRecord.state_dict`), ``relocalised_at`` (the latest relocalisation on known
        ground, ``[robot's vertex, vertex]``) and ``known_edges`` (:meth:`KnownEdges.state_dict`);
        None where there is none.
        """
        at, known = self._relocalised_at, self._known
        return {
            "open": None if self.open is None else self.open.state_dict(),
            "pending": [run.state_dict() for run in self.pending],
            "merges": [record.state_dict() for record in self.merges],
            "relocalised_at": None if at is None else list(at),
            "known_edges": None if known is None else known.state_dict(),
        }

    def load_state(self, state: dict[str, Any]) -> None:
        """Hold the runs and the index :meth:`state_dict` described.

        A state without ``merges`` (written before merges could be split) has none to split.
        """
        self.open = None if state["open"] is None else RevisitRun.from_state(state["open"])
        self.pending = [RevisitRun.from_state(run) for run in state["pending"]]
        self.merges = [MergeRecord.from_state(record) for record in state.get("merges", [])]
        at = state["relocalised_at"]
        self._relocalised_at = None if at is None else (int(at[0]), int(at[1]))
        known = state["known_edges"]
        self._known = None if known is None else KnownEdges.from_state(known)

    def on_vertex(self, vertex: int, parent: int, time: float) -> None:
        """A vertex was added, joined by a sequential edge to ``parent``."""
        if self.open is None:
            start, opened_from = parent, -1
            at = self._relocalised_at
            if at is not None and at[0] == parent:
                start, opened_from = at[1], parent  # re-localised by a link without moving
            self.open = RevisitRun(start=start, opened_from=opened_from, created=time)
        self._relocalised_at = None
        self.open.vertices.append(vertex)

    def on_relocalised(
        self,
        graph: MapGraph,
        end: int,
        closing: tuple[float, float, float],
        time: float,
        params: MapParams,
        robot: int = -1,
    ) -> int:
        """The robot was re-localised on vertex id ``end``; return vertices merged right away.

        ``closing`` is the pose of ``end``'s place in the frame of the current vertex;
        ``robot`` is that current vertex (the robot's, before any set-current event).
        """
        if time - graph.vertex_time[end] < params.integration_min_age:
            return 0  # the robot re-localised on what it just mapped
        self._relocalised_at = (robot, end)
        run = self.open
        if run is None:
            return 0
        self.open = None
        run.end, run.closing, run.closed = end, closing, time
        run.closed_at = robot
        if not _links_agree(graph, run, params):
            self.pending.append(run)  # let the optimisation decide
            return 0
        merged = self._judge(graph, run, params)
        if merged < 0:
            self.pending.append(run)
            return 0
        return merged

    def after_optimisation(self, graph: MapGraph, params: MapParams) -> int:
        """Judge every pending run on the optimised map; return the vertices merged."""
        self._known = None  # poses moved
        runs, self.pending = self.pending, []
        merged = 0
        for run in runs:
            if _links_agree(graph, run, params):
                merged += max(self._judge(graph, run, params, final=True), 0)
        return merged

    def _judge(
        self, graph: MapGraph, run: RevisitRun, params: MapParams, final: bool = False
    ) -> int:
        """Merge what is redundant in a closed run; -1 when it should wait for an optimisation."""
        radius = params.integration_radius
        members = [v for v in run.vertices if graph.alive[v]]
        if not members or radius <= 0:
            return 0
        start = graph.resolve(run.start)[0]
        end = graph.resolve(run.end)[0]
        known_before = run.created - params.integration_min_age
        if end in members or graph.vertex_time[end] > known_before:
            return 0  # not closed on ground known before the run
        if start in members or graph.vertex_time[start] > known_before:
            return 0  # not started on ground known before the run
        if self._known is None:
            self._known = KnownEdges(graph, radius)
        absorbers = []
        for v in members:
            edge = self._known.nearest(graph.pose[v, :2], known_before)
            if edge is None:
                return 0 if final else -1  # off known ground (now): not a re-walk
            u, w = (graph.resolve(x)[0] for x in edge)
            gaps = np.hypot(*(graph.pose[[u, w], :2] - graph.pose[v, :2]).T)
            absorbers.append(u if gaps[0] <= gaps[1] else w)
        links = bracketing = _bracketing_links(graph, run)
        chain = self._run_chain(graph, run, members, params)
        record = MergeRecord.before_merging(graph, members)
        evidence = -1
        merged = 0
        for v, kept in zip(members, absorbers, strict=True):
            kept = graph.resolve(kept)[0]
            if graph.alive[v] and kept != v:
                _merge(graph, v, kept)
                merged += 1
        if chain is not None and merged == len(members):  # (every vertex of the run is gone)
            ends = graph.resolve(chain.first)[0], graph.resolve(run.end)[0]
            evidence = keep_chain_evidence(graph, *ends, chain, run.closed)
            links = [k for k in (evidence, _opening_link(graph, run)) if k >= 0]
        if merged:
            for k in links:
                graph.hold_edge(k)
            rests_on = [k for k in (*bracketing, evidence) if k >= 0]
            self.merges.append(record.merged(graph, rests_on, evidence))
        return merged

    def split_merges_on(self, graph: MapGraph, rejected: set[int]) -> int:
        """Split every merge that rests on a link of ``rejected``, newest first.

        Return the vertices made live again (:mod:`~cogmap_core.merge_records`). The links
        those merges rested on stay held only where a merge that stands rests on them too.
        """
        resting = [bool(rejected.intersection(record.links)) for record in self.merges]
        if not any(resting):
            return 0
        split = [record for record, r in zip(self.merges, resting, strict=True) if r]
        self.merges = [record for record, r in zip(self.merges, resting, strict=True) if not r]
        self._known = None  # the graph's edges changed
        revived = sum(split_merge(graph, record) for record in reversed(split))
        still = {k for record in self.merges for k in record.links}
        for k in {k for record in split for k in record.links} - still:
            graph.edge_held[k] = False
        return revived

    def _run_chain(
        self, graph: MapGraph, run: RevisitRun, members: list[int], params: MapParams
    ) -> ChainMeasurement | None:
        """What a closed run measured, when this map keeps it.

        Its chain of edges from the vertex its first vertex hangs off (``start``, or where a link
        alone re-localised the robot, the vertex that link came from: the link itself stays)
        through its vertices up to the one the closing link was measured from, to ``end``. (The
        robot may have spun back onto a vertex of the run before it closed: the vertices after
        that one hang off the chain and say nothing about where its ends lie.)

        None when the map does not keep it, when a vertex of the run is gone already, when the
        closing link was measured from a vertex outside the run, or when the chain lacks an edge
        (the closing link duplicated one).
        """
        if not self.keeps_evidence or params.integration_keeps_evidence < 0.5:
            return None
        closer = run.closer()
        if len(members) != len(run.vertices) or closer not in members:
            return None
        first = run.opened_from if run.opened_from >= 0 else run.start
        walked = members[: members.index(closer) + 1]
        chain = [graph.resolve(first)[0], *walked, graph.resolve(run.end)[0]]
        return chain_measurement(graph, chain, params.link_sigmas(), params.odometry_noise())


def _bracketing_links(graph: MapGraph, run: RevisitRun) -> list[int]:
    """The loop closures a run's merge rests on: its closing link and, if any, its opening one."""
    closing = graph.edge_between(graph.resolve(run.closer())[0], graph.resolve(run.end)[0])
    return [k for k in (closing, _opening_link(graph, run)) if k >= 0]


def _opening_link(graph: MapGraph, run: RevisitRun) -> int:
    """The edge of the link that alone re-localised the robot where the run began (-1: none).

    None when the robot was set there, or when the link made no edge of its own (it duplicated
    one).
    """
    if run.opened_from < 0:
        return -1
    robot, place = graph.resolve(run.opened_from)[0], graph.resolve(run.start)[0]
    return graph.edge_between(robot, place)


def _links_agree(graph: MapGraph, run: RevisitRun, params: MapParams) -> bool:
    """Whether the links that bracket the run agree with the map (condition 2, module doc)."""
    closing = _link_residual(graph, run.closer(), run.end, run.closing, params)
    if closing > params.integration_max_residual:
        return False
    k = _opening_link(graph, run)
    if k < 0:
        return True  # opened where the robot was set (or drove on from), or no edge of its own
    robot, place = int(graph.edge_from[k]), int(graph.edge_to[k])
    model = params.loop_closure_model()
    if model is None:
        return True  # the paper's Huber rejects no link
    # it need not have converged (the run's end is judged by the closing link): it must only be
    # a link the loop model keeps (the residual is the optimiser's whitened one, so chi^2 = r^2)
    residual = _link_residual(graph, robot, place, tuple(graph.edge_rel[k].tolist()), params)
    return not bool(model.final_kernel.rejects(np.array([residual * residual]))[0])


def _link_residual(
    graph: MapGraph,
    robot: int,
    place: int,
    measured: tuple[float, float, float],
    params: MapParams,
) -> float:
    """Norm of a link's residual on the current poses, weighed as the optimiser does.

    ``measured`` is the pose of ``place`` in the frame of ``robot`` (vertex ids, aliases
    resolved). In metres of loop-closure error: with the noise model, heading counts with the
    ratio of a loop closure's position and heading precision (:mod:`~cogmap_core.edge_noise`).
    """
    at = graph.pose_of(place)
    predicted = compose_scalar(graph.pose_of(robot), measured)
    dx, dy = predicted[0] - at[0], predicted[1] - at[1]
    weight = link_heading_weight(params.link_sigmas())
    return math.sqrt(dx * dx + dy * dy + (weight * wrap_scalar(predicted[2] - at[2])) ** 2)


def _merge(graph: MapGraph, removed: int, kept: int) -> None:
    offset = tuple(between(graph.pose[kept], graph.pose[removed]).tolist())
    graph.merge_vertex(removed, kept, offset)
