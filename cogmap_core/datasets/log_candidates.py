"""Place-recognition loop candidates for generated logs, each with what it really is.

Every keyframe is a query; it yields candidates ``(time, matched time, score)`` to earlier
keyframes, of these kinds (:data:`CANDIDATE_KINDS`), shaped after the TUC Lecture Hall log
(a query every 2.5 s, median 6 candidates per query, most of them scoring low; true matches
score higher on average, but the two overlap):

- ``true``: an earlier keyframe whose true position is within ``match_radius`` and seen from
  about the same direction (or, rarely, the opposite one), detected with some probability;
  the score falls with the distance and the difference in viewing direction;
- ``near``: a near miss, a place 1.2 ``match_radius`` to 4 m off seen from about the same
  direction: beside many true matches, scoring below the threshold, and a share of the false
  matches at or above it (most of Lecture Hall's are such: 9 of its 11 usable false matches
  lie 1-3 m off);
- ``false``: a random far place (over 4 m off): most candidates, scoring below the threshold,
  and the rest of the false matches at or above it;
- ``structured``: a look-alike place (:class:`~cogmap_core.datasets.log_routes.Alias`): the
  same wrong place again and again, a consistent sequence over consecutive queries (in
  parallel corridors, the same-offset place in another corridor), scoring above the threshold;
- ``recent``: a keyframe a few seconds (under 3 m of driving) earlier, as real systems emit
  them (a log reader drops them by ``min_loop_travel``).

The number of false candidates at or above the threshold is set from the true ones there, so
that false matches are exactly the requested fraction of the usable candidates (score at or
above the threshold, not ``recent``): ``structured_fraction`` of them structured, then
``near_fraction`` of the others near misses (as many as the run has), the rest far.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from cogmap_core.datasets.log_routes import Alias
from cogmap_core.errors import ParameterError

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

CANDIDATE_KINDS = ("true", "near", "false", "structured", "recent")
"""Names of the candidate kinds; a candidate's ``kind`` is an index into this tuple."""
TRUE, NEAR, FALSE, STRUCTURED, RECENT = range(len(CANDIDATE_KINDS))

RECENT_TRAVEL = 3.0
"""A ``recent`` candidate matches a keyframe less than this many metres of driving earlier."""
FAR = 4.0
"""False candidates match places at least this far (m) from the query's true position."""


@dataclass(frozen=True)
class CandidateSettings:
    """What the candidate generator needs of the log's configuration (see its docstring)."""

    match_radius: float
    view_angle: float  # rad
    detection_probability: float
    opposite_probability: float
    false_fraction: float
    structured_fraction: float
    near_fraction: float
    score_threshold: float
    false_per_query: float
    recent_probability: float
    min_separation: float


@dataclass(frozen=True)
class Keyframes:
    """Query keyframes: times, true poses (x, y, wrapped heading) and distance driven."""

    times: FloatArray
    poses: FloatArray
    distance: FloatArray


def _angle_diff(a: FloatArray, b: FloatArray) -> FloatArray:
    return np.abs((np.asarray(a) - np.asarray(b) + np.pi) % (2 * np.pi) - np.pi)


def _beta_below(rng: np.random.Generator, a: float, b: float, limit: float, n: int) -> FloatArray:
    """``n`` draws of Beta(a, b) conditioned on being below ``limit`` (by redrawing)."""
    out = rng.beta(a, b, n)
    bad = out >= limit
    while bad.any():
        out[bad] = rng.beta(a, b, int(bad.sum()))
        bad = out >= limit
    return out


class _Collector:
    """Candidates gathered as keyframe index pairs, each pair at most once."""

    def __init__(self) -> None:
        self.query: list[int] = []
        self.target: list[int] = []
        self.score: list[float] = []
        self.kind: list[int] = []
        self.pairs: set[tuple[int, int]] = set()
        self.pairs_of: set[int] = set()  # queries with a candidate

    def add(self, i: int, j: int, score: float, kind: int) -> bool:
        if (i, j) in self.pairs:
            return False
        self.pairs.add((i, j))
        self.pairs_of.add(i)
        self.query.append(i)
        self.target.append(j)
        self.score.append(float(score))
        self.kind.append(kind)
        return True

    def count(self, kind: int, threshold: float) -> int:
        pairs = zip(self.kind, self.score, strict=True)
        return sum(1 for k, s in pairs if k == kind and s >= threshold)


def make_candidates(
    kf: Keyframes,
    aliases: list[Alias],
    cfg: CandidateSettings,
    rng: np.random.Generator,
    ensure_last: bool = False,
) -> tuple[FloatArray, IntArray]:
    """The loop candidates of the keyframes: ``(M, 3)`` rows and each one's kind.

    Rows are ``(time, matched time, score)`` sorted by time, then matched time. With
    ``ensure_last`` the last keyframe gets at least one candidate.

    Raises:
        ParameterError: the run has too few places for the structured false matches asked for.

    """
    n = kf.times.size
    out = _Collector()
    if n < 2:
        return np.zeros((0, 3)), np.zeros(0, dtype=np.int64)
    tree = cKDTree(kf.poses[:, :2])
    _true_and_near(kf, tree, cfg, rng, out)
    _recent(kf, cfg, rng, out)
    true_high = out.count(TRUE, cfg.score_threshold)
    f = cfg.false_fraction
    false_high = int(round(f * true_high / (1.0 - f)))
    structured = int(round(cfg.structured_fraction * false_high))
    _structured(kf, tree, aliases, cfg, rng, out, structured)
    near = _near_high(kf, tree, cfg, rng, out, round(cfg.near_fraction * (false_high - structured)))
    _false_high(kf, cfg, rng, out, false_high - structured - near)
    _false_low(kf, cfg, rng, out)
    if ensure_last and (n - 1) not in out.pairs_of:
        # a low-scoring match of the last query (it counts for nothing usable)
        j = _far_target(kf, n - 1, cfg, rng)
        j = n - 2 if j is None else j
        score = _beta_below(rng, 0.8, 3.5, cfg.score_threshold, 1)[0]
        out.add(n - 1, j, score, _kind_of(kf, n - 1, j, cfg))
    q = np.asarray(out.query, dtype=np.int64)
    t = np.asarray(out.target, dtype=np.int64)
    rows = np.column_stack([kf.times[q], kf.times[t], np.asarray(out.score)]).reshape(-1, 3)
    kind = np.asarray(out.kind, dtype=np.int64)
    order = np.lexsort((rows[:, 1], rows[:, 0]))
    return rows[order], kind[order]


def _kind_of(kf: Keyframes, i: int, j: int, cfg: CandidateSettings) -> int:
    """What a candidate from query ``i`` to keyframe ``j`` is, by driving and true distance."""
    if kf.distance[i] - kf.distance[j] < RECENT_TRAVEL:
        return RECENT
    gap = math.hypot(*(kf.poses[i, :2] - kf.poses[j, :2]))
    return TRUE if gap <= cfg.match_radius else NEAR if gap < FAR else FALSE


def _true_and_near(
    kf: Keyframes, tree: cKDTree, cfg: CandidateSettings, rng: np.random.Generator, out: _Collector
) -> None:
    """True matches (detected with some probability) and the near misses beside them."""
    pairs = tree.query_pairs(cfg.match_radius + 1e-9, output_type="ndarray")
    if pairs.size == 0:
        return
    pairs = pairs[np.lexsort((pairs.min(axis=1), pairs.max(axis=1)))]
    j, i = pairs.min(axis=1), pairs.max(axis=1)
    d = np.hypot(*(kf.poses[i, :2] - kf.poses[j, :2]).T)
    turn = _angle_diff(kf.poses[i, 2], kf.poses[j, 2])
    same = turn <= cfg.view_angle
    opposite = turn >= math.pi - cfg.view_angle
    chance = np.where(same, cfg.detection_probability, 0.0)
    chance = np.where(opposite, cfg.opposite_probability, chance)
    keep = (
        (d <= cfg.match_radius)
        & (kf.distance[i] - kf.distance[j] >= cfg.min_separation)
        & (rng.random(i.size) < chance)
    )
    i, j, d, turn, opposite = i[keep], j[keep], d[keep], turn[keep], opposite[keep]
    # score: closer and more alike views score higher (Lecture Hall: true matches have a
    # median score of 0.52, 13 % at or above 0.8; these are a little better)
    view = np.where(opposite, math.pi - turn, turn) / max(cfg.view_angle, 1e-9)
    mean = 0.85 - 0.35 * d / cfg.match_radius - 0.15 * view - np.where(opposite, 0.2, 0.0)
    mean = np.clip(mean, 0.05, 0.95)
    scores = rng.beta(5.0 * mean, 5.0 * (1.0 - mean))
    near_draw = rng.random(i.size)
    side = rng.integers(0, 2, i.size) * 2 - 1
    near_scores = _beta_below(rng, 2.0, 3.5, cfg.score_threshold, i.size)
    for k in range(i.size):
        out.add(int(i[k]), int(j[k]), scores[k], TRUE)
    for k in np.flatnonzero(near_draw < 0.5).tolist():
        q, m = int(i[k]), int(j[k] + side[k])
        if not 0 <= m < q:
            continue
        gap = math.hypot(*(kf.poses[q, :2] - kf.poses[m, :2]))
        if 1.2 * cfg.match_radius < gap <= FAR and (
            kf.distance[q] - kf.distance[m] >= cfg.min_separation
        ):
            out.add(q, m, near_scores[k], NEAR)


def _recent(
    kf: Keyframes, cfg: CandidateSettings, rng: np.random.Generator, out: _Collector
) -> None:
    """Candidates to the one or two keyframes just before a query."""
    n = kf.times.size
    draw = rng.random((n, 2))
    scores = rng.beta(1.5, 2.5, (n, 2))
    for i in range(1, n):
        for back in (1, 2):
            j = i - back
            if j < 0 or kf.distance[i] - kf.distance[j] >= RECENT_TRAVEL:
                break
            if draw[i, back - 1] >= cfg.recent_probability * (1.0 if back == 1 else 0.5):
                break
            out.add(i, j, scores[i, back - 1], RECENT)


def _far_target(
    kf: Keyframes, i: int, cfg: CandidateSettings, rng: np.random.Generator, tries: int = 30
) -> int | None:
    """A random earlier keyframe far from query ``i`` in place and driving (None: none found)."""
    earliest = int(np.searchsorted(kf.distance, kf.distance[i] - cfg.min_separation, "right"))
    if earliest == 0:
        return None
    for j in rng.integers(0, earliest, tries).tolist():
        if math.hypot(*(kf.poses[i, :2] - kf.poses[j, :2])) > FAR:
            return int(j)
    return None


def _false_high(
    kf: Keyframes, cfg: CandidateSettings, rng: np.random.Generator, out: _Collector, count: int
) -> None:
    """``count`` random false matches scoring at or above the threshold."""
    thr = cfg.score_threshold
    placed, tries = 0, 0
    while placed < count:
        tries += 1
        if tries > 100 * count + 1000:
            raise ParameterError(
                f"cannot place {count} false loop candidates in this run; lengthen --duration"
            )
        i = int(rng.integers(0, kf.times.size))
        j = _far_target(kf, i, cfg, rng)
        if j is not None:
            score = thr + (1.0 - thr) * float(rng.beta(1.0, 2.5))
            placed += out.add(i, j, score, FALSE)


def _near_high(
    kf: Keyframes,
    tree: cKDTree,
    cfg: CandidateSettings,
    rng: np.random.Generator,
    out: _Collector,
    count: int,
) -> int:
    """Up to ``count`` near misses scoring at or above the threshold; returns how many."""
    if count <= 0:
        return 0
    pairs = tree.query_pairs(FAR, output_type="ndarray")
    if pairs.size == 0:
        return 0
    pairs = pairs[np.lexsort((pairs.min(axis=1), pairs.max(axis=1)))]
    j, i = pairs.min(axis=1), pairs.max(axis=1)
    d = np.hypot(*(kf.poses[i, :2] - kf.poses[j, :2]).T)
    ok = (
        (d > 1.2 * cfg.match_radius)
        & (d < FAR)
        & (_angle_diff(kf.poses[i, 2], kf.poses[j, 2]) <= cfg.view_angle)
        & (kf.distance[i] - kf.distance[j] >= cfg.min_separation)
    )
    thr = cfg.score_threshold
    placed = 0
    for k in rng.permutation(np.flatnonzero(ok)).tolist():
        if placed == count:
            break
        score = thr + (1.0 - thr) * float(rng.beta(1.0, 2.5))
        placed += out.add(int(i[k]), int(j[k]), score, NEAR)
    return placed


def _false_low(
    kf: Keyframes, cfg: CandidateSettings, rng: np.random.Generator, out: _Collector
) -> None:
    """The many low-scoring false matches: Poisson(``false_per_query``) per query."""
    per_query = rng.poisson(cfg.false_per_query, kf.times.size)
    scores = _beta_below(rng, 0.8, 3.5, cfg.score_threshold, int(per_query.sum()))
    used = 0
    for i in np.flatnonzero(per_query).tolist():
        for _ in range(int(per_query[i])):
            j = _far_target(kf, i, cfg, rng)
            if j is not None:
                out.add(i, j, scores[used], FALSE)
            used += 1


def _alias_pairs(
    kf: Keyframes, tree: cKDTree, alias: Alias, cfg: CandidateSettings
) -> list[tuple[int, int]]:
    """Query-target pairs an alias makes: queries in it, targets near their look-alike pose."""
    inside = np.flatnonzero(alias.contains(kf.poses[:, :2]))
    if inside.size == 0:
        return []
    looks = alias.apply(kf.poses[inside])
    near = tree.query_ball_point(looks[:, :2], cfg.match_radius + 1e-9)
    pairs = []
    for q, pose, found in zip(inside.tolist(), looks, near, strict=True):
        j = np.asarray(sorted(m for m in found if m < q), dtype=np.int64)
        if j.size == 0:
            continue
        ok = (
            (np.hypot(*(kf.poses[j, :2] - pose[:2]).T) <= cfg.match_radius)
            & (np.hypot(*(kf.poses[j, :2] - kf.poses[q, :2]).T) > FAR)
            & (_angle_diff(kf.poses[j, 2], pose[2]) <= cfg.view_angle)
            & (kf.distance[q] - kf.distance[j] >= cfg.min_separation)
        )
        pairs.extend((q, int(m)) for m in j[ok].tolist())
    return pairs


def _random_alias(kf: Keyframes, rng: np.random.Generator) -> Alias | None:
    """A look-alike region of 3 m around one place, looking like another, earlier place."""
    n = kf.times.size
    q = int(rng.integers(n // 3, n)) if n >= 3 else n - 1
    far = np.flatnonzero(
        (np.hypot(*(kf.poses[:q, :2] - kf.poses[q, :2]).T) > 8.0)
        & (kf.distance[q] - kf.distance[:q] >= 20.0)
    )
    if far.size == 0:
        return None
    p = int(rng.choice(far))
    centre = (float(kf.poses[q, 0]), float(kf.poses[q, 1]))
    shift = (float(kf.poses[p, 0] - kf.poses[q, 0]), float(kf.poses[p, 1] - kf.poses[q, 1]))
    return Alias(centre, (3.0, 3.0), shift, float(kf.poses[p, 2] - kf.poses[q, 2]))


def _structured(
    kf: Keyframes,
    tree: cKDTree,
    aliases: list[Alias],
    cfg: CandidateSettings,
    rng: np.random.Generator,
    out: _Collector,
    count: int,
) -> None:
    """``count`` structured false matches: whole passes through look-alike regions.

    The world's own look-alike regions first (parallel corridors), then random ones: a place
    that looks like another, earlier one.
    """
    if count == 0:
        return
    thr = cfg.score_threshold
    pool = [p for alias in aliases for p in _passes(_alias_pairs(kf, tree, alias, cfg))]
    order = rng.permutation(len(pool)).tolist()
    placed, attempts = 0, 0
    while placed < count:
        while not order:
            attempts += 1
            if attempts > 200:
                raise ParameterError(
                    f"cannot place {count} structured false loop candidates in this run "
                    f"({placed} found); lengthen --duration or lower --structured-fraction"
                )
            alias = _random_alias(kf, rng)
            if alias is not None:
                pool = _passes(_alias_pairs(kf, tree, alias, cfg))
                order = rng.permutation(len(pool)).tolist()
        for i, j in pool[order.pop()]:
            if placed == count:
                break
            score = thr + (1.0 - thr) * float(rng.beta(2.0, 2.0))
            placed += out.add(i, j, score, STRUCTURED)


def _passes(pairs: list[tuple[int, int]]) -> list[list[tuple[int, int]]]:
    """Pairs grouped into passes: runs of queries at most 3 keyframes apart."""
    passes: list[list[tuple[int, int]]] = []
    last = -10
    for i, j in sorted(pairs):
        if i - last > 3 or not passes:
            passes.append([])
        passes[-1].append((i, j))
        last = i
    return passes
