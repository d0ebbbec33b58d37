"""Ground-truth measures: alignment, ATE, interpolation, loop-closure precision."""

from __future__ import annotations

import numpy as np
import pytest

from cogmap_core.evaluation import (
    absolute_trajectory_error,
    align_rigid_2d,
    interpolate_poses,
    score_loop_closures,
)


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
