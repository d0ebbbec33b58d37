"""Camera-only datasets: a generated maze run as a video file or a folder of images.

``cogmap make-maze --camera-only`` renders the same run as :func:`generate_maze_bag` but keeps
only the camera: ``OUT.mp4`` / ``OUT.avi`` (any other name: a folder of JPEG images), with the
frame times (``NAME.times.txt``, inside a folder ``times.txt``), the true poses at the overhead
tracker's rate for evaluation (``groundtruth.txt``: ``time x y theta``) and the front-end
profile (``NAME.frontend.json``: :data:`GENERATED_CAMERA_PROFILE`, the rendered camera's visual
odometry settings). Everything is written under temporary names and renamed when complete.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from cogmap_core.datasets.errors import BagError
from cogmap_core.datasets.generator import MazeConfig, ProgressFn, plan_dataset, render_frames
from cogmap_core.datasets.profile import GENERATED_FRONTEND_PROFILE, write_frontend_profile
from cogmap_core.datasets.video_reader import VIDEO_SUFFIXES
from cogmap_core.fileio import partial_name

#: Front-end settings of the generated camera-only datasets: the bags' profile and RatSLAM's
#: visual odometry for the rendered camera. Measured on the default maze (14,446 frames): the
#: best shift of the upper rows' profile follows the true turn (correlation 0.98), and over
#: the run the shifts times 70 deg / 416 columns add up to the true net turn (69.7 deg would
#: match it exactly); the profile differences times 7.6 add up to the distance driven.
GENERATED_CAMERA_PROFILE: dict[str, float] = {
    **GENERATED_FRONTEND_PROFILE,
    # The walls (upper rows) carry the texture; the floor's gradient says little. One strip
    # for both: one profile and one search a frame.
    "vrot_image_y_max": 120,
    "vtrans_image_y_max": 120,
    "camera_fov_deg": 70.0,  # the renderer's camera
    "vtrans_scaling": 7.6,  # m/s per unit of mean profile difference (distance-matched)
    "vtrans_max": 1.0,  # the robot's top speed is well below
}

VIDEO_CODECS = {".mp4": "mp4v", ".avi": "MJPG"}


@dataclass(frozen=True)
class CameraDataset:
    """What :func:`generate_camera_only` wrote.

    Attributes:
        path: the video file or image folder.
        frames: camera frames.
        duration: data duration (s).
        files: every file written (the input, times, ground truth, profile).
        elapsed: wall-clock time (s).

    """

    path: Path
    frames: int
    duration: float
    files: tuple[Path, ...]
    elapsed: float


def generate_camera_only(
    out: str | Path,
    config: MazeConfig | None = None,
    *,
    overwrite: bool = False,
    workers: int | None = None,
    progress: ProgressFn | None = None,
) -> CameraDataset:
    """Render a maze run camera-only into ``out`` (a video by its suffix, else a folder).

    Raises:
        BagError: the output exists (without ``overwrite``) or cannot be written.

    """
    started = time.perf_counter()
    config = config or MazeConfig()
    out = Path(out)
    suffix = out.suffix.lower()
    video = suffix in VIDEO_SUFFIXES
    if video and suffix not in VIDEO_CODECS:
        raise BagError(f"{out}: write a video as {' or '.join(VIDEO_CODECS)}")
    if out.exists() and not overwrite:
        raise BagError(f"{out} already exists; choose another name or overwrite it (--force)")
    if not out.parent.is_dir():
        raise BagError(f"folder {out.parent} does not exist; create it first")
    plan = plan_dataset(config)
    _, images = render_frames(plan, workers=workers, progress=progress)
    stem = out.stem if video else out.name
    times_path = out.with_name(f"{stem}.times.txt") if video else out / "times.txt"
    truth_path = out.with_name(f"{stem}.groundtruth.txt") if video else out / "groundtruth.txt"
    # (a video keeps its suffix: OpenCV picks the container by it)
    tmp = out.with_name(partial_name(out.stem) + (suffix if video else ""))
    try:
        with contextlib.closing(images):
            if video:
                writer = cv2.VideoWriter(
                    str(tmp),
                    cv2.VideoWriter_fourcc(*VIDEO_CODECS[suffix]),
                    float(config.fps),
                    (416, 240),
                    isColor=False,
                )
                if not writer.isOpened():
                    raise BagError(f"cannot write the video {out}: OpenCV has no {suffix} writer")
                try:
                    for jpeg in images:
                        frame = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_GRAYSCALE)
                        writer.write(frame)
                finally:
                    writer.release()
            else:
                tmp.mkdir()
                for j, jpeg in enumerate(images):
                    (tmp / f"frame_{j:06d}.jpg").write_bytes(jpeg)
        times_text = "".join(f"{t:.9f}\n" for t in plan.frame_times)
        truth_text = "# time x y theta (s, m, m, rad): the overhead tracker's poses\n" + "".join(
            f"{t:.9f} {p[0]:.6f} {p[1]:.6f} {p[2]:.6f}\n"
            for t, p in zip(plan.gt_times, plan.gt_poses, strict=True)
        )
        if video:
            _write_atomic(times_path, times_text)
            _write_atomic(truth_path, truth_text)
        else:
            (tmp / "times.txt").write_text(times_text)
            (tmp / "groundtruth.txt").write_text(truth_text)
        if out.exists():
            shutil.rmtree(out) if out.is_dir() else out.unlink()
        os.replace(tmp, out)
    except OSError as exc:
        raise BagError(f"cannot write {out}: {exc.strerror}; check the folder") from None
    finally:
        if tmp.exists():
            shutil.rmtree(tmp) if tmp.is_dir() else tmp.unlink()
    profile = write_frontend_profile(
        out,
        GENERATED_CAMERA_PROFILE,
        note="front-end and visual-odometry settings for cogmap's rendered maze camera "
        "(see cogmap_core/datasets/camera_writer.py)",
    )
    files = (out, times_path, truth_path, profile)
    return CameraDataset(
        path=out,
        frames=len(plan.frame_times),
        duration=float(plan.frame_times[-1] - plan.frame_times[0]),
        files=files,
        elapsed=time.perf_counter() - started,
    )


def _write_atomic(path: Path, text: str) -> None:
    tmp = path.with_name(partial_name(path.name))
    tmp.write_text(text)
    os.replace(tmp, path)
