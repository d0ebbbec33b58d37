"""The cognitive map: events, storage, neighborhood fields, duplicate links, clustering,
optimisation, short edges, modes and size history (paper, section Method).

Scene integration is in ``test_scene_integration.py``, the relocalisation test in
``test_relocalisation.py``, whole recorded streams in ``test_map_fidelity.py``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from cogmap_core.cognitive_map import CognitiveMap, EdgeKind, MapMode, MapSet, neighborhood_field
from cogmap_core.config import MapParams
from cogmap_core.errors import EventError, ParameterError
from cogmap_core.events import CreateVertex, LinkToVertex, Odometry, SetCurrentVertex
from cogmap_core.geometry import between, compose
from tests.mapscript import Script

HALF_PI = math.pi / 2
# Scripts below place links where the test needs them, not where a robot would be: the
# relocalisation consistency test is switched off unless a test is about it.
NO_GATE = MapParams(gate_position=1e9, gate_heading=1e9)


def edges_of(cmap: CognitiveMap) -> set[tuple[int, int]]:
    snap = cmap.snapshot()
    return set(zip(snap.edge_from.tolist(), snap.edge_to.tolist(), strict=True))


def edge_rel(cmap: CognitiveMap, a: int, b: int, kind: EdgeKind | None = None) -> np.ndarray:
    snap = cmap.snapshot()
    k = np.flatnonzero(
        (snap.edge_from == a) & (snap.edge_to == b) & ((snap.edge_kind == kind) | (kind is None))
    )
    assert k.size == 1
    return snap.edge_rel[k[0]]


def build(
    mode: str, script: Script, params: MapParams | None = None, finish: bool = True
) -> CognitiveMap:
    cmap = CognitiveMap(mode, params or NO_GATE)
    cmap.apply_all(script.events)
    if finish:
        cmap.finish()
    return cmap


# ------------------------------------------------------------------------------------------
# events and storage
# ------------------------------------------------------------------------------------------


def test_standard_map_is_exactly_what_the_events_build():
    s = Script()
    s.create()
    s.move(0.1)
    s.create()
    s.move(0.2, 0.5)
    s.create()
    s.link(0)
    cmap = build("standard", s, finish=False)
    snap = cmap.snapshot()
    assert snap.vertex_ids.tolist() == [0, 1, 2]
    np.testing.assert_allclose(snap.poses, [s.truth[0], s.truth[1], s.truth[2]], atol=1e-12)
    assert snap.edge_kind.tolist() == [
        EdgeKind.SEQUENTIAL,
        EdgeKind.SEQUENTIAL,
        EdgeKind.LOOP_CLOSURE,
    ]
    assert snap.edge_from.tolist() == [0, 1, 2] and snap.edge_to.tolist() == [1, 2, 0]
    # OpenRatSLAM link fields: d, heading_rad, facing_rad relative to the source vertex
    assert snap.edge_d[1] == pytest.approx(0.2)
    assert snap.edge_heading_rad[1] == pytest.approx(0.5)
    assert snap.edge_facing_rad[1] == pytest.approx(0.5)
    # a link puts the target at the robot's position, heading = facing - relative_rad
    np.testing.assert_allclose(snap.edge_rel[2], [0.0, 0.0, -0.5], atol=1e-12)
    assert snap.edge_cluster.tolist() == [-1, -1, 0]
    assert snap.vertex_time.tolist() == [0.0, pytest.approx(0.1), pytest.approx(0.2)]
    assert snap.vertex_view.tolist() == [0, 1, 2]


@pytest.mark.parametrize(
    ("events", "message"),
    [
        ([CreateVertex(0.0, 1, 0)], "next vertex id must be 0"),
        ([CreateVertex(1.0, 0, 0), Odometry(0.5, 0.1, 0.0)], "earlier than the previous event"),
        ([CreateVertex(0.0, 0, 0), LinkToVertex(0.1, 3)], "vertex 3 does not exist"),
        ([LinkToVertex(0.0, 0)], "before any vertex"),
        ([CreateVertex(0.0, 0, 0), Odometry(0.1, float("nan"), 0.0)], "not finite"),
        ([CreateVertex(0.0, 0, 0), SetCurrentVertex(0.1, 0, float("inf"))], "non-finite"),
        ([Odometry(float("nan"), 0.0, 0.0)], "not finite"),
    ],
)
def test_contract_violations_are_clear_errors(events, message):
    cmap = CognitiveMap("standard")
    with pytest.raises(EventError, match=message):
        cmap.apply_all(events)


def test_hundred_thousand_vertices_stay_cheap():
    cmap = CognitiveMap("standard")
    n = 100_000
    for k in range(n):
        cmap.apply(Odometry(k * 0.05, 0.01, 0.0))
        cmap.apply(CreateVertex(k * 0.05, k, k))
    assert (cmap.num_vertices, cmap.num_edges) == (n, n - 1)
    snap = cmap.snapshot()
    assert snap.poses.shape == (n, 3)
    assert snap.poses[-1, 0] == pytest.approx(0.01 * n)  # odometry before vertex 0 counts
    storage = sum(a.nbytes for a in vars(cmap).values() if isinstance(a, np.ndarray))
    assert storage < 300 * n  # flat arrays: a few hundred bytes per vertex and edge at most


# ------------------------------------------------------------------------------------------
# neighborhood fields
# ------------------------------------------------------------------------------------------


def test_neighborhood_field_formula():
    assert neighborhood_field(0.0, 0.0, 10, 10) == 1.0
    assert neighborhood_field(0.2746, 0.0, 10, 10) == pytest.approx(3.746)
    assert neighborhood_field(0.1, -0.1, 10, 10) == pytest.approx(4.0)  # |theta|
    assert neighborhood_field(0.5, 0.2, 2, 3) == pytest.approx(2.0 * 1.6)


def straight_line(n: int = 10, step: float = 0.1) -> Script:
    s = Script()
    s.create()
    for _ in range(n):
        s.move(step)
        s.create()
    return s


def test_compact_merges_consecutive_sequential_edges():
    s = straight_line()
    compact = build("compact", s, finish=False)
    standard = build("standard", s, finish=False)
    assert standard.snapshot().vertex_ids.tolist() == list(range(11))
    assert len(edges_of(standard)) == 10
    # g(0.1)=2, g(0.2)=3 <= 3.746 declined; g(0.3)=4 > 3.746 added: every third proposal.
    assert compact.snapshot().vertex_ids.tolist() == [0, 3, 6, 9]
    assert edges_of(compact) == {(0, 3), (3, 6), (6, 9)}
    for a, b in [(0, 3), (3, 6), (6, 9)]:
        np.testing.assert_allclose(edge_rel(compact, a, b), [0.3, 0.0, 0.0], atol=1e-12)
    assert compact.declined_vertices == 7
    # declined vertices are aliases of the vertex that absorbed them
    target, offset = compact.resolve(10)
    assert target == 9
    np.testing.assert_allclose(offset, [0.1, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(compact.vertex_pose(5), [0.5, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(compact.current_pose(), [1.0, 0.0, 0.0], atol=1e-12)


def test_rotation_alone_can_add_a_vertex():
    s = Script()
    s.create()
    for _ in range(4):
        s.move(0.0, 0.1)
        s.create()
    compact = build("compact", s, finish=False)
    assert compact.snapshot().vertex_ids.tolist() == [0, 3]  # g = 1 + 10 * 0.3 = 4 > 3.746
    np.testing.assert_allclose(edge_rel(compact, 0, 3), [0.0, 0.0, 0.3], atol=1e-12)


def test_alpha_beta_delta_settable_at_any_time():
    s = straight_line(6)
    cmap = CognitiveMap("compact")
    cmap.apply_all(s.events[:7])  # vertices 0..3 proposed -> 0 and 3 kept
    cmap.set_params(cmap.params.with_changes(delta=1.5))  # now g(0.1) = 2 > 1.5
    cmap.apply_all(s.events[7:])
    assert cmap.snapshot().vertex_ids.tolist() == [0, 3, 4, 5, 6]
    cmap2 = CognitiveMap("compact", MapParams(alpha=1.0, beta=0.0))  # g(d) = 1 + d
    cmap2.apply_all(s.events)
    assert cmap2.snapshot().vertex_ids.tolist() == [0]


def test_links_and_set_current_through_aliases():
    s = straight_line(10)
    cmap = build("compact", s, finish=False)
    # "you are at experience 4" (declined: 0.1 m past vertex 3)
    cmap.apply(SetCurrentVertex(2.0, 4, 0.0))
    assert cmap.current_vertex == 3
    np.testing.assert_allclose(cmap.current_pose(), [0.4, 0.0, 0.0], atol=1e-12)
    cmap.apply(Odometry(2.1, 0.1, 0.0))
    cmap.apply(CreateVertex(2.1, 11, 11))  # 0.2 m from vertex 3: declined
    np.testing.assert_allclose(cmap.vertex_pose(11), [0.5, 0.0, 0.0], atol=1e-12)
    # loop closure to experience 10 (alias of 9 at +0.1 m), relative angle 0.25
    cmap.apply(LinkToVertex(2.2, 10, 0.25))
    expected = compose([0.2, 0.0, -0.25], [-0.1, 0.0, 0.0])  # (accum, facing - rel) (+) offset^-1
    np.testing.assert_allclose(edge_rel(cmap, 3, 9, EdgeKind.LOOP_CLOSURE), expected, atol=1e-12)
    # a link to experience 8 (alias of 6, already joined to 3 by a sequential edge) adds nothing
    cmap.apply(LinkToVertex(2.3, 8, 0.0))
    assert len(edges_of(cmap)) == 4


# ------------------------------------------------------------------------------------------
# links: OpenRatSLAM's experience map keeps one edge per pair
# ------------------------------------------------------------------------------------------


def test_duplicate_link_adds_no_edge_but_still_relocalises_and_clusters():
    s = straight_line(4)  # 0 - 1 - 2 - 3 - 4, 0.1 m apart
    s.move(-0.3)  # back to vertex 1's place
    s.relocalise(1)  # 4 -> 1: a new loop closure
    s.move(0.1)
    s.relocalise(2)  # 1 -> 2: already joined by a sequential edge
    s.move(-0.1)
    s.relocalise(1)  # 2 -> 1: the same pair, the other direction
    s.move(0.0, 0.2)
    s.relocalise(1)  # 1 -> 1: the vertex the robot is at
    for mode in ("standard", "scene_integration", "compact"):
        cmap = build(mode, s, finish=False)
        assert cmap.counters.links == 4
        assert len(cmap.clusters) == 1 and cmap.clusters[0].edge_count == 4
    standard = build("standard", s, finish=False)
    assert edges_of(standard) == {(0, 1), (1, 2), (2, 3), (3, 4), (4, 1)}
    assert standard.counters.duplicate_links == 3
    assert standard.current_vertex == 1
    np.testing.assert_allclose(standard.current_pose(), s.pose, atol=1e-12)


# ------------------------------------------------------------------------------------------
# clustering and optimisation inside the map
# ------------------------------------------------------------------------------------------


def square_laps(laps: int, noise: float = 0.0, seed: int = 0) -> Script:
    """Drive a 1.2 m square as the front end reports it.

    Lap 1 proposes a vertex every 0.3 m (16 vertices, 0.3 s apart); on later laps the front end
    recognises each place (link + set current) and, every fourth place, proposes a new vertex
    instead, recognising the next place. ``noise`` scales odometry noise and bias.
    """
    rng = np.random.default_rng(seed)
    s = Script()
    first_lap = [s.create()]
    proposals = 0
    for lap in range(laps):
        for side in range(4):
            for step in range(4):
                for _ in range(3):  # 0.3 m in three odometry steps
                    md = 0.1 * (1 + 0.05 * noise * rng.standard_normal()) + 0.003 * noise
                    mr = noise * (0.01 * rng.standard_normal() + 0.006)
                    s.move(0.1, 0.0, measured=(md, mr))
                if step == 3:
                    for _ in range(3):
                        s.move(0.0, HALF_PI / 3, measured=(0.0, HALF_PI / 3 * (1 + noise * 0.05)))
                index = side * 4 + step + 1
                if lap == 0 and index < 16:
                    first_lap.append(s.create())
                elif lap > 0 and index % 4 == 2:
                    s.create()
                    proposals += 1
                else:
                    s.relocalise(first_lap[index % 16])
    s.wait(3.0)
    return s


def test_one_optimisation_per_cluster_and_none_for_sequential_edges():
    s = straight_line(20)
    cmap = build("standard", s)
    assert cmap.optimizations == [] and cmap.clusters == []
    s = square_laps(3)
    cmap = build("standard", s)
    # links come every 0.3-0.6 s (< T_interval = 2 s) and within 100 s: a single cluster
    assert len(cmap.clusters) == 1
    assert len(cmap.optimizations) == 1
    record = cmap.optimizations[0]
    assert record.cluster_id == 0
    assert record.time == pytest.approx(cmap.clusters[0].last_time + 2.0, abs=0.1 + 1e-9)
    assert cmap.clusters[0].edge_count == cmap.counters.links == 1 + 12 * 2


def test_clusters_split_on_interval_and_total_time_inside_the_map():
    s = square_laps(3)
    links = 1 + 12 * 2
    cmap = build("standard", s, MapParams(t_interval=0.25, t_total=100.0))
    # links at least 0.3 s apart (>= 0.25 s): each its own cluster
    assert len(cmap.clusters) == links
    # only clusters that added an edge trigger an optimisation: the first closure and the
    # links out of the proposed vertices (the others repeat lap 1's sequential edges)
    assert len(cmap.optimizations) == 1 + 4 * 2
    cmap = build("standard", s, MapParams(t_interval=2.0, t_total=2.0))
    sizes = [c.edge_count for c in cmap.clusters]
    assert sum(sizes) == links and max(sizes) <= 7  # 2 s of links at >= 0.3 s apart
    assert len(cmap.clusters) >= 5


@pytest.mark.parametrize("mode", ["standard", "scene_integration", "compact"])
def test_optimisation_corrects_drift(mode):
    noisy = square_laps(4, noise=0.3, seed=3)
    exact = square_laps(4, noise=0.0)
    dead_reckoned = CognitiveMap(mode, MapParams(t_interval=1e9, t_total=1e9))
    dead_reckoned.apply_all(noisy.events)
    cmap = build(mode, noisy, MapParams())  # with the relocalisation test
    snap = cmap.snapshot()
    truth = np.array([exact.truth[v] for v in snap.vertex_ids.tolist()])
    err = np.hypot(*(snap.poses[:, :2] - truth[:, :2]).T).max()
    before = dead_reckoned.snapshot()
    truth_before = np.array([exact.truth[v] for v in before.vertex_ids.tolist()])
    err_before = np.hypot(*(before.poses[:, :2] - truth_before[:, :2]).T).max()
    assert err_before > 0.12
    assert err < 0.035
    np.testing.assert_array_equal(snap.poses[0], [0.0, 0.0, 0.0])  # first vertex fixed
    assert (snap.poses[:, 2] >= -math.pi).all() and (snap.poses[:, 2] < math.pi).all()


# ------------------------------------------------------------------------------------------
# short edges: cases A, B, C
# ------------------------------------------------------------------------------------------

KEEP_ALL = MapParams(
    alpha=1e6,
    beta=1e6,
    integration_radius=0.0,
    short_edge_threshold=0.05,
    gate_position=1e9,
    gate_heading=1e9,
)


def short_edge_script(parallel: bool, existing_i_to_i2: bool) -> Script:
    s = Script()
    s.create()  # i = 0
    s.move(0.3)
    s.create()  # i+1 = 1
    s.move(0.01)
    s.create()  # i+2 = 2, 1 cm from 1
    if parallel:  # a second constraint between e_{i+1} and e_{i+2}
        s.move(-0.01)
        s.link(1)
        s.move(0.01)
    if existing_i_to_i2:  # and a constraint between e_i and e_{i+2}
        s.move(-0.31)
        s.link(0)
        s.move(0.31)
    s.move(0.3)
    s.create()  # 3
    return s


def test_short_edges_case_a_merge_into_one_edge():
    s = short_edge_script(parallel=False, existing_i_to_i2=False)
    cmap = build("compact", s, KEEP_ALL, finish=False)
    assert cmap.num_vertices == 4
    cmap.optimize_now()
    # the newer end goes: e_{i+1} and e_{i+2} are one place, kept as the one made first
    assert cmap.snapshot().vertex_ids.tolist() == [0, 1, 3]
    assert edges_of(cmap) == {(0, 1), (1, 3)}
    np.testing.assert_allclose(edge_rel(cmap, 1, 3), [0.31, 0, 0], atol=1e-9)
    assert cmap.short_edge_vertices == 1 and cmap.resolve(2)[0] == 1
    np.testing.assert_allclose(cmap.resolve(2)[1], [0.01, 0, 0], atol=1e-9)


def test_short_edges_case_b_multiple_constraints():
    s = short_edge_script(parallel=True, existing_i_to_i2=False)
    cmap = build("compact", s, KEEP_ALL, finish=False)
    # the link 2 -> 1 repeats the pair (1, 2): no parallel edge, as in OpenRatSLAM
    assert edges_of(cmap) == {(0, 1), (1, 2), (2, 3)}
    cmap.optimize_now()
    assert cmap.snapshot().vertex_ids.tolist() == [0, 1, 3]
    assert edges_of(cmap) == {(0, 1), (1, 3)}
    np.testing.assert_allclose(edge_rel(cmap, 1, 3), [0.31, 0, 0], atol=1e-9)


def test_short_edges_case_c_edges_just_removed():
    s = short_edge_script(parallel=True, existing_i_to_i2=True)
    cmap = build("compact", s, KEEP_ALL, finish=False)
    assert edges_of(cmap) == {(0, 1), (1, 2), (2, 0), (2, 3)}
    cmap.optimize_now()
    assert cmap.snapshot().vertex_ids.tolist() == [0, 1, 3]
    # e_{i+1,i+2}, the constraint e_{i+2,i} and e_{i+2} removed; e_{i+2,i+3} re-attached
    assert edges_of(cmap) == {(0, 1), (1, 3)}
    np.testing.assert_allclose(edge_rel(cmap, 1, 3), [0.31, 0, 0], atol=1e-9)


def test_short_edges_reattach_with_the_optimised_relative_pose():
    """A loop closure moves the vertices; the merged edge follows the optimised poses."""
    s = Script()
    s.create()  # 0
    s.move(0.3)
    s.create()  # 1
    s.move(0.02, 0.0, measured=(0.06, 0.0))  # odometry says 6 cm, the truth is 2 cm
    s.create()  # 2
    s.move(0.3)
    s.create()  # 3
    s.move(-0.32)
    s.relocalise(1)  # back at 1: 0.32 m, where odometry since 1 says 0.36 m
    params = KEEP_ALL.with_changes(edge_noise_model=0.0)  # the paper's weighting
    cmap = build("compact", s, params, finish=False)
    assert edge_rel(cmap, 1, 2)[0] == pytest.approx(0.06)  # not short before the optimisation
    cmap.optimize_now()
    assert cmap.snapshot().vertex_ids.tolist() == [0, 1, 3]
    optimised = {v: cmap.vertex_pose(v) for v in (1, 2, 3)}
    # 2 -> 3 re-attached to 1 repeats the loop closure 3 -> 1: dropped as redundant
    assert edges_of(cmap) == {(0, 1), (3, 1)}
    # 2 stands for the place the optimisation put it at, in 1's frame -- not the measured 6 cm
    np.testing.assert_allclose(cmap.resolve(2)[1], between(optimised[1], optimised[2]), atol=1e-9)
    assert cmap.resolve(2)[1][0] < 0.05


def test_first_vertex_is_never_removed_by_short_edges():
    s = Script()
    s.create()
    s.move(0.01)
    s.create()
    s.move(0.3)
    s.create()
    cmap = build("compact", s, KEEP_ALL, finish=False)
    cmap.optimize_now()
    assert cmap.snapshot().vertex_ids.tolist() == [0, 2]


# ------------------------------------------------------------------------------------------
# modes and history
# ------------------------------------------------------------------------------------------


def test_three_modes_from_one_stream_and_size_history():
    s = square_laps(5, noise=0.3, seed=1)
    maps = MapSet(MapParams(integration_min_age=3.0))  # a lap takes 6 s
    maps.apply_all(s.events)
    maps.finish()
    standard, integrated, compact = (maps[m] for m in MapMode)
    assert standard.num_vertices == 16 + 4 * 4  # every proposal kept
    assert integrated.num_vertices == 16  # every revisit merged onto lap 1
    assert compact.num_vertices <= integrated.num_vertices
    assert compact.num_vertices >= 4  # the square's corners survive
    for cmap in (standard, integrated, compact):
        times, vertices, edges = cmap.size_history()
        assert (np.diff(times) > 0).all()
        assert vertices[-1] == cmap.num_vertices and edges[-1] == cmap.num_edges
        assert times[0] == 0.0 and vertices[0] == 1
    t_std, v_std, _ = standard.size_history()
    assert (np.diff(v_std) >= 0).all()  # the standard map only grows


def test_parameters_are_validated_with_ranges():
    with pytest.raises(ParameterError, match=r"delta=1.0 is out of range.*\(1, "):
        MapParams(delta=1.0)
    with pytest.raises(ParameterError, match="alpha=-1"):
        MapParams(alpha=-1)
    with pytest.raises(ParameterError, match="t_interval=0"):
        MapParams(t_interval=0)
    with pytest.raises(ParameterError, match="unknown map parameter"):
        MapParams().with_changes(gamma=1.0)


@pytest.mark.parametrize("mode", ["standard", "scene_integration", "compact"])
def test_apply_all_fast_path_equals_event_by_event(mode):
    s = square_laps(5, noise=0.7, seed=4)
    params = MapParams(t_interval=0.5, t_total=3.0)
    one_by_one = CognitiveMap(mode, params)
    for event in s.events:
        one_by_one.apply(event)
    one_by_one.finish()
    batched = build(mode, s, params)
    a, b = one_by_one.snapshot(), batched.snapshot()
    assert len(one_by_one.optimizations) == len(batched.optimizations) > 5
    np.testing.assert_array_equal(a.vertex_ids, b.vertex_ids)
    np.testing.assert_array_equal(a.poses, b.poses)
    np.testing.assert_array_equal(a.edge_rel, b.edge_rel)
    assert [o.time for o in one_by_one.optimizations] == [o.time for o in batched.optimizations]


def test_short_edge_keeps_the_older_place():
    from cogmap_core.map_graph import EdgeKind as Kind
    from cogmap_core.map_graph import MapGraph
    from cogmap_core.short_edges import remove_short_edges

    graph = MapGraph()
    for vid, (t, x) in enumerate([(0.0, 0.0), (1.0, 0.5), (30.0, 0.51), (30.1, 0.9), (30.2, 0.91)]):
        graph.new_id(vid, t, vid)
        graph.add_vertex(vid, (x, 0.0, 0.0))
    graph.add_edge(0, 1, (0.5, 0.0, 0.0), 1.0, Kind.SEQUENTIAL, -1)
    graph.add_edge(1, 2, (0.01, 0.0, 0.0), 30.0, Kind.LOOP_CLOSURE, 0)  # an old place, a new one
    graph.add_edge(2, 3, (0.39, 0.0, 0.0), 30.1, Kind.SEQUENTIAL, -1)
    graph.add_edge(3, 4, (0.01, 0.0, 0.0), 30.2, Kind.SEQUENTIAL, -1)  # made moments apart
    assert remove_short_edges(graph, 0.03) == 2
    assert graph.live_ids().tolist() == [0, 1, 3]  # the newer end of each short edge goes
    assert graph.resolve(2)[0] == 1 and graph.resolve(4)[0] == 3


def test_a_short_loop_closure_is_not_contracted_where_the_map_keeps_links():
    from cogmap_core.map_graph import EdgeKind as Kind
    from cogmap_core.map_graph import MapGraph
    from cogmap_core.short_edges import remove_short_edges

    graph = MapGraph()
    for vid, (t, x) in enumerate([(0.0, 0.0), (1.0, 0.5), (30.0, 0.51), (30.1, 0.9)]):
        graph.new_id(vid, t, vid)
        graph.add_vertex(vid, (x, 0.0, 0.0))
    graph.add_edge(0, 1, (0.5, 0.0, 0.0), 1.0, Kind.SEQUENTIAL, -1)
    link = graph.add_edge(2, 1, (0.0, 0.0, 0.0), 30.0, Kind.LOOP_CLOSURE, 0)  # 1 cm apart
    graph.add_edge(2, 3, (0.39, 0.0, 0.0), 30.1, Kind.SEQUENTIAL, -1)
    # accepted now, the link must stay one the loop model can reject at a later optimisation
    assert remove_short_edges(graph, 0.03, contract_loops=False) == 0
    assert graph.live_ids().tolist() == [0, 1, 2, 3] and graph.edge_alive[link]
    graph.pose[3] = (0.52, 0.0, 0.0)  # a sequential edge beside it does become short
    assert remove_short_edges(graph, 0.03, contract_loops=False) == 1
    assert graph.live_ids().tolist() == [0, 1, 2] and graph.resolve(3)[0] == 2
    # the paper's rule contracts the link too
    assert remove_short_edges(graph, 0.03) == 1 and graph.live_ids().tolist() == [0, 1]


def test_a_log_s_compact_map_keeps_its_accepted_links() -> None:
    from cogmap_core.sources.odometry_log import LOG_MAP_PARAMS

    assert MapParams().short_edge_loops == 1.0 and LOG_MAP_PARAMS.short_edge_loops == 0.0
    s = Script()
    s.create()  # 0
    s.move(0.5)
    s.create()  # 1
    s.move(-0.49)
    s.create()  # 2, back 1 cm from 0
    s.link(0)  # the same place: the optimisation brings the two ends together
    params = KEEP_ALL.with_changes(short_edge_threshold=0.03)
    contracted = build("compact", s, params, finish=False)
    kept = build("compact", s, params.with_changes(short_edge_loops=0.0), finish=False)
    contracted.optimize_now()
    kept.optimize_now()
    assert (2, 0) not in edges_of(contracted) and contracted.num_vertices == 2
    assert (2, 0) in edges_of(kept) and kept.num_vertices == 3
