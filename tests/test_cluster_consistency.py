"""Loop-closure clusters judged against each other: one cluster cannot overrule several, nor a
merge (:mod:`cogmap_core.cluster_consistency`)."""

from __future__ import annotations

import math

import numpy as np

from cogmap_core.cluster_consistency import overrules_a_merge, overrules_several
from cogmap_core.geometry import between
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


def test_a_hypothesis_may_overrule_one_earlier_cluster_but_not_two():
    clusters = np.array([-1, 1, 1, 2, 3, 5, 5], dtype=np.int64)
    loops = clusters >= 0
    new = clusters == 5
    held = loops & ~new
    # the new cluster accepted, one earlier cluster displaced: cost decides
    rejected = np.array([0, 1, 1, 0, 0, 0, 0], dtype=bool)
    assert not overrules_several(clusters, loops, new, held, rejected)
    # two earlier clusters displaced by one: not taken
    rejected = np.array([0, 1, 0, 1, 0, 0, 0], dtype=bool)
    assert overrules_several(clusters, loops, new, held, rejected)
    # ... unless it also brings back an earlier cluster the start rejected
    held = loops & ~new & (clusters != 3)
    assert not overrules_several(clusters, loops, new, held, rejected)
    # a hypothesis whose new links end rejected too has no cluster on its side
    held = loops & ~new
    rejected = np.array([0, 0, 0, 0, 0, 1, 1], dtype=bool)
    assert not overrules_several(clusters, loops, new, held, rejected)
    rejected[1] = True
    assert overrules_several(clusters, loops, new, held, rejected)


def test_a_hypothesis_that_rejects_a_link_a_merge_rests_on_is_not_taken():
    """13 structured false links displace one earlier cluster: cost decides, unless a merge
    rests on one of that cluster's links."""
    one_cluster = [(x, 1, 0.0) for x, _, _ in EARLIER]
    graph, clusters = corridor(one_cluster + STRUCTURED)
    new = clusters == 3
    on_cost = optimize_pose_graph(graph, MODEL, new_loops=new, clusters=clusters)
    assert loop_rejections(graph, on_cost.rejected) == [1] * 4 + [0] * 13
    for held in range(4):
        merged_on = np.zeros(graph.num_edges, dtype=bool)
        merged_on[np.flatnonzero(graph.loop_closures())[held]] = True
        judged = optimize_pose_graph(
            graph, MODEL, new_loops=new, clusters=clusters, merged_on=merged_on
        )
        assert loop_rejections(graph, judged.rejected) == [0] * 4 + [1] * 13
        assert judged.final_cost > on_cost.final_cost
        np.testing.assert_allclose(judged.poses[LENGTH + 1 :, 1], GAP, atol=0.15)
    # a merge resting on one of the new links holds nothing back
    judged = optimize_pose_graph(graph, MODEL, new_loops=new, clusters=clusters, merged_on=new)
    assert loop_rejections(graph, judged.rejected) == [1] * 4 + [0] * 13


def test_only_a_held_link_accepted_at_the_start_and_rejected_at_the_end_counts():
    merged_on = np.array([0, 1, 1, 1, 0], dtype=bool)
    accepted = np.array([0, 1, 1, 0, 1], dtype=bool)  # at the start
    assert not overrules_a_merge(merged_on, accepted, np.array([1, 0, 0, 1, 1], dtype=bool))
    assert overrules_a_merge(merged_on, accepted, np.array([0, 0, 1, 0, 0], dtype=bool))
