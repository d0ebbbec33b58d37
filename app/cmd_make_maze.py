"""``cogmap make-maze OUT.bag``: generate a synthetic iRat-layout bag of a rat-maze run."""

from __future__ import annotations

import argparse

from app.progress import ProgressBar
from cogmap_core.datasets.camera_writer import generate_camera_only
from cogmap_core.datasets.generator import GenerationResult, MazeConfig, generate_maze_bag
from cogmap_core.datasets.layout import DEFAULT_LAYOUT, builtin_layouts
from cogmap_core.datasets.motion import OdometryModel


def config_from_args(args: argparse.Namespace) -> MazeConfig:
    """The generation settings given on the command line (validated)."""
    sigma_v, sigma_w = args.odom_noise
    bias_v, bias_w, drift_w = args.odom_bias
    return MazeConfig(
        layout=args.layout,
        cell=args.cell,
        laps=args.laps,
        seed=args.seed,
        fps=args.fps,
        speed=args.speed,
        odometry=OdometryModel(
            sigma_v=sigma_v, sigma_w=sigma_w, bias_v=bias_v, bias_w=bias_w, drift_w=drift_w
        ),
        jpeg_quality=args.jpeg_quality,
        light_changes=not args.steady_light,
    )


def describe(result: GenerationResult) -> str:
    """A short human-readable summary of a generated bag."""
    laps = len(result.lap_times) - 1
    minutes, seconds = divmod(result.duration, 60.0)
    drift_m, drift_rad = result.odometry_drift
    lines = [
        f"wrote {result.path} ({result.size_bytes / 1e6:.1f} MB) in {result.elapsed:.1f} s "
        f"using {result.workers} process(es)",
        f"  layout {result.layout.name}: {result.layout.size_m[0]:.2f} x "
        f"{result.layout.size_m[1]:.2f} m, cell {result.layout.cell:g} m, "
        f"{len(result.layout.waypoints)} waypoints",
        f"  {laps} laps, {result.distance:.1f} m in {int(minutes)} min {seconds:.0f} s: "
        f"{result.frames} frames, {result.odometry_messages} odometry, "
        f"{result.ground_truth_messages} ground-truth messages",
        f"  dead-reckoning error at the end: {drift_m:.2f} m, {drift_rad * 57.29578:.1f} deg",
    ]
    lines += [f"  preview {p}" for p in result.previews]
    return "\n".join(lines)


def _make_camera_only(args: argparse.Namespace, config: MazeConfig) -> int:
    bar = None if args.quiet else ProgressBar("cogmap make-maze")

    def progress(done: int, total: int) -> None:
        if bar is not None:
            bar(done, total, done / config.fps)

    try:
        result = generate_camera_only(
            args.out, config, overwrite=args.force, workers=args.workers, progress=progress
        )
    finally:
        if bar is not None:
            bar.close()
    minutes, seconds = divmod(result.duration, 60.0)
    print(
        f"wrote {result.path} (camera only: {result.frames} frames, {int(minutes)} min "
        f"{seconds:.0f} s) in {result.elapsed:.1f} s"
    )
    for path in result.files[1:]:
        print(f"  {path}")
    return 0


def _make_maze(args: argparse.Namespace) -> int:
    config = config_from_args(args)
    if args.camera_only:
        return _make_camera_only(args, config)
    bar = None if args.quiet else ProgressBar("cogmap make-maze")
    fps = config.fps

    def progress(done: int, total: int) -> None:
        if bar is not None:
            bar(done, total, done / fps)

    try:
        result = generate_maze_bag(
            args.out,
            config,
            overwrite=args.force,
            preview=args.preview,
            workers=args.workers,
            progress=progress,
        )
    finally:
        if bar is not None:
            bar.close()
    print(describe(result))
    return 0


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``make-maze``."""
    d = MazeConfig()
    o = d.odometry
    parser = subparsers.add_parser(
        "make-maze",
        help="generate a synthetic iRat-layout bag of a robot running laps of a maze",
        description="Render a rat-like robot running laps of an ASCII maze into a ROS1 bag with "
        "the iRat 2011 Australia topics (camera JPEGs, wheel odometry, overhead ground truth). "
        f"Built-in layouts: {', '.join(builtin_layouts())}.",
    )
    parser.add_argument(
        "out",
        metavar="OUT.bag",
        help="bag file to write (with --camera-only: OUT.mp4 / OUT.avi, or an image folder)",
    )
    parser.add_argument(
        "--camera-only",
        action="store_true",
        help="write the camera alone: a video (OUT.mp4, OUT.avi) or a folder of JPEG images "
        "(any other name), with its frame times, ground truth and front-end profile beside it; "
        "cogmap run maps it with RatSLAM's visual odometry",
    )
    parser.add_argument(
        "--layout",
        default=DEFAULT_LAYOUT,
        metavar="NAME_OR_FILE",
        help=f"built-in layout name or layout file (default {DEFAULT_LAYOUT})",
    )
    parser.add_argument(
        "--cell",
        type=float,
        default=None,
        metavar="M",
        help="metres per layout cell (default: the layout's own, else corridors ~0.3 m wide)",
    )
    parser.add_argument("--laps", type=int, default=d.laps, help=f"laps (default {d.laps})")
    parser.add_argument("--seed", type=int, default=d.seed, help=f"random seed (default {d.seed})")
    parser.add_argument(
        "--fps", type=float, default=d.fps, help=f"camera frame rate in Hz (default {d.fps:g})"
    )
    parser.add_argument(
        "--speed",
        type=float,
        default=d.speed,
        metavar="V",
        help=f"mean cruise speed in m/s (default {d.speed:g})",
    )
    parser.add_argument(
        "--odom-noise",
        type=float,
        nargs=2,
        default=(o.sigma_v, o.sigma_w),
        metavar=("SIGMA_V", "SIGMA_W"),
        help="odometry noise: speed (m/s) and turn-rate (rad/s) standard deviations per message "
        f"(default {o.sigma_v:g} {o.sigma_w:g})",
    )
    parser.add_argument(
        "--odom-bias",
        type=float,
        nargs=3,
        default=(o.bias_v, o.bias_w, o.drift_w),
        metavar=("DIST", "TURN", "DRIFT"),
        help="systematic odometry error: distance scale error and turn scale error (fractions) "
        f"and heading drift per metre in rad/m (default {o.bias_v:g} {o.bias_w:g} {o.drift_w:g})",
    )
    parser.add_argument(
        "--jpeg-quality",
        type=int,
        default=d.jpeg_quality,
        metavar="Q",
        help=f"JPEG quality 1-100 (default {d.jpeg_quality})",
    )
    parser.add_argument(
        "--steady-light", action="store_true", help="keep the light level constant over time"
    )
    parser.add_argument(
        "--workers", type=int, default=None, help="rendering processes (default: all CPUs)"
    )
    parser.add_argument("--force", action="store_true", help="overwrite OUT if it exists")
    parser.add_argument(
        "--preview",
        action="store_true",
        help="also save OUT_camera.png (a camera frame) and OUT_maze.png (maze and paths)",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.set_defaults(func=_make_maze)
