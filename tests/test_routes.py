"""Routes on a map (cogmap_core.routes): exact answers on hand-made maps (the search over the
edges, the joins of near vertices, the straightened way), the true-path graph, the on-path
share, a recorded event stream and ``cogmap route``."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from app.cli import main
from cogmap_core.cognitive_map import CognitiveMap, MapMode
from cogmap_core.config import MapParams
from cogmap_core.errors import CogmapError, ParameterError
from cogmap_core.event_file import load_event_file
from cogmap_core.event_log import EventLog
from cogmap_core.events import CreateVertex, LinkToVertex, Odometry
from cogmap_core.g2o import write_g2o
from cogmap_core.map_graph import MapSnapshot, nearest_vertex
from cogmap_core.posegraph import PoseGraph
from cogmap_core.routes import (
    TRUE_PATH_JOIN_RADIUS,
    NoRouteError,
    RouteMap,
    on_path_share,
    segments_on_path,
    shortest_route,
    straighten,
    true_path_graph,
)
from tests.conftest import DATA

SQRT2 = math.sqrt(2.0)
CORNER_CUT = (SQRT2 - 1) * TRUE_PATH_JOIN_RADIUS  # the most a join shortens a right-angle turn
CORRIDOR = MapParams().link_sigma_position  # a route's way strays this far from its vertices
INSET = CORRIDOR / SQRT2  # ... so it turns a right angle this far inside the corner, each way


def plain(source, weight="poses") -> RouteMap:
    """The route map of the edges alone: routes through the vertices, no joins, not straightened."""
    return RouteMap.of(source, weight, join_radius=0.0, corridor=0.0)


def snapshot(poses, edges, rel=None, ids=None) -> MapSnapshot:
    """A map snapshot of hand-made vertices and edges (ids 0.. unless given)."""
    poses = np.asarray(poses, dtype=np.float64)
    if poses.shape[1] == 2:
        poses = np.column_stack([poses, np.zeros(len(poses))])
    ids = np.arange(len(poses)) if ids is None else np.asarray(ids)
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    pos = dict(zip(ids.tolist(), poses[:, :2].tolist(), strict=True))
    if rel is None:  # measured = the poses' difference (headings 0)
        rel = [[pos[b][0] - pos[a][0], pos[b][1] - pos[a][1], 0.0] for a, b in edges.tolist()]
    m = len(edges)
    return MapSnapshot(
        vertex_ids=ids.astype(np.int64),
        poses=poses,
        vertex_time=np.arange(len(poses), dtype=np.float64),
        vertex_view=np.zeros(len(poses), dtype=np.int64),
        edge_from=edges[:, 0].copy(),
        edge_to=edges[:, 1].copy(),
        edge_rel=np.asarray(rel, dtype=np.float64).reshape(m, 3),
        edge_time=np.zeros(m),
        edge_kind=np.zeros(m, dtype=np.int8),
        edge_cluster=np.full(m, -1, dtype=np.int64),
        current_vertex=int(ids[-1]),
        current_pose=poses[-1].copy(),
    )


# a unit square 0 (0,0), 1 (1,0), 2 (1,1), 3 (0,1) with the diagonal 0-2
SQUARE = [(0, 0), (1, 0), (1, 1), (0, 1)]
SQUARE_EDGES = [(0, 1), (1, 2), (2, 3), (3, 0), (0, 2)]


def test_square_with_a_diagonal_takes_the_diagonal():
    routes = plain(snapshot(SQUARE, SQUARE_EDGES))
    route = routes.route_between(0, 2)
    assert route.vertex_ids.tolist() == [0, 2]
    assert route.length == pytest.approx(SQRT2, abs=1e-12)
    assert route.points.tolist() == [[0.0, 0.0], [1.0, 1.0]]
    assert route.num_edges == 1
    # 1 -> 3: around either way or over the diagonal, all 2 m... the diagonal route is 1-0-3 or
    # 1-2-3 (2 m) vs 1-0-2-3 (2 + sqrt 2): two edges
    other = routes.route_between(1, 3)
    assert other.length == pytest.approx(2.0, abs=1e-12)
    assert other.num_edges == 2
    # reversed, the same route backwards
    back = routes.route_between(2, 0)
    assert back.vertex_ids.tolist() == [2, 0]


def test_square_without_its_diagonal_goes_round():
    routes = plain(snapshot(SQUARE, SQUARE_EDGES[:4]))
    route = routes.route_between(0, 2)
    assert route.length == pytest.approx(2.0, abs=1e-12)
    assert route.vertex_ids.tolist() in ([0, 1, 2], [0, 3, 2])


def test_weights_are_the_optimised_lengths_or_the_measured_ones():
    # the diagonal's measurement claims 3 m (odometry drift, a bad link): the optimised poses
    # put its ends sqrt(2) apart; by default the route believes the poses
    rel = [[1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0], [3, 0, 0]]
    snap = snapshot(SQUARE, SQUARE_EDGES, rel=rel)
    assert RouteMap.of(snap).route_between(0, 2).vertex_ids.tolist() == [0, 2]
    measured = RouteMap.of(snap, "measured").route_between(0, 2)
    assert measured.num_edges == 2
    assert measured.length == pytest.approx(2.0, abs=1e-12)
    with pytest.raises(ParameterError, match="'poses' or 'measured'"):
        RouteMap.of(snap, "straight")  # type: ignore[arg-type]


def test_dead_end_is_entered_and_left_the_same_way():
    # a corridor 0-1-2-3 along x with a dead end 1-4-5 going up from 1
    poses = [(0, 0), (1, 0), (2, 0), (3, 0), (1, 1), (1, 2.5)]
    edges = [(0, 1), (1, 2), (2, 3), (1, 4), (4, 5)]
    routes = plain(snapshot(poses, edges))
    route = routes.route_between(5, 3)
    assert route.vertex_ids.tolist() == [5, 4, 1, 2, 3]
    assert route.length == pytest.approx(1.5 + 1 + 2, abs=1e-12)
    # from the dead end's tip to the corridor's start: back out of it first
    assert routes.route_between(5, 0).vertex_ids.tolist() == [5, 4, 1, 0]
    # places snap to the nearest vertex: (1.1, 2.3) is at 5, (2.8, 0.3) at 3
    by_place = routes.route((1.1, 2.3), (2.8, 0.3))
    assert by_place.vertex_ids.tolist() == [5, 4, 1, 2, 3]
    assert by_place.start_gap == pytest.approx(math.hypot(0.1, 0.2))
    assert by_place.goal_gap == pytest.approx(math.hypot(0.2, 0.3))
    # straightened (the default): the same vertices, the way inside the corner at vertex 1
    straight = RouteMap.of(snapshot(poses, edges)).route((1.1, 2.3), (2.8, 0.3))
    assert straight.vertex_ids.tolist() == [5, 4, 1, 2, 3]
    np.testing.assert_allclose(straight.points, [[1, 2.5], [1 + INSET, INSET], [3, 0]], atol=1e-12)
    assert straight.length == pytest.approx(
        math.hypot(INSET, 2.5 - INSET) + math.hypot(2 - INSET, INSET), abs=1e-12
    )
    assert straight.goal_gap == by_place.goal_gap


def test_snapping_to_the_nearest_vertex():
    edges = [(a + 10, b + 10) for a, b in SQUARE_EDGES]  # edges name vertex ids
    routes = RouteMap.of(snapshot(SQUARE, edges, ids=[10, 11, 12, 13]))
    assert routes.snap((0.9, 0.2)) == (11, pytest.approx(math.hypot(0.1, 0.2)))
    assert routes.snap([0.4, 0.6, 0.0]) == (13, pytest.approx(math.hypot(0.4, 0.4)))
    # both places at one vertex: a route of one vertex and no length
    route = routes.route((1.05, 1.0), (0.95, 0.9))
    assert route.vertex_ids.tolist() == [12]
    assert route.length == 0.0
    assert route.num_edges == 0
    for bad in [(math.nan, 0.0), (1.0,), (0.0, math.inf)]:
        with pytest.raises(ParameterError, match="two finite numbers"):
            routes.snap(bad)


def test_the_one_nearest_vertex_rule():
    """nearest_vertex: the row nearest in x, y and its distance, the first on a tie."""
    poses = np.array([[1.0, 0.0, 0.3], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 2.0]])
    assert nearest_vertex(poses, (0.9, 0.2)) == (0, pytest.approx(math.hypot(0.1, 0.2)))
    assert nearest_vertex(poses, np.array([0.0, 0.0])) == (0, 1.0)  # four at 1 m: the first
    assert nearest_vertex(poses, (0.1, 1.0, 5.0)) == (1, pytest.approx(0.1))  # two alike: first
    assert nearest_vertex(np.zeros((0, 3)), (0.0, 0.0)) is None
    tree = cKDTree(poses[:, :2])  # the route map's many snaps: the same vertex
    assert nearest_vertex(poses, (-0.8, 0.1), tree) == (2, pytest.approx(math.hypot(0.2, 0.1)))


def test_disconnected_pieces_give_no_route():
    # two squares 5 m apart, never joined
    poses = SQUARE + [(x + 5, y) for x, y in SQUARE]
    edges = SQUARE_EDGES + [(a + 4, b + 4) for a, b in SQUARE_EDGES]
    routes = RouteMap.of(snapshot(poses, edges))
    assert routes.route_between(4, 6).length == pytest.approx(SQRT2)
    with pytest.raises(NoRouteError) as caught:
        routes.route((0, 0), (6, 1))
    assert isinstance(caught.value, CogmapError)
    assert str(caught.value) == (
        "no route from vertex 0 to vertex 6: they lie on separate pieces of the map "
        "(no chain of edges joins them)"
    )
    assert np.isinf(routes.lengths([0, 4], [6, 6])[0])
    assert routes.lengths([0, 4], [6, 6])[1] == pytest.approx(SQRT2)


def test_an_empty_map_and_an_unknown_vertex_give_no_route():
    empty = RouteMap.of(CognitiveMap(MapMode.COMPACT))
    assert empty.num_vertices == 0
    with pytest.raises(NoRouteError, match="the map has no vertex yet"):
        empty.route((0, 0), (1, 1))
    routes = RouteMap.of(snapshot(SQUARE, SQUARE_EDGES))
    with pytest.raises(NoRouteError, match="vertex 7 is not a live vertex of this map"):
        routes.route_between(0, 7)


def test_parallel_edges_count_once_with_the_shortest_weight():
    # a pose graph (a g2o file) may hold two edges for one pair
    graph = PoseGraph(
        vertex_ids=np.array([3, 1, 2]),
        poses=np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]], dtype=float),
        edge_from=np.array([0, 0, 1]),
        edge_to=np.array([1, 1, 2]),
        measurements=np.array([[1.5, 0, 0], [0.9, 0, 0], [1, 0, 0]], dtype=float),
        information=np.tile(np.eye(3), (3, 1, 1)),
    )
    measured = RouteMap.of(graph, "measured")
    assert measured.num_edges == 2
    route = measured.route_between(3, 2)
    assert route.vertex_ids.tolist() == [3, 1, 2]
    assert route.length == pytest.approx(1.9)
    assert RouteMap.of(graph).route_between(3, 2).length == pytest.approx(2.0)


def test_a_cognitive_map_and_its_snapshot_route_alike():
    # drive a 1 m square (vertices at its corners), then link back to the start
    cmap = CognitiveMap(MapMode.STANDARD)
    cmap.apply(CreateVertex(time=0.0, vertex=0, view_template=0))
    t = 0.0
    for k in range(1, 4):
        t += 1.0
        cmap.apply(Odometry(time=t, translation=1.0, rotation=0.0 if k == 1 else math.pi / 2))
        cmap.apply(CreateVertex(time=t, vertex=k, view_template=k))
    t += 1.0
    cmap.apply(Odometry(time=t, translation=1.0, rotation=math.pi / 2))
    cmap.apply(LinkToVertex(time=t, target=0, relative_rad=0.0))
    assert cmap.num_edges == 4
    from_map = shortest_route(cmap, (0.0, 0.0), (1.0, 1.0))
    from_snapshot = shortest_route(cmap.snapshot(), (0.0, 0.0), (1.0, 1.0))
    # round a corner of the square (either one), straightened inside it
    assert from_map.length == pytest.approx(2 * math.hypot(1 - INSET, INSET), abs=1e-9)
    assert from_map.vertex_ids.tolist() == from_snapshot.vertex_ids.tolist()
    assert from_map.length == from_snapshot.length
    # 3 -> 0 over the loop closure: one edge
    assert RouteMap.of(cmap).route_between(3, 0).vertex_ids.tolist() == [3, 0]


# a corridor driven there (0..5 along y = 0) and back 6 cm to its side (6..11 along y = 0.06),
# vertices 0.3 m apart, the two strands joined only where the robot turned at the far end: view
# matching does not recognise a place seen facing the other way
THERE = [(0.3 * k, 0.0) for k in range(6)]
BACK = [(1.5 - 0.3 * k, 0.06) for k in range(6)]
BOTH_WAYS = [(k, k + 1) for k in range(11)]


def test_joins_let_a_route_cross_between_a_corridor_s_strands():
    snap = snapshot(THERE + BACK, BOTH_WAYS)
    # over the edges alone, from 1 (0.3, 0) to 9 (0.6, 0.06): to the far end and back
    assert plain(snap).route_between(1, 9).length == pytest.approx(1.2 + 0.06 + 0.9, abs=1e-12)
    # vertices within the integration radius (0.1 m) are joined: the six pairs 6 cm apart
    joined = RouteMap.of(snap, corridor=0.0)
    assert joined.join_radius == MapParams().integration_radius == 0.1
    assert joined.num_joins == 6
    assert joined.num_edges == 11 + 5  # the far end's pair 5-6 had its edge already
    route = joined.route_between(1, 9)
    assert route.vertex_ids.tolist() in ([1, 2, 9], [1, 10, 9])  # along, then across, or so
    assert route.length == pytest.approx(0.3 + 0.06, abs=1e-12)
    assert route.num_edges == 2
    # straightened too (the default): inside the turn of either way, by the same length
    straight = RouteMap.of(snap).route_between(1, 9)
    assert straight.vertex_ids.tolist() == route.vertex_ids.tolist()
    assert straight.length == pytest.approx(
        math.hypot(0.3 - INSET, INSET) + math.hypot(INSET, 0.06 - INSET), abs=1e-12
    )
    assert RouteMap.of(snap).lengths([1, 0], [9, 9]).tolist() == pytest.approx(
        [straight.length, RouteMap.of(snap).route_between(0, 9).length], abs=1e-12
    )


def test_joins_never_reach_across_a_wall():
    # two corridors on either side of a 0.1 m wall (centre lines 0.4 m apart), joined round
    # the wall's end at x = 1.5
    there = [(0.3 * k, 0.0) for k in range(6)]
    beyond = [(1.5 - 0.3 * k, 0.4) for k in range(6)]
    snap = snapshot(there + beyond, [(k, k + 1) for k in range(11)])
    routes = RouteMap.of(snap)
    assert routes.num_joins == 0
    route = routes.route_between(0, 11)
    assert route.vertex_ids.tolist() == list(range(12))
    # round the wall's end, inside both corners
    np.testing.assert_allclose(
        route.points,
        [[0, 0], [1.5 - INSET, INSET], [1.5 - INSET, 0.4 - INSET], [0, 0.4]],
        atol=1e-12,
    )
    assert route.length == pytest.approx(
        2 * math.hypot(1.5 - INSET, INSET) + 0.4 - 2 * INSET, abs=1e-12
    )
    # a join radius wider than the wall would cut through it
    assert RouteMap.of(snap, join_radius=0.45).route_between(0, 11).length == pytest.approx(0.4)


def test_the_join_radius_and_corridor_are_the_map_s_own_parameters():
    params = MapParams(integration_radius=0.2, link_sigma_position=0.05)
    cmap = CognitiveMap(MapMode.COMPACT, params)
    assert (RouteMap.of(cmap).join_radius, RouteMap.of(cmap).corridor) == (0.2, 0.05)
    snap = snapshot(SQUARE, SQUARE_EDGES)  # a snapshot or a pose graph: the defaults
    assert (RouteMap.of(snap).join_radius, RouteMap.of(snap).corridor) == (0.1, 0.03)
    assert RouteMap.of(snap, params=params).corridor == 0.05
    # measured weights: joins (weighed in the poses), the way not straightened
    measured = RouteMap.of(snap, "measured")
    assert (measured.join_radius, measured.corridor) == (0.1, 0.0)
    with pytest.raises(ParameterError, match="straightened only when its length is measured"):
        RouteMap([0, 1], [(0, 0), (1, 0)], [0], [1], weights=[1.0], corridor=0.03)
    for bad in (-0.1, math.nan, math.inf):
        with pytest.raises(ParameterError, match="join radius must be a distance of 0 or more"):
            RouteMap([0, 1], [(0, 0), (1, 0)], [0], [1], join_radius=bad)
        with pytest.raises(ParameterError, match="corridor must be a distance of 0 or more"):
            RouteMap([0, 1], [(0, 0), (1, 0)], [0], [1], corridor=bad)


def test_straighten_cuts_inside_a_corner_by_the_corridor():
    c = 0.05 / SQRT2  # the gate at the corner lies on its bisector, 0.05 m each way
    # turning left, then turning right: the way bends at the gate's inner end
    left = straighten(np.array([(0, 0), (1, 0), (1, 1)], float), 0.05)
    np.testing.assert_allclose(left, [[0, 0], [1 - c, c], [1, 1]], atol=1e-15)
    right = straighten(np.array([(0, 0), (1, 0), (1, -1)], float), 0.05)
    np.testing.assert_allclose(right, [[0, 0], [1 - c, -c], [1, -1]], atol=1e-15)
    # a straight run through gates across it: one segment; 0 gives the polyline back
    run = np.array([(0, 0), (1, 0), (2, 0.0)])
    np.testing.assert_array_equal(straighten(run, 0.05), [[0, 0], [2, 0]])
    np.testing.assert_array_equal(straighten(run, 0.0), run)
    np.testing.assert_array_equal(straighten(run[:2], 0.05), run[:2])
    # repeated points (two vertices at one place) are passed once
    np.testing.assert_array_equal(straighten(np.array([(0, 0), (1, 0), (1, 0), (2, 0)]), 0.05),
                                  [[0, 0], [2, 0]])  # fmt: skip
    with pytest.raises(ParameterError, match="corridor must be a distance of 0 or more"):
        straighten(run, -0.01)


def test_straighten_keeps_within_the_corridor_of_a_zigzag():
    # vertices 2 cm either side of a line: the gates (3 cm) leave a way 1 cm off the line
    x = np.linspace(0, 3, 13)
    zigzag = np.column_stack([x, 0.02 * (-1.0) ** np.arange(13)])
    np.testing.assert_allclose(
        straighten(zigzag, 0.03), [[0, 0.02], [0.25, 0.01], [2.75, 0.01], [3, 0.02]], atol=1e-15
    )
    # within 5 cm the line through the first and last vertex fits: straight
    np.testing.assert_allclose(straighten(zigzag, 0.05), [[0, 0.02], [3, 0.02]], atol=1e-15)
    # a polyline folding back on itself reaches to within the corridor of its turn
    np.testing.assert_allclose(
        straighten(np.array([(0, 0), (1, 0), (0, 0)], float), 0.03),
        [[0, 0], [0.97, 0], [0, 0]],
        atol=1e-15,
    )


def line(a, b, step=0.01):
    """Samples from a to b (a included, b not) every ``step`` metres, heading along."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    n = max(int(round(np.hypot(*(b - a)) / step)), 1)
    xy = a + (b - a) * (np.arange(n) / n)[:, None]
    heading = math.atan2(b[1] - a[1], b[0] - a[0])
    return np.column_stack([xy, np.full(n, heading)])


def test_the_true_path_graph_joins_where_the_path_crosses_itself():
    # east along y=0 from x=-1 to 1, down to y=-1, west to x=0.005, then north across the
    # first stretch (3 m of driving later; no sample of one on the other) up to y=1
    path = np.vstack(
        [
            line((-1, 0), (1, 0)),
            line((1, 0), (1, -1)),
            line((1, -1), (0.005, -1)),
            line((0.005, -1), (0.005, 1)),
            [[0.005, 1.0, math.pi / 2]],
        ]
    )
    graph = true_path_graph(path)
    route = graph.route((-1, 0), (0.005, 1))
    # across the crossing, not 6 m round; the join there cuts the turn by up to (sqrt 2 - 1) r
    assert 2.005 - CORNER_CUT <= route.length < 2.005
    assert route.start_gap == 0.0 and route.goal_gap == 0.0
    chain_only = true_path_graph(path, join_radius=0.001)
    assert chain_only.route((-1, 0), (0.005, 1)).length == pytest.approx(5.995, abs=1e-9)
    # every join is within the radius; a route steps no further sideways
    assert np.max(np.hypot(*np.diff(route.points, axis=0).T)) <= 0.05 + 1e-12


def test_the_true_path_graph_never_joins_across_a_wall():
    # there and back along two corridors 0.4 m apart (a 0.1 m wall between 0.3 m corridors)
    path = np.vstack(
        [line((0, 0), (2, 0)), line((2, 0), (2, 0.4)), line((2, 0.4), (0, 0.4)), [[0, 0.4, 0]]]
    )
    graph = true_path_graph(path)
    assert 4.4 - 2 * CORNER_CUT <= graph.route((0, 0), (0, 0.4)).length < 4.4  # two corners
    # a join radius wider than the wall would cut through it
    assert true_path_graph(path, join_radius=0.45).route((0, 0), (0, 0.4)).length < 0.5
    # laps along the same corridor (2 cm apart, the other way) are joined all along
    laps = np.vstack([line((0, 0), (2, 0)), line((2, 0.02), (0, 0.02)), [[0, 0.02, 0]]])
    assert true_path_graph(laps).route((0, 0), (0, 0.02)).length == pytest.approx(0.02, abs=1e-9)


def test_true_path_graph_rejects_bad_input():
    with pytest.raises(ParameterError, match="at least one"):
        true_path_graph(np.zeros((0, 2)))
    with pytest.raises(ParameterError, match="finite"):
        true_path_graph(np.array([[0.0, 0.0], [np.nan, 1.0]]))
    with pytest.raises(ParameterError, match="join radius"):
        true_path_graph(np.zeros((2, 2)), join_radius=0.0)


def test_on_path_share_measures_the_part_within_the_radius():
    path = line((0, 0), (4, 0))
    assert on_path_share([(0, 0.05), (2, 0.05)], path, 0.08) == pytest.approx(1.0)
    # half the route 0.2 m off the path (a shortcut through a wall)
    share = on_path_share([(0, 0), (1, 0), (1, 0.2), (2, 0.2)], path, 0.08)
    off = 0.2 - 0.08 + 1.0  # the step up beyond 8 cm, then the whole 1 m along y=0.2
    assert share == pytest.approx((2.2 - off) / 2.2, abs=0.01)
    lengths, on = segments_on_path(
        np.array([[0, 0], [1, 0.2]]), np.array([[1, 0], [2, 0.2]]), path, 0.08
    )
    assert lengths.tolist() == pytest.approx([1.0, 1.0])
    assert on.tolist() == pytest.approx([1.0, 0.0], abs=0.01)
    assert on_path_share([(1, 1)], path, 0.08) == 1.0  # a single vertex has no length


@pytest.fixture(scope="module")
def figure_eight():
    log = EventLog.from_recording(load_event_file(DATA / "figure_eight_3laps.events.npz"))
    cmap = CognitiveMap(MapMode.COMPACT)
    cmap.apply_all(log.events)
    cmap.finish(log.frame_time[-1])
    return log, cmap


@pytest.mark.parametrize(
    ("start", "goal"),
    [
        ((0.25, 1.05), (2.25, 1.05)),  # A -> D along the top corridor
        ((0.25, 1.05), (2.65, 0.25)),  # A -> the bottom right corner
        ((0.25, 0.25), (2.65, 1.05)),  # C -> the top right corner
    ],
)
def test_compact_route_on_a_recorded_stream_is_the_true_shortest_path(figure_eight, start, goal):
    """3 laps of the figure eight, the compact map: its route between two places (given in the
    ground truth's frame, taken into the map's) is within 2 % of the true shortest path along the
    driven path between the places of its two end vertices, straightened as the route is (the
    driven path rounds its own turns), no longer than that path itself, and lies on it."""
    log, cmap = figure_eight
    snap = cmap.snapshot()
    alignment = log.map_accuracy(snap).alignment
    c, s = math.cos(alignment.theta), math.sin(alignment.theta)

    def to_map(p):
        dx, dy = p[0] - alignment.tx, p[1] - alignment.ty
        return (c * dx + s * dy, -s * dx + c * dy)

    route = RouteMap.of(cmap).route(to_map(start), to_map(goal))
    assert route.start_gap < 0.1 and route.goal_gap < 0.1
    truth = np.asarray(log.ground_truth)
    true_paths = true_path_graph(truth)
    points = alignment.apply(route.points)
    reference = true_paths.route_between(
        true_paths.snap(points[0])[0], true_paths.snap(points[-1])[0]
    )
    straight = straighten(reference.points, CORRIDOR)
    assert route.length == pytest.approx(np.hypot(*np.diff(straight, axis=0).T).sum(), rel=0.02)
    assert route.length <= reference.length
    assert on_path_share(points, truth, 0.08) >= 0.99


def write_map(tmp_path):
    """A report folder holding a compact.g2o: the dead end of the tests above."""
    poses = [(0, 0), (1, 0), (2, 0), (3, 0), (1, 1), (1, 2.5)]
    edges = [(0, 1), (1, 2), (2, 3), (1, 4), (4, 5)]
    snap = snapshot(poses, edges)
    graph = PoseGraph(
        vertex_ids=snap.vertex_ids,
        poses=snap.poses,
        edge_from=snap.edge_from,
        edge_to=snap.edge_to,
        measurements=snap.edge_rel,
        information=np.tile(np.eye(3), (len(edges), 1, 1)),
    )
    write_g2o(graph, tmp_path / "compact.g2o")
    return tmp_path


def test_cli_route_on_a_report_folder(tmp_path, capsys):
    folder = write_map(tmp_path)
    assert main(["route", str(folder), "--from", "1.1,2.3", "--to", "2.8,0.3"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["vertices"] == [5, 4, 1, 2, 3]
    # the way straightened inside the corner at vertex 1 (the default link_sigma_position)
    assert out["length_m"] == round(
        math.hypot(INSET, 2.5 - INSET) + math.hypot(2 - INSET, INSET), 6
    )
    assert out["edges"] == 4
    assert out["points"] == [[1.0, 2.5], [round(1 + INSET, 6), round(INSET, 6)], [3.0, 0.0]]
    assert out["map"] == str(folder / "compact.g2o")
    # a report folder's own map parameters (config.json): straightened within 0.1 m
    config = {"dataset": "x.bag", "map": MapParams(link_sigma_position=0.1).to_dict()}
    (folder / "config.json").write_text(json.dumps(config))
    assert main(["route", str(folder), "--from", "1.1,2.3", "--to", "2.8,0.3"]) == 0
    inset = round(0.1 / SQRT2, 6)
    assert json.loads(capsys.readouterr().out)["points"][1] == [round(1 + 0.1 / SQRT2, 6), inset]
    # a g2o file given directly, a negative coordinate written with "="
    assert main(["route", str(folder / "compact.g2o"), "--from=-0.2,0", "--to", "3,0"]) == 0
    assert json.loads(capsys.readouterr().out)["vertices"] == [0, 1, 2, 3]


def test_cli_route_bad_report_configuration_is_one_line(tmp_path, capsys):
    folder = write_map(tmp_path)
    (folder / "config.json").write_text(json.dumps({"map": {"integration_radius": -1}}))
    assert main(["route", str(folder), "--from", "0,0", "--to", "3,0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "config.json: integration_radius" in err[0], err


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--map", "standard"], "no standard.g2o in this folder"),
        (["--from", "1;2"], "argument --from: place '1;2' is not X,Y"),
        (["--to", "nan,1"], "argument --to: place 'nan,1' is not two finite numbers"),
    ],
)
def test_cli_route_bad_input_is_one_line(tmp_path, capsys, argv, message):
    folder = write_map(tmp_path)
    args = ["route", str(folder), "--from", "0,0", "--to", "3,0"] + argv
    try:
        code = main(args)
    except SystemExit as stop:  # argparse's own errors exit
        code = stop.code
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err


def test_cli_route_unreachable_goal_and_missing_map(tmp_path, capsys):
    graph = PoseGraph(
        vertex_ids=np.array([0, 1, 2]),
        poses=np.array([[0, 0, 0], [1, 0, 0], [5, 0, 0]], dtype=float),
        edge_from=np.array([0]),
        edge_to=np.array([1]),
        measurements=np.array([[1.0, 0, 0]]),
        information=np.eye(3)[None],
    )
    write_g2o(graph, tmp_path / "pieces.g2o")
    assert main(["route", str(tmp_path / "pieces.g2o"), "--from", "0,0", "--to", "5,0"]) == 2
    assert capsys.readouterr().err.strip() == (
        "cogmap route: error: no route from vertex 0 to vertex 2: they lie on separate pieces "
        "of the map (no chain of edges joins them)"
    )
    assert main(["route", str(tmp_path / "none.g2o"), "--from", "0,0", "--to", "5,0"]) == 2
    assert "no such file" in capsys.readouterr().err
