"""What the camera-only readers share: frame times, ground truth, counters, visual odometry.

A camera-only input (a video file, :mod:`.video_reader`, or a folder of images,
:mod:`.image_folder`) has no wheel odometry: each frame's motion comes from the camera as
RatSLAM's visual odometry computes it (:mod:`cogmap_core.frontend.visual_odometry`). Beside it
may lie (``NAME`` = the video's name without its suffix, or the folder's name; inside a folder
the files may also be named without the prefix):

- ``NAME.times.txt`` (a folder: ``times.txt``): one time (s) per frame, in frame order, not
  decreasing; else the frames are ``1 / fps`` apart (``--fps``, or the video's own rate);
- ``NAME.groundtruth.txt`` (a folder: ``groundtruth.txt``): lines ``time x y theta`` (s, m, m,
  rad; ``#`` comments), the true poses, interpolated at the frame times for evaluation;
- ``NAME.frontend.json``: front-end settings (:mod:`cogmap_core.datasets.profile`), e.g. the
  camera's field of view and the visual odometry's scaling.

Bad input is one line (:class:`~cogmap_core.errors.InputFileError`): no frames, no frame times,
a times file that does not fit the frames, an unreadable ground-truth file.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from cogmap_core.errors import InputFileError, ParameterError
from cogmap_core.frames import Frame
from cogmap_core.frontend.config import FrontEndConfig
from cogmap_core.frontend.visual_odometry import with_visual_odometry
from cogmap_core.input_reader import InputReader

CAMERA_ONLY_MAP_CHANGES: dict[str, float] = {
    # Visual odometry drifts far more than wheel odometry (1.5 m of dead-reckoning ATE on the
    # default layout): a true link arrives tens of centimetres off, and the odometry model
    # (edge_noise, wheel odometry's) cannot bend that far at low cost, so at the bags' 3 link
    # sigmas (9 cm) the robust loop model rejected true links: ATE 0.80 m instead of 0.22 m on the
    # default layout, 0.89 m instead of 0.22 m on the figure eight (5 sigmas: 0.71 / 0.69 m;
    # 10: 0.22 / 0.33 m). Camera-only inputs judge loop closures past a metre (33.3 link
    # sigmas), as every map did before the scale was read in link sigmas: 0.215 / 0.221 m.
    "loop_scale": 33.3,
}
"""Map parameters of camera-only inputs (videos, image folders) that differ from a bag's."""

GT_GAP = 1.0
"""Ground truth is interpolated between two poses at most this far apart (s), as for bags."""
GT_HOLD = 0.25
"""Else the nearest pose within this time (s) is taken, as for bags."""


@dataclass(frozen=True)
class CameraInfo:
    """What a camera-only input holds.

    Attributes:
        path: the video file or image folder.
        frame_count: frames (as the container or the folder counts them).
        duration: time from the first frame to the last (s).
        width, height: image size (px).
        has_ground_truth: a ground-truth file came with it.
        times_from: where the frame times come from (``times file``, ``--fps``, ``the video``).

    """

    path: Path
    frame_count: int
    duration: float
    width: int
    height: int
    has_ground_truth: bool
    times_from: str


@dataclass
class CameraCounters:
    """Counts of one pass over a camera-only input (``frames`` yielded, problems skipped)."""

    frames: int = 0
    undecodable_images: int = 0
    image_size_changes: int = 0
    first_seen: dict[str, float] = field(default_factory=dict)


_DESCRIPTIONS = {
    "undecodable_images": "image that does not decode skipped",
    "image_size_changes": "image of another size than the first skipped",
}


def read_times(path: Path) -> NDArray[np.float64]:
    """A times file: one finite, non-decreasing time (s) per line (``#`` comments, blanks)."""
    values = []
    for number, line in enumerate(_lines(path), 1):
        text = line.split("#", 1)[0].strip()
        if not text:
            continue
        try:
            value = float(text.split()[0])
        except ValueError:
            raise InputFileError(f"{path}:{number}: {text[:40]!r} is not a time in s") from None
        if not math.isfinite(value) or (values and value < values[-1]):
            raise InputFileError(f"{path}:{number}: time {text[:40]} is not finite or goes back")
        values.append(value)
    if not values:
        raise InputFileError(f"{path}: no frame times in it")
    return np.array(values)


def read_ground_truth(path: Path) -> NDArray[np.float64]:
    """A ground-truth file: rows ``time x y theta`` (s, m, m, rad), time not decreasing."""
    rows: list[tuple[float, float, float, float]] = []
    for number, line in enumerate(_lines(path), 1):
        text = line.split("#", 1)[0].strip()
        if not text:
            continue
        parts = text.replace(",", " ").split()
        try:
            t, x, y, th = (float(v) for v in parts)
        except ValueError:
            raise InputFileError(
                f"{path}:{number}: expected 'time x y theta', got {text[:60]!r}"
            ) from None
        if not all(math.isfinite(v) for v in (t, x, y, th)) or (rows and t < rows[-1][0]):
            raise InputFileError(f"{path}:{number}: a value is not finite or the time goes back")
        rows.append((t, x, y, th))
    if not rows:
        raise InputFileError(f"{path}: no poses in it")
    return np.array(rows)


def _lines(path: Path) -> list[str]:
    try:
        return path.read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError as exc:
        raise InputFileError(f"{path}: cannot read it ({exc.strerror})") from None


def pose_at(truth: NDArray[np.float64], t: float) -> tuple[float, float, float] | None:
    """The true pose at ``t`` (None when there is none near).

    Interpolated between poses at most :data:`GT_GAP` apart, else the nearest within
    :data:`GT_HOLD`.
    """
    times = truth[:, 0]
    k = int(np.searchsorted(times, t, side="right"))
    if k == 0 or k == len(times) or times[k] - times[k - 1] > GT_GAP:
        near = [j for j in (k - 1, k) if 0 <= j < len(times) and abs(times[j] - t) <= GT_HOLD]
        if not near:
            return None
        j = min(near, key=lambda j: abs(times[j] - t))
        return float(truth[j, 1]), float(truth[j, 2]), float(truth[j, 3])
    t0, t1 = times[k - 1], times[k]
    f = 0.0 if t1 == t0 else (t - t0) / (t1 - t0)
    a, b = truth[k - 1], truth[k]
    dth = math.remainder(float(b[3] - a[3]), 2.0 * math.pi)
    th = math.remainder(float(a[3]) + f * dth, 2.0 * math.pi)
    return float(a[1] + f * (b[1] - a[1])), float(a[2] + f * (b[2] - a[2])), th


def frame_times(
    count: int,
    times_file: Path | None,
    fps: float | None,
    own_fps: float,
    what: Path,
    hint: str = "a times file",
) -> tuple[NDArray[np.float64], str]:
    """Each frame's time: from the times file, else ``--fps``, else the input's own rate.

    Raises:
        InputFileError: none of them (no frame times), or a times file of another length.
        ParameterError: ``fps`` not a positive number.

    """
    if fps is not None and not (math.isfinite(fps) and 0 < fps <= 10_000):
        raise ParameterError(f"--fps {fps}: give the camera's rate in frames per second (0-10000)")
    if times_file is not None and times_file.exists():
        times = read_times(times_file)
        if len(times) != count:
            raise InputFileError(
                f"{times_file}: {len(times)} frame times for the {count} frames of {what}; "
                "give one time per frame"
            )
        return times, "times file"
    rate = fps if fps is not None else own_fps
    if not (rate > 0 and math.isfinite(rate)):
        raise InputFileError(f"{what}: no frame times: give the camera's rate (--fps) or {hint}")
    return np.arange(count) / rate, "--fps" if fps is not None else "the video"


class CameraReader(InputReader):
    """Base of the camera-only readers: frames with visual odometry and ground truth.

    Subclasses set :attr:`info` and implement :meth:`_images` (the decoded images in order, grey
    or blue-green-red as :class:`~cogmap_core.frames.Frame` has them, ``None`` for one that does
    not decode).
    """

    info: CameraInfo
    format: str = "camera"

    def __init__(
        self,
        path: Path,
        times: NDArray[np.float64],
        truth: NDArray[np.float64] | None,
        frontend: FrontEndConfig | None,
    ) -> None:
        """Remember the frame times, the ground truth and the visual odometry's settings.

        Frame times count from the first frame; the ground truth is moved by the same amount
        (both files share one clock).
        """
        self.path = path
        start = float(times[0])
        self.times = times - start
        if truth is not None:
            truth = truth.copy()
            truth[:, 0] -= start
        self.truth = truth
        self.frontend = frontend
        self.counters = CameraCounters()
        self.open_warnings: list[str] = []

    def _images(self) -> Iterator[NDArray[np.uint8] | None]:  # pragma: no cover - abstract
        raise NotImplementedError

    @property
    def warnings(self) -> list[str]:
        """One line per kind of problem met in the last pass."""
        c = self.counters
        return self.open_warnings + [
            f"{getattr(c, name)} x {text} (first at {c.first_seen[name]:.2f} s)"
            for name, text in _DESCRIPTIONS.items()
            if getattr(c, name)
        ]

    def description(self) -> dict[str, object]:
        """What the input is, for the report."""
        return {
            "format": self.format,
            "odometry": "visual",
            "frame_times": self.info.times_from,
        }

    def frames(self, start_time: float = 0.0) -> Iterator[Frame]:
        """Frames in order from ``start_time`` (s), their motion from the camera."""
        if not (0.0 <= start_time <= self.info.duration + 1.0):
            raise ParameterError(
                f"start time {start_time} s is outside the input (0-{self.info.duration:.1f} s)"
            )
        return with_visual_odometry(self._decoded(start_time), self.frontend)

    def _decoded(self, start_time: float) -> Iterator[Frame]:
        self.counters = counters = CameraCounters()
        shape: tuple[int, ...] | None = None
        index = 0
        decoded = 0
        for k, image in enumerate(self._images()):
            if k >= len(self.times):
                break
            t = float(self.times[k])
            if image is None:
                counters.undecodable_images += 1
                counters.first_seen.setdefault("undecodable_images", t)
                continue
            decoded += 1
            if shape is None:  # (height, width): grey and colour images may mix
                shape = image.shape[:2]
            elif image.shape[:2] != shape:
                counters.image_size_changes += 1
                counters.first_seen.setdefault("image_size_changes", t)
                continue
            if t < start_time:
                continue
            pose = None if self.truth is None else pose_at(self.truth, t)
            yield Frame(index=index, time=t, image=image, translation=0.0, rotation=0.0,
                        ground_truth=pose)  # fmt: skip
            index += 1
            counters.frames += 1
        if decoded == 0:
            raise InputFileError(
                f"{self.path}: none of its frames could be decoded; nothing to map"
            )


def companion(path: Path, name: str) -> Path:
    """``NAME.<name>`` beside ``path`` (a video's name without its suffix, a folder's name)."""
    stem = path.name if path.is_dir() else path.stem
    return path.with_name(f"{stem}.{name}")
