"""Routes on each map against the true shortest path along the driven path (issue 26 part 3).

For each 6-lap layout (``irat_australia``, ``figure_eight``, ``long_corridors``,
``junction_dead_end``; bags and front-end events as ``benchmarks/map_layouts.py`` makes them), the
three maps are built with the paper's parameters. Seeded random start/goal pairs are drawn on the
true path (uniform in distance driven, at least ``--min-length`` apart along it). Each map is
aligned to the ground truth (rigid, its vertices against their true positions at creation, as
for the ATE); the two places are taken into the map's frame and the route asked for
(:mod:`cogmap_core.routes`: Dijkstra over the live edges weighted by their optimised length and
over joins of vertices within the map's ``integration_radius``, places snapped to the nearest
vertex, the way straightened within ``link_sigma_position`` of its vertices). Per route:

- the *stretch*: the route's length over the true shortest path along the driven path
  (:func:`~cogmap_core.routes.true_path_graph`) between the places of its two end vertices (their
  aligned positions, snapped to the true path) -- how much longer the map's way is than the
  true way between the same two places;
- the *end-to-end* stretch: the legs from the asked places to the snapped vertices added, over
  the true shortest path between the asked places (what sparse vertices cost a user who clicks
  anywhere); and the stretch with measured edge lengths as weights instead of optimised ones;
- the share of the route's way within ``--radius`` (8 cm) of the true path, with the aligned
  map, and the part of it inside a wall cell of the layout.

Targets, every layout: compact median stretch <= 1.02 and <= 1.05 x the standard map's, and
>= 99 % of every route (every map) on the true path. Where a route falls short, its off-path
pieces are listed: length, the part off the path, the farthest point from it and the part
inside walls, and the kinds of edge the route took (sequential, loop closure, join).

Then what each part of the routing does, per map: the median stretch of routes over the edges
alone through the vertices (no joins, not straightened), with the joins, and straightened (the
routes above); the straightened routes against the true shortest path straightened the same way
(the driven path meanders in its corridor, so a straightened route can be shorter than it); the
largest in-wall length and lowest on-path share of the routes over the edges and joins; and the
excess length per corner turned.

Usage: ``python benchmarks/routes.py [--layouts a,b] [--pairs 200] [--seed 1] [--radius 0.08]
[--min-length 1.0] [--dataset-seed 1]``.
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
from cogmap_core.map_graph import EdgeKind  # noqa: E402
from cogmap_core.routes import (  # noqa: E402
    TRUE_PATH_JOIN_RADIUS,
    NoRouteError,
    RouteMap,
    segments_on_path,
    straighten,
    true_path_graph,
)

ON_PATH_TARGET = 0.99
CORNER = np.radians(45.0)  # a route turns a corner at a vertex where its direction turns more
KIND_NAMES = {int(EdgeKind.SEQUENTIAL): "seq", int(EdgeKind.LOOP_CLOSURE): "loop"}


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
class OffPath:
    """A route below the on-path target: its share, its pieces off the path, its edge kinds."""

    pair: int
    share: float
    pieces: list[tuple[float, float, float, float]]  # (length, off, farthest, in wall) (m)
    kinds: dict[str, int]


@dataclass
class MapRoutes:
    """One map's routes: per pair the figures, and what each part of the routing does."""

    mode: MapMode
    vertices: int
    joins: int
    stretch: np.ndarray
    end_to_end: np.ndarray
    measured: np.ndarray
    on_path: np.ndarray
    snap_gap: np.ndarray
    unreachable: int
    off_path_routes: list[OffPath]
    route_wall: np.ndarray
    edges_only: np.ndarray  # stretch over the edges alone, through the vertices
    joined: np.ndarray  # ... with the joins, through the vertices
    joined_wall: float  # the most route length inside walls of those (m)
    joined_on_path: float  # the lowest on-path share of those
    against_straight: np.ndarray  # stretch against the straightened true shortest path
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


def edge_kinds(cmap: CognitiveMap) -> dict[tuple[int, int], str]:
    """The kind of each live edge, by its two vertex ids (smaller first)."""
    snap = cmap.snapshot()
    kinds: dict[tuple[int, int], str] = {}
    for a, b, kind in zip(
        snap.edge_from.tolist(), snap.edge_to.tolist(), snap.edge_kind.tolist(), strict=True
    ):
        kinds[(min(a, b), max(a, b))] = KIND_NAMES.get(int(kind), "other")
    return kinds


def route_map(
    cmap: CognitiveMap,
    log: EventLog,
    truth: np.ndarray,
    true_graph: RouteMap,
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
    routes = RouteMap.of(cmap)
    corridor = routes.corridor
    measured = RouteMap.of(cmap, "measured")
    edges_only = RouteMap.of(cmap, join_radius=0.0, corridor=0.0)
    joined = RouteMap.of(cmap, corridor=0.0)
    kinds = edge_kinds(cmap)
    row_of = {int(v): k for k, v in enumerate(snap.vertex_ids.tolist())}
    path_tree = cKDTree(truth[:, :2])
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
    joined_wall, joined_on_path = 0.0, 1.0
    off_routes: list[OffPath] = []
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
        way = alignment.apply(route.points)
        piece_length, piece_on = segments_on_path(way[:-1], way[1:], truth, radius)
        piece_wall = in_wall_length(layout, way[:-1], way[1:])
        total = float(piece_length.sum())
        share = float(piece_on.sum()) / total if total > 0 else 1.0
        on_path[i] = share
        route_wall[i] = float(piece_wall.sum())
        turns[i] = corners(route.points)
        through = joined.route_between(int(ends[i, 0]), int(ends[i, 1]))
        if through.num_edges:
            p = alignment.apply(through.points)
            joined_wall = max(joined_wall, float(in_wall_length(layout, p[:-1], p[1:]).sum()))
            j_length, j_on = segments_on_path(p[:-1], p[1:], truth, radius)
            joined_on_path = min(joined_on_path, float(j_on.sum() / j_length.sum()))
        if share < ON_PATH_TARGET:
            pieces = []
            for k in np.flatnonzero(piece_length - piece_on > 1e-3):
                samples = way[k] + (way[k + 1] - way[k]) * np.linspace(0, 1, 21)[:, None]
                far = float(path_tree.query(samples)[0].max())
                pieces.append(
                    (
                        float(piece_length[k]),
                        float(piece_length[k] - piece_on[k]),
                        far,
                        float(piece_wall[k]),
                    )
                )
            ids = route.vertex_ids.tolist()
            used: dict[str, int] = {}
            for a, b in zip(ids[:-1], ids[1:], strict=True):
                kind = kinds.get((min(a, b), max(a, b)), "join")
                used[kind] = used.get(kind, 0) + 1
            off_routes.append(OffPath(i, share, pieces, used))
    ok = np.isfinite(length)
    # the true shortest path between the places of the route's two end vertices
    end_a = np.array([true_graph.snap(aligned[row_of[int(v)]])[0] for v in ends[ok, 0]])
    end_b = np.array([true_graph.snap(aligned[row_of[int(v)]])[0] for v in ends[ok, 1]])
    between = true_graph.lengths(end_a, end_b) if ok.any() else np.zeros(0)
    straight_truth = np.array(
        [
            _polyline_length(straighten(true_graph.route_between(int(a), int(b)).points, corridor))
            for a, b in zip(end_a.tolist(), end_b.tolist(), strict=True)
        ]
    )

    def ratio(route_length: np.ndarray, reference: np.ndarray) -> np.ndarray:
        out = np.full(n, np.nan)
        out[ok] = np.where(reference > 0, route_length / np.maximum(reference, 1e-12), 1.0)
        return out

    excess = np.full(n, np.nan)
    excess[ok] = length[ok] - between
    return MapRoutes(
        mode=cmap.mode,
        vertices=cmap.num_vertices,
        joins=routes.num_joins,
        stretch=ratio(length[ok], between),
        end_to_end=(length + gaps.sum(axis=1)) / true_lengths,
        measured=ratio(measured.lengths(ends[ok, 0], ends[ok, 1]), between),
        on_path=on_path,
        snap_gap=gaps.reshape(-1),
        unreachable=unreachable,
        off_path_routes=off_routes,
        route_wall=route_wall,
        edges_only=ratio(edges_only.lengths(ends[ok, 0], ends[ok, 1]), between),
        joined=ratio(joined.lengths(ends[ok, 0], ends[ok, 1]), between),
        joined_wall=joined_wall,
        joined_on_path=joined_on_path,
        against_straight=ratio(length[ok], straight_truth),
        corners=turns,
        excess=excess,
    )


def _polyline_length(points: np.ndarray) -> float:
    return float(np.hypot(*np.diff(points[:, :2], axis=0).T).sum()) if len(points) > 1 else 0.0


def explain(result: MapRoutes, shown: int = 3) -> None:
    """Why routes leave the true path: their off-path pieces, worst routes first."""
    worst = sorted(result.off_path_routes, key=lambda r: r.share)
    if not worst:
        return
    print(f"      {result.mode.value}: {len(worst)} routes below {ON_PATH_TARGET:.0%}; the worst:")
    for route in worst[:shown]:
        parts = ", ".join(
            f"{length:.2f} m (off {off:.3f} m, farthest {far:.3f} m, in wall {wall:.3f} m)"
            for length, off, far, wall in route.pieces
        )
        took = ", ".join(f"{n} {kind}" for kind, n in sorted(route.kinds.items()))
        print(f"        pair {route.pair}: {route.share:.2%} on path (took {took}); {parts}")


def evaluate_layout(
    layout_name: str,
    params: MapParams,
    pairs: int,
    seed: int,
    radius: float,
    min_length: float,
    dataset_seed: int = 1,
) -> list[str]:
    """Route the pairs on the three maps of one layout; print the figures; return targets missed."""
    data = load_dataset(layout_name, dataset_seed)
    log = EventLog.from_recording(data.recording)
    truth = np.asarray(log.ground_truth)
    layout = load_layout(layout_name)
    started = time.perf_counter()
    true_graph = true_path_graph(truth)
    starts, goals, true_lengths = draw_pairs(truth, true_graph, pairs, seed, min_length)
    graph_s = time.perf_counter() - started
    results: dict[MapMode, MapRoutes] = {}
    for mode in MODES:
        cmap = CognitiveMap(mode, params)
        cmap.apply_all(log.events)
        cmap.finish(log.frame_time[-1])
        results[mode] = route_map(
            cmap, log, truth, true_graph, layout, starts, goals, true_lengths, radius
        )
    driven = float(np.hypot(*np.diff(truth[:, :2], axis=0).T).sum())
    truth_in_wall = float(in_wall_length(layout, truth[:-1, :2], truth[1:, :2]).sum())
    print(
        f"\n{layout_name} (dataset seed {dataset_seed}): {truth.shape[0]} true-path samples, "
        f"{driven:.1f} m driven ({truth_in_wall:.3f} m of it in walls), true-path graph "
        f"{true_graph.num_edges} edges (joins within {TRUE_PATH_JOIN_RADIUS * 100:.0f} cm; built "
        f"and {pairs} pairs drawn in {graph_s:.1f} s); true shortest paths "
        f"{np.median(true_lengths):.2f} m median ({true_lengths.min():.2f}-"
        f"{true_lengths.max():.2f}); routes join vertices within "
        f"{params.integration_radius * 100:.0f} cm and are straightened within "
        f"{params.link_sigma_position * 100:.0f} cm"
    )
    print(
        f"  {'map':18} {'V':>5} {'joins':>6} {'stretch':>7} {'p95':>6} {'max':>6} {'ends':>6} "
        f"{'ends95':>6} {'meas.':>6} {'on-path':>7} {'<99%':>5} {'wall m':>6} {'snap m':>6} "
        f"{'none':>4}"
    )
    for mode in MODES:
        r = results[mode]
        print(
            f"  {mode.value:18} {r.vertices:5d} {r.joins:6d} {np.nanmedian(r.stretch):7.4f} "
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
        "  what each part does: median stretch over the edges alone through the vertices, with "
        "the joins, and straightened (the routes above); the routes against the true shortest "
        "path straightened the same way; the routes with joins unstraightened: most length in "
        f"walls, lowest on-path share; on routes turning no corner (> {np.degrees(CORNER):.0f} "
        "deg), and the excess length per corner"
    )
    print(
        f"  {'map':18} {'edges':>7} {'+joins':>7} {'+straight':>9} {'vs str.':>7} "
        f"{'wall m':>6} {'on-path':>7} {'straight':>8} {'n':>4} {'cm/corner':>9}"
    )
    for mode in MODES:
        r = results[mode]
        straight = r.corners == 0
        cornered = (r.corners > 0) & np.isfinite(r.excess)
        per_corner = (
            np.median(r.excess[cornered] / r.corners[cornered]) * 100 if cornered.any() else np.nan
        )
        print(
            f"  {mode.value:18} {np.nanmedian(r.edges_only):7.4f} {np.nanmedian(r.joined):7.4f} "
            f"{np.nanmedian(r.stretch):9.4f} {np.nanmedian(r.against_straight):7.4f} "
            f"{r.joined_wall:6.3f} {r.joined_on_path:7.2%} "
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
    parser.add_argument(
        "--dataset-seed",
        type=int,
        default=1,
        help="seed of the layouts' bags (other than 1: generated into the cache once)",
    )
    args = parser.parse_args()
    params = MapParams()
    missed = {}
    for layout in args.layouts.split(","):
        failed = evaluate_layout(
            layout, params, args.pairs, args.seed, args.radius, args.min_length, args.dataset_seed
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
