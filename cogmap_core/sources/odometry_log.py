"""Odometry + place recognition -> cognitive-map events: the compact map as someone's back end.

A robot with wheel odometry and any visual place recognition (NetVLAD, sequence matching, ...)
records two streams: velocities ``(time, v, omega)`` and loop candidates ``(time, matched time,
score)`` -- "the view at ``time`` looks like the view at ``matched time``, with this similarity".
This module turns such a log into the event stream of :mod:`cogmap_core.events`, the same
contract the RatSLAM front end fulfils, so the three maps, the report and the web app work on it
unchanged. Readers of concrete formats (:mod:`cogmap_core.sources.tuc`,
:mod:`cogmap_core.sources.odometry_csv`) produce an :class:`OdometryLog`;
:func:`~cogmap_core.sources.log_reader.log_steps` makes the events;
:class:`~cogmap_core.sources.log_reader.LogReader` serves them like a bag reader serves frames.

**Time.** Data time counts from the first odometry sample (the file's stamps minus that one).

**Odometry.** A sample's velocities hold over the interval that ends at its stamp (the first
sample only starts the clock): the robot turns by ``omega * dt`` and goes ``v * dt`` forward --
the map's :class:`~cogmap_core.events.Odometry` (rotate, then translate). Lateral velocity (the
TUC files' ``vy``, a few mm/s) is not part of the map's motion model and is dropped; on Lecture
Hall that changes the dead-reckoning ATE by 2 mm. An interval longer than ``max_odometry_gap``
contributes no motion (counted as a warning). A line repeating an earlier line's time is dropped:
with the same values it is a repeat, with other values it conflicts and the first one is kept
(what the step making always did: it takes the first sample of a time) -- each kind counted, one
warning line each. Odometry going back in time is an error: no rule tells which stretch is right.

**Vertices** come from movement, as the experience map creates experiences: one at the first
sample, then a new one whenever the robot has driven ``vertex_step`` metres or turned
``vertex_turn`` radians since the last. That is the *standard* map, dense like OpenRatSLAM's; the
compact map's neighborhood fields then decline most of these proposals.

**Loop candidates.** A candidate with score at least ``score_threshold`` becomes a
:class:`~cogmap_core.events.LinkToVertex` at its time to the vertex made nearest in time to the
matched time, unless odometry says the robot drove less than ``min_loop_travel`` metres between
the two times (the view simply has not changed yet: odometry knows that relation better than a
keyframe match). Several candidates of one query that land on the same vertex give one link, the
highest score. What the evidence says is "same place": the link's relative pose is zero in
position and ``relative_rad = 0`` in heading -- a camera only recognises a place it sees from
about the same direction (on Lecture Hall the true matches' heading differs by a median of 2.4
degrees, 90 % within 21 degrees). The heading is never judged: loop closures are scored by
position only.

What real place recognition writes is taken as it can be mapped; each kind is counted, with one
warning line naming the first such line (``OdometryLog.read_counts``,
:class:`~cogmap_core.sources.log_reader.LogStats`):

- a candidate whose two times are less than :data:`SAME_VIEW` (1 s) apart matches the robot's
  own view (a loop to itself): dropped;
- one whose matched time is later than its time says the same the other way round ("the view at
  ``time`` looks like the view at ``matched time``" is symmetric): the two are swapped, and the
  link is made at the later time, when both places exist;
- a time up to ``max_odometry_gap`` before the first or after the last odometry stamp (a query
  logged just after the odometry stopped, a match to the first frames) is moved onto that stamp:
  the odometry places the robot there as well as it bridges its own gaps; a candidate with a
  time further out is dropped (:func:`~cogmap_core.sources.log_reader.loops_in_span`);
- with no candidate left, or none in the file, the maps are the odometry's (a warning).

A score outside [0, 1] or a value that is not a finite number is an error naming file and line:
nothing says what such a candidate means.

**No relocalisation.** RatSLAM reports a recognised place as link + set current vertex, and the
robot then continues from the old vertex. With a camera front end that matches views to a few
centimetres that is right; with place recognition that is good to a keyframe spacing (about 1 m)
and makes false matches, it breaks the odometry chain at every match: a false or coarse match
displaces everything mapped after it, and the Huber loss on the loop edge cannot help because the
edge is then the only link between before and after. Measured on Lecture Hall with these
settings (``benchmarks/real_data.py``): standard map ATE 2.33 m with link + set current against
0.37 m with links only (compact 2.81 m against 0.43 m), 2.66 m with the relocalisation test on. So
this source emits links only (``relocalise=False``): odometry stays continuous and a false loop
edge is one robust residual among many. ``relocalise=True`` restores RatSLAM's behaviour.

**Ground truth** (optional) is interpolated at every step. One that covers only part of the run
is dropped with a warning (the maps are still built; the accuracy figures need the whole run);
one that does not overlap the run at all is an error -- it belongs to another recording.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from cogmap_core.config import MapParams
from cogmap_core.errors import ParameterError
from cogmap_core.evaluation import (
    EvaluationSettings,
    loop_candidate_distances,
)
from cogmap_core.sources.log_text import LogFormatError, Rows

__all__ = ["LogFormatError", "Rows"]  # re-exported: the readers' rows and error live in log_text

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]

#: Map parameters for this kind of input, on top of the paper's (see :data:`LOG_MAP_PARAMS`).
LOG_MAP_CHANGES: dict[str, float] = {
    # A vertex every metre on a straight run: place recognition places the robot to about a
    # keyframe spacing (Lecture Hall: a query every 2.5 s at 0.5 m/s), so finer vertices carry
    # no information the loops could correct. g(1 m, 0) = 1 + 2.746 = 3.746 = delta.
    "alpha": 2.746,
    # Place recognition queries every few seconds; a cluster must span consecutive queries
    # (the paper's 2 s is below the query period: every query would be a cluster of its own).
    "t_interval": 5.0,
    # Scene integration: a revisit merges when it lies within half a metre of the known route
    # -- the place recognition's precision (libRSF models these loops with sigma 0.5 m) -- and
    # its closing link converged to 0.3 m: tighter than that precision, so a false link the
    # optimiser satisfied by bending a sparse map (residual 0.3-0.4 m in the tests' square
    # run) is not taken for a converged revisit.
    "integration_radius": 0.5,
    "integration_max_residual": 0.3,
    # A link is weighed by what place recognition knows: the place to about a keyframe spacing
    # (sigma 0.5 m, as libRSF models these loops) and the heading to the spread of a camera's
    # viewpoints on a match (true matches: 90 % within 21 degrees, sigma = 21 / 1.645 deg =
    # 0.22 rad), not RatSLAM's 3 cm / 0.1 rad view matching: weighed as precise as that, coarse
    # links bent the maps (Lecture Hall: standard map ATE 0.55 m, completeness 0.94 at 0.5 m;
    # 0.37 m and 0.99 weighed by their precision). The Huber loss of the other edges starts at
    # one link sigma. The loop closures take every map's robust model (Geman-McClure at three
    # link sigmas, 1.5 m: MapParams.loop_scale), which rejects a false match (11 % of the links
    # at score 0.8) where the odometry contradicts it. The heading is kept, coarse, rather than
    # freed: position-only links (link_sigma_heading 1000) left the scene-integration map at
    # 0.51 m, correctness 0.936 on Lecture Hall (0.42 m, 0.96 with 0.22 rad).
    "link_sigma_position": 0.5,
    "link_sigma_heading": 0.22,
    "huber_scale": 0.5,
    # The relocalisation test is off, as in the paper: without relocalisation (links only) a
    # refused link only drops evidence, and on Lecture Hall the test does not improve the maps.
    "gate_position": 1e9,
    "gate_heading": 1e9,
    # The map's edges are made of the reader's vertex steps (0.2 m or 0.2 rad, LogSourceConfig;
    # LogReader.map_params takes the reader's own): the compact map's metre-long edges weigh as
    # the five steps they replaced, not as one step five times as long -- 2.7 x its variance,
    # which let the compact maps bend to structured false clusters the standard map refused
    # (parallel_corridors_1 compact 3.08 -> 0.90 x its true-links map; docs/maps.md).
    "odometry_step_length": 0.2,
    "odometry_step_turn": 0.2,
    # A link the optimisation accepted is never contracted by short-edge removal: links alone
    # re-localise a log's robot, and the loop model's later rejection is their only guard. A
    # match 2.8 m off, accepted after 24.7 m of drift and contracted, outweighed the six true
    # links after it (long_exploration_5 compact 11.7 m; kept: 1.93 m, its true links alone
    # 1.96 m); Lecture Hall compact 0.388 -> 0.377 m with 1,010 vertices instead of 1,018.
    # Bags keep the paper's rule: their relocalisation test judges each link before the map
    # takes it, and on the four layouts x seeds 1-2 the compact ATE moved both ways (-8 to +9 %).
    "short_edge_loops": 0.0,
}
LOG_MAP_PARAMS = MapParams().with_changes(**LOG_MAP_CHANGES)
"""Default map parameters for odometry + place-recognition logs."""

LOG_EVALUATION = EvaluationSettings(layout_radius=0.5, loop_distance=1.0, loop_heading=None)
"""Judging for this kind of input: layout at 0.5 m; a loop closure is true when the two places
are within 1 m (twice the place recognition's 0.5 m precision), position only."""

ODOMETRY_COLUMNS = ("time", "v", "omega")
LOOP_COLUMNS = ("time", "matched time", "score")
TRUTH_COLUMNS = ("time", "x", "y", "theta")

SAME_VIEW = 1.0
"""A loop candidate whose two times are closer than this (s) matches the robot's own view."""


@dataclass(frozen=True)
class LogSourceConfig:
    """How a log becomes events (defaults: the settings for every log, measured on TUC).

    Attributes:
        vertex_step: a new vertex after driving this far since the last (m).
        vertex_turn: ... or turning this much (rad).
        score_threshold: loop candidates scoring below this are ignored (score in [0, 1]).
        min_loop_travel: candidates whose two times are less than this many metres of
            odometry apart are ignored (m).
        relocalise: also emit SetCurrentVertex after each link (RatSLAM's behaviour).
        max_odometry_gap: odometry intervals longer than this contribute no motion (s).

    """

    vertex_step: float = 0.2
    vertex_turn: float = 0.2
    score_threshold: float = 0.8
    min_loop_travel: float = 5.0
    relocalise: bool = False
    max_odometry_gap: float = 1.0

    def __post_init__(self) -> None:
        """Reject settings outside their ranges."""
        checks = (
            ("vertex_step", self.vertex_step > 0),
            ("vertex_turn", self.vertex_turn > 0),
            ("score_threshold", 0.0 <= self.score_threshold <= 1.0),
            ("min_loop_travel", self.min_loop_travel >= 0),
            ("max_odometry_gap", self.max_odometry_gap > 0),
        )
        for name, ok in checks:
            value = getattr(self, name)
            if not (ok and math.isfinite(value)):
                raise ParameterError(
                    f"log source setting {name}={value!r} is out of range "
                    "(score_threshold in [0, 1], min_loop_travel >= 0, the others > 0)"
                )

    def with_changes(self, **changes: float) -> LogSourceConfig:
        """A copy with some settings changed (validated; unknown names are an error)."""
        known = {f.name for f in fields(self)}
        unknown = set(changes) - known
        if unknown:
            raise ParameterError(
                f"unknown log source setting(s) {sorted(unknown)}; known: {sorted(known)}"
            )
        relocalise = changes.get("relocalise")
        if relocalise is not None and relocalise not in (0, 1):  # (True and False are 1 and 0)
            raise ParameterError(f"log source setting relocalise={relocalise!r} must be 0 or 1")
        values = {k: bool(v) if k == "relocalise" else float(v) for k, v in changes.items()}
        return replace(self, **values)  # type: ignore[arg-type]

    def to_dict(self) -> dict[str, float | bool]:
        """All settings (for config.json and the report)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(frozen=True)
class OdometryLog:
    """A validated log: odometry, loop candidates and (optionally) ground truth.

    Times are the file's own (seconds); :func:`~cogmap_core.sources.log_reader.log_steps` counts
    them from ``odometry[0, 0]``.

    Attributes:
        path: the file the user gave (odometry, or the combined TUC input file).
        format: ``tuc`` or ``csv``.
        odometry: ``(N, 3)`` time, forward velocity v (m/s), yaw rate omega (rad/s); N >= 1,
            times increasing.
        loops: ``(M, 3)`` time, matched time, score -- sorted by time, the matched time at
            least :data:`SAME_VIEW` earlier; times may lie outside the odometry (see
            :func:`~cogmap_core.sources.log_reader.log_steps`).
        ground_truth: ``(G, 4)`` time, x, y, theta covering the run, or None.
        ground_truth_path: where the ground truth came from.
        heading_known: whether the ground truth had a heading (else theta is the direction of
            travel, for display only).
        warnings: problems that did not stop the run (one line each).
        loop_lines: the line of each loop candidate in ``loops_path`` (in the order of
            ``loops``).
        loops_path: the file the loop candidates came from (None: no loop file).
        read_counts: lines the reader dropped or changed, by kind (``odometry_repeated``,
            ``odometry_conflicting``, ``loops_same_view``, ``loops_swapped``).

    """

    path: Path
    format: str
    odometry: FloatArray
    loops: FloatArray
    ground_truth: FloatArray | None = None
    ground_truth_path: Path | None = None
    heading_known: bool = True
    warnings: tuple[str, ...] = ()
    loop_lines: IntArray = field(default_factory=lambda: np.zeros(0, np.int64))
    loops_path: Path | None = None
    read_counts: dict[str, int] = field(default_factory=dict)

    @property
    def start(self) -> float:
        """File time of the first odometry sample (data time 0)."""
        return float(self.odometry[0, 0])

    @property
    def duration(self) -> float:
        """Seconds from the first to the last odometry sample."""
        return float(self.odometry[-1, 0] - self.odometry[0, 0])


def label_loop_candidates(log: OdometryLog, radius: float | None = None) -> NDArray[np.bool_]:
    """Which of a log's loop candidates are true: their two times' true places within ``radius``.

    A candidate ``(time, matched time, score)`` is true when the ground-truth positions at its
    two times (interpolated) are at most ``radius`` metres apart -- position only, the way the
    report judges a log's loop closures (default: :data:`LOG_EVALUATION`'s 1 m). One boolean per
    row of ``log.loops``, in that order; the score plays no part.

    Raises:
        ParameterError: the log has no ground truth, or ``radius`` is not a positive number.

    """
    radius = LOG_EVALUATION.loop_distance if radius is None else radius
    if not (math.isfinite(radius) and radius > 0):
        raise ParameterError(f"loop label radius {radius!r} m is out of range; use > 0 m")
    if log.ground_truth is None:
        raise ParameterError(
            f"{log.path}: the log has no ground truth; loop candidates cannot be labelled"
        )
    truth = log.ground_truth
    return loop_candidate_distances(log.loops, truth[:, 0], truth[:, 1:3]) <= radius


def check_finite(rows: Rows) -> FloatArray:
    """The rows' values; a value that is not finite is an error naming its file:line."""
    data = rows.values
    bad = ~np.isfinite(data)
    if bad.any():
        row, col = (int(v) for v in np.argwhere(bad)[0])
        raise LogFormatError(
            f"{rows.where(row)}: {rows.what} {rows.columns[col]} is {float(data[row, col])}; "
            "every value must be a finite number -- fix or drop the line"
        )
    return data


def check_increasing(rows: Rows, data: FloatArray, hint: str) -> None:
    """Refuse a row whose time (first column) is earlier than the previous one's."""
    back = np.flatnonzero(np.diff(data[:, 0]) < 0)
    if back.size:
        k = int(back[0]) + 1
        raise LogFormatError(
            f"{rows.where(k)}: {rows.what} time {data[k, 0]:.6f} s is earlier than the previous "
            f"({data[k - 1, 0]:.6f} s); {hint}"
        )


def count_note(rows: Rows, mask: BoolArray, what: str) -> str:
    """``"N x <what> (first at file:line)"`` for the rows in ``mask`` (at least one).

    Without line numbers (a log made in code, not read), the note names no line.
    """
    count = int(np.count_nonzero(mask))
    if rows.lines.shape[0] != mask.shape[0]:
        return f"{count} x {what}"
    first = int(np.flatnonzero(mask)[np.argmin(rows.lines[mask])])
    return f"{count} x {what} (first at {rows.where(first)})"


def make_odometry_log(
    path: Path,
    fmt: str,
    odometry: Rows,
    loops: Rows | None,
    truth: Rows | None = None,
    truth_path: Path | None = None,
    warnings: Sequence[str] = (),
) -> OdometryLog:
    """Validate parsed rows and build the log (the rules every format shares; module doc).

    Args:
        path: the file the user gave.
        fmt: ``tuc`` or ``csv``.
        odometry: the odometry rows, in file order.
        loops: the loop rows, in file order; None when there is no loop file (the reader
            warned).
        truth: the ground-truth rows, or None.
        truth_path: the ground-truth file.
        warnings: the reader's own warnings.

    Raises:
        LogFormatError: no odometry, a non-finite value, odometry or ground truth going back in
            time, a score outside [0, 1], ground truth not overlapping the run.

    """
    notes = list(warnings)
    if not len(odometry):
        raise LogFormatError(
            f"{path}: no odometry in the file; a log needs {odometry.what} lines "
            f"({', '.join(odometry.columns)})"
        )
    check_finite(odometry)
    check_increasing(odometry, odometry.values, "odometry must be in time order")
    odometry, counts = _repeated_stamps(odometry, notes)
    odo = odometry.values
    t_first, t_last = float(odo[0, 0]), float(odo[-1, 0])
    loops_path = None if loops is None else loops.path
    loops = loops if loops is not None else Rows.empty("loop", LOOP_COLUMNS, path)
    loops, loop_counts = _loop_candidates(loops, notes)
    counts.update(loop_counts)
    gt = None
    heading_known = True
    if truth is not None:
        gt, heading_known, note = _ground_truth(truth, truth_path or path, t_first, t_last)
        if note:
            notes.append(note)
    return OdometryLog(
        path,
        fmt,
        odo,
        loops.values,
        gt,
        truth_path,
        heading_known,
        tuple(notes),
        loops.lines,
        loops_path,
        counts,
    )


def _repeated_stamps(odometry: Rows, notes: list[str]) -> tuple[Rows, dict[str, int]]:
    """Odometry without the lines repeating an earlier line's time (the first one kept)."""
    t = odometry.values[:, 0]
    repeat = np.zeros(t.size, bool)
    repeat[1:] = t[1:] == t[:-1]
    counts = {"odometry_repeated": 0, "odometry_conflicting": 0}
    if not repeat.any():
        return odometry, counts
    index = np.arange(t.size)
    kept = np.maximum.accumulate(np.where(repeat, 0, index))  # the first line of its time
    same = (odometry.values == odometry.values[kept]).all(axis=1)
    identical, conflicting = repeat & same, repeat & ~same
    if identical.any():
        notes.append(
            count_note(
                odometry,
                identical,
                "odometry line with the time and values of an earlier line: dropped",
            )
        )
    if conflicting.any():
        notes.append(
            count_note(
                odometry,
                conflicting,
                "odometry line with the time of an earlier line but other values: dropped, "
                "the earlier line kept",
            )
        )
    counts["odometry_repeated"] = int(np.count_nonzero(identical))
    counts["odometry_conflicting"] = int(np.count_nonzero(conflicting))
    return odometry.take(~repeat), counts


def _loop_candidates(loops: Rows, notes: list[str]) -> tuple[Rows, dict[str, int]]:
    """Loop rows checked, without the ones matching their own view, later ones swapped, sorted."""
    loop = check_finite(loops)
    score = loop[:, 2]
    bad = np.flatnonzero(~((score >= 0.0) & (score <= 1.0)))
    if bad.size:
        k = int(bad[0])
        raise LogFormatError(
            f"{loops.where(k)}: loop score {float(score[k])!r} is outside [0, 1] (1 = most "
            "similar); rescale the place recognition's scores"
        )
    same = np.abs(loop[:, 0] - loop[:, 1]) < SAME_VIEW
    if same.any():
        notes.append(
            count_note(
                loops,
                same,
                f"loop candidate matching a view less than {SAME_VIEW:g} s from its own: dropped",
            )
        )
        loops = loops.take(~same)
        loop = loops.values
    later = loop[:, 1] > loop[:, 0]
    if later.any():
        notes.append(
            count_note(
                loops,
                later,
                "loop candidate matching a later time: the two swapped (the later view matches "
                "the earlier place)",
            )
        )
        loop = loop.copy()
        loop[later, :2] = loop[later, 1::-1]
        loops = loops.with_values(loop)
    counts = {
        "loops_same_view": int(np.count_nonzero(same)),
        "loops_swapped": int(np.count_nonzero(later)),
    }
    if (np.diff(loop[:, 0]) < 0).any():  # (no copy of a log that is in order)
        loops = loops.take(np.argsort(loop[:, 0], kind="stable"))
    return loops, counts


def _ground_truth(
    truth: Rows, path: Path, t_first: float, t_last: float
) -> tuple[FloatArray | None, bool, str]:
    """Validated ground truth covering the run, or None with the reason (a warning)."""
    if not len(truth):
        return None, True, f"{path}: no ground truth in the file; the report has no accuracy"
    if len(truth.columns) == 4 and np.isnan(truth.values[:, 3]).all():
        truth = truth.with_values(truth.values[:, :3], truth.columns[:3])
    data = check_finite(truth)
    check_increasing(truth, data, "ground truth must be in time order")
    heading_known = data.shape[1] == 4
    if not heading_known:
        data = np.column_stack([data, _direction_of_travel(data[:, 1:3])])
    g0, g1 = float(data[0, 0]), float(data[-1, 0])
    if g1 < t_first or g0 > t_last:
        raise LogFormatError(
            f"{path}: ground truth covers {g0:.3f}-{g1:.3f} s, the odometry {t_first:.3f}-"
            f"{t_last:.3f} s: they do not overlap; give the ground truth of this recording "
            "(or --no-ground-truth)"
        )
    period = float(np.median(np.diff(data[:, 0]))) if data.shape[0] > 1 else 0.0
    slack = max(1.0, 2.0 * period)
    if g0 > t_first + slack or g1 < t_last - slack:
        return (
            None,
            heading_known,
            f"{path}: ground truth covers {g0:.1f}-{g1:.1f} s of the {t_first:.1f}-{t_last:.1f} "
            "s run; the maps are built, the accuracy figures (which need the whole run) left out",
        )
    return data, heading_known, ""


def _direction_of_travel(xy: FloatArray) -> FloatArray:
    """Heading from consecutive positions (for display when the ground truth has none)."""
    step = np.diff(xy, axis=0)
    moving = np.hypot(step[:, 0], step[:, 1]) > 1e-3
    heading = np.full(xy.shape[0], np.nan)
    heading[:-1][moving] = np.arctan2(step[moving, 1], step[moving, 0])
    known = np.flatnonzero(~np.isnan(heading))
    if known.size == 0:
        return np.zeros(xy.shape[0])
    index = np.maximum.accumulate(np.where(~np.isnan(heading), np.arange(xy.shape[0]), 0))
    heading = heading[index]
    heading[: known[0]] = heading[known[0]]
    return heading
