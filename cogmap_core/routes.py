"""Routes on a cognitive map: the shortest way between two places (goal navigation).

OpenRatSLAM's experience map plans the way to a goal experience with Dijkstra over its links;
this module does the same on cogmap's maps, and gives the reference to judge such a route by.

- :class:`RouteMap` (or :func:`shortest_route`) -- Dijkstra over a map's live edges and its
  *joins* (every two vertices within the map's ``integration_radius``); the two places asked for
  are snapped to their nearest live vertex, and the way through the route's vertices is
  *straightened* within the map's ``link_sigma_position`` of them (:func:`straighten`). The
  answer is a :class:`Route`: the vertex path, its poses, the straightened way and its length. A
  goal the start cannot reach (the map is in pieces) raises :class:`NoRouteError`.
- :func:`true_path_graph` -- the driven ground-truth path as a graph, the reference: its samples
  joined in time order, plus joins wherever the path passes within
  :data:`TRUE_PATH_JOIN_RADIUS` of itself (where laps run along the same corridor, and where they
  cross at a junction). Its routes keep to ground the robot really drove, so they never cut
  through a wall, and their length is the true shortest path length along the driven path.
- :func:`segments_on_path`, :func:`on_path_share` -- how much of a route lies within a radius of
  the true path (after the map is aligned to the ground truth).

**Edge weights: lengths in the map's current (optimised) poses, not the measured lengths.** An
edge's measured relative pose is one reading: the odometry integrated between two vertices (with
its drift and scale error), or for a loop closure the odometry since the robot's current vertex
plus the front end's claim that it is back at the target. The batch optimisation reconciles all
of them, so the distance between the optimised poses of an edge's two ends is the map's best
estimate of how far apart the two places are; a link the robust loss played down keeps its full
weight when measured lengths are used. The drawn route (the polyline through the vertex poses)
then has exactly the stated length, which is what a viewer shows beside it. Measured lengths
make loop closures shortcuts: a link is measured from the robot's current vertex to where the robot
is, while its target is wherever the view matched, often some centimetres ahead. On the 6-lap
figure eight the standard map's routes by measured lengths take links whose measurements sum to
87 m where their ends lie 132 m apart, and claim a median 0.90 of the true shortest path -- less
than can be driven (by optimised lengths: 1.01). They remain available (``weight="measured"``:
joins weighed by their length in the poses, the way not straightened);
``benchmarks/routes.py`` prints the stretch with both.

**Joins: vertices within the map's ``integration_radius`` (0.1 m) are one place.** View matching
recognises a place only when the robot faces the way it did before, so where a corridor is driven
both ways, or a junction crossed on other turns, a map holds strands of vertices a few
centimetres apart with no edge between them, and routes over the edges alone go the long way
round (6-lap ``irat_australia``: median 1.20 x the true shortest path on the standard map, 1.05
on the compact one). The route map joins every two vertices closer than the distance within which
the map itself takes a revisit for known ground (scene integration merges it): one rule for "the
same place", in :class:`~cogmap_core.config.MapParams`. It is a quarter of the distance between
corridors on either side of a wall (0.3 m corridors, 0.1 m walls). Measured on the four 6-lap
layouts, seeds 1 and 2, all three maps: two vertices made within 5 cm of each other lie at most
5-8 cm apart in the optimised map (95th percentile; 14 cm at most), two on either side of a wall
at least 30 cm apart -- a join never crosses a wall. Routes with joins stay 100 % within 8 cm of
the true path on every map whose routes over the edges alone do (all but the compact and
scene-integration maps of seed 2's ``junction_dead_end``, wrong in themselves); at 0.15 m some
routes of the standard and scene-integration maps leave it.

**Straightened within the map's ``link_sigma_position`` (3 cm).** A route through its vertices
turns at each of them, where the robot rounds its turns and cuts inside its curves: the compact
map keeps one vertex at a corner's apex, about 9 cm per corner longer than the laps that cut the
corner (``long_corridors``). The way is the shortest that stays within a corridor of the polyline
through the route's vertices (:func:`straighten`, string pulling as navigation meshes are
followed), the corridor being how precisely the map places the robot at a place it recognised --
the loop closure's standard deviation the optimisation weighs: a way that close to the vertices
is as consistent with the map as the polyline through them. Measured (same layouts, seeds and
maps): straightened within 3 cm every route stays 100 % within 8 cm of the true path; within
5 cm, with the map's own error of a few centimetres added, up to 80 of 200 routes of a map fall
below 99 %.
A straightened route can be shorter than the true shortest path along the driven path, which
follows the robot's own turns and curves (``benchmarks/routes.py`` also prints the stretch
against that path straightened the same way).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Literal

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

from cogmap_core.config import MapParams
from cogmap_core.errors import CogmapError, ParameterError
from cogmap_core.evaluation import _sample_polyline_pieces, _within_radius_of_segments
from cogmap_core.map_graph import MapSnapshot, nearest_vertex
from cogmap_core.posegraph import PoseGraph

if TYPE_CHECKING:
    from cogmap_core.cognitive_map import CognitiveMap

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
Weight = Literal["poses", "measured"]
Place = Sequence[float] | FloatArray

TRUE_PATH_JOIN_RADIUS = 0.05
"""Ground-truth samples this close (m) are joined in :func:`true_path_graph`.

Five centimetres: several times the spacing of the samples (one per camera frame, about 1 cm at
the generated bags' 0.15-0.3 m/s and 17.5 Hz), so two stretches of the path that run along the
same corridor, or cross at a junction, are always joined; far below the closest approach of two
corridors on either side of a wall (0.3 m corridors, 0.1 m walls: 0.4 m between centre lines,
0.1 m even for paths hugging both faces of a wall), so a join never crosses one; and below the
8 cm tolerance routes are judged with, so a join's sideways step stays within the corridor. A
join can also cut a turn of the path short, by at most (sqrt(2) - 1) x 5 cm = 2.1 cm at a right
angle: ground a robot can cover in a 0.3 m corridor.
"""

_MIN_WEIGHT = 1e-12  # csgraph drops zero-weight edges: two vertices at one place stay joined


class NoRouteError(CogmapError):
    """No route joins the two places: the map is empty, or they lie on separate pieces."""


@dataclass(frozen=True, slots=True)
class Route:
    """The shortest route between two places on a map.

    Attributes:
        vertex_ids: ``(K,)`` the vertices along the route, start first (ids of the map's
            vertices; for a route on :func:`true_path_graph`, indices of the ground-truth
            samples); consecutive ones are joined by an edge or a join.
        poses: ``(K, 3)`` their poses (x, y, theta) in the map's frame.
        length: the route's length (m): the length of its way (:attr:`points`) when it was
            straightened, else the sum of its edges' weights (with the default weights, the
            length of the polyline through ``poses``).
        start_gap: distance (m) from the start place asked for to the route's first vertex
            (0 when a vertex was asked for).
        goal_gap: distance (m) from the route's last vertex to the goal place asked for.
        path: ``(P, 2)`` the way itself when it was straightened (see :class:`RouteMap`), from
            the first vertex to the last; None when it runs through the vertices.

    """

    vertex_ids: IntArray
    poses: FloatArray
    length: float
    start_gap: float = 0.0
    goal_gap: float = 0.0
    path: FloatArray | None = None

    @property
    def points(self) -> FloatArray:
        """``(P, 2)`` the route's way, start first: ``path``, or the vertices' positions."""
        return self.poses[:, :2] if self.path is None else self.path

    @property
    def num_edges(self) -> int:
        """Edges (and joins) along the route (0 when start and goal snap to one vertex)."""
        return int(self.vertex_ids.shape[0]) - 1


class RouteMap:
    """A map's live graph prepared for routing: build it once, ask it for many routes.

    Args:
        vertex_ids: ``(N,)`` distinct vertex ids.
        poses: ``(N, 2+)`` their poses (x, y[, theta]) in the map's frame.
        edge_from: ``(E,)`` the id of each edge's first vertex ...
        edge_to: ``(E,)`` ... and of its second; edges are travelled both ways.
        weights: ``(E,)`` each edge's length (m); default: the distance between its two ends'
            poses. Of several edges joining one pair, the shortest counts.
        join_radius: vertices this close (m) in ``poses`` are joined as well, each join
            weighed by its length (default 0: the edges alone).
        corridor: every route is straightened (:func:`straighten`) within this distance (m)
            of the polyline through its vertices (default 0: routes run through the
            vertices); only with the default weights, the lengths in ``poses``.

    :meth:`of` gives a map's own join radius and corridor (see the module docstring).

    Attributes:
        num_edges: pairs of vertices joined by an edge or a join.
        num_joins: pairs of vertices within ``join_radius`` (an edge may join them as well).

    Raises:
        ParameterError: an edge names an unknown vertex, or a pose or weight is not finite (or
            a weight negative), or a join radius or corridor is negative or not finite, or a
            corridor comes with weights of their own.

    """

    def __init__(
        self,
        vertex_ids: IntArray | Sequence[int],
        poses: FloatArray | Sequence[Sequence[float]],
        edge_from: IntArray | Sequence[int],
        edge_to: IntArray | Sequence[int],
        weights: FloatArray | Sequence[float] | None = None,
        join_radius: float = 0.0,
        corridor: float = 0.0,
    ) -> None:
        """Index the vertices, add the joins and build the symmetric weighted adjacency."""
        for name, value in (("join radius", join_radius), ("corridor", corridor)):
            if not (value >= 0 and math.isfinite(value)):
                raise ParameterError(f"the {name} must be a distance of 0 or more (m), not {value}")
        if corridor > 0 and weights is not None:
            raise ParameterError(
                "a route is straightened only when its length is measured in the poses "
                "(no weights given)"
            )
        ids = np.asarray(vertex_ids, dtype=np.int64).reshape(-1)
        pose = np.asarray(poses, dtype=np.float64)
        pose = pose.reshape(ids.shape[0], -1) if pose.size else np.zeros((ids.shape[0], 3))
        if pose.shape[1] < 2:
            raise ParameterError("route map poses need at least x and y per vertex")
        if pose.shape[1] == 2:
            pose = np.column_stack([pose, np.zeros(pose.shape[0])])
        if not np.isfinite(pose[:, :3]).all():
            raise ParameterError("route map poses must be finite numbers")
        order = np.argsort(ids, kind="stable")
        self.vertex_ids: IntArray = ids[order]
        if np.any(np.diff(self.vertex_ids) == 0):
            raise ParameterError("route map vertex ids must be distinct")
        self.poses: FloatArray = pose[order, :3].copy()
        e_from = self._rows(np.asarray(edge_from, dtype=np.int64).reshape(-1))
        e_to = self._rows(np.asarray(edge_to, dtype=np.int64).reshape(-1))
        if e_from.shape != e_to.shape:
            raise ParameterError("edge_from and edge_to must have one entry per edge")
        if weights is None:
            w = np.hypot(*(self.poses[e_to, :2] - self.poses[e_from, :2]).T)
        else:
            w = np.asarray(weights, dtype=np.float64).reshape(-1)
            if w.shape != e_from.shape:
                raise ParameterError("route map weights must have one entry per edge")
            if not (np.isfinite(w).all() and (w >= 0).all()):
                raise ParameterError("route map edge weights must be finite and not negative")
        self.join_radius = float(join_radius)
        self.num_joins = 0
        if join_radius > 0 and self.vertex_ids.shape[0] > 1:
            near = cKDTree(self.poses[:, :2]).query_pairs(join_radius, output_type="ndarray")
            self.num_joins = int(near.shape[0])
            e_from, e_to = np.r_[e_from, near[:, 0]], np.r_[e_to, near[:, 1]]
            w = np.r_[w, np.hypot(*(self.poses[near[:, 1], :2] - self.poses[near[:, 0], :2]).T)]
        self.corridor = float(corridor)
        n = self.vertex_ids.shape[0]
        # one weight per unordered pair (the shortest), stored both ways
        lo, hi = np.minimum(e_from, e_to), np.maximum(e_from, e_to)
        keep = lo != hi
        lo, hi, w = lo[keep], hi[keep], w[keep]
        first = np.lexsort((w, hi, lo))
        lo, hi, w = lo[first], hi[first], w[first]
        distinct = np.ones(lo.shape[0], dtype=bool)
        distinct[1:] = (lo[1:] != lo[:-1]) | (hi[1:] != hi[:-1])
        lo, hi, w = lo[distinct], hi[distinct], np.maximum(w[distinct], _MIN_WEIGHT)
        self.num_edges = int(lo.shape[0])
        self._graph = csr_matrix(
            (np.r_[w, w], (np.r_[lo, hi], np.r_[hi, lo])), shape=(n, n), dtype=np.float64
        )
        self._tree: cKDTree | None = None

    def _rows(self, ids: IntArray) -> IntArray:
        """Rows (in the sorted vertex arrays) of vertex ids; every id must be known."""
        if ids.size == 0:
            return np.zeros(0, dtype=np.int64)
        rows = np.searchsorted(self.vertex_ids, ids)
        known = rows < self.vertex_ids.shape[0]
        known[known] = self.vertex_ids[rows[known]] == ids[known]
        if not known.all():
            missing = int(ids[~known][0])
            raise ParameterError(f"an edge names vertex {missing}, which is not a vertex")
        return rows.astype(np.int64)

    @classmethod
    def of(
        cls,
        source: CognitiveMap | MapSnapshot | PoseGraph,
        weight: Weight = "poses",
        params: MapParams | None = None,
        *,
        join_radius: float | None = None,
        corridor: float | None = None,
    ) -> RouteMap:
        """The route map of a cognitive map, its snapshot, or a pose graph.

        A pose graph is e.g. a map saved as g2o (``cogmap run`` writes ``<map>.g2o``) and read
        with :func:`~cogmap_core.g2o.read_g2o`. Only the live vertices and edges count (a
        snapshot holds nothing else). ``weight``: ``"poses"`` (default) weighs each edge by the
        distance between its two ends' current poses, ``"measured"`` by the length of its
        measured relative pose (see the module docstring for the choice).

        Vertices within ``params.integration_radius`` are joined and routes are straightened
        within ``params.link_sigma_position`` (not with measured weights); see the module
        docstring. ``params``: the map's parameters; default a cognitive map's own, else
        (a snapshot, a pose graph) the defaults. ``join_radius`` and ``corridor`` set either
        directly (0: none).
        """
        if weight not in ("poses", "measured"):
            raise ParameterError(f"route weight must be 'poses' or 'measured', not {weight!r}")
        if params is None:
            bare = isinstance(source, (MapSnapshot, PoseGraph))  # no parameters of its own
            params = MapParams() if bare else source.params
        if join_radius is None:
            join_radius = params.integration_radius
        if corridor is None:
            corridor = params.link_sigma_position if weight == "poses" else 0.0
        if isinstance(source, PoseGraph):
            ids = source.vertex_ids
            e_from, e_to = ids[source.edge_from], ids[source.edge_to]
            rel = source.measurements
            poses = source.poses
        else:
            snap = source if isinstance(source, MapSnapshot) else source.snapshot()
            ids, poses = snap.vertex_ids, snap.poses
            e_from, e_to, rel = snap.edge_from, snap.edge_to, snap.edge_rel
        measured = np.hypot(rel[:, 0], rel[:, 1]) if weight == "measured" else None
        return cls(ids, poses, e_from, e_to, measured, join_radius, corridor)

    @property
    def num_vertices(self) -> int:
        """Vertices of the map."""
        return int(self.vertex_ids.shape[0])

    def snap(self, place: Place) -> tuple[int, float]:
        """The live vertex nearest to ``place`` (x, y in the map's frame) and its distance (m).

        Raises:
            NoRouteError: the map has no vertex.
            ParameterError: ``place`` is not two finite numbers.

        """
        xy = np.asarray(place, dtype=np.float64).reshape(-1)
        if xy.shape[0] < 2 or not np.isfinite(xy[:2]).all():
            raise ParameterError(f"a place is two finite numbers x, y (m), not {place!r}")
        if self.num_vertices == 0:
            raise NoRouteError("the map has no vertex yet: there is nothing to route on")
        if self._tree is None:
            self._tree = cKDTree(self.poses[:, :2])
        found = nearest_vertex(self.poses, xy[:2], self._tree)  # many snaps: the tree's
        assert found is not None  # (the map has vertices)
        row, distance = found
        return int(self.vertex_ids[row]), distance

    def route(self, start: Place, goal: Place) -> Route:
        """The shortest route from place ``start`` to place ``goal`` (each snapped to a vertex).

        Raises:
            NoRouteError: the map is empty, or no chain of edges joins the two vertices.
            ParameterError: a place is not two finite numbers.

        """
        a, start_gap = self.snap(start)
        b, goal_gap = self.snap(goal)
        return replace(self.route_between(a, b), start_gap=start_gap, goal_gap=goal_gap)

    def route_between(self, start_id: int, goal_id: int) -> Route:
        """The shortest route from vertex ``start_id`` to vertex ``goal_id``.

        Raises:
            NoRouteError: a vertex is not in the map, or no chain of edges joins the two.

        """
        a, b = self._row_of(start_id), self._row_of(goal_id)
        dist, pred = dijkstra(self._graph, directed=True, indices=a, return_predecessors=True)
        if not math.isfinite(dist[b]):
            raise NoRouteError(
                f"no route from vertex {start_id} to vertex {goal_id}: they lie on separate "
                "pieces of the map (no chain of edges joins them)"
            )
        path = _path_rows(pred, a, b)
        if self.corridor > 0:
            way = straighten(self.poses[path, :2], self.corridor)
            return Route(self.vertex_ids[path], self.poses[path].copy(), _length(way), path=way)
        # the sum of the true weights (a zero-length edge counted as _MIN_WEIGHT is negligible)
        return Route(self.vertex_ids[path], self.poses[path].copy(), float(dist[b]))

    def lengths(
        self, start_ids: IntArray | Sequence[int], goal_ids: IntArray | Sequence[int]
    ) -> FloatArray:
        """Route lengths (m) for many pairs at once: ``inf`` where a goal cannot be reached.

        One Dijkstra per distinct start; faster than :meth:`route_between` for each pair (the
        same lengths, straightened routes' included).
        """
        a = np.array([self._row_of(int(v)) for v in np.asarray(start_ids).reshape(-1)])
        b = np.array([self._row_of(int(v)) for v in np.asarray(goal_ids).reshape(-1)])
        if a.shape != b.shape:
            raise ParameterError("lengths needs as many goals as starts")
        if a.size == 0:
            return np.zeros(0)
        sources, which = np.unique(a, return_inverse=True)
        which = which.reshape(-1)
        if self.corridor <= 0:
            dist = dijkstra(self._graph, directed=True, indices=sources)
            return np.asarray(dist[which, b], dtype=np.float64)
        dist, pred = dijkstra(self._graph, directed=True, indices=sources, return_predecessors=True)
        out = np.asarray(dist[which, b], dtype=np.float64)
        for k in np.flatnonzero(np.isfinite(out)):
            path = _path_rows(pred[which[k]], int(a[k]), int(b[k]))
            out[k] = _length(straighten(self.poses[path, :2], self.corridor))
        return out

    def _row_of(self, vertex_id: int) -> int:
        row = int(np.searchsorted(self.vertex_ids, vertex_id))
        if row >= self.num_vertices or int(self.vertex_ids[row]) != vertex_id:
            if self.num_vertices == 0:
                raise NoRouteError("the map has no vertex yet: there is nothing to route on")
            raise NoRouteError(f"vertex {vertex_id} is not a live vertex of this map")
        return row


def _path_rows(pred: IntArray, a: int, b: int) -> IntArray:
    """The rows from ``a`` to ``b`` along Dijkstra's predecessors (``b`` reachable from ``a``)."""
    rows = [b]
    while rows[-1] != a:
        rows.append(int(pred[rows[-1]]))
    return np.array(rows[::-1], dtype=np.int64)


def _length(points: FloatArray) -> float:
    """The length (m) of a polyline ``(K, 2)``."""
    return float(np.hypot(*np.diff(points, axis=0).T).sum()) if points.shape[0] > 1 else 0.0


def shortest_route(
    source: CognitiveMap | MapSnapshot | PoseGraph,
    start: Place,
    goal: Place,
    weight: Weight = "poses",
) -> Route:
    """The shortest route on a map between two places (x, y in the map's frame).

    Each place is snapped to its nearest live vertex; the route is Dijkstra's over the live edges
    weighted by their length in the map's current poses (``weight="measured"``: their measured
    length). For many routes on one map, build a :class:`RouteMap` once.

    Raises:
        NoRouteError: the map is empty, or no chain of edges joins the two places.
        ParameterError: a place is not two finite numbers.

    """
    return RouteMap.of(source, weight).route(start, goal)


def straighten(points: FloatArray, corridor: float) -> FloatArray:
    """The shortest way from a polyline's first point to its last that stays near the polyline.

    Args:
        points: ``(K, 2+)`` the polyline (a route through its vertices).
        corridor: how far (m) the way may stray from the polyline; 0 gives the polyline back.

    Returns:
        ``(P, 2)`` the way: the first point, then where it bends, then the last point.

    The way must cross every *gate*, in order: the segment of half-length ``corridor`` through
    each inner point of the polyline, across the bisector of its two segments (across the
    polyline where it runs straight). The shortest such way is the funnel algorithm's (string
    pulling, as navigation meshes are followed); it bends only at gate ends. Between two gates
    it is a straight piece whose ends lie within ``corridor`` of two consecutive points, so all
    of it lies within ``corridor`` of the segment joining them: the way never strays farther from
    the polyline than ``corridor``. Should a gate order the algorithm cannot follow (a polyline
    folding back on itself) give a way that does stray farther (checked every
    ``corridor / 8``), the polyline itself is returned.

    Raises:
        ParameterError: the corridor is negative or not finite.

    """
    if not (corridor >= 0 and math.isfinite(corridor)):
        raise ParameterError(f"the corridor must be a distance of 0 or more (m), not {corridor}")
    pts = np.asarray(points, dtype=np.float64)[:, :2]
    if pts.shape[0] > 1:  # repeated points (vertices at one place) have no direction
        keep = np.r_[True, np.hypot(*np.diff(pts, axis=0).T) > 1e-12]
        keep[-1] = True
        pts = pts[keep]
    if corridor == 0 or pts.shape[0] <= 2:
        return pts.copy()
    step = np.diff(pts, axis=0)
    unit = step / np.hypot(*step.T)[:, None]
    along = unit[:-1] + unit[1:]  # the bisector's normal: the mean direction at each inner point
    size = np.hypot(*along.T)
    folded = size < 1e-9  # the polyline turns straight back: the gate lies along it
    along[folded] = np.column_stack([-unit[:-1][folded, 1], unit[:-1][folded, 0]])
    along /= np.where(folded, 1.0, size)[:, None]
    left_of = np.column_stack([-along[:, 1], along[:, 0]]) * corridor
    inner = pts[1:-1]
    left = np.vstack([pts[:1], inner + left_of, pts[-1:]]).tolist()
    right = np.vstack([pts[:1], inner - left_of, pts[-1:]]).tolist()
    way = _funnel(left, right)
    mid, _ = _sample_polyline_pieces(way[:-1], way[1:], corridor / 8.0)
    if not _within_radius_of_segments(mid, pts[:-1], pts[1:], corridor * (1 + 1e-9)).all():
        return pts.copy()
    return way


def _cross(o: list[float], a: list[float], b: list[float]) -> float:
    """Twice the signed area of triangle o, a, b: > 0 when b lies left of the ray o -> a."""
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])


def _funnel(left: list[list[float]], right: list[list[float]]) -> FloatArray:
    """The funnel algorithm: the shortest way through gates ``left[k]`` -- ``right[k]`` in order.

    The first and last gates are single points (start and goal). The funnel is the wedge from
    its apex (the way's last bend) to the left and right ends of the gates seen so far; a gate
    end inside the wedge narrows it, one past the other side makes that side's end the next bend.
    """
    apex = left[0]
    funnel_left, funnel_right = apex, apex
    apex_at = left_at = right_at = 0
    way = [apex]
    k = 1
    while k < len(left):
        gate_left, gate_right = left[k], right[k]
        if _cross(apex, funnel_right, gate_right) >= 0:  # the right side narrows ...
            if funnel_right == apex or _cross(apex, funnel_left, gate_right) < 0:
                funnel_right, right_at = gate_right, k
            else:  # ... past the left side: the left end is the next bend
                apex, apex_at = funnel_left, left_at
                way.append(apex)
                funnel_left = funnel_right = apex
                left_at = right_at = apex_at
                k = apex_at + 1
                continue
        if _cross(apex, funnel_left, gate_left) <= 0:  # the left side narrows ...
            if funnel_left == apex or _cross(apex, funnel_right, gate_left) > 0:
                funnel_left, left_at = gate_left, k
            else:  # ... past the right side: the right end is the next bend
                apex, apex_at = funnel_right, right_at
                way.append(apex)
                funnel_left = funnel_right = apex
                left_at = right_at = apex_at
                k = apex_at + 1
                continue
        k += 1
    if way[-1] != left[-1]:
        way.append(left[-1])
    return np.array(way, dtype=np.float64)


def true_path_graph(true_path: FloatArray, join_radius: float = TRUE_PATH_JOIN_RADIUS) -> RouteMap:
    """The driven ground-truth path as a route map: the reference a map's routes are judged by.

    Args:
        true_path: ``(M, 2+)`` the ground-truth poses in time order (e.g. one per camera frame,
            ``EventLog.ground_truth``).
        join_radius: samples this close are joined (m); see :data:`TRUE_PATH_JOIN_RADIUS`.

    Vertex ``k`` is sample ``k``; consecutive samples are joined (the way the robot drove), and so
    is every pair of samples within ``join_radius`` (the path meeting itself), each edge weighted
    by its length. A route on it follows the driven path, so its length is the true shortest
    path length along that path.

    Raises:
        ParameterError: the path is empty or not finite, or the radius is not positive.

    """
    path = np.asarray(true_path, dtype=np.float64)
    if path.ndim != 2 or path.shape[0] == 0 or path.shape[1] < 2:
        raise ParameterError("the true path needs at least one (x, y) sample")
    if not np.isfinite(path[:, :2]).all():
        raise ParameterError("the true path's positions must be finite numbers")
    if not (join_radius > 0 and math.isfinite(join_radius)):
        raise ParameterError(f"the join radius must be a positive distance (m), not {join_radius}")
    xy = path[:, :2]
    m = xy.shape[0]
    chain = np.arange(m - 1, dtype=np.int64)
    joins = cKDTree(xy).query_pairs(join_radius, output_type="ndarray").astype(np.int64)
    e_from = np.r_[chain, joins[:, 0]]
    e_to = np.r_[chain + 1, joins[:, 1]]
    poses = path[:, :3] if path.shape[1] >= 3 else xy
    return RouteMap(np.arange(m, dtype=np.int64), poses, e_from, e_to)


def segments_on_path(
    start: FloatArray, end: FloatArray, true_path: FloatArray, radius: float
) -> tuple[FloatArray, FloatArray]:
    """Per segment, its length and the part of it within ``radius`` of the true path (m).

    Args:
        start: ``(S, 2+)`` the segments' first points ...
        end: ``(S, 2+)`` ... and their second, in the ground truth's frame (align a map first:
            :func:`~cogmap_core.evaluation.align_rigid_2d`).
        true_path: ``(M, 2+)`` the dense ground-truth path in time order.
        radius: the tolerance (m).

    Each segment is cut into pieces of at most ``radius / 8``, judged at their midpoints against
    the exact distance to the path's segments (as layout correctness is).

    """
    a = np.asarray(start, dtype=np.float64).reshape(-1, np.shape(start)[-1])[:, :2]
    b = np.asarray(end, dtype=np.float64).reshape(-1, np.shape(end)[-1])[:, :2]
    path = np.asarray(true_path, dtype=np.float64)[:, :2]
    if not (radius > 0 and math.isfinite(radius)):
        raise ParameterError(f"the radius must be a positive distance (m), not {radius}")
    lengths = np.hypot(*(b - a).T) if a.size else np.zeros(0)
    if a.shape[0] == 0:
        return lengths, np.zeros(0)
    spacing = radius / 8.0
    mid, piece = _sample_polyline_pieces(a, b, spacing)
    pieces = np.maximum(np.ceil(lengths / spacing).astype(np.int64), 1)  # as the sampler cuts
    owner = np.repeat(np.arange(a.shape[0]), pieces)
    if path.shape[0] >= 2:
        near = _within_radius_of_segments(mid, path[:-1], path[1:], radius)
    else:
        near = np.hypot(*(mid - path[:1]).T) <= radius if path.size else np.zeros(0, bool)
    on = np.bincount(owner, weights=piece * near, minlength=a.shape[0])
    return lengths, np.minimum(on, lengths)


def on_path_share(points: FloatArray, true_path: FloatArray, radius: float) -> float:
    """The share of a polyline's length within ``radius`` of the true path (1.0 if no length).

    ``points``: ``(K, 2+)`` a route's positions in the ground truth's frame (see
    :func:`segments_on_path`).
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.shape[0] < 2:
        return 1.0
    lengths, on = segments_on_path(pts[:-1], pts[1:], true_path, radius)
    total = float(lengths.sum())
    return float(on.sum()) / total if total > 0 else 1.0
