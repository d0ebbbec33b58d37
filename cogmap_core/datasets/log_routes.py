"""Driving patterns for generated odometry logs: where the robot goes, and how it drives there.

A *pattern* (:data:`PATTERNS`) builds a route -- a polyline of waypoints long enough for any
duration -- with the look-alike regions of its world (:class:`Alias`, for structured false
matches). :func:`drive` then follows the route the way a wheeled robot does: pure pursuit on
the polyline (smooth, corner-cutting turns), cruise speed varying from leg to leg, speed
limited by turn rate, lateral acceleration and the next corner, acceleration limits, stopping
and turning on the spot where the route doubles back, and short pauses.

The result (:class:`Trajectory`) is sampled every :data:`SIM_DT` seconds: positions, continuous
heading and the distance driven.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

SIM_DT = 0.05
"""Time step (s) of the driving simulation (20 Hz)."""

PATTERNS = (
    "loop",
    "back_and_forth",
    "parallel_corridors",
    "figure_eight",
    "long_exploration",
    "campus",
)
"""Names of the driving patterns, in the order ``--help`` lists them."""

#: Default cruise speed (m/s) of each pattern: indoor patterns slower, outdoor ones faster.
PATTERN_SPEED = {
    "loop": 0.8,
    "back_and_forth": 0.6,
    "parallel_corridors": 0.6,
    "figure_eight": 0.7,
    "long_exploration": 1.1,
    "campus": 1.0,
}

MIN_SPEED, MAX_SPEED = 0.3, 1.5  # m/s: the range of cruise speeds
_MAX_TURN_RATE = 0.8  # rad/s while driving
_PIVOT_RATE = 0.6  # rad/s turning on the spot
_ACCEL, _BRAKE = 0.4, 0.8  # m/s^2
_LATERAL_ACCEL = 0.4  # m/s^2 in bends
_ANGULAR_ACCEL = 2.0  # rad/s^2
_SHARP_TURN = math.radians(100)  # a waypoint turning more than this is a stop and a pivot


@dataclass(frozen=True)
class Alias:
    """A look-alike region: places in it look like the places it maps to.

    A point ``p`` in the box ``|p - centre| <= half_size`` (per axis) looks like
    ``centre + shift + R(rotation) (p - centre)``, seen with heading ``+ rotation``.
    """

    centre: tuple[float, float]
    half_size: tuple[float, float]
    shift: tuple[float, float]
    rotation: float = 0.0

    def contains(self, xy: FloatArray) -> NDArray[np.bool_]:
        """Whether each ``(n, 2)`` point lies in the region."""
        d = np.abs(np.asarray(xy) - np.asarray(self.centre))
        return (d[:, 0] <= self.half_size[0]) & (d[:, 1] <= self.half_size[1])

    def apply(self, poses: FloatArray) -> FloatArray:
        """The look-alike poses ``(n, 3)`` of ``(n, 3)`` poses (x, y, heading)."""
        c, s = math.cos(self.rotation), math.sin(self.rotation)
        rel = poses[:, :2] - np.asarray(self.centre)
        out = np.empty_like(poses)
        out[:, 0] = self.centre[0] + self.shift[0] + c * rel[:, 0] - s * rel[:, 1]
        out[:, 1] = self.centre[1] + self.shift[1] + s * rel[:, 0] + c * rel[:, 1]
        out[:, 2] = poses[:, 2] + self.rotation
        return out


@dataclass
class Route:
    """Waypoints to drive through, in order.

    Attributes:
        points: ``(K, 2)`` waypoints (m).
        pauses: ``(K,)`` seconds to stand still on reaching each (0: drive through).
        aliases: the world's look-alike regions.

    """

    points: FloatArray
    pauses: FloatArray
    aliases: list[Alias] = field(default_factory=list)


@dataclass(frozen=True)
class Trajectory:
    """The true motion sampled every :data:`SIM_DT` seconds from time 0.

    Attributes:
        times: ``(n,)`` sample times (s).
        xy: ``(n, 2)`` positions (m).
        heading: ``(n,)`` heading (rad), continuous (not wrapped).
        distance: ``(n,)`` distance driven since the start (m).

    """

    times: FloatArray
    xy: FloatArray
    heading: FloatArray
    distance: FloatArray


# ---------------------------------------------------------------------------------- patterns
class _RouteBuilder:
    """Collects waypoints (with a lateral jitter per visit) and random pauses."""

    def __init__(self, rng: np.random.Generator, jitter: float) -> None:
        self.rng = rng
        self.jitter = jitter
        self.points: list[tuple[float, float]] = []
        self.length = 0.0

    def add(self, x: float, y: float, jitter: bool = True) -> None:
        if jitter and self.jitter > 0:
            x += float(self.rng.normal(0.0, self.jitter))
            y += float(self.rng.normal(0.0, self.jitter))
        if self.points:
            px, py = self.points[-1]
            step = math.hypot(x - px, y - py)
            if step < 1e-6:
                return
            self.length += step
        self.points.append((x, y))

    def route(self, aliases: list[Alias] | None = None) -> Route:
        points = np.asarray(self.points, dtype=np.float64)
        seg = np.hypot(*np.diff(points, axis=0).T)
        # a short pause now and then: about 5 per km, 2-8 s each
        chance = np.minimum(0.5, 0.005 * np.concatenate([[0.0], seg]))
        pauses = np.where(
            self.rng.random(points.shape[0]) < chance, self.rng.uniform(2, 8, points.shape[0]), 0.0
        )
        pauses[0] = 0.0
        return Route(points, pauses, aliases or [])


def _loop(rng: np.random.Generator, length: float) -> Route:
    """A rectangular circuit (40-90 m by 25-50 m) driven lap after lap, anticlockwise."""
    w, h = rng.uniform(40, 90), rng.uniform(25, 50)
    b = _RouteBuilder(rng, 0.2)
    b.add(w / 2, 0.0, jitter=False)
    while b.length < length:
        for x, y in ((w, 0.0), (w, h), (0.0, h), (0.0, 0.0)):
            b.add(x, y)
    return b.route()


def _back_and_forth(rng: np.random.Generator, length: float) -> Route:
    """One corridor (50-100 m) driven to its end and back again, turning on the spot."""
    corridor = rng.uniform(50, 100)
    b = _RouteBuilder(rng, 0.15)
    b.add(0.0, 0.0, jitter=False)
    while b.length < length:
        b.add(corridor, 0.0)
        b.add(0.0, 0.0)
    return b.route()


def _parallel_corridors(rng: np.random.Generator, length: float) -> Route:
    """Two or three look-alike parallel corridors joined at their ends, in random order.

    At each end the robot takes another corridor (or, 30 % of the time, the same one back). A
    place in one corridor looks like the place at the same offset in each other one.
    """
    count = int(rng.integers(2, 4))
    corridor, spacing = rng.uniform(40, 80), rng.uniform(8, 15)
    b = _RouteBuilder(rng, 0.15)
    b.add(0.0, 0.0, jitter=False)
    lane, end = 0, 1  # driving lane 0 towards x = corridor
    while b.length < length:
        x_end = corridor * end
        b.add(x_end, lane * spacing)
        others = [c for c in range(count) if c != lane]
        lane = lane if rng.random() < 0.3 else int(rng.choice(others))
        b.add(x_end, lane * spacing)  # along the end corridor (nothing if the same lane)
        end = 1 - end
    aliases = []
    for a in range(count):
        for c in range(count):
            if a != c:
                centre = (corridor / 2, a * spacing)
                shift = (0.0, (c - a) * spacing)
                aliases.append(Alias(centre, (corridor / 2 - 2.0, 1.5), shift))
    return b.route(aliases)


def _figure_eight(rng: np.random.Generator, length: float) -> Route:
    """A figure of eight (50-80 m long, lobes 16-26 m wide), crossing itself in the middle."""
    a, bb = rng.uniform(25, 40), rng.uniform(16, 26)
    t = np.linspace(0.0, 2 * np.pi, 200, endpoint=False)
    curve = np.column_stack([a * np.sin(t), bb * np.sin(t) * np.cos(t)])
    step = np.hypot(*np.diff(curve, axis=0, append=curve[:1]).T)
    keep = np.flatnonzero(np.diff(np.floor(np.cumsum(step) / 2.0), prepend=-1) > 0)  # ~2 m
    b = _RouteBuilder(rng, 0.0)
    while b.length < length:
        shift = rng.normal(0.0, 0.2, 2)  # each lap a little to the side
        for x, y in curve[keep]:
            b.add(float(x + shift[0]), float(y + shift[1]))
    return b.route()


class _Lattice:
    """Junctions of a street grid with spacing ``spacing`` (m), each moved a little."""

    def __init__(self, rng: np.random.Generator, spacing: float, wobble: float) -> None:
        self.rng, self.spacing, self.wobble = rng, spacing, wobble
        self._offsets: dict[tuple[int, int], tuple[float, float]] = {}

    def position(self, node: tuple[int, int]) -> tuple[float, float]:
        if node not in self._offsets:
            dx, dy = self.rng.uniform(-self.wobble, self.wobble, 2)
            self._offsets[node] = (float(dx), float(dy))
        dx, dy = self._offsets[node]
        return node[0] * self.spacing + dx, node[1] * self.spacing + dy


_DIRECTIONS = ((1, 0), (0, 1), (-1, 0), (0, -1))


def _walk_step(
    rng: np.random.Generator, node: tuple[int, int], heading: int, allowed: Callable[..., bool]
) -> int:
    """The next direction index from ``node``: straight 50 %, left or right 25 % each."""
    options = [(heading, 0.5), ((heading + 1) % 4, 0.25), ((heading + 3) % 4, 0.25)]
    good = [(d, w) for d, w in options if allowed(node, d)]
    if not good:
        good = [(d, w) for d, w in options]
    weights = np.asarray([w for _, w in good])
    return good[int(rng.choice(len(good), p=weights / weights.sum()))][0]


def _long_exploration(rng: np.random.Generator, length: float, expected: float) -> Route:
    """A long route over new ground; late in the run it returns to earlier streets.

    A self-avoiding walk on a street grid (15-30 m blocks) for about 70 % of the expected
    distance, then the shortest way back to a junction of the first half of the route, which
    it then drives again the way it went the first time, before exploring on.
    """
    grid = _Lattice(rng, rng.uniform(15, 30), 2.0)
    b = _RouteBuilder(rng, 0.3)
    node, heading = (0, 0), 0
    path = [node]
    visited = {node}

    def unvisited(n: tuple[int, int], d: int) -> bool:
        return (n[0] + _DIRECTIONS[d][0], n[1] + _DIRECTIONS[d][1]) not in visited

    def go(n: tuple[int, int]) -> None:
        path.append(n)
        visited.add(n)
        b.add(*grid.position(n))

    b.add(*grid.position(node), jitter=False)
    while b.length < 0.7 * expected:
        heading = _walk_step(rng, node, heading, unvisited)
        node = (node[0] + _DIRECTIONS[heading][0], node[1] + _DIRECTIONS[heading][1])
        go(node)
    # back to a junction of the first half, along the grid (x first, then y)
    k = int(rng.integers(1, max(2, len(path) // 2)))
    target = path[k]
    while node != target:
        dx, dy = target[0] - node[0], target[1] - node[1]
        node = (
            (node[0] + int(np.sign(dx)), node[1]) if dx else (node[0], node[1] + int(np.sign(dy)))
        )
        go(node)
    # the first route again, the same way, for up to a fifth of the expected distance
    replay_end = b.length + 0.2 * expected
    for n in path[k + 1 :]:
        if b.length >= replay_end:
            break
        node = n
        go(node)
    previous = path[-2]
    heading = _DIRECTIONS.index((node[0] - previous[0], node[1] - previous[1]))
    while b.length < length:
        heading = _walk_step(rng, node, heading, unvisited)
        node = (node[0] + _DIRECTIONS[heading][0], node[1] + _DIRECTIONS[heading][1])
        go(node)
    return b.route()


def _campus(rng: np.random.Generator, length: float) -> Route:
    """A random walk over a campus street grid (3-4 by 3-4 junctions, 25-45 m blocks).

    At every junction the robot goes straight or turns (never back unless at a corner it
    must), so it passes the same streets again and again, in both directions.
    """
    nx, ny = int(rng.integers(3, 5)), int(rng.integers(3, 5))
    xs = np.concatenate([[0.0], np.cumsum(rng.uniform(25, 45, nx - 1))])
    ys = np.concatenate([[0.0], np.cumsum(rng.uniform(25, 45, ny - 1))])
    b = _RouteBuilder(rng, 0.25)
    node, heading = (0, 0), 0
    b.add(float(xs[0]), float(ys[0]), jitter=False)

    def inside(n: tuple[int, int], d: int) -> bool:
        x, y = n[0] + _DIRECTIONS[d][0], n[1] + _DIRECTIONS[d][1]
        return 0 <= x < nx and 0 <= y < ny

    while b.length < length:
        heading = _walk_step(rng, node, heading, inside)
        if not inside(node, heading):
            heading = (heading + 2) % 4  # a corner with no way on: back (not reached on a grid)
        node = (node[0] + _DIRECTIONS[heading][0], node[1] + _DIRECTIONS[heading][1])
        b.add(float(xs[node[0]]), float(ys[node[1]]))
    return b.route()


def build_route(pattern: str, rng: np.random.Generator, length: float, expected: float) -> Route:
    """The route of ``pattern``: at least ``length`` metres (``expected``: what will be driven).

    Raises:
        ValueError: an unknown pattern (the configuration checks names first).

    """
    if pattern == "loop":
        return _loop(rng, length)
    if pattern == "back_and_forth":
        return _back_and_forth(rng, length)
    if pattern == "parallel_corridors":
        return _parallel_corridors(rng, length)
    if pattern == "figure_eight":
        return _figure_eight(rng, length)
    if pattern == "long_exploration":
        return _long_exploration(rng, length, expected)
    if pattern == "campus":
        return _campus(rng, length)
    raise ValueError(f"unknown pattern {pattern!r}")


# ---------------------------------------------------------------------------------- driving
def _wrap(angle: float) -> float:
    return (angle + math.pi) % (2 * math.pi) - math.pi


def drive(route: Route, duration: float, speed: float, rng: np.random.Generator) -> Trajectory:
    """Follow ``route`` for ``duration`` seconds at cruise speeds around ``speed`` (m/s).

    Pure pursuit along the polyline (look-ahead 1.5 m + 1 s of travel), cruise speed drawn per
    leg within +-15 % of ``speed`` (clipped to 0.3-1.5 m/s); waypoints turning by more than
    100 degrees are driven to, stopped at and turned on the spot. A route must be long enough
    for the duration (the patterns build ``1.5 m/s * duration`` and more).
    """
    pts = route.points
    seg = np.diff(pts, axis=0)
    seg_len = np.hypot(seg[:, 0], seg[:, 1])
    seg_dir = np.arctan2(seg[:, 1], seg[:, 0])
    arc = np.concatenate([[0.0], np.cumsum(seg_len)])
    turn = np.zeros(pts.shape[0])
    turn[1:-1] = np.abs((np.diff(seg_dir) + np.pi) % (2 * np.pi) - np.pi)
    stop = (turn > _SHARP_TURN) | (route.pauses > 0)
    stop[-1] = True
    next_stop = np.empty(pts.shape[0], dtype=np.int64)  # the first stop waypoint after k
    following = pts.shape[0] - 1
    for k in range(pts.shape[0] - 1, -1, -1):
        next_stop[k] = following
        if stop[k]:
            following = k
    # speed through each waypoint: pure pursuit cuts a corner on an arc of radius about
    # 1 m / sin(turn / 2) (1.4 m at a right angle)
    radius = 2.0 / (2.0 * np.maximum(np.sin(turn / 2), 1e-6))
    corner_speed = np.minimum(np.sqrt(_LATERAL_ACCEL * radius), _MAX_TURN_RATE * radius)
    cruise = np.clip(speed * rng.uniform(0.85, 1.15, pts.shape[0]), MIN_SPEED, MAX_SPEED)
    xy_list = pts.tolist()
    seg_list = seg_len.tolist()
    cos_dir, sin_dir = np.cos(seg_dir).tolist(), np.sin(seg_dir).tolist()
    corner_list, cruise_list, arc_list = corner_speed.tolist(), cruise.tolist(), arc.tolist()

    steps = int(math.ceil(duration / SIM_DT)) + 1
    out = np.empty((steps, 4))  # x, y, heading, distance
    x, y = xy_list[0]
    th = float(seg_dir[0])
    v = w = driven = 0.0
    k = 0  # current segment pts[k] -> pts[k + 1]
    mode, timer = "follow", 0.0
    for i in range(steps):
        out[i] = (x, y, th, driven)
        v_des = w_des = 0.0
        if k >= seg_len.size:
            raise RuntimeError("the route is shorter than the drive")  # the patterns prevent it
        if mode == "pause":
            timer -= SIM_DT
            if timer <= 0 and v == 0.0:
                mode = "pivot"
        elif mode == "pivot":
            err = _wrap(float(seg_dir[k + 1]) - th)
            if abs(err) < 0.02 and abs(w) < 0.1:
                k, mode = k + 1, "follow"
            else:
                w_des = min(max(2.0 * err, -_PIVOT_RATE), _PIVOT_RATE)
        else:
            # advance along the route while the robot is nearer the next segment
            while k + 1 < seg_len.size and not stop[k + 1]:
                if _segment_distance(xy_list, k + 1, x, y) > _segment_distance(xy_list, k, x, y):
                    break
                k += 1
            ax, ay = xy_list[k]
            along = (x - ax) * cos_dir[k] + (y - ay) * sin_dir[k]
            along = min(max(along, 0.0), seg_list[k])
            s_here = float(arc[k]) + along
            s_stop = float(arc[next_stop[k]])
            if s_stop - s_here < 0.05 or (along >= seg_len[k] and stop[k + 1]):
                k = int(next_stop[k]) - 1  # the segment that ends at the stop
                if k + 2 >= pts.shape[0]:
                    raise RuntimeError("the route is shorter than the drive")
                mode, timer = "pause", float(route.pauses[k + 1])
            else:
                look = 1.5 + v
                s_target = min(s_here + look, s_stop)
                tx = float(np.interp(s_target, arc, pts[:, 0]))
                ty = float(np.interp(s_target, arc, pts[:, 1]))
                dist = math.hypot(tx - x, ty - y)
                alpha = _wrap(math.atan2(ty - y, tx - x) - th) if dist > 1e-6 else 0.0
                if abs(alpha) > 1.2:  # facing away: turn towards the route first
                    w_des = math.copysign(_PIVOT_RATE, alpha)
                else:
                    kappa = 2.0 * math.sin(alpha) / max(dist, 0.3)
                    v_des = cruise_list[k]
                    if abs(kappa) > 1e-9:
                        v_des = min(v_des, _MAX_TURN_RATE / abs(kappa))
                        v_des = min(v_des, math.sqrt(_LATERAL_ACCEL / abs(kappa)))
                    # brake for the next stop and the next corners
                    v_des = min(v_des, math.sqrt(2 * _BRAKE * max(s_stop - s_here - 0.03, 0.0)))
                    j = k + 1
                    while j < next_stop[k] and arc_list[j] - s_here < 12.0:
                        reach = max(arc_list[j] - s_here, 0.0)
                        v_des = min(v_des, math.sqrt(corner_list[j] ** 2 + 2 * _BRAKE * reach))
                        j += 1
                    v_des = max(v_des, 0.05 if s_stop - s_here > 0.05 else 0.0)
                    w_des = v_des * kappa
        if mode != "follow":
            v_des = 0.0
        v = max(v + min(max(v_des - v, -_BRAKE * SIM_DT), _ACCEL * SIM_DT), 0.0)
        w += min(max(w_des - w, -_ANGULAR_ACCEL * SIM_DT), _ANGULAR_ACCEL * SIM_DT)
        w = min(max(w, -_MAX_TURN_RATE), _MAX_TURN_RATE)
        th += w * SIM_DT
        x += v * SIM_DT * math.cos(th)
        y += v * SIM_DT * math.sin(th)
        driven += v * SIM_DT
    times = np.arange(steps) * SIM_DT
    return Trajectory(times, out[:, :2].copy(), out[:, 2].copy(), out[:, 3].copy())


def _segment_distance(pts: list[list[float]], k: int, x: float, y: float) -> float:
    """Distance from ``(x, y)`` to the segment ``pts[k] -> pts[k + 1]``."""
    ax, ay = pts[k]
    bx, by = pts[k + 1]
    dx, dy = bx - ax, by - ay
    length2 = dx * dx + dy * dy
    t = 0.0 if length2 == 0 else min(max(((x - ax) * dx + (y - ay) * dy) / length2, 0.0), 1.0)
    return math.hypot(ax + t * dx - x, ay + t * dy - y)
