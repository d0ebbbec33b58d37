"""Seeded generator of odometry + place-recognition logs with ground truth (``cogmap make-log``).

Tests and benchmarks of the robust back end need many logs, so that no default is fitted to one
file. :func:`generate_log` makes one from a :class:`LogGeneratorConfig`, deterministically
(the same configuration gives bit-identical arrays):

1. **Route and driving** (:mod:`cogmap_core.datasets.log_routes`): one of the
   :data:`~cogmap_core.datasets.log_routes.PATTERNS`, driven at 0.3-1.5 m/s with smooth turns,
   turns on the spot where the route doubles back and short stops.
2. **Ground truth** at 5 Hz (times 0, 0.2, 0.4, ... s, as in the TUC dataset): position and
   continuous (unwrapped) heading.
3. **Wheel odometry** at 10 Hz (stamps jittered by a few tens of microseconds, the first one
   at 0 with zero velocities, as in TUC): the true velocities over each interval with a scale
   error on ``v``, a yaw-rate bias and white noise on both, all zero while the robot stands
   (wheel encoders do not tick). The error model's shape is drawn per seed; its size is then
   fitted so that the dead-reckoning ATE after rigid alignment meets the ``drift`` target
   (:data:`DRIFT_LEVELS`, drawn per seed within the level's range, or a number of metres).
   Each sample carries covariances (``cov_v``, ``cov_vy``, ``cov_omega``): the model's white
   noise plus its systematic error at that sample, to two significant digits. ``vy`` is
   ``v * sin(omega * dt)``, as in TUC's ``odom2`` lines.
4. **Loop candidates** (:mod:`cogmap_core.datasets.log_candidates`): a query at every keyframe
   (every ``keyframe_period`` s +-25 %, none while the robot stands still), with true,
   near-miss, false, structured false and recent candidates; false matches are exactly
   ``false_fraction`` of the usable candidates (score at or above ``score_threshold``, not
   recent), ``structured_fraction`` of them structured, ``near_fraction`` of the others near
   misses.

Every candidate is labelled: ``true_match`` (its two true positions within ``match_radius``,
computed from the ground truth as written, exactly as
:func:`~cogmap_core.sources.odometry_log.label_loop_candidates` computes it on the log read
back), ``structured`` and ``recent``. Writers: :mod:`cogmap_core.datasets.log_writer`.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np
from numpy.typing import NDArray

from cogmap_core.datasets.log_candidates import (
    CANDIDATE_KINDS,
    NEAR,
    RECENT,
    STRUCTURED,
    CandidateSettings,
    Keyframes,
    make_candidates,
)
from cogmap_core.datasets.log_routes import PATTERN_SPEED, PATTERNS, build_route, drive
from cogmap_core.errors import ParameterError
from cogmap_core.evaluation import (
    absolute_trajectory_error,
    dead_reckoning,
    interpolate_poses,
    loop_candidate_distances,
)

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

ODOMETRY_PERIOD = 0.1
"""Seconds between odometry samples (10 Hz)."""
TRUTH_PERIOD = 0.2
"""Seconds between ground-truth poses (5 Hz)."""

DRIFT_LEVELS: dict[str, tuple[float, float]] = {
    "low": (2.0, 4.0),
    "medium": (6.0, 14.0),
    "high": (15.0, 30.0),
    "extreme": (35.0, 60.0),
}
"""Dead-reckoning ATE (m) ranges of the drift levels; a seed draws its target log-uniformly."""

#: The odometry error model at size 1 (multiplied by a per-seed shape and a fitted size).
_UNIT_SCALE, _UNIT_BIAS, _UNIT_SIGMA_V, _UNIT_SIGMA_W = 0.01, 0.001, 0.01, 0.003
#: Largest errors the fit may use: scale, yaw-rate bias (rad/s), sigma_v (m/s), sigma_w (rad/s).
_MAX_SCALE, _MAX_BIAS, _MAX_SIGMA_V, _MAX_SIGMA_W = 0.25, 0.05, 0.15, 0.05


@dataclass(frozen=True)
class LogGeneratorConfig:
    """What log to generate (validated on construction).

    Attributes:
        pattern: driving pattern, one of :data:`~cogmap_core.datasets.log_routes.PATTERNS`.
        seed: random seed; the same configuration gives the same log, bit for bit.
        duration: seconds of data (60 s to 4 h).
        speed: mean cruise speed (m/s, 0.3-1.5); None: the pattern's (0.6 indoors to 1.2 on
            a campus).
        drift: a level of :data:`DRIFT_LEVELS` or the dead-reckoning ATE to aim at (m, > 0).
        false_fraction: share of false matches among the usable candidates (0-0.9).
        structured_fraction: share of structured matches among those false ones (0-1).
        near_fraction: share of near misses (1.2 ``match_radius`` to 4 m off) among the
            other false ones (0-1; the rest are far).
        score_threshold: the score from which a candidate counts as usable (a log reader's
            ``score_threshold``).
        keyframe_period: mean seconds between place-recognition queries (1-10).
        match_radius: true matches are up to this far from the query's true position (m).
        view_angle: largest difference in viewing direction of a true match (degrees).
        detection_probability: chance that a true match is found.
        opposite_probability: chance that a place seen from the opposite direction is
            recognised (a true match too).
        false_per_query: mean number of low-scoring false candidates per query.
        recent_probability: chance that a query also matches the keyframe just before it.
        min_separation: driving (m) between a query and a match, recent ones aside; keep it
            above the reader's ``min_loop_travel`` (5 m) plus the odometry's scale error.
        trailing_loops: when positive, the last query lies up to this many seconds (at most
            0.5) after the last odometry sample, as some real logs have it.

    """

    pattern: str = "loop"
    seed: int = 1
    duration: float = 1200.0
    speed: float | None = None
    drift: str | float = "medium"
    false_fraction: float = 0.1
    structured_fraction: float = 0.3
    near_fraction: float = 0.6
    score_threshold: float = 0.8
    keyframe_period: float = 2.5
    match_radius: float = 1.0
    view_angle: float = 30.0
    detection_probability: float = 0.8
    opposite_probability: float = 0.1
    false_per_query: float = 4.0
    recent_probability: float = 0.3
    min_separation: float = 10.0
    trailing_loops: float = 0.0

    def __post_init__(self) -> None:
        """Reject unknown names and values outside their ranges (one line each)."""
        if self.pattern not in PATTERNS:
            raise ParameterError(
                f"unknown pattern {self.pattern!r}; choose from {', '.join(PATTERNS)}"
            )
        if isinstance(self.drift, str):
            if self.drift not in DRIFT_LEVELS:
                raise ParameterError(
                    f"drift {self.drift!r} is neither a level ({', '.join(DRIFT_LEVELS)}) nor "
                    "a dead-reckoning ATE in metres"
                )
        elif not (math.isfinite(self.drift) and 0 < self.drift <= 500):
            raise ParameterError(f"drift {self.drift!r} m is out of range; use 0-500 m")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ParameterError(f"seed {self.seed!r} must be a whole number >= 0")
        checks = (
            ("duration", self.duration, 60.0, 14400.0, "s"),
            ("speed", self.speed, 0.3, 1.5, "m/s"),
            ("false_fraction", self.false_fraction, 0.0, 0.9, ""),
            ("structured_fraction", self.structured_fraction, 0.0, 1.0, ""),
            ("near_fraction", self.near_fraction, 0.0, 1.0, ""),
            ("score_threshold", self.score_threshold, 0.05, 0.99, ""),
            ("keyframe_period", self.keyframe_period, 1.0, 10.0, "s"),
            ("match_radius", self.match_radius, 0.1, 3.0, "m"),
            ("view_angle", self.view_angle, 1.0, 90.0, "deg"),
            ("detection_probability", self.detection_probability, 0.0, 1.0, ""),
            ("opposite_probability", self.opposite_probability, 0.0, 1.0, ""),
            ("false_per_query", self.false_per_query, 0.0, 50.0, ""),
            ("recent_probability", self.recent_probability, 0.0, 1.0, ""),
            ("min_separation", self.min_separation, 5.0, 1000.0, "m"),
            ("trailing_loops", self.trailing_loops, 0.0, 0.5, "s"),
        )
        for name, value, low, high, unit in checks:
            if value is None and name == "speed":
                continue
            if not (isinstance(value, int | float) and math.isfinite(value)):
                raise ParameterError(f"{name} {value!r} is not a number")
            if not low <= value <= high:
                raise ParameterError(
                    f"{name} {value:g}{' ' + unit if unit else ''} is out of range; "
                    f"use {low:g}-{high:g}{' ' + unit if unit else ''}"
                )
        if self.false_fraction > 0 and self.detection_probability == 0:
            raise ParameterError(
                "false_fraction needs true matches to be a share of; detection_probability is 0"
            )

    @property
    def cruise_speed(self) -> float:
        """The mean cruise speed (m/s): ``speed`` or the pattern's."""
        return PATTERN_SPEED[self.pattern] if self.speed is None else float(self.speed)

    def to_dict(self) -> dict[str, object]:
        """All settings (for a summary)."""
        return asdict(self)


@dataclass(frozen=True)
class OdometryErrors:
    """The wheel-odometry error model of one log.

    Attributes:
        scale: scale error of ``v`` (measured = true * (1 + scale)).
        bias: yaw-rate bias added while moving (rad/s).
        sigma_v: white noise on ``v`` (m/s).
        sigma_w: white noise on ``omega`` (rad/s).
        target_ate: the dead-reckoning ATE aimed at (m).

    """

    scale: float
    bias: float
    sigma_v: float
    sigma_w: float
    target_ate: float


@dataclass(frozen=True)
class GeneratedLog:
    """A generated log and what is true about it.

    Attributes:
        config: how it was made.
        odometry: ``(N, 3)`` time, v (m/s), omega (rad/s), as a log reader returns it.
        lateral: ``(N,)`` lateral velocity vy (m/s) of the TUC ``odom2`` lines.
        covariance: ``(N, 3)`` variances of v, vy and omega per sample.
        loops: ``(M, 3)`` time, matched time, score; sorted by time, then matched time.
        ground_truth: ``(G, 4)`` time, x, y, heading (continuous, not wrapped) at 5 Hz.
        true_match: ``(M,)`` whether each candidate's two true positions are within
            ``config.match_radius``.
        structured: ``(M,)`` whether it is a structured false match.
        recent: ``(M,)`` whether it matches a keyframe under 3 m of driving earlier.
        kind: ``(M,)`` index into :data:`CANDIDATE_KINDS`.
        keyframe_times: times of the place-recognition queries.
        errors: the odometry error model.
        dead_reckoning_ate: ATE (m) of the odometry alone after rigid alignment, at every
            odometry sample (as ``cogmap run`` reports it, to within the loop-query frames).
        path_length: true distance driven (m).

    """

    config: LogGeneratorConfig
    odometry: FloatArray
    lateral: FloatArray
    covariance: FloatArray
    loops: FloatArray
    ground_truth: FloatArray
    true_match: BoolArray
    structured: BoolArray
    recent: BoolArray
    kind: NDArray[np.int64]
    keyframe_times: FloatArray
    errors: OdometryErrors
    dead_reckoning_ate: float
    path_length: float
    kinds: tuple[str, ...] = field(default=CANDIDATE_KINDS)

    @property
    def duration(self) -> float:
        """Seconds from the first to the last odometry sample."""
        return float(self.odometry[-1, 0] - self.odometry[0, 0])

    @property
    def usable(self) -> BoolArray:
        """Candidates a reader may link: score at or above the threshold, not recent."""
        return (self.loops[:, 2] >= self.config.score_threshold) & ~self.recent

    def counts(self) -> dict[str, int]:
        """Candidate counts: all, queries, usable, usable true / false / structured / near."""
        usable = self.usable
        return {
            "candidates": int(self.loops.shape[0]),
            "queries": int(np.unique(self.loops[:, 0]).size),
            "usable": int(usable.sum()),
            "true": int((usable & self.true_match).sum()),
            "false": int((usable & ~self.true_match).sum()),
            "structured": int((usable & self.structured).sum()),
            "near": int((usable & (self.kind == NEAR)).sum()),
        }


def _dead_reckoning_ate(odometry: FloatArray, truth_xy: FloatArray) -> float:
    """ATE of the odometry integrated alone against the true positions at its stamps."""
    dt = np.diff(odometry[:, 0], prepend=odometry[0, 0])
    poses = dead_reckoning(odometry[:, 1] * dt, odometry[:, 2] * dt)
    return absolute_trajectory_error(poses, truth_xy)


def _odometry(
    times: FloatArray, true_v: FloatArray, true_w: FloatArray, noise: FloatArray, e: OdometryErrors
) -> FloatArray:
    """Measured ``(N, 3)`` odometry from the true velocities (zero while standing)."""
    moving = (true_v != 0) | (true_w != 0)
    v = np.where(moving, true_v * (1.0 + e.scale) + e.sigma_v * noise[:, 0], 0.0)
    w = np.where(moving, true_w + e.bias + e.sigma_w * noise[:, 1], 0.0)
    v[0] = w[0] = 0.0
    return np.column_stack([times, v, w])


def _fit_errors(
    times: FloatArray,
    true_v: FloatArray,
    true_w: FloatArray,
    truth_xy: FloatArray,
    target: float,
    rng: np.random.Generator,
) -> tuple[OdometryErrors, FloatArray, float]:
    """The error model meeting the dead-reckoning ATE ``target``, its odometry and its ATE.

    The shape (signs and relative sizes of the four errors) is drawn per seed; one common size
    factor is then found by a scan and bisection. A target beyond the largest errors allowed
    gets the largest ATE they reach.
    """
    shape = np.array(
        [
            rng.choice([-1.0, 1.0]) * rng.uniform(0.3, 1.0) * _UNIT_SCALE,
            rng.choice([-1.0, 1.0]) * rng.uniform(0.5, 1.0) * _UNIT_BIAS,
            rng.uniform(0.6, 1.4) * _UNIT_SIGMA_V,
            rng.uniform(0.6, 1.4) * _UNIT_SIGMA_W,
        ]
    )
    noise = rng.standard_normal((times.size, 2))
    caps = np.array([_MAX_SCALE, _MAX_BIAS, _MAX_SIGMA_V, _MAX_SIGMA_W])
    k_max = float(np.min(caps / np.abs(shape)))

    def model(k: float) -> OdometryErrors:
        scale, bias, sigma_v, sigma_w = (float(x) for x in k * shape)
        return OdometryErrors(scale, bias, sigma_v, sigma_w, target)

    def ate(k: float) -> float:
        return _dead_reckoning_ate(_odometry(times, true_v, true_w, noise, model(k)), truth_xy)

    grid = np.geomspace(k_max * 1e-4, k_max, 48)
    values = [ate(float(k)) for k in grid]
    above = [n for n, a in enumerate(values) if a >= target]
    if not above:
        best = float(grid[int(np.argmax(values))])
    elif above[0] == 0:
        best = float(grid[0])
    else:
        lo, hi = float(grid[above[0] - 1]), float(grid[above[0]])
        for _ in range(40):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if ate(mid) < target else (lo, mid)
        best = hi
    errors = model(best)
    odometry = _odometry(times, true_v, true_w, noise, errors)
    return errors, odometry, _dead_reckoning_ate(odometry, truth_xy)


def _keyframe_times(
    cfg: LogGeneratorConfig,
    end: float,
    sim_t: FloatArray,
    distance: FloatArray,
    heading: FloatArray,
    rng: np.random.Generator,
) -> FloatArray:
    """Query times: every ``keyframe_period`` +-25 %, skipped while the robot stands still."""
    times: list[float] = []
    last_d = last_h = -1e9
    t = float(rng.uniform(1.0, 1.0 + cfg.keyframe_period))
    while t <= end:
        d = float(np.interp(t, sim_t, distance))
        h = float(np.interp(t, sim_t, heading))
        if d - last_d >= 0.3 or abs(h - last_h) >= 0.3:
            times.append(t)
            last_d, last_h = d, h
        t += cfg.keyframe_period * float(rng.uniform(0.75, 1.25))
    return np.asarray(times)


def generate_log(config: LogGeneratorConfig) -> GeneratedLog:
    """Generate the log ``config`` describes (see the module docstring).

    Raises:
        ParameterError: the run cannot hold what is asked (too short for the structured false
            matches, for instance).

    """
    cfg = config
    streams = np.random.default_rng(cfg.seed).spawn(6)
    rng_route, rng_drive, rng_stamps, rng_drift, rng_keys, rng_loops = streams
    speed = cfg.cruise_speed
    sim_end = cfg.duration + 2.0
    route = build_route(cfg.pattern, rng_route, 1.5 * sim_end + 200.0, 0.9 * speed * cfg.duration)
    path = drive(route, sim_end, speed, rng_drive)

    # odometry stamps at 10 Hz, jittered a little as real ones are (the first at 0)
    n_odo = int(math.floor(cfg.duration / ODOMETRY_PERIOD + 1e-9)) + 1
    jitter = rng_stamps.normal(0.0, 2e-5, n_odo).clip(-5e-5, 5e-5)
    stamps = np.arange(n_odo) * ODOMETRY_PERIOD + jitter
    stamps[0] = 0.0
    end = float(stamps[-1])
    # ground truth at 5 Hz from 0 s, covering the odometry and any trailing query
    n_truth = int(math.ceil((end + cfg.trailing_loops) / TRUTH_PERIOD - 1e-9)) + 1
    gt_t = np.round(np.arange(n_truth) * TRUTH_PERIOD, 9)
    gt = np.column_stack(
        [
            gt_t,
            np.interp(gt_t, path.times, path.xy[:, 0]),
            np.interp(gt_t, path.times, path.xy[:, 1]),
            np.interp(gt_t, path.times, path.heading),
        ]
    )
    # the true velocities over each odometry interval, then the error model
    s = np.interp(stamps, path.times, path.distance)
    h = np.interp(stamps, path.times, path.heading)
    dt = np.diff(stamps, prepend=-1.0)  # (the first sample has no interval: v = omega = 0)
    true_v = np.diff(s, prepend=s[0]) / dt
    true_w = np.diff(h, prepend=h[0]) / dt
    true_v[np.abs(true_v) < 1e-9] = 0.0
    true_w[np.abs(true_w) < 1e-9] = 0.0
    truth_xy = interpolate_poses(gt[:, 0], gt[:, 1:4], stamps)[:, :2]
    if isinstance(cfg.drift, str):
        low, high = DRIFT_LEVELS[cfg.drift]
        target = float(np.exp(rng_drift.uniform(np.log(low), np.log(high))))
    else:
        target = float(cfg.drift)
    errors, odometry, ate = _fit_errors(stamps, true_v, true_w, truth_xy, target, rng_drift)
    dt_odo = np.diff(stamps, prepend=stamps[0])
    lateral = odometry[:, 1] * np.sin(odometry[:, 2] * dt_odo)
    cov_v = errors.sigma_v**2 + (errors.scale * odometry[:, 1]) ** 2
    cov_w = np.full(n_odo, errors.sigma_w**2 + errors.bias**2)
    covariance = _two_digits(np.column_stack([cov_v, np.full(n_odo, errors.sigma_v**2), cov_w]))

    # keyframes and their loop candidates
    key_t = _keyframe_times(cfg, end, path.times, path.distance, path.heading, rng_keys)
    if cfg.trailing_loops > 0:
        extra = end + cfg.trailing_loops * float(rng_keys.uniform(0.25, 1.0))
        key_t = np.append(key_t, extra)
    keyframes = Keyframes(
        key_t,
        interpolate_poses(gt[:, 0], gt[:, 1:4], key_t),
        np.interp(key_t, path.times, path.distance),
    )
    settings = CandidateSettings(
        match_radius=cfg.match_radius,
        view_angle=math.radians(cfg.view_angle),
        detection_probability=cfg.detection_probability,
        opposite_probability=cfg.opposite_probability,
        false_fraction=cfg.false_fraction,
        structured_fraction=cfg.structured_fraction,
        near_fraction=cfg.near_fraction,
        score_threshold=cfg.score_threshold,
        false_per_query=cfg.false_per_query,
        recent_probability=cfg.recent_probability,
        min_separation=cfg.min_separation,
    )
    loops, kind = make_candidates(
        keyframes, route.aliases, settings, rng_loops, ensure_last=cfg.trailing_loops > 0
    )
    distance = loop_candidate_distances(loops, gt[:, 0], gt[:, 1:3])
    return GeneratedLog(
        config=cfg,
        odometry=odometry,
        lateral=lateral,
        covariance=covariance,
        loops=loops,
        ground_truth=gt,
        true_match=distance <= cfg.match_radius,
        structured=kind == STRUCTURED,
        recent=kind == RECENT,
        kind=kind,
        keyframe_times=key_t,
        errors=errors,
        dead_reckoning_ate=ate,
        path_length=float(np.interp(end, path.times, path.distance)),
    )


def _two_digits(values: FloatArray) -> FloatArray:
    """Values rounded to two significant digits (as TUC writes its covariances: 0.0025)."""
    flat = [float(f"{x:.2g}") for x in values.ravel().tolist()]
    return np.asarray(flat, dtype=np.float64).reshape(values.shape)
