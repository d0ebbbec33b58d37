"""One cognitive map's part of a session file: its state saved as arrays and JSON, and restored.

The map's state is its own (:meth:`CognitiveMap.state_dict
<cogmap_core.cognitive_map.CognitiveMap.state_dict>`); this module only lays it out: the graph
arrays, adjacency in its order, aliases, the loop-closure clusters, scene integration's spatial
index, the optimisation and relocalisation records and the size history as arrays; scene
integration's open and pending revisit runs, the relocalisation gate's streak, the robot's
state and the counters in the header's JSON; all under a prefix such as ``map.compact.``
(format: :mod:`cogmap_core.session_file`).
"""

from __future__ import annotations

import math

import numpy as np

from cogmap_core.cognitive_map import CognitiveMap, OptimizationRecord
from cogmap_core.errors import StateError
from cogmap_core.map_graph import EDGE_ARRAYS, VERTEX_ARRAYS
from cogmap_core.relocalisation import RelocalisationCheck
from cogmap_core.session_arrays import (
    Arrays,
    Json,
    SessionError,
    load_lists,
    load_records,
    save_lists,
    save_records,
)

_GRAPH_COUNTS = ("num_ids", "num_edges_total", "num_vertices", "num_edges", "num_loop_edges")
_CLUSTER_FIELDS = ("start_time", "last_time", "edge_count", "closed_time")
_KNOWN_EDGES_ARRAYS = ("start", "end", "ends", "newest")
#: a merge record's per-edge arrays and each row's shape
_MERGE_EDGE_ARRAYS = {"edges": (), "ends": (2,), "rel": (3,), "cov": (3, 3)}


def save_map(cmap: CognitiveMap, prefix: str, arrays: Arrays) -> Json:
    """Put ``cmap``'s arrays into ``arrays`` under ``prefix``; return its scalars."""
    state = cmap.state_dict()
    g = state["graph"]
    for name in (*VERTEX_ARRAYS, *EDGE_ARRAYS):
        arrays[prefix + "graph." + name] = g[name]
    # adjacency in each dict's own order: merges and short-edge removal iterate it
    adjacency = g["adjacency"]
    counts = np.array([len(a) for a in adjacency], dtype=np.int64)
    arrays[prefix + "adjacency.count"] = counts
    arrays[prefix + "adjacency.neighbour"] = np.fromiter(
        (w for a in adjacency for w in a), dtype=np.int64, count=int(counts.sum())
    )
    arrays[prefix + "adjacency.edge"] = np.fromiter(
        (k for a in adjacency for k in a.values()), dtype=np.int64, count=int(counts.sum())
    )
    save_lists(arrays, prefix + "absorbed", g["absorbed"])
    clusters = state["clusterer"]["clusters"]
    for name in _CLUSTER_FIELDS[:2]:
        arrays[prefix + "clusters." + name] = np.array([c[name] for c in clusters])
    arrays[prefix + "clusters.edge_count"] = np.array(
        [c["edge_count"] for c in clusters], dtype=np.int64
    )
    arrays[prefix + "clusters.closed_time"] = np.array(  # NaN: still open
        [math.nan if c["closed_time"] is None else c["closed_time"] for c in clusters]
    )
    integration = state["integration"]
    known = integration["known_edges"]
    if known is not None:
        for name in _KNOWN_EDGES_ARRAYS:
            arrays[prefix + "known_edges." + name] = known[name]
    _save_merges(arrays, prefix + "merges.", integration["merges"])
    save_records(arrays, prefix + "optimizations.", state["optimizations"], OptimizationRecord)
    save_records(arrays, prefix + "refused.", state["refused"], RelocalisationCheck)
    gate = state["gate"]
    save_records(
        arrays,
        prefix + "accepted_by_consensus.",
        gate["accepted_by_consensus"],
        RelocalisationCheck,
    )
    for name in ("time", "vertices", "edges"):
        arrays[prefix + "size_history." + name] = state["size_history"][name]
    return {
        "mode": state["mode"],
        "params": state["params"],
        "graph": {name: g[name] for name in _GRAPH_COUNTS},
        "open_cluster": state["clusterer"]["open"],
        "integration": {
            "open": integration["open"],
            "pending": integration["pending"],
            "relocalised_at": integration["relocalised_at"],
            "known_edges": None
            if known is None
            else {"reach": known["reach"], "radius": known["radius"], "tree": known["tree"]},
        },
        "streak": gate["streak"],
        "counters": state["counters"],
        "robot": state["robot"],
        "edges_at_last_optimization": state["edges_at_last_optimization"],
        "optimized_once": state["optimized_once"],
    }


def load_map(s: Json, prefix: str, arrays: Arrays) -> CognitiveMap:
    """The map saved by :func:`save_map` (scalars ``s``, arrays under ``prefix``)."""
    counts = arrays[prefix + "adjacency.count"].tolist()
    neighbours = arrays[prefix + "adjacency.neighbour"].tolist()
    edges = arrays[prefix + "adjacency.edge"].tolist()
    if sum(counts) != len(neighbours):
        raise SessionError(f"{prefix}adjacency does not match the graph")
    adjacency = []
    start = 0
    for c in counts:
        pairs = zip(neighbours[start : start + c], edges[start : start + c], strict=True)
        adjacency.append(dict(pairs))
        start += c
    # (graph arrays added later are absent from older files: MapGraph.load_state fills them)
    graph: Json = {
        name: arrays[prefix + "graph." + name]
        for name in (*VERTEX_ARRAYS, *EDGE_ARRAYS)
        if prefix + "graph." + name in arrays
    }
    graph.update(s["graph"], adjacency=adjacency, absorbed=load_lists(arrays, prefix + "absorbed"))
    closed = arrays[prefix + "clusters.closed_time"].tolist()
    clusters = [
        {
            "start_time": a,
            "last_time": b,
            "edge_count": c,
            "closed_time": None if math.isnan(d) else d,
        }
        for a, b, c, d in zip(
            arrays[prefix + "clusters.start_time"].tolist(),
            arrays[prefix + "clusters.last_time"].tolist(),
            arrays[prefix + "clusters.edge_count"].tolist(),
            closed,
            strict=True,
        )
    ]
    si = s["integration"]
    known = si["known_edges"]
    if known is not None:
        known = {
            **{name: arrays[prefix + "known_edges." + name] for name in _KNOWN_EDGES_ARRAYS},
            **known,
        }
    state: Json = {
        "mode": s["mode"],
        "params": s["params"],
        "graph": graph,
        "clusterer": {"clusters": clusters, "open": s["open_cluster"]},
        "integration": {
            "open": None if si["open"] is None else _run(si["open"]),
            "pending": [_run(r) for r in si["pending"]],
            "merges": _load_merges(arrays, prefix + "merges."),
            # (absent from files of before it existed: no pending one)
            "relocalised_at": si.get("relocalised_at"),
            "known_edges": known,
        },
        "gate": {
            "streak": s["streak"],
            "accepted_by_consensus": load_records(
                arrays, prefix + "accepted_by_consensus.", RelocalisationCheck
            ),
        },
        "optimizations": load_records(arrays, prefix + "optimizations.", OptimizationRecord),
        "refused": load_records(arrays, prefix + "refused.", RelocalisationCheck),
        "counters": s["counters"],
        "robot": s["robot"],
        "edges_at_last_optimization": s["edges_at_last_optimization"],
        "optimized_once": s["optimized_once"],
        "size_history": {
            name: arrays[prefix + "size_history." + name] for name in ("time", "vertices", "edges")
        },
    }
    try:
        return CognitiveMap.from_state(state)
    except StateError as exc:
        raise SessionError(f"{prefix}{exc}") from None


def _save_merges(arrays: Arrays, prefix: str, merges: list[Json]) -> None:
    """Scene integration's merge records (:class:`~cogmap_core.merge_records.MergeRecord`)."""
    save_lists(arrays, prefix + "links", [m["links"] for m in merges])
    save_lists(arrays, prefix + "removed", [m["removed"] for m in merges])
    save_lists(arrays, prefix + "moved", [moved for m in merges for moved in m["moved"]])
    arrays[prefix + "evidence"] = np.array([m["evidence"] for m in merges], dtype=np.int64)
    arrays[prefix + "edge_count"] = np.array([len(m["edges"]) for m in merges], dtype=np.int64)
    for name, shape in _MERGE_EDGE_ARRAYS.items():
        parts = [np.asarray(m[name]).reshape(-1, *shape) for m in merges]
        dtype = np.int64 if name in ("edges", "ends") else np.float64
        arrays[prefix + name] = np.concatenate(parts) if parts else np.zeros((0, *shape), dtype)


def _load_merges(arrays: Arrays, prefix: str) -> list[Json]:
    """The merge records :func:`_save_merges` saved (none in files of before they existed)."""
    if prefix + "edge_count" not in arrays:
        return []
    links = load_lists(arrays, prefix + "links")
    removed = load_lists(arrays, prefix + "removed")
    moved = load_lists(arrays, prefix + "moved")
    evidence = arrays[prefix + "evidence"].tolist()
    counts = arrays[prefix + "edge_count"].tolist()
    edge_arrays = {name: arrays[prefix + name] for name in _MERGE_EDGE_ARRAYS}
    sizes = {len(links), len(removed), len(evidence), len(counts)}
    if (
        len(sizes) != 1
        or sum(len(r) for r in removed) != len(moved)
        or any(len(a) != sum(counts) for a in edge_arrays.values())
    ):
        raise SessionError(f"{prefix[:-1]} records do not fit together")
    merges = []
    first_edge = first_moved = 0
    for k, count in enumerate(counts):
        n = len(removed[k])
        merges.append(
            {
                "links": links[k],
                "evidence": evidence[k],
                "removed": removed[k],
                "moved": moved[first_moved : first_moved + n],
                **{name: a[first_edge : first_edge + count] for name, a in edge_arrays.items()},
            }
        )
        first_edge += count
        first_moved += n
    return merges


def _run(s: Json) -> Json:
    """A revisit run's state as saved.

    ``opened_from`` and ``closed_at`` are absent from sessions saved before them: -1 (for
    ``closed_at``, the run's last vertex) is what those sessions meant.
    """
    return {"opened_from": -1, "closed_at": -1, **s}


__all__ = ["load_map", "save_map"]
