"""``cogmap run [FILE] --out DIR``: the headless mode -- one pass, three maps, a report folder.

FILE is a bag, or a log of odometry and place recognition (TUC or CSV, see
:mod:`cogmap_core.sources`); its kind is detected from the content unless ``--format`` says.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from app.cli_common import (
    add_frontend_arguments,
    add_input_arguments,
    add_map_arguments,
    add_topic_arguments,
    frontend_from_args,
    input_kind,
    log_options_from_args,
    params_from_args,
    resolve_bag,
    topics_from_args,
)
from app.pipeline import RunOptions, run_headless
from app.progress import ProgressBar
from cogmap_core.sources.detect import LogOptions


def _run(args: argparse.Namespace) -> int:
    params_from_args(args)  # validate the options before any work
    bag = resolve_bag(args.bag)
    kind = input_kind(args, bag)
    camera = kind.has_camera
    options = RunOptions(
        params=params_from_args(args, kind.map_params),
        frontend=frontend_from_args(args, bag) if camera else None,
        topics=topics_from_args(args),
        force=args.force,
        format=kind.name,
        log=log_options_from_args(args) if not camera else LogOptions(),
    )
    bar = ProgressBar("cogmap run")
    try:
        result = run_headless(bag, Path(args.out), options, bar)
    finally:
        bar.close()
    for warning in result.summary["read_warnings"].get("warnings", []):
        print(f"cogmap run: warning: {warning}", file=sys.stderr)
    print(result.table())
    print(f"report written to {result.out_dir}")
    return 0


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``cogmap run``."""
    parser = subparsers.add_parser(
        "run",
        help="headless mode: process a bag or log once, build the three maps, write a report",
        description="Process the whole input (default: the built-in dataset) through its front "
        "end and build the standard, scene_integration and compact maps. The input is an "
        "iRat-layout bag, or a log of odometry and place recognition (TUC odom2/loop file, or a "
        "CSV time,v,omega file with its loops). Writes summary.json, sizes.csv, size.png, "
        "map.png, <map>.g2o, trajectory_tum.txt (+ groundtruth_tum.txt) and config.json into DIR.",
    )
    parser.add_argument(
        "bag",
        nargs="?",
        default=None,
        metavar="FILE",
        help="iRat-layout ROS bag, TUC input file or CSV odometry file",
    )
    parser.add_argument("--out", required=True, metavar="DIR", help="report folder")
    parser.add_argument("--force", action="store_true", help="overwrite a non-empty DIR")
    add_input_arguments(parser)
    add_map_arguments(parser)
    add_frontend_arguments(parser)
    add_topic_arguments(parser)
    parser.set_defaults(func=_run)
