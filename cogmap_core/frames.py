"""What sources yield: camera frames for the SLAM front end, or steps with their map events."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from cogmap_core.events import MapEvent


@dataclass(frozen=True, slots=True)
class Frame:
    """One camera frame with the odometry integrated since the previous frame.

    Attributes:
        index: 0-based position of the frame in the stream (counting only frames yielded).
        time: data time in seconds since the start of the bag (the first message's stamp).
        image: the decoded image, ``uint8``: grey ``(height, width)``, or a colour camera's
            ``(height, width, 3)`` (blue, green, red) when the front end's arithmetic averages
            colour as OpenRatSLAM does (:func:`~cogmap_core.frontend.local_view.averages_colour`).
        translation: forward distance travelled since the previous frame (m), from odometry
            ``twist.linear.x`` integrated over header-stamp intervals.
        rotation: heading change since the previous frame (rad), from ``twist.angular.z``.
        ground_truth: ``(x, y, theta)`` from ``/overhead/pose`` at this frame's time, or ``None``
            when the bag has no ground truth.
        odometry_steps: the same motion message by message, ``(k, 2)`` rows of (translation m,
            rotation rad) in arrival order (what OpenRatSLAM's pose cells take one at a time),
            or ``None`` when the source only knows the total (then it is one step).

    """

    index: int
    time: float
    image: NDArray[np.uint8]
    translation: float
    rotation: float
    ground_truth: tuple[float, float, float] | None = None
    odometry_steps: NDArray[np.float64] | None = None


@dataclass(frozen=True, slots=True)
class EventStep:
    """One moment of a recorded log whose map events are already known (no camera front end).

    A log of odometry and place recognition (:mod:`cogmap_core.sources.odometry_log`) needs no
    local view cells or pose cells: it is turned into map events directly, one step per
    odometry sample or place-recognition query. Sessions apply ``events`` as they are.

    Attributes:
        index: 0-based position of the step in the stream.
        time: data time in seconds since the log's first odometry sample.
        events: the map events of this step (time-ordered, all at ``time``).
        ground_truth: ``(x, y, theta)`` at this step's time, or ``None`` without ground truth.
        link_scores: the place-recognition score of each
            :class:`~cogmap_core.events.LinkToVertex` in ``events``, in order.

    """

    index: int
    time: float
    events: tuple[MapEvent, ...]
    ground_truth: tuple[float, float, float] | None = None
    link_scores: tuple[float, ...] = ()
