"""The relocalisation gate's path search, compiled: the same answer as the map's Python search.

The consistency test (:mod:`~cogmap_core.relocalisation`) asks whether a path of edges shorter
than some length joins the robot's vertex to the one it was re-localised on
(:meth:`MapGraph.graph_distance_below <cogmap_core.map_graph.MapGraph.graph_distance_below>`:
Dijkstra over measured edge lengths, stopped at the length). On a long run the ball it searches
holds every lap's vertices: on a 60-lap bag that search was 60-70 % of a map's replay with the
solves skipped (``benchmarks/rebuild_floor.py``). :class:`PathSearch` answers the same question
over the graph's arrays with compiled loops, and the compiled replay
(:mod:`~cogmap_core.compiled_replay`) hands it to the graph while it replays.

**The same answer, to the bit.** An edge's length is CPython's ``math.hypot`` of its measured
x, y (:func:`~cogmap_core.compiled_loop._python_hypot`, compiled), and a path's length is summed
from the source outwards, as the Python search sums it; the answer is whether the shortest such
sum is below the limit, which does not depend on the order the two searches visit vertices in.
``tests/test_compiled_search.py`` compares both on random graphs with removed edges and merged
vertices, and the compiled replay's tests compare whole maps.

**The index.** Each vertex id has a list of the edges that touch it (``head``/``next``
over entries appended as edges are added). A removed edge stays listed and is skipped; an edge
whose end moved to another vertex (a merge) is skipped at its old end, so merges rebuild the
index (:meth:`PathSearch.sync`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from cogmap_core.compiled_loop import _python_hypot as _hypot

if TYPE_CHECKING:
    from cogmap_core.map_graph import MapGraph

IntArray = NDArray[np.int64]


def _add_entries(
    head: IntArray,
    entry_edge: IntArray,
    entry_next: IntArray,
    used: int,
    edge_from: IntArray,
    edge_to: IntArray,
    edge_alive: NDArray[np.bool_],
    lo: int,
    hi: int,
) -> int:
    """List the live edges ``lo .. hi - 1`` at both their ends; return the entries in use."""
    for k in range(lo, hi):
        if not edge_alive[k]:
            continue
        for v in (edge_from[k], edge_to[k]):
            entry_edge[used] = k
            entry_next[used] = head[v]
            head[v] = used
            used += 1
    return used


def _heap_push(keys: NDArray[np.float64], items: IntArray, size: int, key: float, item: int) -> int:
    """Push onto the binary min-heap ``keys``/``items`` of ``size`` entries; return its size."""
    i = size
    while i > 0:
        parent = (i - 1) // 2
        if keys[parent] <= key:
            break
        keys[i], items[i] = keys[parent], items[parent]
        i = parent
    keys[i], items[i] = key, item
    return size + 1


def _heap_pop(keys: NDArray[np.float64], items: IntArray, size: int) -> int:
    """Remove the heap's smallest entry (read ``keys[0]``, ``items[0]`` first); return its size."""
    size -= 1
    key, item = keys[size], items[size]
    i = 0
    while True:
        child = 2 * i + 1
        if child >= size:
            break
        if child + 1 < size and keys[child + 1] < keys[child]:
            child += 1
        if keys[child] >= key:
            break
        keys[i], items[i] = keys[child], items[child]
        i = child
    keys[i], items[i] = key, item
    return size


def _distance_below(
    source: int,
    target: int,
    limit: float,
    head: IntArray,
    entry_edge: IntArray,
    entry_next: IntArray,
    edge_from: IntArray,
    edge_to: IntArray,
    edge_alive: NDArray[np.bool_],
    edge_rel: NDArray[np.float64],
    num_ids: int,
) -> bool:
    """Whether a path of live edges from ``source`` to ``target`` is shorter than ``limit``."""
    if source == target:
        return limit > 0
    best = np.full(num_ids, math.inf)
    best[source] = 0.0
    capacity = 64
    keys = np.empty(capacity)
    items = np.empty(capacity, dtype=np.int64)
    size = _heap_push(keys, items, 0, 0.0, source)
    while size > 0:
        dist, v = keys[0], items[0]
        size = _heap_pop(keys, items, size)
        if dist >= limit:
            return False
        if v == target:
            return True
        if dist > best[v]:
            continue
        i = head[v]
        while i >= 0:
            k = entry_edge[i]
            i = entry_next[i]
            if not edge_alive[k]:
                continue
            if edge_from[k] == v:
                w = edge_to[k]
            elif edge_to[k] == v:
                w = edge_from[k]
            else:
                continue  # its end moved to another vertex (a merge)
            nd = dist + _hypot(edge_rel[k, 0], edge_rel[k, 1])
            if nd < best[w] and nd < limit:
                best[w] = nd
                if size == capacity:
                    capacity *= 2
                    grown_keys = np.empty(capacity)
                    grown_items = np.empty(capacity, dtype=np.int64)
                    grown_keys[:size] = keys[:size]
                    grown_items[:size] = items[:size]
                    keys, items = grown_keys, grown_items
                size = _heap_push(keys, items, size, nd, w)
    return False


_COMPILED = ("_add_entries", "_heap_push", "_heap_pop", "_distance_below")


def compile_all(jit: Callable[[Any], Any]) -> None:
    """Compile the search with ``jit``, each function in place of its Python self.

    Call it after :func:`compiled_loop.compile_all <cogmap_core.compiled_loop.compile_all>`: the
    search calls that module's compiled hypot.
    """
    from cogmap_core import compiled_loop

    globals()["_hypot"] = compiled_loop._hypot
    globals().update({name: jit(globals()[name]) for name in _COMPILED})


class PathSearch:
    """The compiled path search over one graph's arrays, kept in step with the graph (module doc).

    Install it with ``graph.path_search = PathSearch(graph)``; the graph's
    :meth:`~cogmap_core.map_graph.MapGraph.graph_distance_below` then answers through it.
    """

    def __init__(self, graph: MapGraph) -> None:
        """Index the graph's live edges."""
        self.graph = graph
        self._head = np.empty(0, dtype=np.int64)
        self._entry_edge = np.empty(0, dtype=np.int64)
        self._entry_next = np.empty(0, dtype=np.int64)
        self._used = 0
        self._indexed = 0  # edges listed so far
        self._revision = -1  # the graph's revision when indexed (none yet)

    def sync(self) -> None:
        """List the edges added since; rebuild after a merge or when the ids outgrow the index."""
        g = self.graph
        if g.revision != self._revision or g.num_ids > self._head.shape[0]:
            if g.num_ids > self._head.shape[0]:
                self._head = np.empty(max(2 * g.num_ids, 64), dtype=np.int64)
            self._head.fill(-1)
            self._used = 0
            self._indexed = 0
            self._revision = g.revision
        need = self._used + 2 * (g.num_edges_total - self._indexed)
        if need > self._entry_edge.shape[0]:
            size = max(need, 2 * self._entry_edge.shape[0], 256)
            self._entry_edge = np.resize(self._entry_edge, size)
            self._entry_next = np.resize(self._entry_next, size)
        self._used = int(
            _add_entries(
                self._head, self._entry_edge, self._entry_next, self._used,
                g.edge_from, g.edge_to, g.edge_alive, self._indexed, g.num_edges_total,
            )
        )  # fmt: skip
        self._indexed = g.num_edges_total

    def __call__(self, source: int, target: int, limit: float) -> bool:
        """Whether a path of edges from ``source`` to ``target`` is shorter than ``limit`` (m)."""
        self.sync()
        g = self.graph
        return bool(
            _distance_below(
                source, target, limit, self._head, self._entry_edge, self._entry_next,
                g.edge_from, g.edge_to, g.edge_alive, g.edge_rel, g.num_ids,
            )
        )  # fmt: skip


__all__ = ["PathSearch", "compile_all"]
