"""The event contract between the SLAM front end and the cognitive map.

The front end (local view cells + pose cell network, as in OpenRatSLAM) turns camera frames and
odometry into a time-ordered stream of four kinds of events. The cognitive map consumes them; the
*standard* map is exactly what these events build with nothing declined or removed.

- :class:`Odometry` -- the robot moved: forward ``translation`` (m) then ``rotation`` (rad),
  integrated as OpenRatSLAM's experience map does (rotate first, then translate along the new
  facing).
- :class:`CreateVertex` -- the front end proposes a new vertex (an OpenRatSLAM *experience*) at the
  current dead-reckoned pose, linked to the current vertex by a sequential edge. In the compact map
  the neighborhood field may decline it; the sequential edges are then merged.
- :class:`LinkToVertex` -- a loop closure: link the current vertex to the existing vertex
  ``target``; ``relative_rad`` is the relative angle found by view-template matching.
- :class:`SetCurrentVertex` -- the robot is now at vertex ``target``; odometry accumulates from
  there.

``relative_rad`` is always the robot's heading minus the target vertex's heading (the rotation
view matching found between the current view and the view stored with the target): a link puts
the target at the robot's dead-reckoned position with heading ``facing - relative_rad``, and
setting the current vertex puts the robot at the target's position with heading
``theta_target + relative_rad``.

Vertex ids are the front end's experience ids: ``0, 1, 2, ...`` in creation order. All maps use
these ids, so the same place has the same id in the standard and the compact map; a vertex the
compact map declined or removed is an *alias* of the vertex that absorbed it.

Timestamps are seconds of data time (never wall-clock time) and must not decrease.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class Odometry:
    """Motion since the previous odometry event: rotate by ``rotation``, then go ``translation``."""

    time: float
    translation: float
    rotation: float


@dataclass(frozen=True, slots=True)
class CreateVertex:
    """Propose vertex ``vertex`` (the next experience id) at the current dead-reckoned pose."""

    time: float
    vertex: int
    view_template: int


@dataclass(frozen=True, slots=True)
class LinkToVertex:
    """Loop closure: an edge from the current vertex to the existing vertex ``target``."""

    time: float
    target: int
    relative_rad: float = 0.0


@dataclass(frozen=True, slots=True)
class SetCurrentVertex:
    """Make the existing vertex ``target`` the current one (odometry accumulates from it)."""

    time: float
    target: int
    relative_rad: float = 0.0


MapEvent = Odometry | CreateVertex | LinkToVertex | SetCurrentVertex
"""Any event the cognitive map accepts."""
