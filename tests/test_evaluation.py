"""Ground-truth measures: alignment, ATE, interpolation, loop-closure precision."""

from __future__ import annotations

import numpy as np
import pytest

from cogmap_core.evaluation import (
    RigidTransform2D,
    absolute_trajectory_error,
    align_rigid_2d,
    dead_reckoning,
    interpolate_poses,
    layout_fidelity,
    map_accuracy,
    score_loop_closures,
    size_change,
)
from cogmap_core.map_graph import MapSnapshot


def test_alignment_recovers_a_rigid_motion_exactly():
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(30, 2))
    theta, t = 0.7, np.array([1.5, -2.0])
    c, s = np.cos(theta), np.sin(theta)
    moved = pts @ np.array([[c, s], [-s, c]]) + t
    tf = align_rigid_2d(pts, moved)
    assert tf.theta == pytest.approx(theta)
    assert (tf.tx, tf.ty) == (pytest.approx(1.5), pytest.approx(-2.0))
    assert absolute_trajectory_error(pts, moved) == pytest.approx(0.0, abs=1e-12)


def test_inverse_and_then_undo_and_chain_transforms():
    # a quarter turn then (1, 2): (1, 0) -> (1, 3); the inverse takes it back exactly
    quarter = RigidTransform2D(np.pi / 2, 1.0, 2.0)
    np.testing.assert_allclose(quarter.apply(np.array([[1.0, 0.0]])), [[1.0, 3.0]], atol=1e-15)
    back = quarter.inverse()
    assert back.theta == -np.pi / 2
    assert (back.tx, back.ty) == (pytest.approx(-2.0), pytest.approx(1.0))
    np.testing.assert_allclose(back.apply(np.array([[1.0, 3.0]])), [[1.0, 0.0]], atol=1e-15)
    rng = np.random.default_rng(3)
    pts = rng.normal(size=(50, 2)) * 10
    for theta, tx, ty in rng.normal(size=(20, 3)) * [3.0, 5.0, 5.0]:
        tf = RigidTransform2D(float(theta), float(tx), float(ty))
        np.testing.assert_allclose(tf.inverse().apply(tf.apply(pts)), pts, atol=1e-12)
        np.testing.assert_allclose(tf.apply(tf.inverse().apply(pts)), pts, atol=1e-12)
        other = RigidTransform2D(0.4, -1.0, 0.5)
        np.testing.assert_allclose(
            tf.then(other).apply(pts), other.apply(tf.apply(pts)), atol=1e-12
        )
    # an alignment found by align_rigid_2d, inverted, takes the truth into the map's frame
    theta, t = 0.7, np.array([1.5, -2.0])
    c, s = np.cos(theta), np.sin(theta)
    moved = pts @ np.array([[c, s], [-s, c]]) + t
    np.testing.assert_allclose(align_rigid_2d(pts, moved).inverse().apply(moved), pts, atol=1e-9)


def test_ate_is_rmse_after_alignment():
    est = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [3.0, 0.0]])
    gt = est.copy()
    gt[:, 1] = [0.1, -0.1, -0.1, 0.1]  # zero mean, uncorrelated with x: cannot be aligned away
    assert absolute_trajectory_error(est, gt) == pytest.approx(0.1, rel=1e-9)


def test_interpolation_handles_heading_wrap():
    times = np.array([0.0, 1.0])
    poses = np.array([[0.0, 0.0, 3.0], [1.0, 2.0, -3.0]])  # crosses +-pi
    mid = interpolate_poses(times, poses, np.array([0.5, 2.0]))
    assert mid[0, :2].tolist() == [0.5, 1.0]
    assert abs(abs(mid[0, 2]) - np.pi) < 0.15
    assert mid[1].tolist() == pytest.approx([1.0, 2.0, -3.0])  # clamped at the end


def test_loop_closure_precision():
    robot = np.array([[0, 0], [1, 1], [2, 2]], dtype=float)
    target = np.array([[0.05, 0], [1, 1.2], [2, 2.09]], dtype=float)
    score = score_loop_closures(robot, target)
    assert (score.total, score.true, score.false) == (3, 2, 1)
    assert score.precision == pytest.approx(2 / 3)
    assert score_loop_closures(np.zeros((0, 2)), np.zeros((0, 2))).precision is None


def test_loop_closures_are_judged_by_heading_too():
    robot = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 1.0]])
    target = np.array([[0.02, 0.0, 0.0], [1.0, 0.05, 0.5], [2.0, 0.0, 0.0]])
    relative = np.array([0.0, 0.0, 1.0])  # the second link misses the robot's heading by 0.5
    score = score_loop_closures(robot, target, relative)
    assert (score.total, score.true, score.false) == (3, 2, 1)
    assert score.false_indices == (1,)
    np.testing.assert_allclose(score.heading_error, [0.0, 0.5, 0.0], atol=1e-12)
    np.testing.assert_allclose(score.position_error, [0.02, 0.05, 0.0], atol=1e-12)
    assert score_loop_closures(robot, target, relative, heading=0.6).false == 0
    with pytest.raises(ValueError, match="heading"):
        score_loop_closures(robot[:, :2], target[:, :2], relative)


def test_dead_reckoning_turns_then_drives():
    poses = dead_reckoning(np.array([1.0, 1.0, 1.0, 0.0]), np.array([0, 0, 0, 0.0]))
    np.testing.assert_allclose(poses[:, :2], [[1, 0], [2, 0], [3, 0], [3, 0]], atol=1e-12)
    square = dead_reckoning(np.ones(4), np.array([0, 1, 1, 1]) * np.pi / 2)
    np.testing.assert_allclose(square[:, :2], [[1, 0], [1, 1], [0, 1], [0, 0]], atol=1e-12)


def straight_path(length: float) -> np.ndarray:
    return np.c_[np.linspace(0.0, length, 201), np.zeros(201)]


def test_layout_fidelity_both_ways_with_exact_lengths():
    vertices = np.array([[0.0, 0.0], [0.5, 0.0], [1.0, 0.0], [0.5, 0.5]])
    on_path = layout_fidelity(vertices[:3], vertices[:3], [0, 1], [1, 2], straight_path(1.0))
    assert (on_path.completeness, on_path.correctness) == (1.0, 1.0)
    assert on_path.edges_per_vertex == pytest.approx(2 / 3)
    assert on_path.edge_length == pytest.approx(1.0) and on_path.path_length == pytest.approx(1.0)
    # a spur across a wall: only its first 8 cm lie within 8 cm of the path
    spur = layout_fidelity(vertices, vertices, [0, 1, 1], [1, 2, 3], straight_path(1.0))
    assert spur.completeness == 1.0
    assert spur.correctness == pytest.approx(1.08 / 1.5, abs=1e-9)
    # the true path goes on for another metre the map does not have
    half = layout_fidelity(vertices[:3], vertices[:3], [0, 1], [1, 2], straight_path(2.0))
    assert half.completeness == pytest.approx(1.08 / 2.0, abs=1e-9)
    assert half.correctness == 1.0
    tighter = layout_fidelity(vertices, vertices, [0, 1, 1], [1, 2, 3], straight_path(1.0), 0.02)
    assert tighter.correctness == pytest.approx(1.02 / 1.5, abs=1e-9)


def test_layout_fidelity_aligns_the_map_first():
    vertices = np.array([[0.0, 0.0], [0.5, 0.0], [1.0, 0.0]])
    theta = 0.7
    c, s = np.cos(theta), np.sin(theta)
    moved = vertices @ np.array([[c, s], [-s, c]]) + [3.0, -1.0]  # the map's own frame
    result = layout_fidelity(moved, vertices, [0, 1], [1, 2], straight_path(1.0))
    assert result.completeness == pytest.approx(1.0) and result.correctness == pytest.approx(1.0)
    with pytest.raises(ValueError, match="radius"):
        layout_fidelity(moved, vertices, [0, 1], [1, 2], straight_path(1.0), radius=0.0)


def _snapshot(poses: np.ndarray, edge_from: list[int], edge_to: list[int]) -> MapSnapshot:
    n, e = poses.shape[0], len(edge_from)
    return MapSnapshot(
        vertex_ids=np.arange(n, dtype=np.int64),
        poses=poses,
        vertex_time=np.arange(n, dtype=np.float64),
        vertex_view=np.zeros(n, dtype=np.int64),
        edge_from=np.asarray(edge_from, dtype=np.int64),
        edge_to=np.asarray(edge_to, dtype=np.int64),
        edge_rel=np.zeros((e, 3)),
        edge_time=np.zeros(e),
        edge_kind=np.zeros(e, dtype=np.int8),
        edge_cluster=np.zeros(e, dtype=np.int64),
        current_vertex=0,
        current_pose=np.zeros(3),
    )


def test_map_accuracy_gives_the_figures_of_the_functions_alone():
    rng = np.random.default_rng(3)
    truth = np.column_stack([np.linspace(0.0, 2.0, 9), np.zeros(9), np.zeros(9)])
    c, s = np.cos(0.4), np.sin(0.4)
    poses = truth.copy()
    poses[:, :2] = truth[:, :2] @ np.array([[c, s], [-s, c]]) + [1.0, 2.0]
    poses[:, :2] += rng.normal(scale=0.02, size=(9, 2))
    edges = (list(range(8)), list(range(1, 9)))
    path = straight_path(2.0)
    accuracy = map_accuracy(_snapshot(poses, *edges), truth, path, 0.03)
    assert accuracy.ate == absolute_trajectory_error(poses, truth)
    assert accuracy.fidelity == layout_fidelity(poses, truth, *edges, path, 0.03)
    assert accuracy.alignment == align_rigid_2d(poses, truth)
    given = layout_fidelity(poses, truth, *edges, path, 0.03, alignment=accuracy.alignment)
    assert given == accuracy.fidelity
    empty = map_accuracy(_snapshot(np.zeros((0, 3)), [], []), np.zeros((0, 3)), path)
    assert empty.ate is None and empty.alignment is None


def test_size_change_sets_exploration_apart():
    # the robot maps x = 0 -> 1 (t 0-10), drives back to x = 0 (t 10-20), then explores
    # y = 0 -> 1 (t 20-30); the map has 10 vertices at t = 10 and 13 at t = 30
    path_times = np.linspace(0.0, 30.0, 301)
    x = np.interp(path_times, [0, 10, 20, 30], [0.0, 1.0, 0.0, 0.0])
    y = np.interp(path_times, [0, 10, 20, 30], [0.0, 0.0, 0.0, 1.0])
    path = np.c_[x, y]
    size_times = np.array([0.0, 5.0, 14.0, 19.5, 25.0])
    size_vertices = np.array([1, 10, 11, 12, 13])
    # alive at the end: one old vertex and three new: on known ground (x = 0.6), 5 cm before
    # the new corridor (the turn into it) and in it
    vertex_time = np.array([0.0, 14.0, 19.5, 25.0])
    change = size_change(size_times, size_vertices, vertex_time, path_times, path, 10.0, 30.0)
    assert (change.start_vertices, change.end_vertices, change.exploration_vertices) == (10, 13, 2)
    assert change.change == pytest.approx(0.3)
    assert change.change_without_exploration == pytest.approx(0.1)
    strict = size_change(
        size_times, size_vertices, vertex_time, path_times, path, 10.0, 30.0, margin=0.0
    )
    assert strict.exploration_vertices == 1  # without the margin the turn counts as known


def test_radius_test_agrees_with_brute_force():
    from cogmap_core.evaluation import _within_radius_of_segments

    rng = np.random.default_rng(1)
    for _ in range(50):
        a = rng.uniform(0, 1, (30, 2))
        b = a + rng.normal(0, 0.2, (30, 2))
        points = rng.uniform(-0.2, 1.2, (400, 2))
        radius = rng.uniform(0.01, 0.15)
        ab = b - a
        nearest = np.full(len(points), np.inf)
        for k in range(len(a)):
            t = np.clip((points - a[k]) @ ab[k] / (ab[k] @ ab[k]), 0, 1)
            nearest = np.minimum(nearest, np.hypot(*(points - a[k] - t[:, None] * ab[k]).T))
        np.testing.assert_array_equal(
            _within_radius_of_segments(points, a, b, radius), nearest <= radius
        )
