"""Accuracy measures against ground truth.

- rigid 2-D alignment and ATE (RMSE of positions after the best alignment);
- dead reckoning: the odometry integrated on its own, the baseline every map must beat;
- loop-closure precision: a link is true when both the position *and* the heading it claims
  agree with the ground truth within set tolerances;
- layout fidelity: how much of the true path a map covers (completeness) and how much of the
  map lies on the true path (correctness), both at a radius ``r``, after aligning the map's
  vertices (at their creation times) to the ground truth.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from cogmap_core.map_graph import MapSnapshot

FloatArray = NDArray[np.float64]

TRUE_LOOP_CLOSURE_DISTANCE = 0.1
"""A loop closure is true when the ground-truth positions of its two ends are this close (m) ..."""

TRUE_LOOP_CLOSURE_HEADING = math.radians(10.0)
"""... and the heading it claims is this close to the true relative heading (rad)."""

LAYOUT_RADIUS = 0.08
"""Default radius of layout completeness and correctness (m)."""


@dataclass(frozen=True, slots=True)
class EvaluationSettings:
    """How a session is judged against ground truth (tolerances suit the kind of input).

    Attributes:
        layout_radius: radius of layout completeness and correctness (m).
        loop_distance: a loop closure is true when its two ends are this close (m) ...
        loop_heading: ... and its claimed heading this close to the true one (rad); ``None``
            judges position only (place recognition that claims no heading, or ground truth
            without heading).

    """

    layout_radius: float = LAYOUT_RADIUS
    loop_distance: float = TRUE_LOOP_CLOSURE_DISTANCE
    loop_heading: float | None = TRUE_LOOP_CLOSURE_HEADING


@dataclass(frozen=True, slots=True)
class RigidTransform2D:
    """``p -> R(theta) p + t``."""

    theta: float
    tx: float
    ty: float

    def apply(self, points: FloatArray) -> FloatArray:
        """Transform ``(N, 2)`` points."""
        c, s = np.cos(self.theta), np.sin(self.theta)
        p = np.asarray(points, dtype=np.float64)
        return np.stack(
            [c * p[:, 0] - s * p[:, 1] + self.tx, s * p[:, 0] + c * p[:, 1] + self.ty], 1
        )

    def inverse(self) -> RigidTransform2D:
        """The transform undoing this one: ``p -> R(-theta) (p - t)``.

        An alignment taking a map onto the ground truth, inverted, takes ground-truth points
        (or places picked where the map is shown aligned) into the map's frame.
        """
        c, s = math.cos(self.theta), math.sin(self.theta)
        return RigidTransform2D(
            -self.theta, -(c * self.tx + s * self.ty), s * self.tx - c * self.ty
        )

    def then(self, other: RigidTransform2D) -> RigidTransform2D:
        """The transform applying this one, then ``other`` (``other.apply(self.apply(p))``)."""
        c, s = math.cos(other.theta), math.sin(other.theta)
        return RigidTransform2D(
            self.theta + other.theta,
            c * self.tx - s * self.ty + other.tx,
            s * self.tx + c * self.ty + other.ty,
        )


def align_rigid_2d(source: FloatArray, target: FloatArray) -> RigidTransform2D:
    """Least-squares rotation and translation taking ``source`` points onto ``target`` (Kabsch)."""
    src = np.asarray(source, dtype=np.float64)[:, :2]
    dst = np.asarray(target, dtype=np.float64)[:, :2]
    if src.shape != dst.shape or src.shape[0] == 0:
        raise ValueError("align_rigid_2d needs two non-empty point sets of the same shape")
    mu_s, mu_d = src.mean(0), dst.mean(0)
    a, b = src - mu_s, dst - mu_d
    # optimal angle maximises sum(b . R a)
    num = float(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]))
    den = float(np.sum(a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1]))
    theta = float(np.arctan2(num, den))
    c, s = np.cos(theta), np.sin(theta)
    t = mu_d - np.array([c * mu_s[0] - s * mu_s[1], s * mu_s[0] + c * mu_s[1]])
    return RigidTransform2D(theta, float(t[0]), float(t[1]))


def absolute_trajectory_error(estimate: FloatArray, truth: FloatArray) -> float:
    """RMSE (m) between estimated and true positions after the best rigid 2D alignment."""
    est = np.asarray(estimate, dtype=np.float64)[:, :2]
    gt = np.asarray(truth, dtype=np.float64)[:, :2]
    if est.shape[0] == 0:
        return float("nan")
    return _aligned_rmse(align_rigid_2d(est, gt), est, gt)


def _aligned_rmse(alignment: RigidTransform2D, est: FloatArray, gt: FloatArray) -> float:
    """RMSE (m) between ``(N, 2)`` positions ``est`` moved by ``alignment`` and ``gt``."""
    aligned = alignment.apply(est)
    return float(np.sqrt(np.mean(np.sum((aligned - gt) ** 2, axis=1))))


def interpolate_poses(times: FloatArray, poses: FloatArray, query: FloatArray) -> FloatArray:
    """Poses at ``query`` times by linear interpolation (headings unwrapped first); clamped."""
    t = np.asarray(times, dtype=np.float64)
    p = np.asarray(poses, dtype=np.float64)
    q = np.asarray(query, dtype=np.float64)
    out = np.empty((q.shape[0], 3))
    out[:, 0] = np.interp(q, t, p[:, 0])
    out[:, 1] = np.interp(q, t, p[:, 1])
    heading = np.interp(q, t, np.unwrap(p[:, 2]))
    out[:, 2] = (heading + np.pi) % (2 * np.pi) - np.pi
    return out


def loop_candidate_distances(
    loops: FloatArray, truth_times: FloatArray, truth: FloatArray
) -> FloatArray:
    """Distance (m) between the true positions at each loop candidate's two times.

    Args:
        loops: ``(M, >=2)`` candidates: time, matched time (further columns ignored).
        truth_times: ``(G,)`` ground-truth times, increasing.
        truth: ``(G, >=2)`` true positions (x, y) at those times; interpolated linearly and
            clamped at the ends, as :func:`interpolate_poses` does.

    """
    pairs = np.asarray(loops, dtype=np.float64)
    if pairs.size == 0:
        return np.zeros(0)
    t = np.asarray(truth_times, dtype=np.float64)
    xy = np.asarray(truth, dtype=np.float64)
    dx = np.interp(pairs[:, 0], t, xy[:, 0]) - np.interp(pairs[:, 1], t, xy[:, 0])
    dy = np.interp(pairs[:, 0], t, xy[:, 1]) - np.interp(pairs[:, 1], t, xy[:, 1])
    return np.hypot(dx, dy)


@dataclass(frozen=True, slots=True)
class LoopClosureScore:
    """Loop closures judged by ground truth.

    Attributes:
        total: links judged.
        true: links whose two ends agree in position and heading.
        false: the others.
        false_indices: index (in the order given) of every false link.
        position_error: per link, distance between the true positions of its two ends (m).
        heading_error: per link, claimed minus true relative heading, wrapped (rad).

    """

    total: int
    true: int
    false: int
    false_indices: tuple[int, ...] = ()
    position_error: FloatArray | None = None
    heading_error: FloatArray | None = None

    @property
    def precision(self) -> float | None:
        """True / total, or None without loop closures."""
        return self.true / self.total if self.total else None


def score_loop_closures(
    robot_poses: FloatArray,
    target_poses: FloatArray,
    relative_rad: FloatArray | None = None,
    distance: float = TRUE_LOOP_CLOSURE_DISTANCE,
    heading: float = TRUE_LOOP_CLOSURE_HEADING,
) -> LoopClosureScore:
    """Judge loop closures by the true poses of their two ends.

    A link claims that the robot (true pose ``robot_poses[k]``) is at the place of the target
    vertex (true pose at its creation ``target_poses[k]``), with heading ``theta_target +
    relative_rad[k]``. It is true when the positions are within ``distance`` and, when
    ``relative_rad`` is given (poses then need a heading column), the claimed heading is within
    ``heading`` of the robot's true heading.
    """
    a = np.asarray(robot_poses, dtype=np.float64)
    b = np.asarray(target_poses, dtype=np.float64)
    n = int(a.shape[0]) if a.ndim == 2 else 0
    if n == 0:
        return LoopClosureScore(0, 0, 0, (), np.zeros(0), np.zeros(0))
    position_error = np.hypot(a[:, 0] - b[:, 0], a[:, 1] - b[:, 1])
    good = position_error <= distance
    heading_error = np.zeros(n)
    if relative_rad is not None:
        if a.shape[1] < 3 or b.shape[1] < 3:
            raise ValueError("judging link headings needs (x, y, theta) poses")
        claimed = b[:, 2] + np.asarray(relative_rad, dtype=np.float64)
        heading_error = (claimed - a[:, 2] + np.pi) % (2 * np.pi) - np.pi
        good &= np.abs(heading_error) <= heading
    false = tuple(int(k) for k in np.flatnonzero(~good))
    true = n - len(false)
    return LoopClosureScore(n, true, len(false), false, position_error, heading_error)


def dead_reckoning(translation: FloatArray, rotation: FloatArray) -> FloatArray:
    """Integrate odometry alone (rotate, then translate along the new heading) from the origin.

    Returns ``(N, 3)`` poses after each step, the way the cognitive map integrates odometry.
    """
    theta = np.cumsum(np.asarray(rotation, dtype=np.float64))
    step = np.asarray(translation, dtype=np.float64)
    poses = np.empty((step.shape[0], 3))
    poses[:, 0] = np.cumsum(step * np.cos(theta))
    poses[:, 1] = np.cumsum(step * np.sin(theta))
    poses[:, 2] = (theta + np.pi) % (2 * np.pi) - np.pi
    return poses


@dataclass(frozen=True, slots=True)
class LayoutFidelity:
    """How well a map's edges represent the true path (both ways), at ``radius``.

    Attributes:
        completeness: fraction of the true path's length within ``radius`` of the map (an edge,
            or a vertex without edges).
        correctness: fraction of the map's edge length within ``radius`` of the true path
            (``nan`` for a map without edge length).
        radius: the radius (m).
        edges_per_vertex: live edges / live vertices.
        path_length: length of the true path (m).
        edge_length: total length of the map's edges after alignment (m).

    """

    completeness: float
    correctness: float
    radius: float
    edges_per_vertex: float
    path_length: float
    edge_length: float


def _sample_polyline_pieces(
    start: FloatArray, end: FloatArray, spacing: float
) -> tuple[FloatArray, FloatArray]:
    """Split segments into equal pieces no longer than ``spacing``; return midpoints, lengths."""
    length = np.hypot(*(end - start).T)
    pieces = np.maximum(np.ceil(length / spacing).astype(np.int64), 1)
    owner = np.repeat(np.arange(start.shape[0]), pieces)
    first = np.cumsum(pieces) - pieces
    index = np.arange(owner.size) - first[owner]
    frac = (index + 0.5) / pieces[owner]
    mid = start[owner] + (end[owner] - start[owner]) * frac[:, None]
    return mid, (length / pieces)[owner]


def _within_radius_of_segments(
    points: FloatArray, start: FloatArray, end: FloatArray, radius: float
) -> NDArray[np.bool_]:
    """Whether each point lies within ``radius`` of at least one segment (exact test).

    The segments are sampled every ``s = radius / 4``; a point whose nearest sample is within
    ``radius`` is covered, one farther than ``sqrt(radius^2 + (s/2)^2)`` from every sample is
    not (every point of a segment lies within ``s/2`` of a sample, along it). Only the points in
    between are tested against the segments themselves.
    """
    covered = np.zeros(points.shape[0], dtype=bool)
    if start.shape[0] == 0 or points.shape[0] == 0:
        return covered
    spacing = max(radius, 1e-3) / 4.0
    length = np.hypot(*(end - start).T)
    counts = np.maximum(np.ceil(length / spacing).astype(np.int64), 1)
    owner = np.repeat(np.arange(start.shape[0]), counts + 1)
    first = np.cumsum(counts + 1) - (counts + 1)
    frac = (np.arange(owner.size) - first[owner]) / counts[owner]
    samples = start[owner] + (end[owner] - start[owner]) * frac[:, None]
    tree = cKDTree(samples)
    distance, _ = tree.query(points, k=1)
    covered = distance <= radius
    band = np.flatnonzero(~covered & (distance <= math.hypot(radius, spacing / 2.0)))
    if band.size == 0:
        return covered
    reach = math.hypot(radius, spacing / 2.0)
    lists = tree.query_ball_point(points[band], reach)
    sizes = np.fromiter((len(x) for x in lists), dtype=np.int64, count=len(lists))
    point = np.repeat(band, sizes)
    segment = owner[np.fromiter((i for x in lists for i in x), dtype=np.int64, count=sizes.sum())]
    a, b = start[segment], end[segment]
    ab = b - a
    denom = np.einsum("ij,ij->i", ab, ab)
    t = np.clip(
        np.einsum("ij,ij->i", points[point] - a, ab) / np.where(denom > 0, denom, 1.0), 0, 1
    )
    gap = points[point] - (a + ab * t[:, None])
    close = np.einsum("ij,ij->i", gap, gap) <= radius * radius
    covered[point[close]] = True
    return covered


def layout_fidelity(
    vertex_positions: FloatArray,
    vertex_truth: FloatArray,
    edge_from: NDArray[np.int64],
    edge_to: NDArray[np.int64],
    true_path: FloatArray,
    radius: float = LAYOUT_RADIUS,
    *,
    alignment: RigidTransform2D | None = None,
) -> LayoutFidelity:
    """Completeness and correctness of a map's layout against the true path.

    Args:
        vertex_positions: ``(N, 2+)`` map positions of the live vertices.
        vertex_truth: ``(N, 2+)`` true positions of the same vertices at their creation times;
            the map is rigidly aligned to them first (as for the ATE).
        edge_from: ``(E,)`` index (into the vertex arrays) of each edge's first vertex.
        edge_to: ``(E,)`` index of each edge's second vertex.
        true_path: ``(M, 2+)`` the dense ground-truth path in time order (the bag's overhead
            poses), not the vertex poses.
        radius: the tolerance (m).
        alignment: the rigid alignment of ``vertex_positions`` onto ``vertex_truth`` when the
            caller has it already (:func:`align_rigid_2d` of the two); computed when ``None``.

    Both measures are length-weighted: the path and the edges are cut into pieces of at most
    ``radius / 8`` and each piece counts with its length, judged at its midpoint against the
    exact distance to the other side's segments.

    """
    if radius <= 0 or not math.isfinite(radius):
        raise ValueError(f"layout radius must be a positive number of metres, got {radius!r}")
    pos = np.asarray(vertex_positions, dtype=np.float64)[:, :2]
    truth = np.asarray(vertex_truth, dtype=np.float64)[:, :2]
    path = np.asarray(true_path, dtype=np.float64)[:, :2]
    e_from = np.asarray(edge_from, dtype=np.int64)
    e_to = np.asarray(edge_to, dtype=np.int64)
    n = pos.shape[0]
    epv = e_from.shape[0] / n if n else float("nan")
    if n == 0 or path.shape[0] < 2:
        return LayoutFidelity(float("nan"), float("nan"), radius, epv, 0.0, 0.0)
    if alignment is None:
        alignment = align_rigid_2d(pos, truth)
    aligned = alignment.apply(pos)
    spacing = radius / 8.0
    # the map's segments: every edge, plus every vertex as a point (covers an edge-less map)
    seg_a = np.concatenate([aligned[e_from], aligned])
    seg_b = np.concatenate([aligned[e_to], aligned])
    path_mid, path_len = _sample_polyline_pieces(path[:-1], path[1:], spacing)
    moving = path_len > 0
    path_mid, path_len = path_mid[moving], path_len[moving]
    total_path = float(path_len.sum())
    covered = _within_radius_of_segments(path_mid, seg_a, seg_b, radius)
    completeness = float(path_len[covered].sum() / total_path) if total_path > 0 else float("nan")
    edge_mid, edge_len = _sample_polyline_pieces(aligned[e_from], aligned[e_to], spacing)
    total_edges = float(edge_len.sum()) if e_from.size else 0.0
    if total_edges > 0:
        on_path = _within_radius_of_segments(edge_mid, path[:-1], path[1:], radius)
        correctness = float(edge_len[on_path].sum() / total_edges)
    else:
        correctness = float("nan")
    return LayoutFidelity(completeness, correctness, radius, epv, total_path, total_edges)


@dataclass(frozen=True, slots=True)
class MapAccuracy:
    """A map against ground truth, as every report of cogmap states it.

    Attributes:
        ate: RMSE (m) of the vertex positions after the best rigid alignment (None: no vertex).
        fidelity: completeness and correctness of the layout at the radius.
        alignment: that rigid alignment, taking map positions onto the truth (None: no vertex).

    """

    ate: float | None
    fidelity: LayoutFidelity
    alignment: RigidTransform2D | None


def map_accuracy(
    snapshot: MapSnapshot,
    vertex_truth: FloatArray,
    true_path: FloatArray,
    radius: float = LAYOUT_RADIUS,
) -> MapAccuracy:
    """ATE (:func:`absolute_trajectory_error`) and :func:`layout_fidelity` of one map.

    ``vertex_truth``: the true pose at each vertex's creation time (rows of ``snapshot``);
    ``true_path``: the dense true path. The figures of ``cogmap run``'s report, the page and
    sweeps; the rigid alignment is computed once and serves both, so the ATE and fidelity are
    the same numbers as those two functions give alone (as benchmarks call them).
    """
    poses = snapshot.poses
    edge_from, edge_to = snapshot.edge_ends()
    if len(poses) == 0:
        fidelity = layout_fidelity(poses, vertex_truth, edge_from, edge_to, true_path, radius)
        return MapAccuracy(None, fidelity, None)
    est = np.asarray(poses, dtype=np.float64)[:, :2]
    gt = np.asarray(vertex_truth, dtype=np.float64)[:, :2]
    alignment = align_rigid_2d(est, gt)
    fidelity = layout_fidelity(
        poses, vertex_truth, edge_from, edge_to, true_path, radius, alignment=alignment
    )
    return MapAccuracy(_aligned_rmse(alignment, est, gt), fidelity, alignment)


@dataclass(frozen=True, slots=True)
class SizeChange:
    """How a map's vertex count changed over a stretch of data, with exploration set apart.

    Attributes:
        start_vertices: live vertices at the start.
        end_vertices: live vertices at the end.
        exploration_vertices: vertices alive at the end that were made during the stretch while
            the robot explored: the true path within ``margin`` metres of travel around the
            vertex's creation reaches ground it had not passed (within the radius) before the
            start -- the new corridor itself, and the turns into and out of it.
        change: (end - start) / start.
        change_without_exploration: (end - exploration - start) / start: growth or shrinking
            on ground that was already known -- what a map that "does not grow unless the
            unknown environment is explored" keeps at zero.

    """

    start_vertices: int
    end_vertices: int
    exploration_vertices: int
    change: float
    change_without_exploration: float


def size_change(
    size_times: FloatArray,
    size_vertices: NDArray[np.int64],
    vertex_time: FloatArray,
    path_times: FloatArray,
    true_path: FloatArray,
    start: float,
    end: float,
    radius: float = LAYOUT_RADIUS,
    margin: float = 0.3,
) -> SizeChange:
    """Size change of a map between data times ``start`` and ``end`` (see :class:`SizeChange`).

    Args:
        size_times: the map's size history: times ...
        size_vertices: ... and live vertices after each.
        vertex_time: creation times of the vertices alive at ``end``.
        path_times: times of the dense ground-truth path ...
        true_path: ... and its ``(M, 2+)`` poses.
        start: start of the stretch (s).
        end: end of the stretch (s).
        radius: how close the path must have passed before ``start`` for ground to be known.
        margin: metres of travel around a vertex's creation that decide whether it was made
            while exploring (about a compact vertex spacing).

    """

    def size_at(t: float) -> int:
        k = int(np.searchsorted(size_times, t, side="right")) - 1
        return int(size_vertices[k]) if k >= 0 else 0

    v0, v1 = size_at(start), size_at(end)
    times = np.asarray(vertex_time, dtype=np.float64)
    made = (times > start) & (times <= end)
    path = np.asarray(true_path, dtype=np.float64)[:, :2]
    path_t = np.asarray(path_times, dtype=np.float64)
    before = path_t <= start
    explored = 0
    if made.any():
        during = ~before
        new_ground = np.zeros(path.shape[0], dtype=bool)
        if before.any():
            gap, _ = cKDTree(path[before]).query(path[during])
            new_ground[during] = gap > radius
        else:
            new_ground[during] = True
        travelled = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(path, axis=0).T))])
        new_count = np.concatenate([[0], np.cumsum(new_ground)])
        at = np.interp(times[made], path_t, travelled)
        lo = np.searchsorted(travelled, at - margin, side="left")
        hi = np.searchsorted(travelled, at + margin, side="right")
        explored = int(np.count_nonzero(new_count[hi] - new_count[lo] > 0))
    if v0 == 0:
        return SizeChange(v0, v1, explored, float("nan"), float("nan"))
    return SizeChange(v0, v1, explored, (v1 - v0) / v0, (v1 - explored - v0) / v0)


def loop_edge_links(
    link_time: FloatArray,
    link_target: NDArray[np.int64],
    snapshot: MapSnapshot,
    alias: NDArray[np.int64],
    refused: frozenset[tuple[float, int]] = frozenset(),
) -> NDArray[np.int64]:
    """Per edge of ``snapshot``, the index of the link (loop closure) that made it; -1 for none.

    A map makes a loop-closure edge from a link (time ``t``, target vertex ``g``) that it does not
    refuse (``refused``: the ``(time, target)`` of its refused relocalisations) and that does not
    duplicate a connection; the edge is stamped ``t`` and ends at ``g`` -- or, once ``g`` was
    merged into another vertex, at the vertex standing for it (``alias[g]``, the map's alias table,
    which the edge's end follows). So a live loop-closure edge (``t``, end ``v``) was made by the
    first link of time ``t`` whose target stands for ``v`` and which was not refused. Sequential
    edges get -1 (so would a loop-closure edge with no such link, which a map never holds).
    """
    out = np.full(snapshot.edge_from.shape[0], -1, dtype=np.int64)
    loops = np.flatnonzero(snapshot.edge_kind == 1)
    if loops.size == 0 or len(link_time) == 0:
        return out
    times = np.asarray(link_time, dtype=np.float64)
    targets = np.asarray(link_target, dtype=np.int64)
    table = np.asarray(alias, dtype=np.int64)
    known = (targets >= 0) & (targets < table.size)
    stands = np.full(targets.shape, -1, dtype=np.int64)
    stands[known] = table[targets[known]]
    first: dict[tuple[float, int], int] = {}
    for k, (t, g, v) in enumerate(
        zip(times.tolist(), targets.tolist(), stands.tolist(), strict=True)
    ):
        if v >= 0 and (t, g) not in refused:
            first.setdefault((t, v), k)
    for e in loops.tolist():
        out[e] = first.get((float(snapshot.edge_time[e]), int(snapshot.edge_to[e])), -1)
    return out


def false_loop_edges(
    edge_links: NDArray[np.int64], false_links: NDArray[np.bool_]
) -> NDArray[np.bool_]:
    """Per edge, whether it is a loop-closure edge made from a link judged false.

    ``edge_links``: :func:`loop_edge_links`; ``false_links``: per link, whether the ground truth
    calls it false (:meth:`~cogmap_core.event_log.EventLog.false_links`). The definition of "false
    loop closures in the map" of the page and of ``summary.json``.
    """
    made = edge_links >= 0
    out = np.zeros(edge_links.shape[0], dtype=bool)
    flags = np.asarray(false_links, dtype=bool)
    inside = made & (edge_links < flags.size)
    out[inside] = flags[edge_links[inside]]
    return out
