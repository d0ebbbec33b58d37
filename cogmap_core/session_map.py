"""One cognitive map's part of a session file: its state saved as arrays and JSON, and restored.

The graph arrays, aliases, adjacency in its order, the loop-closure clusterer, scene
integration's open and pending revisit runs and its spatial index, the relocalisation gate's
streak, the robot's state, counters, size history and optimisation records, under a prefix such
as ``map.compact.`` (format: :mod:`cogmap_core.session_file`).
"""

from __future__ import annotations

import math
from dataclasses import asdict
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from cogmap_core.clustering import Cluster, LoopClosureClusterer
from cogmap_core.cognitive_map import CognitiveMap, MapCounters, MapMode, OptimizationRecord
from cogmap_core.config import MapParams
from cogmap_core.map_graph import MapGraph, grow_array
from cogmap_core.relocalisation import RelocalisationCheck, RelocalisationGate
from cogmap_core.scene_integration import KnownEdges, RevisitRun, SceneIntegration
from cogmap_core.session_arrays import (
    Arrays,
    Json,
    SessionError,
    load_lists,
    load_records,
    save_lists,
    save_records,
)


def save_map(cmap: CognitiveMap, prefix: str, arrays: Arrays) -> Json:
    """Put ``cmap``'s arrays into ``arrays`` under ``prefix``; return its scalars."""
    g = cmap.graph
    n, m = g.num_ids, g.num_edges_total
    for name in ("pose", "vertex_time", "view", "alive", "alias", "alias_offset"):
        arrays[prefix + "graph." + name] = getattr(g, name)[:n].copy()
    for name in ("from", "to", "rel", "time", "kind", "cluster", "alive"):
        arrays[prefix + "graph.edge_" + name] = getattr(g, "edge_" + name)[:m].copy()
    # adjacency in each dict's own order: merges and short-edge removal iterate it
    counts = np.array([len(a) for a in g.adjacency], dtype=np.int64)
    arrays[prefix + "adjacency.count"] = counts
    arrays[prefix + "adjacency.neighbour"] = np.fromiter(
        (w for a in g.adjacency for w in a), dtype=np.int64, count=int(counts.sum())
    )
    arrays[prefix + "adjacency.edge"] = np.fromiter(
        (k for a in g.adjacency for k in a.values()), dtype=np.int64, count=int(counts.sum())
    )
    save_lists(arrays, prefix + "absorbed", g._absorbed)
    clusters = cmap.clusterer.clusters
    open_cluster = cmap.clusterer.open_cluster
    if open_cluster is not None and (not clusters or clusters[-1] is not open_cluster):
        raise ValueError("the open cluster is not the newest one; cannot save the clusterer")
    arrays[prefix + "clusters.start_time"] = np.array([c.start_time for c in clusters])
    arrays[prefix + "clusters.last_time"] = np.array([c.last_time for c in clusters])
    arrays[prefix + "clusters.edge_count"] = np.array(
        [c.edge_count for c in clusters], dtype=np.int64
    )
    arrays[prefix + "clusters.closed_time"] = np.array(
        [math.nan if c.closed_time is None else c.closed_time for c in clusters]
    )
    integration = cmap.integration
    known = integration._known
    if known is not None:
        for name in ("start", "end", "ends", "newest"):
            arrays[prefix + "known_edges." + name] = getattr(known, name).copy()
    save_records(arrays, prefix + "optimizations.", cmap.optimizations, OptimizationRecord)
    save_records(arrays, prefix + "refused.", cmap.refused, RelocalisationCheck)
    save_records(
        arrays,
        prefix + "accepted_by_consensus.",
        cmap.gate.accepted_by_consensus,
        RelocalisationCheck,
    )
    times, vertices, edges = cmap.size_history()
    arrays[prefix + "size_history.time"] = times
    arrays[prefix + "size_history.vertices"] = vertices
    arrays[prefix + "size_history.edges"] = edges
    return {
        "mode": cmap.mode.value,
        "params": cmap.params.to_dict(),
        "graph": {
            "num_ids": n,
            "num_edges_total": m,
            "num_vertices": g.num_vertices,
            "num_edges": g.num_edges,
            "num_loop_edges": g.num_loop_edges,
        },
        "open_cluster": open_cluster is not None,
        "integration": {
            "open": None if integration.open is None else _run_json(integration.open),
            "pending": [_run_json(run) for run in integration.pending],
            "relocalised_at": None
            if integration._relocalised_at is None
            else list(integration._relocalised_at),
            "known_edges": None
            if known is None
            else {"reach": known.reach, "radius": known.radius, "tree": known.tree is not None},
        },
        "streak": [_check_json(c) for c in cmap.gate.streak],
        "counters": asdict(cmap.counters),
        "robot": {
            "current": cmap._current,
            "accum": list(cmap._accum),
            "travelled": cmap._travelled,
            "last_rotation": cmap._last_rotation,
            "last_time": cmap._last_time,
            "last_link": None if cmap._last_link is None else list(cmap._last_link),
        },
        "edges_at_last_optimization": cmap._edges_at_last_optimization,
        "optimized_once": cmap._optimized_once,
    }


def _run_json(run: RevisitRun) -> Json:
    return {
        "start": run.start,
        "opened_from": run.opened_from,
        "vertices": list(run.vertices),
        "created": run.created,
        "end": run.end,
        "closing": list(run.closing),
        "closed": run.closed,
    }


def _check_json(check: RelocalisationCheck) -> Json:
    out = asdict(check)
    out["correction"] = list(check.correction)
    return out


def load_map(s: Json, prefix: str, arrays: Arrays) -> CognitiveMap:
    """The map saved by :func:`save_map` (scalars ``s``, arrays under ``prefix``)."""
    cmap = CognitiveMap(MapMode(s["mode"]), MapParams.from_dict(s["params"]))
    g = MapGraph()
    sizes = s["graph"]
    n, m = int(sizes["num_ids"]), int(sizes["num_edges_total"])
    for name in ("pose", "vertex_time", "view", "alive", "alias", "alias_offset"):
        fill = -1 if name == "alias" else 0
        setattr(g, name, _graph_array(arrays, prefix + "graph." + name, getattr(g, name), n, fill))
    for name in ("from", "to", "rel", "time", "kind", "cluster", "alive"):
        fill = -1 if name == "cluster" else 0
        key = prefix + "graph.edge_" + name
        setattr(g, "edge_" + name, _graph_array(arrays, key, getattr(g, "edge_" + name), m, fill))
    g.num_ids, g.num_edges_total = n, m
    g.num_vertices = int(sizes["num_vertices"])
    g.num_edges = int(sizes["num_edges"])
    g.num_loop_edges = int(sizes["num_loop_edges"])
    counts = arrays[prefix + "adjacency.count"].tolist()
    neighbours = arrays[prefix + "adjacency.neighbour"].tolist()
    edges = arrays[prefix + "adjacency.edge"].tolist()
    if len(counts) != n or sum(counts) != len(neighbours):
        raise SessionError(f"{prefix}adjacency does not match the graph")
    g.adjacency = []
    start = 0
    for c in counts:
        pairs = zip(neighbours[start : start + c], edges[start : start + c], strict=True)
        g.adjacency.append(dict(pairs))
        start += c
    g._absorbed = load_lists(arrays, prefix + "absorbed")
    if len(g._absorbed) != n:
        raise SessionError(f"{prefix}aliases do not match the graph")
    if int(np.count_nonzero(g.alive[:n])) != g.num_vertices:
        raise SessionError(f"{prefix}graph's live vertices do not match its header")
    cmap.graph = g

    clusterer = LoopClosureClusterer(cmap.params.t_interval, cmap.params.t_total)
    closed = arrays[prefix + "clusters.closed_time"].tolist()
    clusterer.clusters = [
        Cluster(k, a, b, c, None if math.isnan(d) else d)
        for k, (a, b, c, d) in enumerate(
            zip(
                arrays[prefix + "clusters.start_time"].tolist(),
                arrays[prefix + "clusters.last_time"].tolist(),
                arrays[prefix + "clusters.edge_count"].tolist(),
                closed,
                strict=True,
            )
        )
    ]
    if s["open_cluster"]:
        clusterer._open = clusterer.clusters[-1]
    cmap.clusterer = clusterer

    integration = SceneIntegration()
    si = s["integration"]
    integration.open = None if si["open"] is None else _run_from_json(si["open"])
    integration.pending = [_run_from_json(r) for r in si["pending"]]
    at = si.get("relocalised_at")  # absent from files of before it existed: no pending one
    integration._relocalised_at = None if at is None else (int(at[0]), int(at[1]))
    if si["known_edges"] is not None:
        known = KnownEdges.__new__(KnownEdges)
        for name in ("start", "end", "ends", "newest"):
            setattr(known, name, arrays[prefix + "known_edges." + name])
        known.reach = float(si["known_edges"]["reach"])
        known.radius = float(si["known_edges"]["radius"])
        # the same midpoints build the same tree
        known.tree = cKDTree(0.5 * (known.start + known.end)) if si["known_edges"]["tree"] else None
        integration._known = known
    cmap.integration = integration

    gate = RelocalisationGate()
    gate.streak = [_check_from_json(c) for c in s["streak"]]
    gate.accepted_by_consensus = load_records(  # type: ignore[assignment]
        arrays, prefix + "accepted_by_consensus.", RelocalisationCheck
    )
    cmap.gate = gate
    cmap.optimizations = load_records(  # type: ignore[assignment]
        arrays, prefix + "optimizations.", OptimizationRecord
    )
    cmap.refused = load_records(arrays, prefix + "refused.", RelocalisationCheck)  # type: ignore[assignment]
    cmap.counters = MapCounters(**s["counters"])
    _check_counters(cmap, prefix)
    robot = s["robot"]
    cmap._current = int(robot["current"])
    cmap._accum = [float(v) for v in robot["accum"]]
    cmap._travelled = float(robot["travelled"])
    cmap._last_rotation = float(robot["last_rotation"])
    cmap._last_time = float(robot["last_time"])
    link = robot["last_link"]
    cmap._last_link = None if link is None else (float(link[0]), int(link[1]), bool(link[2]))
    cmap._edges_at_last_optimization = int(s["edges_at_last_optimization"])
    cmap._optimized_once = bool(s["optimized_once"])
    cmap._hist_time = arrays[prefix + "size_history.time"].tolist()
    cmap._hist_vertices = arrays[prefix + "size_history.vertices"].tolist()
    cmap._hist_edges = arrays[prefix + "size_history.edges"].tolist()
    return cmap


def _check_counters(cmap: CognitiveMap, prefix: str) -> None:
    """Refuse counters that do not add up with the loaded graph (they are shown, never derived).

    Every proposal made an id; every id that is not a live vertex was declined, integrated or
    removed as a short edge; every refused relocalisation is on record.
    """
    counters, graph = cmap.counters, cmap.graph
    removed = counters.declined + counters.integrated + counters.short_edges
    if (
        counters.proposed != graph.num_ids
        or removed != graph.num_ids - graph.num_vertices
        or counters.refused_relocalisations != len(cmap.refused)
    ):
        raise SessionError(f"{prefix}counters do not match the graph")


def _graph_array(
    arrays: Arrays, name: str, empty: NDArray[Any], rows: int, fill: int
) -> NDArray[Any]:
    """Saved array ``name`` (``rows`` rows) as a graph array like ``empty`` (a new graph's).

    Grown as the graph grows its own: at least ``empty``'s capacity, the rows past ``rows``
    holding ``fill``.
    """
    saved = arrays[name]
    if saved.shape != (rows, *empty.shape[1:]):
        raise SessionError(f"{name} does not match the graph")
    return grow_array(saved.astype(empty.dtype, copy=False), max(empty.shape[0], rows), fill)


def _run_from_json(s: Json) -> RevisitRun:
    return RevisitRun(
        start=int(s["start"]),
        opened_from=int(s.get("opened_from", -1)),  # (absent from sessions saved before it)
        vertices=[int(v) for v in s["vertices"]],
        created=float(s["created"]),
        end=int(s["end"]),
        closing=tuple(float(v) for v in s["closing"]),  # type: ignore[arg-type]
        closed=float(s["closed"]),
    )


def _check_from_json(s: Json) -> RelocalisationCheck:
    values = dict(s)
    values["correction"] = tuple(float(v) for v in s["correction"])
    return RelocalisationCheck(**values)


__all__ = ["load_map", "save_map"]
