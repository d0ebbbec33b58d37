"""The frame type that dataset readers yield and the SLAM front end consumes."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True, slots=True)
class Frame:
    """One camera frame with the odometry integrated since the previous frame.

    Attributes:
        index: 0-based position of the frame in the stream (counting only frames yielded).
        time: data time in seconds since the start of the bag (the first message's stamp).
        image: decoded grayscale image, ``uint8`` of shape ``(height, width)``.
        translation: forward distance travelled since the previous frame (m), from odometry
            ``twist.linear.x`` integrated over header-stamp intervals.
        rotation: heading change since the previous frame (rad), from ``twist.angular.z``.
        ground_truth: ``(x, y, theta)`` from ``/overhead/pose`` at this frame's time, or ``None``
            when the bag has no ground truth.

    """

    index: int
    time: float
    image: NDArray[np.uint8]
    translation: float
    rotation: float
    ground_truth: tuple[float, float, float] | None = None
