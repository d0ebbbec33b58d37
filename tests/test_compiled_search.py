"""The compiled path search gives the map's Python search's answer (cogmap_core.compiled_search).

Random graphs with removed edges, merged vertices and edges added after the index was built, and
every search the relocalisation gate makes while the compiled replay rebuilds recorded streams
with a strict gate: each question is answered by both searches and the answers must agree.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from cogmap_core import compiled_replay
from cogmap_core.cognitive_map import CognitiveMap, MapMode
from cogmap_core.compiled_search import PathSearch
from cogmap_core.config import MapParams
from cogmap_core.event_file import load_event_file
from cogmap_core.event_log import EventLog
from cogmap_core.map_graph import EdgeKind, MapGraph
from tests.conftest import DATA

pytestmark = pytest.mark.skipif(
    not compiled_replay.available(), reason=f"{compiled_replay.unavailable_reason()}"
)


def random_graph(rng: np.random.Generator, n: int, extra: int) -> MapGraph:
    """A chain of ``n`` vertices about 0.1 m apart plus ``extra`` random links."""
    graph = MapGraph()
    for v in range(n):
        graph.new_id(v, float(v), v)
        graph.add_vertex(v, [0.1 * v, 0.0, 0.0])
        if v:
            step = [0.1 + 0.02 * rng.standard_normal(), 0.01 * rng.standard_normal(), 0.0]
            graph.add_edge(v - 1, v, step, float(v), EdgeKind.SEQUENTIAL, -1)
    for _ in range(extra):
        a, b = (int(x) for x in rng.choice(n, 2, replace=False))
        if graph.edge_between(a, b) < 0:
            rel = [0.1 * (b - a) * rng.uniform(0.2, 1.0), 0.3 * rng.standard_normal(), 0.0]
            graph.add_edge(a, b, rel, float(n), EdgeKind.LOOP_CLOSURE, 0)
    return graph


def ask_both(graph: MapGraph, search: PathSearch, rng: np.random.Generator, count: int) -> int:
    """Ask ``count`` random questions of both searches; return how many paths were found."""
    live = graph.live_ids()
    found = 0
    for _ in range(count):
        source, target = (int(x) for x in rng.choice(live, 2))
        limit = float(rng.uniform(0.0, 3.0))
        answer = search(source, target, limit)
        assert answer == graph.python_distance_below(source, target, limit), (source, target, limit)
        found += answer
    return found


def test_the_compiled_search_answers_as_the_python_search_through_merges_and_removals() -> None:
    rng = np.random.default_rng(33)
    graph = random_graph(rng, 300, 120)
    search = PathSearch(graph)
    found = [ask_both(graph, search, rng, 300)]
    for k in rng.choice(graph.num_edges_total, 60, replace=False):
        graph.remove_edge(int(k))
    found.append(ask_both(graph, search, rng, 300))
    for removed in rng.choice(np.arange(1, 300), 40, replace=False):
        kept = int(removed) - 1
        if graph.alive[removed] and graph.alive[kept]:
            graph.merge_vertex(int(removed), kept, [0.1, 0.0, 0.0])
    found.append(ask_both(graph, search, rng, 300))
    for v in range(300, 330):  # more vertices and edges after the index was built
        graph.new_id(v, float(v), v)
        graph.add_vertex(v, [0.1 * v, 0.0, 0.0])
        first = int(graph.live_ids()[0])
        graph.add_edge(first, v, [0.5, 0.0, 0.0], float(v), EdgeKind.SEQUENTIAL, -1)
    found.append(ask_both(graph, search, rng, 300))
    # both answers occur at every stage (the questions are not all trivially no, or all yes)
    assert all(0 < f < 300 for f in found), found


def test_the_index_follows_many_rounds_of_merges_without_growing_past_the_graph() -> None:
    rng = np.random.default_rng(7)
    graph = random_graph(rng, 400, 150)
    search = PathSearch(graph)
    for _ in range(60):
        live = graph.live_ids()
        removed = int(rng.choice(live[1:]))
        kept = int(live[np.searchsorted(live, removed) - 1])
        graph.merge_vertex(removed, kept, [0.1, 0.0, 0.0])
        ask_both(graph, search, rng, 5)
    assert search._head.shape[0] <= 2 * graph.num_ids + 64
    assert search._entry_edge.shape[0] <= 4 * graph.num_edges_total + 256


def test_the_search_treats_a_vertex_and_zero_limits_as_the_python_search() -> None:
    graph = random_graph(np.random.default_rng(1), 5, 0)
    search = PathSearch(graph)
    assert search(2, 2, 0.0) is False and search(2, 2, 1e-9) is True
    assert search(0, 4, math.inf) is True
    assert search(0, 4, 0.0) is False


def test_every_gate_search_of_a_compiled_rebuild_agrees_with_the_python_search(monkeypatch) -> None:
    strict = MapParams(gate_position=0.02, gate_heading=0.05, gate_consensus=3.0)
    log = EventLog.from_recording(load_event_file(DATA / "junction_dead_end_2laps.events.npz"))
    asked: list[bool] = []
    compiled_call = PathSearch.__call__

    def both(self: PathSearch, source: int, target: int, limit: float) -> bool:
        answer = compiled_call(self, source, target, limit)
        assert answer == self.graph.python_distance_below(source, target, limit)
        asked.append(answer)
        return answer

    monkeypatch.setattr(PathSearch, "__call__", both)
    for mode in MapMode:
        cmap = CognitiveMap(mode, strict)
        compiled_replay.CompiledReplay(cmap).apply(log.columns(), 0, log.event_count)
        assert cmap.graph.path_search is None  # installed only while the Python code applies
    assert len(asked) > 100 and 0 < sum(asked) < len(asked), (len(asked), sum(asked))
