"""Undoable merges (cogmap_core/merge_records.py): a merge's record puts the graph back."""

from __future__ import annotations

import numpy as np
import pytest

from cogmap_core.errors import StateError
from cogmap_core.geometry import between
from cogmap_core.map_graph import EdgeKind, MapGraph
from cogmap_core.merge_records import MergeRecord, split_merge

# a corridor walked twice: 0 1 2 3 on the first pass, 4 5 on the second (beside 1 and 2)
POSES = [
    (0.0, 0.0, 0.0),
    (1.0, 0.0, 0.0),
    (2.0, 0.0, 0.1),
    (3.0, 0.1, 0.0),
    (1.02, 0.03, 0.02),
    (2.01, -0.02, 0.08),
]


def corridor() -> MapGraph:
    """Vertices 0-5, odometry 0-1-2-3 and 3-4-5 (4 and 5 revisit 1 and 2), a link 5 -> 2, and
    id 6, declined, standing for 4."""
    graph = MapGraph()
    for vid, pose in enumerate(POSES):
        graph.new_id(vid, float(vid), vid)
        graph.add_vertex(vid, pose)
    graph.new_id(6, 6.0, 6)
    graph.add_alias(6, 4, (0.05, 0.0, 0.0))
    for a, b in ((0, 1), (1, 2), (2, 3), (3, 4), (4, 5)):
        rel = between(graph.pose[a], graph.pose[b]).tolist()
        graph.add_edge(a, b, rel, float(b), EdgeKind.SEQUENTIAL, -1)
    graph.add_edge(5, 2, (0.01, 0.02, 0.0), 5.0, EdgeKind.LOOP_CLOSURE, 0)
    return graph


def merge(graph: MapGraph, removed: int, kept: int) -> None:
    graph.merge_vertex(removed, kept, between(graph.pose[kept], graph.pose[removed]).tolist())


def comparable(graph: MapGraph) -> dict:
    """The graph's state with each vertex's adjacency as a set (a split restores the same
    edges, not the dicts' order) and without the revision counter."""
    state = graph.state_dict()
    state["adjacency"] = [set(a.items()) for a in state["adjacency"]]
    state["absorbed"] = [sorted(a) for a in state["absorbed"]]
    return state


def assert_same_graph(actual: MapGraph, expected: MapGraph) -> None:
    a, e = comparable(actual), comparable(expected)
    assert a.keys() == e.keys()
    for key, value in e.items():
        if isinstance(value, np.ndarray) and value.dtype.kind == "f":
            assert np.allclose(a[key], value, rtol=0, atol=1e-12), key
        elif isinstance(value, np.ndarray):
            assert a[key].tolist() == value.tolist(), key
        else:
            assert a[key] == value, key


def test_splitting_a_merge_puts_the_graph_back():
    graph = corridor()
    before = corridor()
    record = MergeRecord.before_merging(graph, [4, 5])
    merge(graph, 4, 1)
    merge(graph, 5, 2)
    record.merged(graph, [5], -1)
    # 3-4 became 3-1; 4-5 became 1-2 and duplicated 1-2: dropped; 5-2 became a self-loop: dropped
    assert graph.num_vertices == 4 and graph.num_edges == 4
    assert record.removed == [4, 5] and record.moved == [[6], []]
    assert record.edges.tolist() == [3, 4, 5]  # 3-4, 4-5, 5-2: every edge of 4 and 5
    assert split_merge(graph, record) == 2
    assert_same_graph(graph, before)


def test_a_split_joins_the_vertex_its_absorber_was_merged_into_since():
    """4 merged into 1, then 1 into 0: 4 comes back with its edge 3-4 and 4-5 as measured, and
    the alias 6 stands for it again, where the map puts it now."""
    graph = corridor()
    record = MergeRecord.before_merging(graph, [4])
    merge(graph, 4, 1)
    record.merged(graph, [], -1)
    merge(graph, 1, 0)
    where = {i: graph.pose_of(i) for i in (4, 6)}
    assert split_merge(graph, record) == 1
    assert graph.alive[4] and graph.num_vertices == 5
    assert graph.resolve(6) == (4, pytest.approx([0.05, 0.0, 0.0], abs=1e-12))
    for i in (4, 6):
        assert graph.pose_of(i) == pytest.approx(where[i], abs=1e-12)
    assert sorted(graph.adjacency[4]) == [3, 5]
    for k in graph.live_edges():  # every edge still agrees with the poses it joins
        a, b = int(graph.edge_from[k]), int(graph.edge_to[k])
        if k != 5:  # (the link 5 -> 2 never agreed exactly)
            want = between(graph.pose[a], graph.pose[b])
            assert np.allclose(graph.edge_rel[k], want, atol=1e-12), k


def test_an_edge_that_would_duplicate_a_connection_stays_removed():
    """After 4 merged into 1, a later edge joins 3 to 1: 4's edge to 3 would duplicate nothing
    (4 is live again), but 4's edge to 5, where 5 was merged into 3 since, would join 4 to 3
    a second time: it stays removed."""
    graph = corridor()
    record = MergeRecord.before_merging(graph, [4])
    merge(graph, 4, 1)
    record.merged(graph, [], -1)
    merge(graph, 5, 3)
    split_merge(graph, record)
    assert graph.edge_between(4, 3) == 3  # its own edge 3-4
    assert not graph.edge_alive[4]  # 4-5, now 4-3: a duplicate
    assert sorted(graph.adjacency[4]) == [3]


def test_a_live_vertex_cannot_be_revived():
    graph = corridor()
    with pytest.raises(StateError, match="vertex 4 is live"):
        graph.revive_vertex(4, [])


def test_a_record_survives_its_state_dict():
    graph = corridor()
    record = MergeRecord.before_merging(graph, [4, 5]).merged(corridor(), [5, 7], 7)
    again = MergeRecord.from_state(record.state_dict())
    state, other = record.state_dict(), again.state_dict()
    assert state.keys() == other.keys()
    for key, value in state.items():
        assert np.array_equal(np.asarray(other[key]), np.asarray(value)), key
    assert again.ends.tolist() == [[3, 4], [4, 5], [5, 2]] and again.links == [5, 7]
