"""Accuracy measures against ground truth: rigid 2D alignment, ATE, loop-closure precision."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

TRUE_LOOP_CLOSURE_DISTANCE = 0.1
"""A loop closure is true when the ground-truth positions of its two ends are this close (m)."""


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
    aligned = align_rigid_2d(est, gt).apply(est)
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


@dataclass(frozen=True, slots=True)
class LoopClosureScore:
    """Loop closures judged by ground truth."""

    total: int
    true: int
    false: int

    @property
    def precision(self) -> float | None:
        """True / total, or None without loop closures."""
        return self.true / self.total if self.total else None


def score_loop_closures(
    robot_positions: FloatArray,
    target_positions: FloatArray,
    distance: float = TRUE_LOOP_CLOSURE_DISTANCE,
) -> LoopClosureScore:
    """Count loop closures whose two ends (true positions) are within ``distance``."""
    a = np.asarray(robot_positions, dtype=np.float64)[:, :2]
    b = np.asarray(target_positions, dtype=np.float64)[:, :2]
    good = int(np.count_nonzero(np.hypot(*(a - b).T) <= distance)) if a.size else 0
    return LoopClosureScore(total=int(a.shape[0]), true=good, false=int(a.shape[0]) - good)
