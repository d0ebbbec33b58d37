"""A log's steps: the events made from an :class:`~cogmap_core.sources.odometry_log.OdometryLog`.

:func:`log_steps` turns a log into the map's events, step by step, by the rules described in
:mod:`cogmap_core.sources.odometry_log` (vertices from movement, loop candidates as links, no
relocalisation, ground truth interpolated); :class:`LogStats` says what became of the log's loop
candidates and odometry; :class:`LogReader` serves the steps the way a bag reader serves frames.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from cogmap_core.config import MapParams
from cogmap_core.errors import ParameterError
from cogmap_core.evaluation import (
    EvaluationSettings,
    interpolate_poses,
)
from cogmap_core.events import CreateVertex, LinkToVertex, MapEvent, Odometry, SetCurrentVertex
from cogmap_core.frames import EventStep
from cogmap_core.input_reader import InputReader
from cogmap_core.odometry_scale import OdometryScale, estimate_odometry_scale
from cogmap_core.sources.log_text import Rows
from cogmap_core.sources.odometry_log import (
    LOG_EVALUATION,
    LOG_MAP_PARAMS,
    LOOP_COLUMNS,
    BoolArray,
    FloatArray,
    LogSourceConfig,
    OdometryLog,
    count_note,
)


# ---------------------------------------------------------------------------------- events
@dataclass
class LogStats:
    """What became of a log's loop candidates and odometry (for the report).

    Attributes:
        frames: steps produced.
        loop_candidates: candidates in the log (after the reader's drops, see
            :attr:`OdometryLog.read_counts`).
        loops_clamped: candidates with a time up to ``max_odometry_gap`` outside the odometry,
            moved onto its first or last stamp.
        loops_outside: candidates with a time further outside the odometry, ignored.
        below_threshold: ignored for a score below the threshold.
        too_close: ignored for less than ``min_loop_travel`` of odometry between the two times.
        duplicates: candidates of one query that landed on a vertex another candidate of it
            already linked, or on the vertex the robot is at.
        links: links emitted.
        odometry_gaps: odometry intervals longer than ``max_odometry_gap`` (no motion).
        warnings: one line per kind of loop candidate or odometry interval not used as it was.
        used_loops: ``(K, 2)`` time and matched time (counted from the log's start) of the
            candidates kept by the score and travel thresholds, before the duplicates.

    """

    frames: int = 0
    loop_candidates: int = 0
    loops_clamped: int = 0
    loops_outside: int = 0
    below_threshold: int = 0
    too_close: int = 0
    duplicates: int = 0
    links: int = 0
    odometry_gaps: int = 0
    warnings: list[str] = field(default_factory=list)
    used_loops: FloatArray = field(default_factory=lambda: np.zeros((0, 2)), compare=False)


def loops_in_span(log: OdometryLog, tolerance: float) -> tuple[FloatArray, BoolArray, BoolArray]:
    """The loop candidates the odometry's time span can place (module doc, *Loop candidates*).

    A time up to ``tolerance`` seconds before the first or after the last odometry stamp is
    moved onto that stamp (the robot's pose there is known to the odometry's own tolerance for
    gaps); a candidate with a time further out is dropped.

    Returns:
        The kept candidates (file times, moved ones moved), and per candidate of ``log.loops``
        whether it was moved and whether it was dropped.

    """
    times = log.loops[:, :2]
    t_first, t_last = log.start, float(log.odometry[-1, 0])
    outside = ((times < t_first - tolerance) | (times > t_last + tolerance)).any(axis=1)
    inside = np.clip(times, t_first, t_last)
    moved = (inside != times).any(axis=1) & ~outside
    kept = log.loops[~outside]
    if moved.any():
        kept[:, :2] = inside[~outside]
    return kept, moved, outside


def log_steps(
    log: OdometryLog, config: LogSourceConfig | None = None
) -> tuple[list[EventStep], LogStats]:
    """The log as steps of map events (module doc), with what became of its loops.

    Steps are at every odometry stamp and at the time of every loop query with a candidate at
    or above the score threshold; each holds the odometry since the previous step, a proposed
    vertex when the robot moved far enough, and the query's links. A candidate below the
    threshold changes nothing, not even where the odometry is sampled (the vertices would move
    by a step, and the maps with them). Deterministic: the same log and settings give the same
    steps.
    """
    cfg = config or LogSourceConfig()
    odo = log.odometry
    t0 = log.start
    t_odo = odo[:, 0] - t0
    loops, moved, outside = loops_in_span(log, cfg.max_odometry_gap)
    loops[:, :2] -= t0
    times = np.union1d(t_odo, loops[_reaches_threshold(loops, cfg), 0])
    # velocities of sample i hold over (t_{i-1}, t_i]
    sample = np.minimum(np.searchsorted(t_odo, times, side="left"), t_odo.size - 1)
    interval = np.diff(t_odo, prepend=t_odo[0])[sample]
    raw_dt = np.diff(times, prepend=times[0])
    gap = interval > cfg.max_odometry_gap
    dt = np.where(gap, 0.0, raw_dt)
    translation = odo[sample, 1] * dt
    rotation = odo[sample, 2] * dt
    travelled = np.cumsum(np.abs(translation))
    stats = LogStats(
        frames=int(times.size),
        loop_candidates=int(log.loops.shape[0]),
        loops_clamped=int(np.count_nonzero(moved)),
        loops_outside=int(np.count_nonzero(outside)),
        odometry_gaps=int(np.count_nonzero(gap & (raw_dt > 0))),
    )
    stats.warnings = _step_warnings(log, cfg, stats, moved, outside)
    truth = None
    if log.ground_truth is not None:
        gt = log.ground_truth
        truth = interpolate_poses(gt[:, 0] - t0, gt[:, 1:4], times)
    queries = _queries(loops, times, travelled, cfg, stats)
    steps: list[EventStep] = []
    vertex_times: list[float] = []
    driven = turned = 0.0
    for k, t in enumerate(times.tolist()):
        events: list[MapEvent] = [Odometry(t, float(translation[k]), float(rotation[k]))]
        driven += abs(float(translation[k]))
        turned += float(rotation[k])
        if not vertex_times or driven >= cfg.vertex_step or abs(turned) >= cfg.vertex_turn:
            events.append(CreateVertex(t, len(vertex_times), len(vertex_times)))
            vertex_times.append(t)
            driven = turned = 0.0
        scores: list[float] = []
        linked: set[int] = set()
        for score, matched in queries.get(k, ()):
            target = _nearest(vertex_times, matched)
            if target in linked or target == len(vertex_times) - 1:
                stats.duplicates += 1
                continue
            linked.add(target)
            events.append(LinkToVertex(t, target, 0.0))
            if cfg.relocalise:
                events.append(SetCurrentVertex(t, target, 0.0))
            scores.append(score)
        stats.links += len(scores)
        pose = (
            None if truth is None else (float(truth[k, 0]), float(truth[k, 1]), float(truth[k, 2]))
        )
        steps.append(EventStep(k, t, tuple(events), pose, tuple(scores)))
    return steps, stats


def _step_warnings(
    log: OdometryLog, cfg: LogSourceConfig, stats: LogStats, moved: BoolArray, outside: BoolArray
) -> list[str]:
    """One line per kind of loop candidate or odometry interval :func:`log_steps` changed."""
    out = []
    span = f"({log.start:.3f}-{float(log.odometry[-1, 0]):.3f} s)"
    gap = f"{cfg.max_odometry_gap:g} s"
    path = log.loops_path or log.path
    loops = Rows("loop", LOOP_COLUMNS, path, log.loops, log.loop_lines)
    if stats.loops_clamped:
        what = f"loop candidate with a time up to {gap} outside the odometry {span}: moved onto it"
        out.append(count_note(loops, moved, what))
    if stats.loops_outside:
        what = f"loop candidate with a time more than {gap} outside the odometry {span}: dropped"
        out.append(count_note(loops, outside, what))
    if stats.odometry_gaps:
        out.append(
            f"{stats.odometry_gaps} x odometry gap longer than {gap} (no motion integrated over it)"
        )
    if log.loops_path is not None and stats.loop_candidates == stats.loops_outside:
        dropped = stats.loops_outside or log.read_counts.get("loops_same_view", 0)
        out.append(
            f"{log.loops_path}: no loop candidates{' left' if dropped else ''}: the map is its "
            "odometry"
        )
    return out


def _queries(
    loops: FloatArray,
    times: FloatArray,
    travelled: FloatArray,
    cfg: LogSourceConfig,
    stats: LogStats,
) -> dict[int, list[tuple[float, float]]]:
    """Step index -> the accepted candidates of the query at that step, best score first."""
    out: dict[int, list[tuple[float, float]]] = {}
    if not loops.size:
        return out
    keep, close = _candidate_verdicts(loops, times, travelled, cfg)
    stats.below_threshold = int(np.count_nonzero(~keep))
    stats.too_close = int(np.count_nonzero(close))
    stats.used_loops = loops[keep & ~close, :2]
    step = np.searchsorted(times, loops[:, 0])
    for k in np.flatnonzero(keep & ~close).tolist():
        out.setdefault(int(step[k]), []).append((float(loops[k, 2]), float(loops[k, 1])))
    for candidates in out.values():
        candidates.sort(key=lambda c: (-c[0], c[1]))
    return out


def _candidate_verdicts(
    loops: FloatArray, times: FloatArray, travelled: FloatArray, cfg: LogSourceConfig
) -> tuple[BoolArray, BoolArray]:
    """Per candidate: its score reaches the threshold; ... but too little was driven since."""
    keep = _reaches_threshold(loops, cfg)
    driven = travelled[np.searchsorted(times, loops[:, 0])] - np.interp(
        loops[:, 1], times, travelled
    )
    return keep, keep & (driven < cfg.min_loop_travel)


def _reaches_threshold(loops: FloatArray, cfg: LogSourceConfig) -> BoolArray:
    """Per candidate: its score reaches ``score_threshold`` (below it, a candidate is nothing)."""
    return loops[:, 2] >= cfg.score_threshold


def _nearest(times: list[float], t: float) -> int:
    """Index of the time in sorted ``times`` nearest to ``t`` (the earlier one on a tie)."""
    k = bisect.bisect_left(times, t)
    if k == 0:
        return 0
    if k == len(times):
        return k - 1
    return k - 1 if t - times[k - 1] <= times[k] - t else k


# ---------------------------------------------------------------------------------- reader
@dataclass(frozen=True)
class LogInfo:
    """What a log holds (the bag reader's :class:`~cogmap_core.datasets.BagInfo` counterpart).

    Attributes:
        path: the log file.
        format: ``tuc`` or ``csv``.
        duration: seconds of odometry.
        frame_count: steps the log becomes.
        odometry_count: odometry samples.
        loop_count: loop candidates.
        has_ground_truth: whether ground truth covering the run came with it.

    """

    path: Path
    format: str
    duration: float
    frame_count: int
    odometry_count: int
    loop_count: int
    has_ground_truth: bool


@dataclass
class LogCounters:
    """Problems met reading the log that did not stop it (``summary.json``'s read_warnings)."""

    frames: int = 0
    warnings: list[str] = field(default_factory=list)


class LogReader(InputReader):
    """Serves a log's steps the way :class:`~cogmap_core.datasets.BagReader` serves frames.

    There is no camera: :attr:`has_camera` is False and the steps are
    :class:`~cogmap_core.frames.EventStep` objects carrying their events and link scores.
    """

    has_camera = False

    def __init__(self, log: OdometryLog, config: LogSourceConfig | None = None) -> None:
        """Make the steps of ``log`` once (cheap: a few ms per thousand samples)."""
        self.log = log
        self.config = config or LogSourceConfig()
        self.steps, self.stats = log_steps(log, self.config)
        self._odometry_scale: OdometryScale | None = None
        self.path = log.path
        self.info = LogInfo(
            path=log.path,
            format=log.format,
            duration=log.duration,
            frame_count=len(self.steps),
            odometry_count=int(log.odometry.shape[0]),
            loop_count=int(log.loops.shape[0]),
            has_ground_truth=log.ground_truth is not None,
        )
        self.counters = LogCounters(
            frames=len(self.steps), warnings=[*log.warnings, *self.stats.warnings]
        )
        self._times = [s.time for s in self.steps]

    @property
    def warnings(self) -> list[str]:
        """Problems met reading the log that did not stop it, one line each (empty when clean)."""
        return list(self.counters.warnings)

    @property
    def odometry_scale(self) -> OdometryScale:
        """How precise this log's odometry is, measured by its loop candidates.

        The estimate of :mod:`cogmap_core.odometry_scale` over the candidates the map is given
        (score and travel thresholds applied), with the log defaults' link precision.
        """
        if self._odometry_scale is None:
            odometry = self.log.odometry.copy()
            odometry[:, 0] -= self.log.start
            self._odometry_scale = estimate_odometry_scale(
                odometry, self.stats.used_loops, LOG_MAP_PARAMS.link_sigma_position
            )
        return self._odometry_scale

    @property
    def map_params(self) -> MapParams:
        """Default map parameters for this input: a log's, with its own :attr:`odometry_scale`.

        The odometry steps the map's edges are made of are the reader's vertex step and turn.
        """
        return LOG_MAP_PARAMS.with_changes(
            odometry_scale=self.odometry_scale.scale,
            odometry_step_length=self.config.vertex_step,
            odometry_step_turn=self.config.vertex_turn,
        )

    @property
    def evaluation(self) -> EvaluationSettings:
        """How maps of this kind of input are judged."""
        return LOG_EVALUATION

    def frames(self, start_time: float = 0.0) -> Iterator[EventStep]:
        """The steps from data time ``start_time`` (s) on.

        Raises:
            ParameterError: ``start_time`` outside the log.

        """
        if not (0.0 <= start_time <= self.info.duration + 1.0) or not math.isfinite(start_time):
            raise ParameterError(
                f"start time {start_time} s is outside the log (0-{self.info.duration:.1f} s)"
            )
        first = bisect.bisect_left(self._times, start_time)
        return iter(self.steps[first:])

    def description(self) -> dict[str, Any]:
        """The source's settings and what became of its loop candidates (for the report)."""
        stats = self.stats
        return {
            "format": self.log.format,
            "ground_truth": None
            if self.log.ground_truth_path is None
            else str(self.log.ground_truth_path),
            "ground_truth_heading": self.log.heading_known,
            "settings": self.config.to_dict(),
            "odometry_samples": self.info.odometry_count,
            **self.log.read_counts,
            "loop_candidates": stats.loop_candidates,
            "loops_clamped": stats.loops_clamped,
            "loops_outside": stats.loops_outside,
            "below_threshold": stats.below_threshold,
            "too_close": stats.too_close,
            "duplicates": stats.duplicates,
            "links": stats.links,
        }
