"""Rat-like motion through a maze and the wheel odometry it produces.

The robot visits the layout's waypoints in alphabetical order each lap and returns to ``A``,
along shortest paths that keep to corridor centres (a clearance-weighted Dijkstra on the grid),
smoothed into continuous curves. Speed varies smoothly around the requested cruise speed, drops
in bends (turn-rate and lateral-acceleration limits), and the robot pauses at some waypoints and
at random places, sometimes looking around; it turns on the spot where the route doubles back.
Occasional detours to a nearby corridor make laps differ and add revisits in both directions.

The true trajectory is piecewise linear in time (``times``, ``xy``, unwrapped ``heading``); the
odometry model turns it into ``(v, w)`` messages with configurable noise and systematic bias.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage, sparse
from scipy.ndimage import gaussian_filter1d
from scipy.sparse.csgraph import dijkstra

from cogmap_core.datasets.layout import Layout
from cogmap_core.errors import ParameterError

FloatArray = NDArray[np.float64]

_CLEARANCE_WEIGHT = 4.0  # how strongly paths keep to corridor centres
_SMOOTH_SIGMA = 0.06  # m: radius-like scale of the rounding of corners
_DS = 0.005  # m: arc-length step of the speed profile
_TURN_DT = 0.01  # s: sampling of turns on the spot


@dataclass(frozen=True)
class MotionParams:
    """How the simulated rat moves.

    Attributes:
        speed: mean cruise speed (m/s); the actual speed varies by about +-25% and is lower in
            bends.
        laps: number of tours A -> B -> ... -> A.
        max_turn_rate: turn-rate limit (rad/s) in bends and when turning on the spot.
        max_accel: forward acceleration / braking limit (m/s^2).
        max_lateral_accel: limit on v^2 * curvature in bends (m/s^2).
        waypoint_pause_probability: chance of a pause at each waypoint (always when doubling
            back).
        pauses_per_metre: rate of random pauses along the way.
        look_around_probability: chance that a pause includes turning the head (body) aside
            and back.
        detour_probability: chance, per leg, of first visiting a random nearby corridor.

    """

    speed: float = 0.2
    laps: int = 6
    max_turn_rate: float = 1.8
    max_accel: float = 0.5
    max_lateral_accel: float = 0.35
    waypoint_pause_probability: float = 0.5
    pauses_per_metre: float = 0.06
    look_around_probability: float = 0.4
    detour_probability: float = 0.15

    def __post_init__(self) -> None:
        """Validate ranges (one-line messages with the valid range)."""
        if not (0.02 <= self.speed <= 1.0) or not math.isfinite(self.speed):
            raise ParameterError(f"speed {self.speed} m/s is out of range; use 0.02-1.0 m/s")
        if not (1 <= self.laps <= 1000):
            raise ParameterError(f"laps {self.laps} is out of range; use 1-1000")


@dataclass(frozen=True)
class Trajectory:
    """The true motion: piecewise linear in time between samples.

    Attributes:
        times: strictly increasing sample times (s), starting at 0.
        xy: ``(n, 2)`` positions (m).
        heading: ``(n,)`` unwrapped heading (rad), continuous.
        distance: ``(n,)`` cumulative distance travelled (m).
        lap_times: start time of each lap and, last, the end time.
        waypoint_times: ``(letter, time)`` of every waypoint arrival, in order.

    """

    times: FloatArray
    xy: FloatArray
    heading: FloatArray
    distance: FloatArray
    lap_times: tuple[float, ...]
    waypoint_times: tuple[tuple[str, float], ...]

    @property
    def duration(self) -> float:
        """Total duration (s)."""
        return float(self.times[-1])

    @property
    def length(self) -> float:
        """Total distance travelled (m)."""
        return float(self.distance[-1])

    def pose_at(self, t: ArrayLike) -> FloatArray:
        """True ``(x, y, theta)`` at times ``t`` (theta unwrapped), shape ``(..., 3)``."""
        t = np.asarray(t, dtype=np.float64)
        x = np.interp(t, self.times, self.xy[:, 0])
        y = np.interp(t, self.times, self.xy[:, 1])
        th = np.interp(t, self.times, self.heading)
        return np.stack([x, y, th], axis=-1)

    def distance_at(self, t: ArrayLike) -> FloatArray:
        """Cumulative distance travelled at times ``t``."""
        return np.interp(np.asarray(t, dtype=np.float64), self.times, self.distance)

    def heading_at(self, t: ArrayLike) -> FloatArray:
        """Unwrapped heading at times ``t``."""
        return np.interp(np.asarray(t, dtype=np.float64), self.times, self.heading)


@dataclass(frozen=True)
class OdometryModel:
    """Wheel-odometry errors: white noise while moving plus systematic bias.

    The reported velocities are ``v' = (1 + bias_v) v + sigma_v n1`` and
    ``w' = (1 + bias_w) w + drift_w v + sigma_w n2`` with ``n ~ N(0, 1)`` drawn per message; the
    noise is only added while the wheels turn (a parked robot reads exactly zero). The scale
    errors alone cancel on closed loops; ``drift_w`` (unequal wheel sizes: a heading error
    proportional to the distance driven) makes dead reckoning drift further every lap.

    Attributes:
        sigma_v: linear-speed noise (m/s) per message.
        sigma_w: turn-rate noise (rad/s) per message.
        bias_v: fractional scale error of distances (0.01 reads 1% too far).
        bias_w: fractional scale error of turns (0.01 reads turns 1% too large).
        drift_w: heading drift per metre driven (rad/m), positive to the left.

    """

    sigma_v: float = 0.005
    sigma_w: float = 0.02
    bias_v: float = 0.01
    bias_w: float = 0.01
    drift_w: float = 0.01

    def __post_init__(self) -> None:
        """Validate ranges (one-line messages with the valid range)."""
        for name in ("sigma_v", "sigma_w"):
            value = getattr(self, name)
            if not (0.0 <= value <= 1.0) or not math.isfinite(value):
                raise ParameterError(f"odometry noise {name}={value} is out of range; use 0-1")
        for name in ("bias_v", "bias_w"):
            value = getattr(self, name)
            if not (-0.5 <= value <= 0.5) or not math.isfinite(value):
                raise ParameterError(
                    f"odometry bias {name}={value} is out of range; use -0.5..0.5 (a fraction)"
                )
        if not (-1.0 <= self.drift_w <= 1.0) or not math.isfinite(self.drift_w):
            raise ParameterError(
                f"odometry drift_w={self.drift_w} rad/m is out of range; use -1..1"
            )


def odometry_messages(
    trajectory: Trajectory,
    stamps: ArrayLike,
    model: OdometryModel,
    rng: np.random.Generator,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Odometry messages at ``stamps`` (s, increasing).

    Message ``k`` reports the mean velocities over ``(stamps[k-1], stamps[k]]`` (the first one
    zero), so integrating ``v dt`` over header-stamp intervals, as OpenRatSLAM does, reproduces the
    true distance and turn exactly when noise and bias are zero.

    Returns:
        ``(v_true, w_true, v_measured, w_measured)``.

    """
    stamps = np.asarray(stamps, dtype=np.float64)
    dist = trajectory.distance_at(stamps)
    head = trajectory.heading_at(stamps)
    dt = np.diff(stamps)
    v_true = np.concatenate([[0.0], np.diff(dist) / dt])
    w_true = np.concatenate([[0.0], np.diff(head) / dt])
    moving = (np.abs(v_true) > 1e-9) | (np.abs(w_true) > 1e-9)
    noise = rng.standard_normal((2, stamps.size))
    v_meas = (1.0 + model.bias_v) * v_true + model.sigma_v * noise[0] * moving
    w_meas = (1.0 + model.bias_w) * w_true + model.drift_w * v_true
    w_meas += model.sigma_w * noise[1] * moving
    return v_true, w_true, v_meas, w_meas


class RoutePlanner:
    """Shortest paths on the free cells of a layout that keep to corridor centres."""

    def __init__(self, layout: Layout) -> None:
        """Build the 8-connected grid graph with clearance-weighted edge costs."""
        self.layout = layout
        free = ~layout.walls
        rows, cols = free.shape
        self.clearance = layout.clearance()
        weight = 1.0 + _CLEARANCE_WEIGHT / np.maximum(self.clearance, 0.25) ** 2
        index = -np.ones(free.shape, dtype=np.int64)
        cells = np.argwhere(free)
        index[free] = np.arange(len(cells))
        self.index = index
        self.cells = cells
        src: list[NDArray[np.int64]] = []
        dst: list[NDArray[np.int64]] = []
        cost: list[FloatArray] = []
        for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
            r0, r1 = max(0, -dr), rows - max(0, dr)
            c0, c1 = max(0, -dc), cols - max(0, dc)
            a = free[r0:r1, c0:c1]
            b = free[r0 + dr : r1 + dr, c0 + dc : c1 + dc]
            ok = a & b
            if dr and dc:  # no cutting corners: both orthogonal neighbours must be free
                ok &= free[r0 + dr : r1 + dr, c0:c1] & free[r0:r1, c0 + dc : c1 + dc]
            rr, cc = np.nonzero(ok)
            rr, cc = rr + r0, cc + c0
            length = math.hypot(dr, dc)
            wa = weight[rr, cc]
            wb = weight[rr + dr, cc + dc]
            src.append(index[rr, cc])
            dst.append(index[rr + dr, cc + dc])
            cost.append(length * 0.5 * (wa + wb))
        n = len(cells)
        s, d, w = np.concatenate(src), np.concatenate(dst), np.concatenate(cost)
        self.graph = sparse.csr_matrix(
            (np.concatenate([w, w]), (np.concatenate([s, d]), np.concatenate([d, s]))), shape=(n, n)
        )
        self._cache: dict[int, tuple[FloatArray, NDArray[np.int32]]] = {}

    def _search(self, start: tuple[int, int]) -> tuple[FloatArray, NDArray[np.int32]]:
        node = int(self.index[start])
        if node not in self._cache:
            dist, pred = dijkstra(self.graph, indices=node, return_predecessors=True)
            self._cache[node] = (dist, pred)
        return self._cache[node]

    def reachable(self, start: tuple[int, int]) -> NDArray[np.bool_]:
        """Boolean grid of the free cells reachable from ``start``."""
        dist, _ = self._search(start)
        out = np.zeros(self.layout.walls.shape, dtype=bool)
        ok = np.isfinite(dist)
        out[self.cells[ok, 0], self.cells[ok, 1]] = True
        return out

    def path(self, start: tuple[int, int], goal: tuple[int, int]) -> NDArray[np.int64]:
        """Cells ``(row, col)`` of the path from ``start`` to ``goal`` (both included)."""
        dist, pred = self._search(start)
        goal_node = int(self.index[goal])
        if goal_node < 0 or not np.isfinite(dist[goal_node]):
            raise ParameterError(f"cell {goal} cannot be reached from {start}")
        nodes = [goal_node]
        start_node = int(self.index[start])
        while nodes[-1] != start_node:
            nodes.append(int(pred[nodes[-1]]))
        return self.cells[np.array(nodes[::-1])]


class _Builder:
    """Accumulates trajectory samples piece by piece."""

    def __init__(self, x: float, y: float, heading: float) -> None:
        self.t: list[FloatArray] = [np.zeros(1)]
        self.xy: list[FloatArray] = [np.array([[x, y]])]
        self.th: list[FloatArray] = [np.array([heading])]
        self.now = 0.0
        self.x, self.y, self.heading = x, y, heading

    def append(self, dt: FloatArray, xy: FloatArray, th: FloatArray) -> None:
        """Append samples at times ``now + dt`` (``dt`` > 0, increasing)."""
        if dt.size == 0:
            return
        self.t.append(self.now + dt)
        self.xy.append(xy)
        self.th.append(th)
        self.now = float(self.now + dt[-1])
        self.x, self.y = float(xy[-1, 0]), float(xy[-1, 1])
        self.heading = float(th[-1])

    def pause(self, duration: float) -> None:
        """Stand still."""
        if duration > 0:
            self.append(
                np.array([duration]), np.array([[self.x, self.y]]), np.array([self.heading])
            )

    def turn_to(self, target: float, max_rate: float, accel: float = 6.0) -> None:
        """Turn on the spot to the (unwrapped) heading ``target`` with a trapezoidal profile."""
        delta = target - self.heading
        if abs(delta) < 1e-9:
            return
        angle = abs(delta)
        t_acc = max_rate / accel
        if angle < max_rate * t_acc:  # triangular profile
            t_acc = math.sqrt(angle / accel)
            t_total = 2 * t_acc
            peak = accel * t_acc
        else:
            peak = max_rate
            t_total = 2 * t_acc + (angle - max_rate * t_acc) / max_rate
        n = max(2, int(math.ceil(t_total / _TURN_DT)))
        tt = np.linspace(0.0, t_total, n + 1)[1:]
        ramp_up = np.minimum(tt, t_acc)
        ramp_dn = np.clip(tt - (t_total - t_acc), 0.0, t_acc)
        middle = np.clip(tt - t_acc, 0.0, max(0.0, t_total - 2 * t_acc))
        swept = 0.5 * accel * ramp_up**2 + peak * middle
        swept += peak * ramp_dn - 0.5 * accel * ramp_dn**2
        swept = swept * (angle / swept[-1])
        th = self.heading + math.copysign(1.0, delta) * swept
        xy = np.repeat([[self.x, self.y]], n, axis=0)
        self.append(tt, xy, th)

    def drive(self, path: FloatArray, params: MotionParams, rng: np.random.Generator) -> None:
        """Drive along a smooth path (first point = current position), from rest to rest."""
        seg = np.diff(path, axis=0)
        s = np.concatenate([[0.0], np.cumsum(np.hypot(seg[:, 0], seg[:, 1]))])
        if s[-1] < 1e-6:
            return
        n = max(2, int(math.ceil(s[-1] / _DS)) + 1)
        su = np.linspace(0.0, s[-1], n)
        px = np.interp(su, s, path[:, 0])
        py = np.interp(su, s, path[:, 1])
        dx, dy = np.gradient(px), np.gradient(py)
        th = np.unwrap(np.arctan2(dy, dx))
        th += self.heading - th[0] + _wrap(th[0] - self.heading)  # continue the unwrapping
        self.turn_to(float(th[0]), params.max_turn_rate)
        curv = np.abs(np.gradient(th, su))
        curv = gaussian_filter1d(curv, 4.0, mode="nearest")
        lam1, lam2 = rng.uniform(1.5, 3.0), rng.uniform(0.5, 1.0)
        ph1, ph2 = rng.uniform(0.0, 2 * np.pi, 2)
        wobble = 0.6 * np.sin(2 * np.pi * su / lam1 + ph1) + 0.4 * np.sin(
            2 * np.pi * su / lam2 + ph2
        )
        cruise = params.speed * np.clip(1.0 + 0.25 * wobble, 0.5, 1.5)
        with np.errstate(divide="ignore"):
            limit = np.minimum(
                params.max_turn_rate / curv, np.sqrt(params.max_lateral_accel / curv)
            )
        v = np.minimum(cruise, limit)
        v[0] = v[-1] = 0.0
        ds = su[1] - su[0]
        two_a_ds = 2.0 * params.max_accel * ds
        for i in range(1, n):  # acceleration limit
            v[i] = min(v[i], math.sqrt(v[i - 1] ** 2 + two_a_ds))
        for i in range(n - 2, -1, -1):  # braking limit
            v[i] = min(v[i], math.sqrt(v[i + 1] ** 2 + two_a_ds))
        dt = 2.0 * ds / np.maximum(v[:-1] + v[1:], 1e-3)
        tt = np.cumsum(dt)
        self.append(tt, np.stack([px[1:], py[1:]], axis=1), th[1:])

    def build(self, lap_times: list[float], waypoint_times: list[tuple[str, float]]) -> Trajectory:
        """The finished trajectory."""
        t = np.concatenate(self.t)
        xy = np.concatenate(self.xy)
        th = np.concatenate(self.th)
        seg = np.diff(xy, axis=0)
        dist = np.concatenate([[0.0], np.cumsum(np.hypot(seg[:, 0], seg[:, 1]))])
        return Trajectory(t, xy, th, dist, tuple(lap_times), tuple(waypoint_times))


def _wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


def _smooth_path(points: FloatArray) -> FloatArray:
    """Round the corners of a polyline of cell centres; the endpoints stay where they are."""
    seg = np.diff(points, axis=0)
    keep = np.concatenate([[True], np.hypot(seg[:, 0], seg[:, 1]) > 1e-9])
    points = points[keep]
    if len(points) < 3:
        return points
    seg = np.diff(points, axis=0)
    s = np.concatenate([[0.0], np.cumsum(np.hypot(seg[:, 0], seg[:, 1]))])
    n = max(3, int(math.ceil(s[-1] / _DS)) + 1)
    su = np.linspace(0.0, s[-1], n)
    p = np.stack([np.interp(su, s, points[:, 0]), np.interp(su, s, points[:, 1])], axis=1)
    sm = gaussian_filter1d(p, _SMOOTH_SIGMA / (su[1] - su[0]), axis=0, mode="nearest")
    # Blend the (small) endpoint offsets out smoothly so the path starts and ends exactly.
    reach = min(3 * _SMOOTH_SIGMA, 0.5 * s[-1])
    w_start = np.clip(1.0 - su / reach, 0.0, 1.0)[:, None]
    w_end = np.clip(1.0 - (su[-1] - su) / reach, 0.0, 1.0)[:, None]
    w_start, w_end = _smoothstep(w_start), _smoothstep(w_end)
    return sm + w_start * (p[0] - sm[0]) + w_end * (p[-1] - sm[-1])


def _smoothstep(x: FloatArray) -> FloatArray:
    return x * x * (3.0 - 2.0 * x)


def _turn_angle(incoming: FloatArray, outgoing: FloatArray) -> float:
    """Absolute angle (rad) between the last direction of one path and the first of the next."""
    if len(incoming) < 2 or len(outgoing) < 2:
        return 0.0
    a = incoming[-1] - incoming[max(0, len(incoming) - 4)]
    b = outgoing[min(len(outgoing) - 1, 3)] - outgoing[0]
    ang = math.atan2(a[0] * b[1] - a[1] * b[0], a[0] * b[0] + a[1] * b[1])
    return abs(ang)


def simulate_route(layout: Layout, params: MotionParams, rng: np.random.Generator) -> Trajectory:
    """Simulate ``params.laps`` tours of the layout's waypoints (see the module docstring)."""
    planner = RoutePlanner(layout)
    letters = list(layout.waypoints)
    home = layout.waypoints[letters[0]]
    reachable = planner.reachable(home)
    clear = planner.clearance
    ridge = clear >= ndimage.maximum_filter(clear, size=3) - 1e-9
    centre_cells = np.argwhere(reachable & ridge)

    # Targets: (letter or None for a detour, cell).
    legs: list[tuple[str | None, tuple[int, int]]] = []
    lap_ends: list[int] = []
    current = home
    for _ in range(params.laps):
        for letter in [*letters[1:], letters[0]]:
            goal = layout.waypoints[letter]
            if rng.random() < params.detour_probability:
                here = np.array(current)
                d = np.hypot(*(centre_cells - here).T) * layout.cell
                near = centre_cells[(d > 0.4) & (d < 1.2)]
                if len(near):
                    detour = near[rng.integers(len(near))]
                    legs.append((None, (int(detour[0]), int(detour[1]))))
            legs.append((letter, goal))
            current = goal
        lap_ends.append(len(legs) - 1)

    # Group legs into continuous drives separated by stops.
    hx, hy = layout.cell_center(*home)
    first = planner.path(home, legs[0][1])
    p0 = layout.cell_centers(first)
    heading0 = math.atan2(p0[min(3, len(p0) - 1), 1] - hy, p0[min(3, len(p0) - 1), 0] - hx)
    builder = _Builder(hx, hy, heading0)
    lap_times: list[float] = [0.0]
    waypoint_times: list[tuple[str, float]] = [(letters[0], 0.0)]
    current = home
    pending: list[FloatArray] = []  # cell-centre polylines of the current drive
    pending_marks: list[tuple[str | None, int]] = []  # (letter, leg index) reached at drive end
    for i, (letter, goal) in enumerate(legs):
        pts = layout.cell_centers(planner.path(current, goal))
        pending.append(pts if not pending else pts[1:])
        pending_marks.append((letter, i))
        current = goal
        nxt = legs[i + 1][1] if i + 1 < len(legs) else None
        pause = letter is not None and rng.random() < params.waypoint_pause_probability
        stop = pause or letter is None or nxt is None
        if not stop and nxt is not None:
            following = layout.cell_centers(planner.path(goal, nxt))
            stop = _turn_angle(np.concatenate(pending), following) > math.radians(100)
        if stop:
            _drive_with_pauses(builder, np.concatenate(pending), params, rng)
            for mark_letter, leg_index in pending_marks:
                if mark_letter is not None:
                    waypoint_times.append((mark_letter, builder.now))
                if leg_index in lap_ends:
                    lap_times.append(builder.now)
            if pause:
                _pause_here(builder, params, rng, long=True)
            pending, pending_marks = [], []
    return builder.build(lap_times, waypoint_times)


def _drive_with_pauses(
    builder: _Builder, cells_xy: FloatArray, params: MotionParams, rng: np.random.Generator
) -> None:
    """Drive a smoothed polyline, splitting it at random places for short pauses."""
    path = _smooth_path(cells_xy)
    seg = np.diff(path, axis=0)
    s = np.concatenate([[0.0], np.cumsum(np.hypot(seg[:, 0], seg[:, 1]))])
    n_pauses = rng.poisson(params.pauses_per_metre * s[-1])
    cuts = np.sort(rng.uniform(0.3, max(0.3, s[-1] - 0.3), n_pauses)) if s[-1] > 0.8 else []
    bounds = [0.0, *[float(c) for c in cuts], float(s[-1])]
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        if b - a < 0.05:
            continue
        inside = (s > a) & (s < b)
        pa = np.array([[np.interp(a, s, path[:, 0]), np.interp(a, s, path[:, 1])]])
        pb = np.array([[np.interp(b, s, path[:, 0]), np.interp(b, s, path[:, 1])]])
        part = np.concatenate([pa, path[inside], pb])
        part[0] = (builder.x, builder.y)
        builder.drive(part, params, rng)
        if b < s[-1]:
            _pause_here(builder, params, rng, long=False)


def _pause_here(
    builder: _Builder, params: MotionParams, rng: np.random.Generator, long: bool
) -> None:
    """A pause, sometimes with a look to one side and back."""
    builder.pause(float(rng.uniform(0.8, 3.0) if long else rng.uniform(0.3, 1.5)))
    if rng.random() < params.look_around_probability:
        heading = builder.heading
        aside = float(rng.uniform(0.3, 0.8)) * (1 if rng.random() < 0.5 else -1)
        builder.turn_to(heading + aside, params.max_turn_rate * 0.7)
        builder.pause(float(rng.uniform(0.3, 1.0)))
        builder.turn_to(heading, params.max_turn_rate * 0.7)
