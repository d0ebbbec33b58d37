"""Undoable merges: what scene integration's merge of a revisit run changed, and its split.

Beyond the paper. Scene integration (:mod:`cogmap_core.scene_integration`) merges a revisit run
only when the links that bracket it agree with the map, and the merge then rests on them: they
are held, and no hypothesis of a later optimisation that rejects one is taken
(:func:`~cogmap_core.cluster_consistency.overrules_a_merge`). A link that agreed with a drifted
map can still be false, and the solution a later optimisation keeps can reject it all the same
(its own reweighting, from a start where the link was not yet accepted, or pulled away by the
links that arrived since). The run's vertices were then merged on a place the robot was not:
the merge stands on nothing, and must not stay (issue: "a false link merged and later rejected
is undone"; as Kurz et al.'s geometry-based graph pruning keeps what it pruned).

A :class:`MergeRecord` is taken before a run is merged: the vertices merged, the ids that stood
for each (the aliases they had absorbed), and every edge they had, as it was measured. Splitting
the merge (:func:`split_merge`) puts them back:

- each merged vertex is live again where the map now places it (its alias's pose), and the ids
  that stood for it stand for it again;
- each of their edges is restored as it was measured; where its other end has been merged into
  another vertex since, it joins that vertex, its measurement re-expressed as a merge re-expresses
  it; where it would join a vertex to itself or duplicate a connection, it stays removed (the
  map keeps one edge per vertex pair);
- the evidence edge the merge left (:mod:`cogmap_core.marginalisation`) is removed.

The rejected link stays in the map, rejected like any other; the links the merge rested on are
no longer held unless another merge rests on them (:class:`~cogmap_core.scene_integration.
SceneIntegration` keeps the records and decides which merges to split). A later edge that joined
an id of the run while it stood for the old vertex stays on the old vertex.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cogmap_core.map_graph import MapGraph

IntArray = NDArray[np.int64]
FloatArray = NDArray[np.float64]


@dataclass(slots=True)
class MergeRecord:
    """What one run's merge changed, to split it again (module doc).

    Attributes:
        links: the loop closures the merge rests on (held while it stands).
        evidence: the evidence edge it left (-1: none).
        removed: the vertices merged away, in order.
        moved: per vertex of ``removed``, the ids that stood for it besides itself.
        edges: ``(m,)`` the edges those vertices had before the merge, ascending.
        ends: ``(m, 2)`` their first and second vertex then.
        rel: ``(m, 3)`` their measurements then.
        cov: ``(m, 3, 3)`` their own covariances then (zeros: the noise model weighs them).

    """

    links: list[int]
    evidence: int
    removed: list[int]
    moved: list[list[int]]
    edges: IntArray
    ends: IntArray
    rel: FloatArray
    cov: FloatArray

    @classmethod
    def before_merging(cls, graph: MapGraph, vertices: Sequence[int]) -> MergeRecord:
        """The record of merging live ``vertices`` of ``graph``, taken before any is merged.

        ``links`` and ``evidence`` are filled in once the merge is done; ``removed`` lists the
        vertices the merge did remove (:meth:`merged`).
        """
        edges = np.array(
            sorted({k for v in vertices for k in graph.adjacency[v].values()}), dtype=np.int64
        )
        return cls(
            links=[],
            evidence=-1,
            removed=list(vertices),
            moved=[graph.standing_for(v) for v in vertices],
            edges=edges,
            ends=np.stack([graph.edge_from[edges], graph.edge_to[edges]], axis=1),
            rel=graph.edge_rel[edges].copy(),
            cov=graph.edge_cov[edges].copy(),
        )

    def merged(self, graph: MapGraph, links: Sequence[int], evidence: int) -> MergeRecord:
        """The record once the merge is done: the vertices it removed, its links, its evidence."""
        gone = [k for k, v in enumerate(self.removed) if not graph.alive[v]]
        self.removed = [self.removed[k] for k in gone]
        self.moved = [self.moved[k] for k in gone]
        self.links = [int(k) for k in links]
        self.evidence = int(evidence)
        return self

    def state_dict(self) -> dict[str, Any]:
        """The record as plain data (every attribute; arrays copied, lists as lists)."""
        return {
            "links": list(self.links),
            "evidence": self.evidence,
            "removed": list(self.removed),
            "moved": [list(m) for m in self.moved],
            "edges": self.edges.copy(),
            "ends": self.ends.copy(),
            "rel": self.rel.copy(),
            "cov": self.cov.copy(),
        }

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> MergeRecord:
        """The record :meth:`state_dict` described."""
        return cls(
            links=[int(k) for k in state["links"]],
            evidence=int(state["evidence"]),
            removed=[int(v) for v in state["removed"]],
            moved=[[int(i) for i in m] for m in state["moved"]],
            edges=np.asarray(state["edges"], dtype=np.int64).reshape(-1),
            ends=np.asarray(state["ends"], dtype=np.int64).reshape(-1, 2),
            rel=np.asarray(state["rel"], dtype=np.float64).reshape(-1, 3),
            cov=np.asarray(state["cov"], dtype=np.float64).reshape(-1, 3, 3),
        )


def split_merge(graph: MapGraph, record: MergeRecord) -> int:
    """Undo the merge ``record`` describes (module doc); return the vertices made live again."""
    if record.evidence >= 0:
        graph.remove_edge(record.evidence)
        graph.edge_held[record.evidence] = False
    for vertex, moved in zip(record.removed, record.moved, strict=True):
        graph.revive_vertex(vertex, moved)
    for k, (src, dst), rel, cov in zip(
        record.edges.tolist(), record.ends.tolist(), record.rel, record.cov, strict=True
    ):
        graph.restore_edge(k, src, dst, rel.tolist(), cov)
    return len(record.removed)


__all__ = ["MergeRecord", "split_merge"]
