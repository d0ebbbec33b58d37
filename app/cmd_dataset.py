"""``cogmap dataset list|path|regenerate|info``: the default dataset cache and bag inspection."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from app.cli_common import add_topic_arguments, topics_from_args
from app.progress import ProgressBar
from cogmap_core.datasets.cache import (
    CACHE_ENV,
    DEFAULT_CONFIG,
    cache_dir,
    cached_bags,
    default_dataset_file,
    default_dataset_path,
)
from cogmap_core.datasets.generator import ProgressFn
from cogmap_core.datasets.layout import builtin_layouts, load_layout
from cogmap_core.datasets.rosbag_reader import open_bag


def _progress_bar(label: str) -> tuple[ProgressBar, ProgressFn]:
    bar = ProgressBar(label)
    fps = DEFAULT_CONFIG.fps

    def progress(done: int, total: int) -> None:
        bar(done, total, done / fps)

    return bar, progress


def _generate(regenerate: bool, workers: int | None) -> Path:
    bar, progress = _progress_bar("generating the default dataset")
    try:
        return default_dataset_path(progress=progress, regenerate=regenerate, workers=workers)
    finally:
        bar.close()


def _list(args: argparse.Namespace) -> int:
    folder = cache_dir()
    print(f"cache: {folder} (set {CACHE_ENV} to move it)")
    default = default_dataset_file()
    c = DEFAULT_CONFIG
    state = "present" if default.exists() else "not generated yet (cogmap dataset path makes it)"
    print(f"default dataset: {default.name} (layout {c.layout}, {c.laps} laps, seed {c.seed})")
    print(f"  {state}")
    bags = cached_bags()
    for bag in bags:
        mark = "*" if bag.is_default else " "
        print(f" {mark} {bag.path.name}  {bag.size_bytes / 1e6:.1f} MB")
    if not bags:
        print("  (no bags in the cache)")
    print("built-in layouts:")
    for name in builtin_layouts():
        layout = load_layout(name)
        w, h = layout.size_m
        print(f"  {name}: {w:.1f} x {h:.1f} m, waypoints {''.join(layout.waypoints)}")
    return 0


def _path(args: argparse.Namespace) -> int:
    print(_generate(regenerate=False, workers=args.workers))
    return 0


def _regenerate(args: argparse.Namespace) -> int:
    print(_generate(regenerate=True, workers=args.workers))
    return 0


def _info(args: argparse.Namespace) -> int:
    topics = topics_from_args(args)
    path = Path(args.bag) if args.bag else _generate(regenerate=False, workers=None)
    with open_bag(path, topics=topics, image_scale=args.image_scale) as reader:
        info = reader.info
        print(f"bag: {info.path} (ROS{info.ros_version})")
        print(f"duration: {info.duration:.1f} s")
        print(f"camera: {info.image_topic}: {info.frame_count} frames ({info.frame_rate:.2f} Hz)")
        print(f"odometry: {info.odometry_topic}: {info.odometry_count} messages")
        if info.has_ground_truth:
            print(
                f"ground truth: {info.ground_truth_topic} ({info.ground_truth_type}): "
                f"{info.ground_truth_count} messages"
            )
        else:
            print("ground truth: none")
        print("topics:")
        for topic, msgtype in sorted(info.topics.items()):
            print(f"  {topic}  {msgtype}")
        if args.scan:
            start = time.perf_counter()
            n = 0
            shape: tuple[int, ...] = ()
            travelled = 0.0
            for frame in reader.frames():
                n += 1
                shape = frame.image.shape
                travelled += abs(frame.translation)
            elapsed = time.perf_counter() - start
            per_frame = 1e3 * elapsed / max(n, 1)
            print(
                f"scan: {n} frames of {shape[1] if shape else 0}x{shape[0] if shape else 0} "
                f"(scale 1/{args.image_scale}) read in {elapsed:.2f} s: {per_frame:.3f} ms/frame, "
                f"{info.duration / max(elapsed, 1e-9):.0f}x real time; odometry distance "
                f"{travelled:.2f} m"
            )
            for line in reader.warnings:
                print(f"warning: {line}")
    return 0


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``dataset`` and its sub-commands."""
    parser = subparsers.add_parser(
        "dataset",
        help="the built-in default dataset (list, path, regenerate) and bag inspection (info)",
        description="The default dataset is generated once into the cache (about a minute) and "
        f"reused. Cache folder: ${CACHE_ENV}, default ~/.cache/cogmap.",
    )
    sub = parser.add_subparsers(dest="dataset_command", metavar="ACTION", required=True)
    p = sub.add_parser("list", help="show the cache folder, cached bags and built-in layouts")
    p.set_defaults(func=_list)
    p = sub.add_parser("path", help="print the default dataset's path, generating it if needed")
    p.add_argument("--workers", type=int, default=None, help="rendering processes")
    p.set_defaults(func=_path)
    p = sub.add_parser("regenerate", help="generate the default dataset again")
    p.add_argument("--workers", type=int, default=None, help="rendering processes")
    p.set_defaults(func=_regenerate)
    p = sub.add_parser("info", help="describe a bag (default: the default dataset)")
    p.add_argument("bag", nargs="?", default=None, help="bag file or ROS2 bag folder")
    add_topic_arguments(p)
    p.add_argument(
        "--scan", action="store_true", help="read every frame: read speed and data warnings"
    )
    p.add_argument(
        "--image-scale",
        type=int,
        default=1,
        choices=(1, 2, 4, 8),
        help="JPEG decoding reduction for --scan (default 1)",
    )
    p.set_defaults(func=_info)
