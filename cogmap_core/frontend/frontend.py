"""The SLAM front end: camera frames and odometry in, cognitive-map events out.

Per frame, in OpenRatSLAM's order: the local view cells match the image (or store a new
template), the view cell injects energy into the pose cells, the odometry moves the pose cell
activity, and the pose cells' ``get_action`` decides the experience-map action. The action becomes
events of :mod:`cogmap_core.events`:

- ``CREATE_NODE`` -> :class:`~cogmap_core.events.CreateVertex` (the next experience id);
- ``CREATE_EDGE`` -> :class:`~cogmap_core.events.LinkToVertex` then
  :class:`~cogmap_core.events.SetCurrentVertex` to the same target (as OpenRatSLAM's experience
  map does: create the link, then set the experience), both with the view's relative angle;
- ``SET_NODE`` -> :class:`~cogmap_core.events.SetCurrentVertex`.

Every frame first yields an :class:`~cogmap_core.events.Odometry` event for its motion. Nothing
depends on wall-clock time; ground truth in the frames is never read.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from cogmap_core.errors import InputFileError
from cogmap_core.events import CreateVertex, LinkToVertex, MapEvent, Odometry, SetCurrentVertex
from cogmap_core.frames import Frame
from cogmap_core.frontend.config import FrontEndConfig
from cogmap_core.frontend.local_view import LocalViewCells, ViewMatch
from cogmap_core.frontend.pose_cells import ActionKind, PoseCellExperiences


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
        hint = self.last_view.template_id if self.last_view is not None else None
        view = self.local_view.observe(frame.image, hint)
        self.last_view = view
        pc = self.pose_cells
        pc.on_view_template(view.template_id, view.relative_rad)
        pc.on_odo(translation, rotation)
        action = pc.get_action()
        self.frames += 1
        events: list[MapEvent] = [Odometry(time, translation, rotation)]
        if action.kind is ActionKind.CREATE_NODE:
            events.append(CreateVertex(time, action.dest, view.template_id))
        elif action.kind is ActionKind.CREATE_EDGE:
            events.append(LinkToVertex(time, action.dest, action.relative_rad))
            events.append(SetCurrentVertex(time, action.dest, action.relative_rad))
        elif action.kind is ActionKind.SET_NODE:
            events.append(SetCurrentVertex(time, action.dest, action.relative_rad))
        return events

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
