"""Loop-closure clusters judged against each other: one cluster cannot overrule several, and a
contested cluster is revised when later links contradict it (:mod:`cogmap_core.loop_revision`)."""

from __future__ import annotations

import math

import numpy as np

from cogmap_core.cognitive_map import CognitiveMap
from cogmap_core.geometry import between
from cogmap_core.loop_revision import ContestedClusters
from cogmap_core.optimizer import OptimizerOptions, optimize_pose_graph
from cogmap_core.posegraph import PoseGraph
from cogmap_core.robust import LoopClosureModel

LENGTH = 20  # metres of corridor, one vertex a metre
GAP = 2.0  # the way back runs this far beside the way out
SHIFT = 3.0  # a structured false link puts the way back this much nearer (at y = -1)
MODEL = OptimizerOptions(loop_model=LoopClosureModel())

# (metre of the corridor, cluster id, how much nearer the link says the way back is)
EARLIER = [(2, 1, 0.0), (3, 1, 0.0), (17, 2, 0.0), (18, 2, 0.0)]
STRUCTURED = [(x, 3, SHIFT) for x in range(4, 17)]
LATER = [(x, 4, 0.0) for x in range(5, 16)]


def corridor(
    links: list[tuple[int, int, float]], start: np.ndarray | None = None
) -> tuple[PoseGraph, np.ndarray]:
    """Out along a corridor (y = 0), a U-turn, back beside it (y = ``GAP``); loop closures.

    Odometry is exact and stiff but for the U-turn, whose position is loose (sigma 3.2 m):
    the way back can be moved sideways as a whole. Each link joins the way out at metre ``x``
    to the way back at the same metre; a false one says the way back is ``shift`` nearer.
    Returns the graph (start: the true poses unless given) and each edge's cluster (-1 for
    odometry).
    """
    out = [np.array([float(k), 0.0, 0.0]) for k in range(LENGTH + 1)]
    back = [np.array([float(LENGTH - k), GAP, math.pi]) for k in range(LENGTH + 1)]
    truth = np.array(out + back)
    n = truth.shape[0]
    frm, to = list(range(n - 1)), list(range(1, n))
    meas = [between(truth[k], truth[k + 1]) for k in range(n - 1)]
    stiff, loose = np.diag([400.0, 400.0, 2500.0]), np.diag([0.1, 0.1, 2500.0])
    info = [loose if k == LENGTH else stiff for k in range(n - 1)]
    clusters = [-1] * (n - 1)
    for x, cluster, shift in links:
        way_back = 2 * LENGTH + 1 - (x + 1)  # the vertex of the way back at metre x
        frm.append(x)
        to.append(way_back)
        seen = truth[way_back] + np.array([0.0, -shift, 0.0])
        meas.append(between(truth[x], seen))
        info.append(np.eye(3))
        clusters.append(cluster)
    loops = np.array(clusters) >= 0
    poses = truth.copy() if start is None else start
    graph = PoseGraph(np.arange(n), poses, frm, to, meas, info, loop_closure=loops)
    return graph, np.array(clusters, dtype=np.int64)


def loop_rejections(graph: PoseGraph, rejected: np.ndarray | None) -> list[int]:
    """The loop closures' rejections, in order, as 0/1."""
    assert rejected is not None
    return rejected[graph.loop_closures()].astype(int).tolist()


def test_one_cluster_cannot_overrule_several_earlier_ones():
    """13 structured false links outweigh 4 true ones of two earlier clusters on cost alone."""
    graph, clusters = corridor(EARLIER + STRUCTURED)
    new = clusters == 3
    on_cost = optimize_pose_graph(graph, MODEL, new_loops=new)
    assert loop_rejections(graph, on_cost.rejected) == [1] * 4 + [0] * 13
    judged = optimize_pose_graph(graph, MODEL, new_loops=new, clusters=clusters)
    assert loop_rejections(graph, judged.rejected) == [0] * 4 + [1] * 13
    assert judged.final_cost > on_cost.final_cost  # not the cheaper one: the one allowed
    way_back = slice(LENGTH + 1, None)
    np.testing.assert_allclose(on_cost.poses[way_back, 1], GAP - SHIFT, atol=0.1)
    np.testing.assert_allclose(judged.poses[way_back, 1], GAP, atol=0.15)  # rejected links pull


def test_a_contested_cluster_is_dropped_when_later_links_contradict_it():
    """The structured cluster was accepted; a later true cluster says otherwise."""
    first, clusters = corridor(EARLIER + STRUCTURED)
    accepted = optimize_pose_graph(first, MODEL, new_loops=clusters == 3)
    graph, clusters = corridor(EARLIER + STRUCTURED + LATER, start=accepted.poses)
    new = clusters == 4
    frozen = optimize_pose_graph(graph, MODEL, new_loops=new, clusters=clusters)
    assert loop_rejections(graph, frozen.rejected) == [1] * 4 + [0] * 13 + [1] * 11
    revised = optimize_pose_graph(
        graph, MODEL, new_loops=new, suspects=[clusters == 3], clusters=clusters
    )
    assert loop_rejections(graph, revised.rejected) == [0] * 4 + [1] * 13 + [0] * 11
    assert revised.final_cost < frozen.final_cost
    way_back = slice(LENGTH + 1, None)
    np.testing.assert_allclose(frozen.poses[way_back, 1], GAP - SHIFT, atol=0.15)
    np.testing.assert_allclose(revised.poses[way_back, 1], GAP, atol=0.15)


def test_contested_clusters_are_those_that_displaced_earlier_links():
    record = ContestedClusters()
    live = np.array([3, 4, 7, 8, 9], dtype=np.int64)
    new = np.array([False, False, False, True, True])
    before = np.array([True, True, False, False, False])
    # nothing displaced: not contested
    assert not record.note(live, new, before, np.array([False, False, False, True, False]))
    # it displaced edge 4 and was accepted (9; 8 rejected): contested
    assert record.note(live, new, before, np.array([False, True, False, True, False]))
    assert record.state_dict() == [[9]]
    masks = record.suspects(np.array([3, 9, 11], dtype=np.int64))
    assert [m.tolist() for m in masks] == [[False, True, False]]
    assert record.suspects(np.array([3, 4], dtype=np.int64)) == []  # its links are gone
    again = ContestedClusters()
    again.load_state(record.state_dict())
    assert again.state_dict() == [[9]]


def test_the_map_keeps_its_contested_clusters_in_its_state():
    cmap = CognitiveMap("standard")
    cmap.contested.groups.append(np.array([5, 6], dtype=np.int64))
    state = cmap.state_dict()
    assert state["contested"] == [[5, 6]]
    assert CognitiveMap.from_state(state).contested.state_dict() == [[5, 6]]
    del state["contested"]  # a state saved before the record existed
    assert CognitiveMap.from_state(state).contested.state_dict() == []
