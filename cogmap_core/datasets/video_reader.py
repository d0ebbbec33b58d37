"""Camera-only input from a video file (what OpenCV reads: mp4, avi, ...).

:func:`open_video` checks the file (it opens and holds frames) and reads its frame count and
rate; :meth:`VideoReader.frames` then streams :class:`~cogmap_core.frames.Frame` objects: the
frame as OpenCV gives it (blue, green, red) when the front end averages colour
(:func:`~cogmap_core.frontend.local_view.averages_colour`), else converted to its luma; its
motion from RatSLAM's visual odometry; the ground truth of a ``NAME.groundtruth.txt`` beside it.
Frame times come from ``NAME.times.txt`` beside it, else ``--fps``, else the video's own rate
(:mod:`.camera_common`).

Errors (one line each): a missing file, a file OpenCV cannot read as a video, a video without
frames, no frame times.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from cogmap_core.datasets.camera_common import (
    CameraInfo,
    CameraReader,
    companion,
    frame_times,
    read_ground_truth,
)
from cogmap_core.errors import InputFileError
from cogmap_core.frontend.config import FrontEndConfig
from cogmap_core.frontend.local_view import averages_colour, grey_image

VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".m4v", ".mpg", ".mpeg", ".webm", ".wmv")


class VideoReader(CameraReader):
    """An open video file; iterate :meth:`frames`."""

    format = "video"

    def __init__(
        self, path: Path, fps: float | None = None, frontend: FrontEndConfig | None = None
    ) -> None:
        """Open and check the video; see :func:`open_video`."""
        if not path.is_file():
            raise InputFileError(f"{path}: no such video file")
        capture = cv2.VideoCapture(str(path))
        try:
            ok, first = capture.read() if capture.isOpened() else (False, None)
            if not capture.isOpened():
                raise InputFileError(
                    f"{path}: not a video OpenCV can read (damaged, or an unknown format)"
                )
            if not ok or first is None:
                raise InputFileError(f"{path}: the video has no frames; nothing to map")
            own_fps = float(capture.get(cv2.CAP_PROP_FPS) or 0.0)
            count = int(capture.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
            if count <= 0:  # a stream without an index: count by reading
                count = 1
                while capture.grab():
                    count += 1
        finally:
            capture.release()
        times_file = companion(path, "times.txt")
        times, source = frame_times(
            count, times_file, fps, own_fps, path, f"{times_file.name} beside it"
        )
        gt_path = companion(path, "groundtruth.txt")
        truth = read_ground_truth(gt_path) if gt_path.exists() else None
        super().__init__(path, times, truth, frontend)
        height, width = first.shape[:2]
        self.info = CameraInfo(
            path=path,
            frame_count=count,
            duration=float(times[-1] - times[0]),
            width=width,
            height=height,
            has_ground_truth=truth is not None,
            times_from=source,
        )

    def _images(self) -> Iterator[NDArray[np.uint8] | None]:
        colour = averages_colour(self.frontend)
        capture = cv2.VideoCapture(str(self.path))
        try:
            while True:
                ok, image = capture.read()
                if not ok or image is None:
                    return
                yield image if colour else grey_image(image)
        finally:
            capture.release()


def open_video(
    path: str | Path, fps: float | None = None, frontend: FrontEndConfig | None = None
) -> VideoReader:
    """Open a video file as a camera-only input.

    Args:
        path: the video (any container and codec OpenCV's FFmpeg reads).
        fps: the frame rate when there is no times file (default: the video's own).
        frontend: the visual odometry's settings (default: the iRat defaults).

    Raises:
        InputFileError: missing, unreadable or empty video; no frame times; a bad times or
            ground-truth file.
        ParameterError: a bad ``fps``.

    """
    return VideoReader(Path(path), fps, frontend)
