"""The SLAM front end: camera frames and odometry in, cognitive-map events out.

In OpenRatSLAM's order (``pc_update_per_odometry = 1``, the default): each odometry message that
arrived before the frame updates the pose cells (attractor dynamics, then path integration) and
asks ``get_action``, which acts only at the first message after a view; then the local view cells
match the frame's image (or store a new template) and the view cell injects energy. So a frame's
action is decided at the first odometry message after it, as OpenRatSLAM's ROS nodes do when
fed a bag, and its events come out with the next frame (none after the last frame). With
``pc_update_per_odometry = 0`` (cogmap's former order): the view, one pose-cell update with all
the frame's odometry, then ``get_action`` at once. The action becomes events of
:mod:`cogmap_core.events`:

- ``CREATE_NODE`` -> :class:`~cogmap_core.events.CreateVertex` (the next experience id);
- ``CREATE_EDGE`` -> :class:`~cogmap_core.events.LinkToVertex` then
  :class:`~cogmap_core.events.SetCurrentVertex` to the same target (as OpenRatSLAM's experience
  map does: create the link, then set the experience), both with the view's relative angle;
- ``SET_NODE`` -> :class:`~cogmap_core.events.SetCurrentVertex`.

Every frame first yields an :class:`~cogmap_core.events.Odometry` event for its motion (in
OpenRatSLAM's order: for the motion up to the action, and another for the rest after it). Nothing
depends on wall-clock time; ground truth in the frames is never read.
"""

from __future__ import annotations

import math
from dataclasses import asdict
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cogmap_core.errors import InputFileError
from cogmap_core.events import CreateVertex, LinkToVertex, MapEvent, Odometry, SetCurrentVertex
from cogmap_core.frames import Frame
from cogmap_core.frontend.config import FrontEndConfig
from cogmap_core.frontend.local_view import LocalViewCells, ViewMatch
from cogmap_core.frontend.pose_cells import Action, ActionKind, PoseCellExperiences


class FrontEnd:
    """Local view cells + pose cell network producing the cognitive map's event stream."""

    def __init__(self, config: FrontEndConfig | None = None) -> None:
        """Create a front end with no templates and no experiences (defaults: iRat config)."""
        self.config = config if config is not None else FrontEndConfig()
        self.local_view = LocalViewCells(self.config)
        self.pose_cells = PoseCellExperiences(self.config)
        self.last_view: ViewMatch | None = None
        self.frames = 0
        self._last_time = -math.inf
        #: When a list: each action taken is appended as ``(frame, action, peak, experiences)``
        #: with ``frame`` the index of the view it was decided for (benchmarks compare these).
        self.decisions: list[tuple[int, Action, tuple[float, float, float], int]] | None = None

    def process(self, frame: Frame) -> list[MapEvent]:
        """Process one frame; return its events (``Odometry`` first), all at ``frame.time``."""
        time = float(frame.time)
        if not math.isfinite(time) or time < self._last_time:
            raise InputFileError(
                f"frame {frame.index}: time {frame.time!r} is not finite or goes backwards "
                f"(previous {self._last_time})"
            )
        translation = float(frame.translation)
        rotation = float(frame.rotation)
        if not (math.isfinite(translation) and math.isfinite(rotation)):
            raise InputFileError(
                f"frame {frame.index}: odometry is not finite "
                f"(translation {frame.translation!r}, rotation {frame.rotation!r})"
            )
        self._last_time = time
        if self.config.pc_update_per_odometry:
            return self._process_per_odometry(frame, time, translation, rotation)
        hint = self.last_view.template_id if self.last_view is not None else None
        view = self.local_view.observe(frame.image, hint)
        self.last_view = view
        pc = self.pose_cells
        pc.on_view_template(view.template_id, view.relative_rad)
        pc.on_odo(translation, rotation)
        action = pc.get_action()
        self.frames += 1
        events: list[MapEvent] = [Odometry(time, translation, rotation)]
        self._action_events(action, time, events)
        return events

    def _process_per_odometry(
        self, frame: Frame, time: float, translation: float, rotation: float
    ) -> list[MapEvent]:
        """OpenRatSLAM's order: the odometry messages before the frame, then its view."""
        steps = frame.odometry_steps
        if steps is None:
            pairs: list[tuple[float, float]] = [(translation, rotation)]
        else:
            pairs = [(float(t), float(r)) for t, r in np.asarray(steps, dtype=np.float64)]
            if not all(math.isfinite(t) and math.isfinite(r) for t, r in pairs):
                raise InputFileError(f"frame {frame.index}: an odometry step is not finite")
        pc = self.pose_cells
        events: list[MapEvent] = []
        moved_t = moved_r = 0.0
        for step_t, step_r in pairs:
            pc.on_odo(step_t, step_r)
            moved_t += step_t
            moved_r += step_r
            action = pc.get_action()
            if action.kind is not ActionKind.NO_ACTION:
                events.append(Odometry(time, moved_t, moved_r))
                moved_t = moved_r = 0.0
                self._action_events(action, time, events)
        if moved_t or moved_r or not events:
            events.append(Odometry(time, moved_t, moved_r))
        hint = self.last_view.template_id if self.last_view is not None else None
        view = self.local_view.observe(frame.image, hint)
        self.last_view = view
        pc.on_view_template(view.template_id, view.relative_rad)
        self.frames += 1
        return events

    # ------------------------------------------------------------------ state
    def state_dict(self) -> dict[str, Any]:
        """Everything but the settings, as plain data; :meth:`load_state` restores it.

        ``frames`` processed, ``last_time``, ``last_view`` (a dict, or None), ``local_view``
        (:meth:`LocalViewCells.state_dict`) and ``pose_cells``
        (:meth:`PoseCellExperiences.state_dict`). ``decisions`` (a benchmark's trace) is not
        state.
        """
        last = self.last_view
        return {
            "frames": self.frames,
            "last_time": self._last_time,
            "last_view": None if last is None else asdict(last),
            "local_view": self.local_view.state_dict(),
            "pose_cells": self.pose_cells.state_dict(),
        }

    def load_state(self, state: dict[str, Any]) -> None:
        """Continue from the state :meth:`state_dict` described (a front end with no template).

        Raises:
            StateError: the parts do not fit this front end's settings
                (:meth:`LocalViewCells.load_state`, :meth:`PoseCellExperiences.load_state`).

        """
        self.local_view.load_state(state["local_view"])
        last = state["last_view"]
        self.last_view = None if last is None else ViewMatch(**last)
        self.frames = int(state["frames"])
        self._last_time = float(state["last_time"])
        self.pose_cells.load_state(state["pose_cells"])

    def _action_events(self, action: Action, time: float, events: list[MapEvent]) -> None:
        """Append the map events of a pose-cell action (the module doc's table)."""
        if self.decisions is not None and action.kind is not ActionKind.NO_ACTION:
            pc = self.pose_cells
            self.decisions.append((self.frames - 1, action, pc.network.best, pc.experience_count))
        if action.kind is ActionKind.CREATE_NODE:
            vt = self.pose_cells.experience_view(action.dest)
            events.append(CreateVertex(time, action.dest, vt))
        elif action.kind is ActionKind.CREATE_EDGE:
            events.append(LinkToVertex(time, action.dest, action.relative_rad))
            events.append(SetCurrentVertex(time, action.dest, action.relative_rad))
        elif action.kind is ActionKind.SET_NODE:
            events.append(SetCurrentVertex(time, action.dest, action.relative_rad))

    # ------------------------------------------------------------------ state for a GUI
    @property
    def current_template(self) -> int | None:
        """Id of the view template matched (or created) by the last frame; ``None`` before any."""
        return None if self.last_view is None else self.last_view.template_id

    @property
    def template_count(self) -> int:
        """Number of view templates stored so far."""
        return self.local_view.count

    @property
    def pose_cell_peak(self) -> tuple[float, float, float]:
        """Decoded pose-cell activity peak ``(x, y, theta)`` in cell units."""
        return self.pose_cells.network.best

    @property
    def pose_cell_activity(self) -> NDArray[np.float64]:
        """The pose cell activity, indexed ``[theta, y, x]`` (a read-only view)."""
        view = self.pose_cells.network.cells.view()
        view.flags.writeable = False
        return view

    @property
    def current_vertex(self) -> int | None:
        """Current experience (vertex) id; ``None`` before the first is created."""
        pc = self.pose_cells
        return pc.current_exp if pc.experience_count else None

    @property
    def vertex_count(self) -> int:
        """Number of experiences (vertices) proposed so far."""
        return self.pose_cells.experience_count
