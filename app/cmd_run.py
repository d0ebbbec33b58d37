"""``cogmap run [BAG] --out DIR``: the headless mode -- one pass, three maps, a report folder."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from app.pipeline import RunOptions, run_headless
from app.progress import ProgressBar
from cogmap_core.config import MapParams
from cogmap_core.errors import InputFileError


def resolve_bag(bag: str | None) -> Path:
    """The bag to use: the given path, or the built-in default dataset (generated on first use)."""
    if bag is not None:
        path = Path(bag)
        if not path.exists():
            raise InputFileError(f"{path}: no such bag; give an existing .bag file or omit BAG")
        return path
    from cogmap_core.datasets.cache import default_dataset_path

    return default_dataset_path(progress=_generation_progress)


def _generation_progress(done: int, total: int) -> None:
    sys.stderr.write(f"\rgenerating the default dataset: {done}/{total} frames")
    if done >= total:
        sys.stderr.write("\n")
    sys.stderr.flush()


def params_from_args(args: argparse.Namespace) -> MapParams:
    """Map parameters from the command line (validated: out-of-range values name the range)."""
    return MapParams(
        alpha=args.alpha,
        beta=args.beta,
        delta=args.delta,
        t_interval=args.t_interval,
        t_total=args.t_total,
    )


def add_map_arguments(parser: argparse.ArgumentParser) -> None:
    """The map parameter options shared by ``run`` and ``serve``."""
    d = MapParams()
    parser.add_argument(
        "--alpha", type=float, default=d.alpha, help=f"translation weight (default {d.alpha:g})"
    )
    parser.add_argument(
        "--beta", type=float, default=d.beta, help=f"rotation weight (default {d.beta:g})"
    )
    parser.add_argument(
        "--delta",
        type=float,
        default=d.delta,
        help=f"neighborhood field threshold, > 1 (default {d.delta:g})",
    )
    parser.add_argument(
        "--t-interval",
        type=float,
        default=d.t_interval,
        help=f"cluster interval threshold in s (default {d.t_interval:g})",
    )
    parser.add_argument(
        "--t-total",
        type=float,
        default=d.t_total,
        help=f"cluster total-time threshold in s (default {d.t_total:g})",
    )


def _run(args: argparse.Namespace) -> int:
    params = params_from_args(args)  # validate before any work
    bag = resolve_bag(args.bag)
    bar = ProgressBar("cogmap run")
    try:
        result = run_headless(bag, Path(args.out), RunOptions(params=params, force=args.force), bar)
    finally:
        bar.close()
    print(result.table())
    print(f"report written to {result.out_dir}")
    return 0


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``cogmap run``."""
    parser = subparsers.add_parser(
        "run",
        help="headless mode: process a bag once, build the three maps, write a report folder",
        description="Process the whole bag (default: the built-in dataset) through the front end "
        "and build the standard, scene_integration and compact maps. Writes summary.json, "
        "sizes.csv, size.png, map.png, <map>.g2o, trajectory_tum.txt (+ groundtruth_tum.txt) "
        "and config.json into DIR.",
    )
    parser.add_argument("bag", nargs="?", default=None, metavar="BAG", help="iRat-layout ROS bag")
    parser.add_argument("--out", required=True, metavar="DIR", help="report folder")
    parser.add_argument("--force", action="store_true", help="overwrite a non-empty DIR")
    add_map_arguments(parser)
    parser.set_defaults(func=_run)
