"""Consistency test before a relocalisation is accepted (robustness to false loop closures).

The paper leaves robustness open ("a robustness method is considered to reject incorrect loop
closure constraints") and relies on the Huber loss of the batch optimisation. That is not enough
for RatSLAM's event stream: a loop closure comes as *link + set current vertex*, and a false one
also makes the robot continue from the wrong vertex, so the next sequential edge is measured from
the wrong place. A robust loss on the loop-closure edge alone cannot absorb that; a few false
relocalisations bend the whole map while the optimiser's cost stays low (the edges agree with each
other, not with the world).

So each map tests a relocalisation before accepting it: the pose the link claims for the robot
(the target vertex's pose, heading plus the link's relative angle) is compared with the robot's
pose in the map (current vertex composed with the odometry since). The difference may be at most

    position:  gate_position + gate_drift_position * L
    heading:   gate_heading  + gate_drift_heading  * L + |rotation in the latest frame|

where ``L`` is the length of the shortest path in the map between the robot and the target
(edges' measured lengths, plus the odometry since the current vertex and the target's offset in
the vertex that stands for it): the drift odometry could have accumulated between the two. A true
loop closure on ground the robot keeps re-localising on is tight (small ``L``) and agrees; the
first closure after a long exploration may disagree by the drift of that exploration (large
``L``); a false one to a look-alike place metres away, or facing the other way, fails. The last
term of the heading tolerance covers timing: odometry arrives at its own rate, so while the robot
spins, the heading of a frame (and of the vertex it created) lags the camera by up to one
odometry period, about a frame's rotation.

One wrong relocalisation that slips through leaves the robot's estimate off, and then every true
one disagrees with it. So refusals are not final: when ``gate_consensus`` refused relocalisations
in a row (no accepted one between them, within ``CONSENSUS_WINDOW`` seconds) agree with each other
on the correction they ask for (the rigid transform from the robot's map pose to the claimed one,
within ``gate_position`` and ``gate_heading``), the map's own estimate is the odd one out and the
latest of them is accepted. False loop closures are isolated or interleaved with true ones, which
reset the streak. A refused
relocalisation is ignored as a whole -- no edge, the current vertex stays and odometry continues
from it -- but still joins the time clustering of loop closures, so every map keeps the same
optimisation schedule. This is a Mahalanobis-style gate with the covariance of odometry drift
approximated by path length; it needs no change to the paper's Huber formulation on Ceres.

Setting ``gate_position`` and ``gate_heading`` to their maximum (1e9) accepts every
relocalisation (the paper's behaviour).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from cogmap_core.config import MapParams
from cogmap_core.geometry import compose_scalar, inverse_scalar, wrap_scalar
from cogmap_core.map_graph import MapGraph

CONSENSUS_WINDOW = 5.0
"""Refusals older than this (s) no longer count towards a consensus."""


@dataclass(frozen=True, slots=True)
class RelocalisationCheck:
    """The outcome of the consistency test of one relocalisation.

    Attributes:
        time: data time of the relocalisation.
        target: the vertex id the front end relocalised on.
        accepted: whether the map follows it.
        position_error: distance between the robot's map pose and the claimed pose (m).
        heading_error: absolute heading difference between them (rad).
        correction: the world-frame rigid transform taking the robot's map pose onto the
            claimed pose.
        by_consensus: accepted because it agreed with a streak of refused ones.

    """

    time: float
    target: int
    accepted: bool
    position_error: float
    heading_error: float
    correction: tuple[float, float, float] = (0.0, 0.0, 0.0)
    by_consensus: bool = False

    def state_dict(self) -> dict[str, Any]:
        """The outcome as plain data (every attribute; ``correction`` as a list)."""
        return {
            "time": self.time,
            "target": self.target,
            "accepted": self.accepted,
            "position_error": self.position_error,
            "heading_error": self.heading_error,
            "correction": list(self.correction),
            "by_consensus": self.by_consensus,
        }

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> RelocalisationCheck:
        """The outcome :meth:`state_dict` described."""
        values = dict(state)
        values["correction"] = tuple(float(v) for v in state["correction"])
        return cls(**values)


@dataclass(frozen=True, slots=True)
class RobotInMap:
    """Where a map has the robot when a relocalisation arrives.

    Attributes:
        current: the live current vertex.
        odometry: the robot's pose in the current vertex's frame.
        travelled: odometry distance driven since the current vertex (m).
        frame_rotation: rotation (rad) of the latest odometry step (the timing term).

    """

    current: int
    odometry: tuple[float, float, float]
    travelled: float
    frame_rotation: float = 0.0


def check_relocalisation(
    graph: MapGraph,
    robot: RobotInMap,
    target: int,
    relative_rad: float,
    time: float,
    params: MapParams,
) -> RelocalisationCheck:
    """Test whether relocalising on vertex id ``target`` agrees with the map (module doc).

    Args:
        graph: the map's graph.
        robot: where the map has the robot.
        target: the vertex id the front end relocalised on (may be an alias).
        relative_rad: robot heading minus the target's heading, from view matching.
        time: data time.
        params: the map parameters (``gate_*``).

    """
    pose = compose_scalar(graph.pose[robot.current].tolist(), robot.odometry)
    vertex, offset = graph.resolve(target)
    place = compose_scalar(graph.pose[vertex].tolist(), offset)
    position_error = math.hypot(pose[0] - place[0], pose[1] - place[1])
    claimed = (place[0], place[1], place[2] + relative_rad)
    heading_error = abs(wrap_scalar(pose[2] - claimed[2]))
    correction = compose_scalar(claimed, inverse_scalar(pose))
    p = params
    heading_tolerance = p.gate_heading + abs(robot.frame_rotation)
    excess = max(
        drift_excess(position_error, p.gate_position, p.gate_drift_position),
        drift_excess(heading_error, heading_tolerance, p.gate_drift_heading),
    )
    if excess <= 0.0:
        return RelocalisationCheck(time, target, True, position_error, heading_error, correction)
    # The errors need a path of at least `excess` metres between robot and target to be drift.
    needed = excess - robot.travelled - math.hypot(offset[0], offset[1])
    accepted = needed <= 0.0 or (
        math.isfinite(needed) and not graph.graph_distance_below(robot.current, vertex, needed)
    )
    return RelocalisationCheck(time, target, accepted, position_error, heading_error, correction)


class RelocalisationGate:
    """The consistency test with its memory of refused relocalisations (module doc)."""

    def __init__(self) -> None:
        """No refusal yet."""
        self.streak: list[RelocalisationCheck] = []
        self.accepted_by_consensus: list[RelocalisationCheck] = []

    def state_dict(self) -> dict[str, Any]:
        """The gate's memory as plain data, what :meth:`load_state` restores.

        ``streak`` (the refusals in a row) and ``accepted_by_consensus``, as lists of
        :meth:`RelocalisationCheck.state_dict` records.
        """
        return {
            "streak": [c.state_dict() for c in self.streak],
            "accepted_by_consensus": [c.state_dict() for c in self.accepted_by_consensus],
        }

    def load_state(self, state: dict[str, Any]) -> None:
        """Hold the streak and the acceptances :meth:`state_dict` described."""
        self.streak = [RelocalisationCheck.from_state(c) for c in state["streak"]]
        self.accepted_by_consensus = [
            RelocalisationCheck.from_state(c) for c in state["accepted_by_consensus"]
        ]

    def check(
        self,
        graph: MapGraph,
        robot: RobotInMap,
        target: int,
        relative_rad: float,
        time: float,
        params: MapParams,
    ) -> RelocalisationCheck:
        """Test one relocalisation (see :func:`check_relocalisation`), then the consensus."""
        result = check_relocalisation(graph, robot, target, relative_rad, time, params)
        if result.accepted:
            self.streak.clear()
            return result
        self.streak = [c for c in self.streak if time - c.time <= CONSENSUS_WINDOW]
        pose = compose_scalar(graph.pose[robot.current].tolist(), robot.odometry)
        agreeing = sum(_agree(c.correction, result.correction, pose, params) for c in self.streak)
        self.streak.append(result)
        if params.gate_consensus >= 1 and agreeing + 1 >= params.gate_consensus:
            self.streak.clear()
            accepted = RelocalisationCheck(
                time,
                target,
                True,
                result.position_error,
                result.heading_error,
                result.correction,
                by_consensus=True,
            )
            self.accepted_by_consensus.append(accepted)
            return accepted
        return result


def _agree(
    a: tuple[float, float, float],
    b: tuple[float, float, float],
    robot: tuple[float, float, float],
    params: MapParams,
) -> bool:
    """Whether two corrections put the robot at the same pose (within the fixed tolerances)."""
    pa, pb = compose_scalar(a, robot), compose_scalar(b, robot)
    return (
        math.hypot(pa[0] - pb[0], pa[1] - pb[1]) <= params.gate_position
        and abs(wrap_scalar(pa[2] - pb[2])) <= params.gate_heading
    )


def drift_excess(error: float, tolerance: float, per_metre: float) -> float:
    """Path length (m) the error needs beyond the fixed tolerance to count as drift."""
    if error <= tolerance:
        return 0.0
    if per_metre <= 0.0:
        return math.inf
    return (error - tolerance) / per_metre
