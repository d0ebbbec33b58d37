"""Routes on each map against the true shortest path along the driven path (issue 26 part 3).

For each 6-lap layout (``irat_australia``, ``figure_eight``, ``long_corridors``,
``junction_dead_end``; bags and front-end events as ``benchmarks/map_layouts.py`` makes them), the
three maps are built with the paper's parameters. Seeded random start/goal pairs are drawn on the
true path (uniform in distance driven, at least ``--min-length`` apart along it). Each map is
aligned to the ground truth (rigid, its vertices against their true positions at creation, as
for the ATE); the two places are taken into the map's frame and the route asked for
(:mod:`cogmap_core.routes`: Dijkstra over the live edges weighted by their optimised length,
places snapped to the nearest vertex). Per route:

- the *stretch*: the route's length over the true shortest path along the driven path
  (:func:`~cogmap_core.routes.true_path_graph`) between the places of its two end vertices (their
  aligned positions, snapped to the true path) -- how much longer the map's way is than the
  true way between the same two places;
- the *end-to-end* stretch: the legs from the asked places to the snapped vertices added, over
  the true shortest path between the asked places (what sparse vertices cost a user who clicks
  anywhere); and the stretch with measured edge lengths as weights instead of optimised ones;
- the share of the route's length within ``--radius`` (8 cm) of the true path, with the aligned
  map, and the part of it inside a wall cell of the layout.

Targets, every layout: compact median stretch <= 1.02 and <= 1.05 x the standard map's, and
>= 99 % of every route (every map) on the true path. Where a route falls short, its off-path
edges are listed: kind (sequential or loop closure), length, the part off the path, the
farthest point from it and the part inside walls.

Usage: ``python benchmarks/routes.py [--layouts a,b] [--pairs 200] [--seed 1] [--radius 0.08]
[--min-length 1.0]``.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parent))

from map_layouts import LAYOUTS, MODES, load_dataset  # noqa: E402

from cogmap_core.cognitive_map import CognitiveMap, MapMode  # noqa: E402
from cogmap_core.config import MapParams  # noqa: E402
from cogmap_core.datasets.layout import Layout, load_layout  # noqa: E402
from cogmap_core.event_log import EventLog  # noqa: E402
from cogmap_core.map_graph import EdgeKind, MapSnapshot  # noqa: E402
from cogmap_core.routes import (  # noqa: E402
    TRUE_PATH_JOIN_RADIUS,
    NoRouteError,
    RouteMap,
    segments_on_path,
    true_path_graph,
)

ON_PATH_TARGET = 0.99
SAME_HEADING = np.radians(60.0)  # joins a view-based loop closure could make
PROXIMITY_JOIN = 0.10  # m, the diagnostic joins of map vertices this close
CORNER = np.radians(45.0)  # a route turns a corner at a vertex where its direction turns more


def same_heading_graph(truth: np.ndarray) -> RouteMap:
    """The true-path graph with joins only where the two samples head the same way (< 60 deg).

    What a map can know when its loop closures come from view matching, which recognises a place
    only when it is seen facing the same way: a corridor driven both ways stays two strands.
    """
    xy = truth[:, :2]
    pairs = cKDTree(xy).query_pairs(TRUE_PATH_JOIN_RADIUS, output_type="ndarray")
    turn = np.abs((truth[pairs[:, 0], 2] - truth[pairs[:, 1], 2] + np.pi) % (2 * np.pi) - np.pi)
    pairs = pairs[turn < SAME_HEADING]
    chain = np.arange(xy.shape[0] - 1)
    return RouteMap(
        np.arange(xy.shape[0]), truth, np.r_[chain, pairs[:, 0]], np.r_[chain + 1, pairs[:, 1]]
    )


def with_proximity_joins(snap: MapSnapshot, radius: float) -> RouteMap:
    """A map's route map plus a join between every two vertices within ``radius`` in its poses."""
    pairs = cKDTree(snap.poses[:, :2]).query_pairs(radius, output_type="ndarray")
    ids = snap.vertex_ids
    return RouteMap(
        ids,
        snap.poses,
        np.r_[snap.edge_from, ids[pairs[:, 0]]],
        np.r_[snap.edge_to, ids[pairs[:, 1]]],
    )


def corners(points: np.ndarray) -> int:
    """Vertices where a polyline's direction turns by more than :data:`CORNER`."""
    step = np.diff(points[:, :2], axis=0)
    step = step[np.hypot(*step.T) > 1e-6]
    if step.shape[0] < 2:
        return 0
    heading = np.arctan2(step[:, 1], step[:, 0])
    turn = np.abs((np.diff(heading) + np.pi) % (2 * np.pi) - np.pi)
    return int(np.count_nonzero(turn > CORNER))


def in_wall_length(layout: Layout, a: np.ndarray, b: np.ndarray, step: float = 0.005) -> np.ndarray:
    """Per segment ``a -> b`` (truth frame), its length inside the layout's wall cells (m)."""
    length = np.hypot(*(b - a).T)
    pieces = np.maximum(np.ceil(length / step).astype(np.int64), 1)
    owner = np.repeat(np.arange(a.shape[0]), pieces)
    first = np.cumsum(pieces) - pieces
    frac = (np.arange(owner.size) - first[owner] + 0.5) / pieces[owner]
    mid = a[owner] + (b[owner] - a[owner]) * frac[:, None]
    col = np.floor(mid[:, 0] / layout.cell).astype(np.int64)
    row = layout.rows - 1 - np.floor(mid[:, 1] / layout.cell).astype(np.int64)
    inside = (row >= 0) & (row < layout.rows) & (col >= 0) & (col < layout.cols)
    wall = np.ones(mid.shape[0], dtype=bool)  # outside the grid is wall
    wall[inside] = layout.walls[row[inside], col[inside]]
    return np.bincount(owner, weights=(length / pieces)[owner] * wall, minlength=a.shape[0])


@dataclass
class MapRoutes:
    """One map's routes: per pair the figures, and per edge its on-path and in-wall lengths."""

    mode: MapMode
    vertices: int
    stretch: np.ndarray
    end_to_end: np.ndarray
    measured: np.ndarray
    on_path: np.ndarray
    snap_gap: np.ndarray
    unreachable: int
    off_path_routes: list[tuple[int, float, list[int]]]  # (pair, share, off-path edge indices)
    edge_kind: np.ndarray
    edge_length: np.ndarray
    edge_on: np.ndarray
    edge_wall: np.ndarray
    edge_far: np.ndarray
    route_wall: np.ndarray
    same_heading: np.ndarray  # stretch against the same-heading true path
    joined: np.ndarray  # stretch with proximity joins added to the map
    joined_wall: float  # the most route length inside walls with those joins (m)
    corners: np.ndarray  # per route, the corners it turns
    excess: np.ndarray  # per route, its length minus the true shortest path's (m)


def draw_pairs(
    truth: np.ndarray, graph: RouteMap, pairs: int, seed: int, min_length: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Seeded start/goal samples on the true path, uniform in distance driven, far enough apart."""
    rng = np.random.default_rng(seed)
    step = np.hypot(*np.diff(truth[:, :2], axis=0).T)
    driven = np.r_[0.0, np.cumsum(step)]
    starts: list[int] = []
    goals: list[int] = []
    lengths: list[float] = []
    while len(starts) < pairs:
        u = rng.uniform(0.0, driven[-1], size=(2 * pairs, 2))
        s = np.minimum(np.searchsorted(driven, u[:, 0]), len(driven) - 1)
        g = np.minimum(np.searchsorted(driven, u[:, 1]), len(driven) - 1)
        true = graph.lengths(s, g)
        for a, b, length in zip(s.tolist(), g.tolist(), true.tolist(), strict=True):
            if length >= min_length and len(starts) < pairs:
                starts.append(a)
                goals.append(b)
                lengths.append(length)
    return np.array(starts), np.array(goals), np.array(lengths)


def route_map(
    cmap: CognitiveMap,
    log: EventLog,
    truth: np.ndarray,
    true_graph: RouteMap,
    heading_graph: RouteMap,
    layout: Layout,
    starts: np.ndarray,
    goals: np.ndarray,
    true_lengths: np.ndarray,
    radius: float,
) -> MapRoutes:
    """Route every pair on one map and judge the routes."""
    snap = cmap.snapshot()
    accuracy = log.map_accuracy(snap, radius)
    assert accuracy is not None and accuracy.alignment is not None
    alignment = accuracy.alignment
    aligned = alignment.apply(snap.poses[:, :2])
    routes = RouteMap.of(snap)
    measured = RouteMap.of(snap, "measured")
    joined = with_proximity_joins(snap, PROXIMITY_JOIN)
    row_of = {int(v): k for k, v in enumerate(snap.vertex_ids.tolist())}
    # every live edge once: its aligned length, the part on the true path, in walls, farthest
    a_rows, b_rows = snap.edge_ends()
    e_a, e_b = aligned[a_rows], aligned[b_rows]
    e_len, e_on = segments_on_path(e_a, e_b, truth, radius)
    e_wall = in_wall_length(layout, e_a, e_b)
    path_tree = cKDTree(truth[:, :2])
    fractions = np.linspace(0.0, 1.0, 21)
    e_far = np.zeros(e_len.shape[0])
    if e_len.size:
        samples = e_a[:, None, :] + (e_b - e_a)[:, None, :] * fractions[None, :, None]
        far, _ = path_tree.query(samples.reshape(-1, 2))
        e_far = far.reshape(-1, fractions.size).max(axis=1)
    edge_of = {
        (min(a, b), max(a, b)): k
        for k, (a, b) in enumerate(zip(a_rows.tolist(), b_rows.tolist(), strict=True))
    }
    to_map = alignment.inverse()  # the truth's frame -> the map's
    start_map = to_map.apply(truth[starts, :2])
    goal_map = to_map.apply(truth[goals, :2])
    n = starts.shape[0]
    length = np.full(n, np.nan)
    gaps = np.zeros((n, 2))
    ends = np.zeros((n, 2), dtype=np.int64)
    on_path = np.full(n, np.nan)
    route_wall = np.zeros(n)
    turns = np.zeros(n, dtype=np.int64)
    joined_length = np.full(n, np.nan)
    joined_wall = 0.0
    off_routes: list[tuple[int, float, list[int]]] = []
    unreachable = 0
    for i in range(n):
        try:
            route = routes.route(start_map[i], goal_map[i])
        except NoRouteError:
            unreachable += 1
            continue
        length[i] = route.length
        gaps[i] = route.start_gap, route.goal_gap
        ends[i] = route.vertex_ids[0], route.vertex_ids[-1]
        rows = [row_of[int(v)] for v in route.vertex_ids.tolist()]
        edges = [edge_of[(min(a, b), max(a, b))] for a, b in zip(rows[:-1], rows[1:], strict=True)]
        total = float(e_len[edges].sum()) if edges else 0.0
        share = float(e_on[edges].sum()) / total if total > 0 else 1.0
        on_path[i] = share
        route_wall[i] = float(e_wall[edges].sum()) if edges else 0.0
        turns[i] = corners(route.points)
        shortcut = joined.route_between(int(ends[i, 0]), int(ends[i, 1]))
        joined_length[i] = shortcut.length
        if shortcut.num_edges:
            p = alignment.apply(shortcut.points)
            joined_wall = max(joined_wall, float(in_wall_length(layout, p[:-1], p[1:]).sum()))
        if share < ON_PATH_TARGET:
            off = [k for k in edges if e_len[k] - e_on[k] > 1e-3]
            off_routes.append((i, share, off))
    ok = np.isfinite(length)
    # the true shortest path between the places of the route's two end vertices
    end_a = np.array([true_graph.snap(aligned[row_of[int(v)]])[0] for v in ends[ok, 0]])
    end_b = np.array([true_graph.snap(aligned[row_of[int(v)]])[0] for v in ends[ok, 1]])
    between = true_graph.lengths(end_a, end_b) if ok.any() else np.zeros(0)
    same_way = heading_graph.lengths(end_a, end_b) if ok.any() else np.zeros(0)

    def ratio(route_length: np.ndarray, reference: np.ndarray) -> np.ndarray:
        out = np.full(n, np.nan)
        out[ok] = np.where(reference > 0, route_length / np.maximum(reference, 1e-12), 1.0)
        return out

    stretch = ratio(length[ok], between)
    excess = np.full(n, np.nan)
    excess[ok] = length[ok] - between
    end_to_end = (length + gaps.sum(axis=1)) / true_lengths
    by_measure = ratio(measured.lengths(ends[ok, 0], ends[ok, 1]), between)
    return MapRoutes(
        cmap.mode,
        cmap.num_vertices,
        stretch,
        end_to_end,
        by_measure,
        on_path,
        gaps.reshape(-1),
        unreachable,
        off_routes,
        snap.edge_kind,
        e_len,
        e_on,
        e_wall,
        e_far,
        route_wall,
        ratio(length[ok], same_way),
        ratio(joined_length[ok], between),
        joined_wall,
        turns,
        excess,
    )


def explain(result: MapRoutes, shown: int = 3) -> None:
    """Why routes leave the true path: their off-path edges, worst routes first."""
    worst = sorted(result.off_path_routes, key=lambda r: r[1])
    edges = sorted({k for _, _, off in worst for k in off})
    if not edges:
        return
    kinds = {EdgeKind.SEQUENTIAL: "seq", EdgeKind.LOOP_CLOSURE: "loop"}
    loops = sum(result.edge_kind[k] == EdgeKind.LOOP_CLOSURE for k in edges)
    walls = sum(result.edge_wall[k] > 0.005 for k in edges)
    print(
        f"      {result.mode.value}: {len(worst)} routes below {ON_PATH_TARGET:.0%}, through "
        f"{len(edges)} distinct off-path edges ({loops} loop closures, {walls} crossing a wall "
        "by > 5 mm); the worst routes:"
    )
    for pair, share, off in worst[:shown]:
        parts = ", ".join(
            f"{kinds[EdgeKind(int(result.edge_kind[k]))]} {result.edge_length[k]:.2f} m "
            f"(off {result.edge_length[k] - result.edge_on[k]:.3f} m, farthest "
            f"{result.edge_far[k]:.3f} m, in wall {result.edge_wall[k]:.3f} m)"
            for k in off
        )
        print(f"        pair {pair}: {share:.2%} on path; {parts}")


def evaluate_layout(
    layout_name: str, params: MapParams, pairs: int, seed: int, radius: float, min_length: float
) -> list[str]:
    """Route the pairs on the three maps of one layout; print the figures; return targets missed."""
    data = load_dataset(layout_name)
    log = EventLog.from_recording(data.recording)
    truth = np.asarray(log.ground_truth)
    layout = load_layout(layout_name)
    started = time.perf_counter()
    true_graph = true_path_graph(truth)
    heading_graph = same_heading_graph(truth)
    starts, goals, true_lengths = draw_pairs(truth, true_graph, pairs, seed, min_length)
    graph_s = time.perf_counter() - started
    results: dict[MapMode, MapRoutes] = {}
    for mode in MODES:
        cmap = CognitiveMap(mode, params)
        cmap.apply_all(log.events)
        cmap.finish(log.frame_time[-1])
        results[mode] = route_map(
            cmap, log, truth, true_graph, heading_graph, layout, starts, goals, true_lengths, radius
        )
    driven = float(np.hypot(*np.diff(truth[:, :2], axis=0).T).sum())
    truth_in_wall = float(in_wall_length(layout, truth[:-1, :2], truth[1:, :2]).sum())
    print(
        f"\n{layout_name}: {truth.shape[0]} true-path samples, {driven:.1f} m driven "
        f"({truth_in_wall:.3f} m of it in walls), true-path graph {true_graph.num_edges} edges "
        f"(joins within {TRUE_PATH_JOIN_RADIUS * 100:.0f} cm; built and {pairs} pairs drawn in "
        f"{graph_s:.1f} s); true shortest paths {np.median(true_lengths):.2f} m median "
        f"({true_lengths.min():.2f}-{true_lengths.max():.2f})"
    )
    print(
        f"  {'map':18} {'V':>5} {'stretch':>7} {'p95':>6} {'max':>6} {'ends':>6} {'ends95':>6} "
        f"{'meas.':>6} {'on-path':>7} {'<99%':>5} {'wall m':>6} {'snap m':>6} {'none':>4}"
    )
    for mode in MODES:
        r = results[mode]
        print(
            f"  {mode.value:18} {r.vertices:5d} {np.nanmedian(r.stretch):7.4f} "
            f"{np.nanpercentile(r.stretch, 95):6.3f} {np.nanmax(r.stretch):6.3f} "
            f"{np.nanmedian(r.end_to_end):6.3f} {np.nanpercentile(r.end_to_end, 95):6.3f} "
            f"{np.nanmedian(r.measured):6.3f} {np.nanmin(r.on_path):7.2%} "
            f"{len(r.off_path_routes):5d} {np.nanmax(r.route_wall):6.3f} "
            f"{np.median(r.snap_gap):6.3f} {r.unreachable:4d}"
        )
    std, cm = results[MapMode.STANDARD], results[MapMode.COMPACT]
    cm_median = float(np.nanmedian(cm.stretch))
    ratio = cm_median / float(np.nanmedian(std.stretch))
    worst = {m.value: float(np.nanmin(results[m].on_path)) for m in MODES}
    unreachable = sum(r.unreachable for r in results.values())
    print(f"  compact median stretch / standard's: {ratio:.4f}")
    checks = [
        (f"compact median stretch <= 1.02 ({cm_median:.4f})", cm_median <= 1.02),
        (f"compact median stretch <= 1.05 x standard's ({ratio:.4f})", ratio <= 1.05),
        (
            ">= 99 % of every route on the true path (worst: "
            + ", ".join(f"{k} {v:.2%}" for k, v in worst.items())
            + ")",
            min(worst.values()) >= ON_PATH_TARGET,
        ),
        (f"every goal reachable ({unreachable} not)", unreachable == 0),
    ]
    for label, ok in checks:
        print(f"    {'OK    ' if ok else 'MISSED'} {label}")
    print(
        "  why: stretch against the same-heading true path (joins only where the robot faced "
        f"the same way, < {np.degrees(SAME_HEADING):.0f} deg), with the map's vertices within "
        f"{PROXIMITY_JOIN * 100:.0f} cm joined, on routes turning no corner (> "
        f"{np.degrees(CORNER):.0f} deg), and the excess length per corner"
    )
    print(
        f"  {'map':18} {'same-way':>8} {'p95':>6} {'joined':>7} {'p95':>6} {'wall m':>6} "
        f"{'straight':>8} {'n':>4} {'cm/corner':>9}"
    )
    for mode in MODES:
        r = results[mode]
        straight = r.corners == 0
        cornered = (r.corners > 0) & np.isfinite(r.excess)
        per_corner = (
            np.median(r.excess[cornered] / r.corners[cornered]) * 100 if cornered.any() else np.nan
        )
        print(
            f"  {mode.value:18} {np.nanmedian(r.same_heading):8.4f} "
            f"{np.nanpercentile(r.same_heading, 95):6.3f} {np.nanmedian(r.joined):7.4f} "
            f"{np.nanpercentile(r.joined, 95):6.3f} {r.joined_wall:6.3f} "
            f"{np.nanmedian(r.stretch[straight]) if straight.any() else np.nan:8.4f} "
            f"{int(straight.sum()):4d} {per_corner:9.1f}"
        )
    if min(worst.values()) < ON_PATH_TARGET:
        for mode in MODES:
            explain(results[mode])
    return [label for label, ok in checks if not ok]


def main() -> None:
    """Run the benchmark."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--layouts", default=",".join(LAYOUTS), help="comma-separated layouts")
    parser.add_argument("--pairs", type=int, default=200, help="start/goal pairs per layout")
    parser.add_argument("--seed", type=int, default=1, help="seed of the pairs")
    parser.add_argument("--radius", type=float, default=0.08, help="on-path radius (m)")
    parser.add_argument(
        "--min-length", type=float, default=1.0, help="shortest true path of a pair (m)"
    )
    args = parser.parse_args()
    params = MapParams()
    missed = {}
    for layout in args.layouts.split(","):
        failed = evaluate_layout(
            layout, params, args.pairs, args.seed, args.radius, args.min_length
        )
        if failed:
            missed[layout] = failed
    n = len(args.layouts.split(","))
    print(
        f"\nroutes: {n - len(missed)}/{n} layouts meet every target"
        + (f" (missed: {', '.join(missed)})" if missed else "")
    )


if __name__ == "__main__":
    main()
