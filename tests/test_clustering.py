"""Loop-closure clustering: the five clusters of the paper's figure, and its boundaries."""

from __future__ import annotations

from cogmap_core.clustering import LoopClosureClusterer


def assign(times: list[float], t_interval: float = 2.0, t_total: float = 100.0) -> list[int]:
    clusterer = LoopClosureClusterer(t_interval, t_total)
    return [clusterer.add_edge(t)[0] for t in times]


def test_paper_figure_clusters_1_to_5():
    # Cluster 1: a normal cluster; the next edge comes more than T_interval later.
    c1 = [10.0, 11.0, 12.5]
    # Clusters 2 and 3: consecutive edges 1 s apart, but the total time passes T_total = 100 s.
    c23 = [20.0 + k for k in range(106)]  # 20 ... 125
    # Clusters 4 and 5: split because the interval reaches T_interval.
    c45 = [130.0, 131.0, 133.0, 134.5]
    ids = assign(c1 + c23 + c45)
    assert ids[:3] == [0, 0, 0]
    cluster2 = ids[3 : 3 + 101]  # 20 .. 120: 120 - 20 = 100 is not greater than T_total
    cluster3 = ids[3 + 101 : 3 + 106]  # 121 .. 125
    assert set(cluster2) == {1} and set(cluster3) == {2}
    assert ids[-4:] == [3, 3, 4, 4]


def test_interval_boundary_is_exclusive_and_total_inclusive():
    assert assign([0.0, 1.999, 3.998]) == [0, 0, 0]
    assert assign([0.0, 2.0]) == [0, 1]  # "smaller than T_interval" joins; equal does not
    assert assign([0.0, 1.0, 2.0], t_interval=2.0, t_total=2.0) == [0, 0, 0]  # total == T_total
    assert assign([0.0, 1.0, 2.0, 2.5], t_interval=2.0, t_total=2.0) == [0, 0, 0, 1]


def test_cluster_closes_as_soon_as_no_edge_can_join():
    clusterer = LoopClosureClusterer(2.0, 100.0)
    clusterer.add_edge(10.0)
    clusterer.add_edge(11.0)
    assert clusterer.due(12.9) is None
    closed = clusterer.due(13.0)
    assert closed is not None and closed.cluster_id == 0 and closed.closed_time == 13.0
    assert closed.edge_count == 2 and (closed.start_time, closed.last_time) == (10.0, 11.0)
    assert clusterer.open_cluster is None
    # total-time closing
    clusterer.add_edge(20.0)
    for t in range(21, 121):
        clusterer.add_edge(float(t))
    assert clusterer.due(120.5) is not None  # 120.5 - 20 > 100
