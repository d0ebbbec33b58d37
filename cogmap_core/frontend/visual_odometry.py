"""RatSLAM's visual odometry: speed and turn rate from the camera alone.

As OpenRatSLAM's ``VisualOdometry`` (``visual_odometry.cpp``), per frame:

1. two image strips (``vtrans_image_*`` and ``vrot_image_*``, given in reference pixels like the
   template crop) become intensity profiles: each column's mean, divided by 255 (a colour
   image's in OpenRatSLAM's arithmetic: the column's sum of blue, green and red, divided by
   ``255 * 3`` and by its rows, as its ``bgr8`` branch; with ``vt_whole_crop = 1`` its luma);
2. each profile is compared with the previous frame's at shifts of 0 to 39 columns either way:
   the mean absolute difference over the overlapping columns, the smallest winning (a strict
   ``<`` scan: first the current profile against the previous shifted left, then right);
3. the rotation strip's best shift ``s`` is a turn rate ``s * camera_fov_deg / width * hz``
   (degrees per second, ``width`` the whole image's; a positive shift, the scene moving right,
   turns counter-clockwise); the speed strip's smallest difference times ``vtrans_scaling`` is
   the speed (m/s), at most ``vtrans_max``.

The rates are integrated over each frame's interval, as OpenRatSLAM's pose cells do with the
odometry message it publishes per frame. With ``camera_hz = 0`` the frame's own interval is the
camera's period, so a shift is a turn of ``s * camera_fov_deg / width`` whatever the rate. The
first frame has nothing to compare with: no motion (OpenRatSLAM's pose cells only start their
clock at the first message).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator
from dataclasses import replace

import cv2
import numpy as np
from numpy.typing import NDArray

from cogmap_core.errors import InputFileError
from cogmap_core.frames import Frame
from cogmap_core.frontend.config import FrontEndConfig
from cogmap_core.frontend.local_view import averages_colour, grey_image

SHIFTS = 40
"""Columns a profile is shifted by at most, each way (OpenRatSLAM's ``slen``)."""

_Strip = tuple[slice, slice]  # (rows, columns) of the image


class VisualOdometry:
    """Turns consecutive camera images into ``(translation m, rotation rad)`` per frame."""

    def __init__(self, config: FrontEndConfig | None = None) -> None:
        """No previous frame yet."""
        self.config = config if config is not None else FrontEndConfig()
        self._previous: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None
        self._strips: dict[tuple[int, ...], tuple[_Strip, _Strip]] = {}

    def _strips_for(self, shape: tuple[int, ...]) -> tuple[_Strip, _Strip]:
        strips = self._strips.get(shape)
        if strips is None:
            c = self.config
            sx = shape[1] / c.reference_image_width
            sy = shape[0] / c.reference_image_height

            def strip(name: str) -> _Strip:
                x0 = round(getattr(c, f"{name}_image_x_min") * sx)
                x1 = round(getattr(c, f"{name}_image_x_max") * sx)
                y0 = round(getattr(c, f"{name}_image_y_min") * sy)
                y1 = round(getattr(c, f"{name}_image_y_max") * sy)
                if x1 - x0 <= SHIFTS or y1 <= y0:
                    raise InputFileError(
                        f"camera images of {shape[1]}x{shape[0]} px are too small for visual "
                        f"odometry: its {name} strip is {x1 - x0}x{y1 - y0} px; it needs more "
                        f"than {SHIFTS} columns"
                    )
                return slice(y0, y1), slice(x0, x1)

            strips = self._strips[shape] = (strip("vtrans"), strip("vrot"))
        return strips

    def profiles(self, image: NDArray[np.uint8]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The speed and rotation strips' column profiles (means in [0, 1]).

        A colour image ``(h, w, 3)`` sums blue, green and red (module doc).
        """
        if image.ndim == 3 and not averages_colour(self.config):
            image = grey_image(image)
        out = []
        strips = self._strips_for(image.shape[:2])
        for rows, cols in strips:
            strip = image[rows, cols]
            if strip.ndim == 3:
                height, width = strip.shape[:2]
                flat = np.ascontiguousarray(strip).reshape(height, width * 3)
                per_byte = cv2.reduce(flat, 0, cv2.REDUCE_SUM, dtype=cv2.CV_32S)
                sums = per_byte.reshape(width, 3).sum(axis=1, dtype=np.int64)
                out.append(sums / 765.0 / height)
            else:
                sums = strip.sum(axis=0, dtype=np.int64)
                out.append(sums / 255.0 / strip.shape[0])
            if strips[0] == strips[1]:  # one strip for both: one profile
                return out[0], out[0]
        return out[0], out[1]

    def step(self, image: NDArray[np.uint8], dt: float) -> tuple[float, float]:
        """Motion since the previous image, ``dt`` seconds ago: (translation m, rotation rad)."""
        vtrans, vrot = self.profiles(image)
        previous = self._previous
        self._previous = (vtrans, vrot)
        if previous is None or dt <= 0.0:
            return 0.0, 0.0
        difference, shift = best_shift(vtrans, previous[0])
        if vrot is not vtrans:  # (one strip for both: the same search answers both)
            _, shift = best_shift(vrot, previous[1])
        c = self.config
        speed = min(difference * c.vtrans_scaling, c.vtrans_max)
        turn = shift * c.camera_fov_deg / image.shape[1] * math.pi / 180.0  # per frame
        rotation = turn * c.camera_hz * dt if c.camera_hz > 0 else turn
        return speed * dt, rotation


def best_shift(data: NDArray[np.float64], old: NDArray[np.float64]) -> tuple[float, int]:
    """OpenRatSLAM's ``visual_odo``: the smallest mean absolute difference and its shift.

    Shifts ``-39 .. 0`` compare ``data[k]`` with ``old[k + s]``, then ``0 .. 39`` compare
    ``data[k + s]`` with ``old[k]``; the first smallest wins (so 0 counts as ``-0``).
    """
    n = len(data)
    mask, counts = _overlap(n)
    padded = np.zeros((2, n + SHIFTS))
    padded[0, :n] = old
    padded[1, :n] = data
    # rows o: old[k + o] and data[k + o] (overlapping windows of the zero-padded profiles)
    step = padded.strides[1]
    old_shifted = np.lib.stride_tricks.as_strided(padded[0], (SHIFTS, n), (step, step))
    data_shifted = np.lib.stride_tricks.as_strided(padded[1], (SHIFTS, n), (step, step))
    both = np.empty((2 * SHIFTS, n))
    np.subtract(data, old_shifted, out=both[:SHIFTS])
    np.subtract(data_shifted, old, out=both[SHIFTS:])
    np.abs(both, out=both)
    both *= mask  # only the overlapping k < n - o
    means = both.sum(axis=1) / counts
    best = int(np.argmin(means))
    shift = -best if best < SHIFTS else best - SHIFTS
    return float(means[best]), shift


_OVERLAPS: dict[int, tuple[NDArray[np.float64], NDArray[np.float64]]] = {}


def _overlap(n: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``(2 SHIFTS, n)`` 0/1 mask of the compared columns per shift, and their counts."""
    cached = _OVERLAPS.get(n)
    if cached is None:
        offsets = np.arange(SHIFTS)
        mask = (np.arange(n)[None, :] < n - offsets[:, None]).astype(np.float64)
        counts = (n - offsets).astype(np.float64)
        cached = _OVERLAPS[n] = (np.vstack([mask, mask]), np.concatenate([counts, counts]))
    return cached


def with_visual_odometry(
    frames: Iterable[Frame], config: FrontEndConfig | None = None
) -> Iterator[Frame]:
    """The frames with their odometry replaced by the camera's (one step per frame)."""
    vo = VisualOdometry(config)
    last_time: float | None = None
    for frame in frames:
        dt = 0.0 if last_time is None else frame.time - last_time
        last_time = frame.time
        translation, rotation = vo.step(frame.image, dt)
        yield replace(
            frame,
            translation=translation,
            rotation=rotation,
            odometry_steps=np.array([[translation, rotation]]) if dt > 0 else np.zeros((0, 2)),
        )
