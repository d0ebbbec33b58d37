"""A tiny driver that writes front-end event streams for map tests, with exact geometry."""

from __future__ import annotations

import math

import numpy as np

from cogmap_core.events import CreateVertex, LinkToVertex, MapEvent, Odometry, SetCurrentVertex
from cogmap_core.geometry import compose


class Script:
    """Drive a robot (exact odometry unless noise is added) and record the events."""

    def __init__(self, dt: float = 0.1) -> None:
        self.events: list[MapEvent] = []
        self.t = 0.0
        self.dt = dt
        self.pose = np.zeros(3)
        self.truth: dict[int, np.ndarray] = {}
        self.next_id = 0

    def move(
        self, d: float = 0.0, rot: float = 0.0, measured: tuple[float, float] | None = None
    ) -> None:
        """Rotate by ``rot`` then translate ``d`` (one odometry event)."""
        self.t += self.dt
        self.pose = compose(self.pose, [0.0, 0.0, rot])
        self.pose = compose(self.pose, [d, 0.0, 0.0])
        md, mr = measured if measured is not None else (d, rot)
        self.events.append(Odometry(self.t, md, mr))

    def create(self) -> int:
        vid = self.next_id
        self.events.append(CreateVertex(self.t, vid, vid))
        self.truth[vid] = self.pose.copy()
        self.next_id += 1
        return vid

    def rel_to(self, vid: int) -> float:
        """Robot heading minus the vertex's true heading."""
        return math.remainder(self.pose[2] - self.truth[vid][2], 2 * math.pi)

    def link(self, vid: int) -> None:
        self.events.append(LinkToVertex(self.t, vid, self.rel_to(vid)))

    def set_current(self, vid: int) -> None:
        self.events.append(SetCurrentVertex(self.t, vid, self.rel_to(vid)))

    def relocalise(self, vid: int, heading_error: float = 0.0) -> None:
        """What the front end emits when it recognises vertex ``vid``: link, then set current."""
        rel = self.rel_to(vid) + heading_error
        self.events.append(LinkToVertex(self.t, vid, rel))
        self.events.append(SetCurrentVertex(self.t, vid, rel))

    def drive(self, d: float, steps: int, rot: float = 0.0) -> None:
        """Drive ``d`` metres in ``steps`` odometry events (turning ``rot`` in total first)."""
        for k in range(steps):
            self.move(d / steps, rot if k == 0 else 0.0)

    def wait(self, seconds: float) -> None:
        """Let data time pass (odometry events without motion)."""
        steps = int(round(seconds / self.dt))
        for _ in range(steps):
            self.move(0.0, 0.0)
