"""Synthetic iRat-layout bags: a rat-like robot driving laps of an ASCII maze.

:func:`generate_maze_bag` simulates the motion (:mod:`.motion`), renders the camera
(:mod:`.render`, in worker processes for long runs), derives noisy biased wheel odometry and
writes a ROS1 bag in the iRat 2011 Australia layout: JPEG images on
``/irat_red/camera/image/compressed``, ``nav_msgs/Odometry`` on ``/irat_red/odom`` and the true
pose as ``geometry_msgs/PoseStamped`` on ``/overhead/pose``. Everything is deterministic for a
given layout and seed: each frame's sensor noise has its own seed, so serial and parallel
rendering give identical bags.
"""

from __future__ import annotations

import contextlib
import itertools
import math
import multiprocessing
import multiprocessing.connection
import os
import signal
import sys
import threading
import time
import types
from collections import deque
from collections.abc import Callable, Generator, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from cogmap_core.datasets.bag_writer import IratBagWriter
from cogmap_core.datasets.layout import DEFAULT_LAYOUT, Layout, load_layout, parse_layout
from cogmap_core.datasets.motion import (
    MotionParams,
    OdometryModel,
    Trajectory,
    odometry_messages,
    simulate_route,
)
from cogmap_core.datasets.profile import GENERATED_FRONTEND_PROFILE, write_frontend_profile
from cogmap_core.datasets.render import CameraModel, MazeRenderer, encode_jpeg
from cogmap_core.errors import CogmapError, ParameterError

FloatArray = NDArray[np.float64]
ProgressFn = Callable[[int, int], None]

#: Bag start: 28 November 2011, 13:00 AEST, the day the iRat Australia bag was recorded.
START_STAMP_NS = 1_322_449_200 * 1_000_000_000
_CAMERA_OFFSET = 0.0113  # s: camera, odometry and overhead clocks are not in phase
_GROUND_TRUTH_OFFSET = 0.0051
_CHUNK = 24  # frames per rendering task
_MIN_FRAMES_PER_WORKER = 1500
_IN_FLIGHT = 4  # chunks per worker rendered ahead of the writer


@dataclass(frozen=True)
class MazeConfig:
    """Everything that defines a generated dataset (same config, same bag).

    Attributes:
        layout: built-in layout name or layout file.
        cell: cell size (m); ``None`` keeps the layout's own (or automatic) size.
        laps: tours of the waypoints.
        seed: seed of the motion, odometry noise, lighting and sensor noise.
        fps: camera rate (Hz); the iRat's is about 17.5.
        speed: mean cruise speed (m/s).
        odometry_rate: odometry message rate (Hz).
        ground_truth_rate: overhead tracker rate (Hz).
        odometry: noise and bias of the wheel odometry.
        jpeg_quality: JPEG quality (1-100).
        noise_sigma: camera sensor noise (grey levels).
        light_changes: vary the light level over time (slow drifts and a few steps).

    """

    layout: str = DEFAULT_LAYOUT
    cell: float | None = None
    laps: int = 6
    seed: int = 1
    fps: float = 17.5
    speed: float = 0.2
    odometry_rate: float = 20.0
    ground_truth_rate: float = 10.0
    odometry: OdometryModel = field(default_factory=OdometryModel)
    jpeg_quality: int = 80
    noise_sigma: float = 3.0
    light_changes: bool = True

    def __post_init__(self) -> None:
        """Validate ranges (one-line messages with the valid range)."""
        checks = (
            ("fps", self.fps, 1.0, 100.0),
            ("odometry_rate", self.odometry_rate, 1.0, 1000.0),
            ("ground_truth_rate", self.ground_truth_rate, 0.5, 1000.0),
            ("jpeg_quality", self.jpeg_quality, 1, 100),
            ("noise_sigma", self.noise_sigma, 0.0, 50.0),
        )
        for name, value, lo, hi in checks:
            if not (lo <= value <= hi) or not math.isfinite(value):
                raise ParameterError(f"{name} {value} is out of range; use {lo}-{hi}")
        if not (0 <= self.seed < 2**63):
            raise ParameterError(f"seed {self.seed} is out of range; use 0 to 2^63-1")
        MotionParams(speed=self.speed, laps=self.laps)  # validates speed and laps


@dataclass(frozen=True)
class GenerationResult:
    """What :func:`generate_maze_bag` produced.

    Attributes:
        path: the bag.
        layout: the layout used.
        duration: data duration (s).
        frames, odometry_messages, ground_truth_messages: message counts.
        distance: true distance driven (m).
        lap_times: start time of each lap, then the end time (s).
        odometry_drift: ``(position error m, heading error rad)`` of dead reckoning at the end.
        size_bytes: bag size.
        elapsed: wall-clock generation time (s).
        workers: rendering processes used (1 = in-process).
        previews: the preview PNGs written (camera frame, maze map).

    """

    path: Path
    layout: Layout
    duration: float
    frames: int
    odometry_messages: int
    ground_truth_messages: int
    distance: float
    lap_times: tuple[float, ...]
    odometry_drift: tuple[float, float]
    size_bytes: int
    elapsed: float
    workers: int
    previews: tuple[Path, ...] = ()


@dataclass(frozen=True)
class DatasetPlan:
    """The simulated data of a run, before rendering: all times are seconds from the start."""

    layout: Layout
    config: MazeConfig
    trajectory: Trajectory
    frame_times: FloatArray
    frame_poses: FloatArray  # (n, 3), heading wrapped
    frame_light: FloatArray
    odom_times: FloatArray
    odom_v: FloatArray  # measured
    odom_w: FloatArray
    odom_pose: FloatArray  # the robot's own dead reckoning, (n, 3)
    gt_times: FloatArray
    gt_poses: FloatArray


def _wrap(a: FloatArray) -> FloatArray:
    return (a + np.pi) % (2 * np.pi) - np.pi


def light_levels(times: FloatArray, rng: np.random.Generator, enabled: bool = True) -> FloatArray:
    """Global light level over time: slow drifts plus a few smooth steps (lights, clouds)."""
    if not enabled:
        return np.ones_like(times)
    ph = rng.uniform(0, 2 * np.pi, 2)
    base = 1.0 + 0.08 * np.sin(2 * np.pi * times / 173.0 + ph[0])
    base += 0.05 * np.sin(2 * np.pi * times / 61.0 + ph[1])
    end = float(times[-1]) if times.size else 0.0
    knots_t = [0.0]
    knots_v = [1.0]
    t = float(rng.uniform(40.0, 120.0))
    level = 1.0
    while t < end:
        new = float(rng.uniform(0.8, 1.1))
        knots_t += [t - 1.5, t + 1.5]
        knots_v += [level, new]
        level = new
        t += float(rng.uniform(60.0, 200.0))
    steps = np.interp(times, knots_t, knots_v)
    return base * steps


def dead_reckon(v: FloatArray, w: FloatArray, dt: FloatArray, start: Sequence[float]) -> FloatArray:
    """Integrate velocity messages (midpoint heading); returns poses ``(n, 3)``, heading wrapped."""
    dth = w * dt
    th = start[2] + np.cumsum(dth)
    mid = th - 0.5 * dth
    x = start[0] + np.cumsum(v * dt * np.cos(mid))
    y = start[1] + np.cumsum(v * dt * np.sin(mid))
    return np.stack([x, y, _wrap(th)], axis=1)


def plan_dataset(config: MazeConfig, layout: Layout | None = None) -> DatasetPlan:
    """Simulate motion, odometry, ground truth and lighting (everything but the images)."""
    layout = layout or load_layout(config.layout, cell=config.cell)
    seeds = np.random.SeedSequence(config.seed).spawn(4)
    motion_rng, odom_rng, stamp_rng, light_rng = (np.random.default_rng(s) for s in seeds)
    params = MotionParams(speed=config.speed, laps=config.laps)
    trajectory = simulate_route(layout, params, motion_rng)
    end = trajectory.duration

    n_frames = int(math.floor((end - _CAMERA_OFFSET) * config.fps)) + 1
    frame_times = _CAMERA_OFFSET + np.arange(n_frames) / config.fps
    frame_times += stamp_rng.uniform(-0.002, 0.002, n_frames)  # webcam timing jitter
    frame_times = np.clip(frame_times, 0.0, end)
    poses = trajectory.pose_at(frame_times)
    poses[:, 2] = _wrap(poses[:, 2])

    odom_times = np.arange(int(math.floor(end * config.odometry_rate)) + 1) / config.odometry_rate
    _, _, v, w = odometry_messages(trajectory, odom_times, config.odometry, odom_rng)
    dt = np.concatenate([[0.0], np.diff(odom_times)])
    odom_pose = dead_reckon(v, w, dt, (0.0, 0.0, 0.0))

    n_gt = int(math.floor((end - _GROUND_TRUTH_OFFSET) * config.ground_truth_rate)) + 1
    gt_times = _GROUND_TRUTH_OFFSET + np.arange(n_gt) / config.ground_truth_rate
    gt_poses = trajectory.pose_at(gt_times)
    gt_poses[:, 2] = _wrap(gt_poses[:, 2])
    return DatasetPlan(
        layout=layout,
        config=config,
        trajectory=trajectory,
        frame_times=frame_times,
        frame_poses=poses,
        frame_light=light_levels(frame_times, light_rng, config.light_changes),
        odom_times=odom_times,
        odom_v=v,
        odom_w=w,
        odom_pose=odom_pose,
        gt_times=gt_times,
        gt_poses=gt_poses,
    )


class GenerationError(CogmapError):
    """Rendering failed for a reason outside the user's input (a worker process died)."""


# ---------------------------------------------------------------------------- rendering workers
_WORKER: dict[str, object] = {}


def _exit_with_parent() -> None:
    """In a rendering process: exit as soon as the parent process is gone.

    A parent killed with SIGKILL cannot stop its pool, and the workers would wait forever for
    tasks (each holding ~100 MB); a daemon thread watches the parent's sentinel instead.
    """
    parent = multiprocessing.parent_process()
    if parent is None:
        return

    def watch() -> None:
        multiprocessing.connection.wait([parent.sentinel])
        os._exit(1)

    threading.Thread(target=watch, name="cogmap-parent-watch", daemon=True).start()


def _init_worker(
    layout_text: str, name: str, cell: float, camera: CameraModel, settings: tuple[int, float, int]
) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle
    _exit_with_parent()
    layout = parse_layout(layout_text, name=name, cell=cell)
    _WORKER["renderer"] = MazeRenderer(layout, camera)
    _WORKER["settings"] = settings


def _render_chunk(task: tuple[int, FloatArray, FloatArray]) -> list[bytes]:
    start, poses, light = task
    renderer = _WORKER["renderer"]
    seed, noise_sigma, quality = _WORKER["settings"]  # type: ignore[misc]
    assert isinstance(renderer, MazeRenderer)
    return [
        _render_one(renderer, start + i, poses[i], float(light[i]), seed, noise_sigma, quality)
        for i in range(len(poses))
    ]


def _render_one(
    renderer: MazeRenderer,
    index: int,
    pose: FloatArray,
    light: float,
    seed: int,
    noise_sigma: float,
    quality: int,
) -> bytes:
    rng = np.random.default_rng((seed, 0xCA3E7A, index))
    image = renderer.render(float(pose[0]), float(pose[1]), float(pose[2]), light, rng, noise_sigma)
    return encode_jpeg(image, quality)


@contextlib.contextmanager
def _neutral_main() -> Iterator[None]:
    """Hide the ``__main__`` module while worker processes start.

    Spawned workers would otherwise re-run the caller's main script (or fail on ``<stdin>``);
    they only need this module to unpickle their tasks.
    """
    real = sys.modules.get("__main__")
    sys.modules["__main__"] = types.ModuleType("__main__")
    try:
        yield
    finally:
        if real is not None:
            sys.modules["__main__"] = real


def render_frames(
    plan: DatasetPlan,
    workers: int | None = None,
    progress: ProgressFn | None = None,
    camera: CameraModel | None = None,
    min_frames_per_worker: int = _MIN_FRAMES_PER_WORKER,
) -> tuple[int, Generator[bytes, None, None]]:
    """Start rendering the plan's frames; returns ``(workers used, iterator of JPEG bytes)``.

    Uses up to ``workers`` processes (default: all CPUs), at most one per
    ``min_frames_per_worker`` frames (starting a process costs about a second), else renders in
    this process. The iterator yields frames in order; the output does not depend on the number
    of processes.
    """
    config = plan.config
    n = len(plan.frame_times)
    camera = camera or CameraModel()
    settings = (config.seed, config.noise_sigma, config.jpeg_quality)
    wanted = workers if workers is not None else (os.cpu_count() or 1)
    if wanted < 1:
        raise ParameterError(f"workers {wanted} must be at least 1")
    used = max(1, min(wanted, n // max(1, min_frames_per_worker)))
    tasks = [
        (s, plan.frame_poses[s : s + _CHUNK], plan.frame_light[s : s + _CHUNK])
        for s in range(0, n, _CHUNK)
    ]

    def generate() -> Generator[bytes, None, None]:
        done = 0
        if used == 1:
            renderer = MazeRenderer(plan.layout, camera)
            for s, poses, light in tasks:
                for i in range(len(poses)):
                    yield _render_one(renderer, s + i, poses[i], float(light[i]), *settings)
                done += len(poses)
                if progress:
                    progress(done, n)
            return
        ctx = multiprocessing.get_context("spawn")
        init = (plan.layout.text, plan.layout.name, plan.layout.cell, camera, settings)
        queue = iter(tasks)
        # At most _IN_FLIGHT chunks per worker are rendered ahead of the writer, so memory stays
        # flat however long the run and however slow the disk.
        with _neutral_main():  # workers start during construction and the first submissions
            pool = ProcessPoolExecutor(
                used, mp_context=ctx, initializer=_init_worker, initargs=init
            )
            ahead = deque(
                pool.submit(_render_chunk, task)
                for task in itertools.islice(queue, _IN_FLIGHT * used)
            )
        try:
            while ahead:
                chunk = ahead.popleft().result()
                task = next(queue, None)
                if task is not None:
                    ahead.append(pool.submit(_render_chunk, task))
                yield from chunk
                done += len(chunk)
                if progress:
                    progress(done, n)
        except BrokenProcessPool:
            raise GenerationError(
                "a rendering process died (out of memory?); retry with fewer workers"
            ) from None
        finally:
            pool.shutdown(wait=True, cancel_futures=True)

    return used, generate()


def _previews(out: Path, plan: DatasetPlan, camera_jpeg: bytes | None) -> tuple[Path, ...]:
    """Write ``<out>_camera.png`` (a camera frame) and ``<out>_maze.png`` (map and paths)."""
    stem = out.with_suffix("")
    cam_path = stem.with_name(stem.name + "_camera.png")
    maze_path = stem.with_name(stem.name + "_maze.png")
    written: list[Path] = []
    if camera_jpeg is not None:
        image = cv2.imdecode(np.frombuffer(camera_jpeg, np.uint8), cv2.IMREAD_GRAYSCALE)
        cv2.imwrite(str(cam_path), image)
        written.append(cam_path)
    cv2.imwrite(str(maze_path), maze_picture(plan))
    written.append(maze_path)
    return tuple(written)


def preview_frame(plan: DatasetPlan, candidates: int = 80) -> int:
    """Index of a frame worth showing: the longest view down a corridor in the first lap."""
    end = plan.trajectory.lap_times[1] if len(plan.trajectory.lap_times) > 1 else np.inf
    first_lap = int(np.searchsorted(plan.frame_times, end))
    indices = np.unique(np.linspace(0, max(first_lap - 1, 0), candidates).astype(np.int64))
    renderer = MazeRenderer(plan.layout)
    depth = [float(np.median(renderer.cast(*plan.frame_poses[i])[0])) for i in indices]
    return int(indices[int(np.argmax(depth))])


def maze_picture(plan: DatasetPlan, pixels_per_metre: float = 160.0) -> NDArray[np.uint8]:
    """A colour picture of the maze with the true and the dead-reckoned paths.

    Walls are dark, waypoints blue, the ground truth green and the robot's odometry red (it
    drifts over the laps).
    """
    layout = plan.layout
    k = pixels_per_metre
    w_m, h_m = layout.size_m
    margin = 10
    width, height = round(w_m * k) + 2 * margin, round(h_m * k) + 2 * margin
    img = np.full((height, width, 3), 235, np.uint8)
    cell_px = layout.cell * k
    for r, c in np.argwhere(layout.walls):
        x0, y0 = int(margin + c * cell_px), int(margin + r * cell_px)
        x1, y1 = int(margin + (c + 1) * cell_px), int(margin + (r + 1) * cell_px)
        cv2.rectangle(img, (x0, y0), (x1 - 1, y1 - 1), (70, 70, 70), -1)

    def to_px(xy: FloatArray) -> NDArray[np.int32]:
        px = margin + xy[:, 0] * k
        py = margin + (h_m - xy[:, 1]) * k
        return np.stack([px, py], axis=1).round().astype(np.int32)

    start = plan.trajectory.pose_at(0.0)
    c, s = math.cos(start[2]), math.sin(start[2])
    odom = plan.odom_pose
    odom_world = np.stack(
        [start[0] + c * odom[:, 0] - s * odom[:, 1], start[1] + s * odom[:, 0] + c * odom[:, 1]],
        axis=1,
    )
    cv2.polylines(img, [to_px(odom_world[::2])], False, (60, 60, 220), 1, cv2.LINE_AA)
    cv2.polylines(img, [to_px(plan.gt_poses[:, :2])], False, (40, 160, 40), 1, cv2.LINE_AA)
    for letter, (r, cc) in layout.waypoints.items():
        x, y = layout.cell_center(r, cc)
        p = to_px(np.array([[x, y]]))[0]
        cv2.circle(img, (int(p[0]), int(p[1])), 7, (200, 120, 0), -1, cv2.LINE_AA)
        cv2.putText(
            img,
            letter,
            (int(p[0]) - 5, int(p[1]) + 4),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.4,
            (255, 255, 255),
            1,
            cv2.LINE_AA,
        )
    cv2.putText(
        img,
        "green: ground truth   red: odometry",
        (margin, height - 3),
        cv2.FONT_HERSHEY_SIMPLEX,
        0.35,
        (0, 0, 0),
        1,
        cv2.LINE_AA,
    )
    return img


def generate_maze_bag(
    out: str | Path,
    config: MazeConfig | None = None,
    *,
    overwrite: bool = False,
    preview: bool = False,
    workers: int | None = None,
    progress: ProgressFn | None = None,
) -> GenerationResult:
    """Generate a synthetic iRat-layout bag at ``out``.

    The bag is written under a temporary name and renamed when complete.

    Args:
        out: the ``.bag`` to write.
        config: what to generate (default: the iRat-like maze, 6 laps, seed 1).
        overwrite: replace an existing file.
        preview: also write ``<out>_camera.png`` and ``<out>_maze.png``.
        workers: rendering processes (default: all CPUs; short runs render in-process).
        progress: called with ``(frames done, frames total)``.

    Raises:
        LayoutError, ParameterError: bad layout or settings.
        BagError: the output exists (without ``overwrite``) or cannot be written.

    """
    t_start = time.perf_counter()
    config = config or MazeConfig()
    out = Path(out)
    plan = plan_dataset(config)
    preview_index = preview_frame(plan) if preview else -1
    used, images = render_frames(plan, workers=workers, progress=progress)  # starts lazily
    writer = IratBagWriter(out, overwrite=overwrite)
    preview_jpeg: bytes | None = None
    odom_times, gt_times = plan.odom_times, plan.gt_times
    to_ns = 1e9
    oi = gi = 0

    def flush_until(t: float) -> None:
        nonlocal oi, gi
        while True:
            t_o = odom_times[oi] if oi < len(odom_times) else math.inf
            t_g = gt_times[gi] if gi < len(gt_times) else math.inf
            if min(t_o, t_g) > t or (t_o == math.inf and t_g == math.inf):
                return
            if t_o <= t_g:
                pose = plan.odom_pose[oi]
                writer.write_odometry(
                    START_STAMP_NS + int(round(t_o * to_ns)),
                    float(plan.odom_v[oi]),
                    float(plan.odom_w[oi]),
                    (float(pose[0]), float(pose[1]), float(pose[2])),
                )
                oi += 1
            else:
                g = plan.gt_poses[gi]
                writer.write_ground_truth(
                    START_STAMP_NS + int(round(t_g * to_ns)), float(g[0]), float(g[1]), float(g[2])
                )
                gi += 1

    with writer, contextlib.closing(images):
        for j, jpeg in enumerate(images):
            t = float(plan.frame_times[j])
            flush_until(t)
            writer.write_image(START_STAMP_NS + int(round(t * to_ns)), jpeg)
            if j == preview_index:
                preview_jpeg = jpeg
        flush_until(math.inf)

    write_frontend_profile(
        out,
        GENERATED_FRONTEND_PROFILE,
        note="front-end settings for cogmap's rendered maze camera "
        "(see cogmap_core/datasets/profile.py)",
    )
    previews = _previews(out, plan, preview_jpeg) if preview else ()
    truth_end = plan.trajectory.pose_at(float(plan.odom_times[-1]))
    start = plan.trajectory.pose_at(0.0)
    odom_end = plan.odom_pose[-1]
    c, s = math.cos(start[2]), math.sin(start[2])
    est = (
        start[0] + c * odom_end[0] - s * odom_end[1],
        start[1] + s * odom_end[0] + c * odom_end[1],
    )
    drift_pos = math.hypot(est[0] - truth_end[0], est[1] - truth_end[1])
    drift_th = abs(float(_wrap(np.array(odom_end[2] + start[2] - truth_end[2]))))
    return GenerationResult(
        path=out,
        layout=plan.layout,
        duration=float(plan.trajectory.duration),
        frames=len(plan.frame_times),
        odometry_messages=len(odom_times),
        ground_truth_messages=len(gt_times),
        distance=plan.trajectory.length,
        lap_times=plan.trajectory.lap_times,
        odometry_drift=(drift_pos, drift_th),
        size_bytes=out.stat().st_size,
        elapsed=time.perf_counter() - t_start,
        workers=used,
        previews=previews,
    )
