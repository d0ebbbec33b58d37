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
    input_options_from_args,
    map_changes_from_args,
    resolve_bag,
)
from app.pipeline import RunOptions, run_headless
from app.progress import ProgressBar
from cogmap_core.errors import ParameterError
from cogmap_core.frontend.compiled import prefer_compiled


def _run(args: argparse.Namespace) -> int:
    changes = map_changes_from_args(args)  # validate before any work
    prefer_compiled(False)  # the same maps; ~100 MB less peak memory (COGMAP_COMPILED_FRONTEND=1)
    if args.resume is not None and args.bag is None:
        raise ParameterError("--resume needs a bag to continue on: cogmap run BAG --resume FILE")
    bag = resolve_bag(args.bag)
    kind = input_kind(args, bag)
    frontend = frontend_from_args(args, bag) if kind.has_camera else None
    options = RunOptions(
        input=input_options_from_args(args, kind, frontend),
        force=args.force,
        on_clock_jump=args.on_clock_jump,
        until_error=args.until_error,
        resume=None if args.resume is None else Path(args.resume),
        param_changes=changes,
        save_session=None if args.save_session is None else Path(args.save_session),
        save_events=None if args.save_events is None else Path(args.save_events),
    )
    bar = ProgressBar("cogmap run")

    def announce(message: str) -> None:
        bar.close()
        print(f"cogmap run: {message}", file=sys.stderr, flush=True)

    try:
        result = run_headless(bag, Path(args.out), options, bar, announce)
    finally:
        bar.close()
    print(result.table())
    for line in result.warnings:
        print(f"warning: {line}")
    for note in result.session_notes:
        print(note)
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
        "map.png, <map>.g2o, trajectory_tum.txt (+ groundtruth_tum.txt) and config.json into DIR. "
        "With --save-session FILE the SLAM state is saved at the end; cogmap run BAG2 --resume "
        "FILE continues it on another bag (sessions are for bags only).",
    )
    parser.add_argument("--out", required=True, metavar="DIR", help="report folder")
    parser.add_argument(
        "--force",
        action="store_true",
        help="write into a non-empty DIR: replaces only the report's own files (listed in "
        "DIR/.cogmap-report), once the new report is complete; nothing else in DIR is touched; "
        "also replaces an existing --save-session or --save-events FILE",
    )
    add_input_arguments(parser)
    parser.add_argument(
        "--on-clock-jump",
        choices=("drop", "stop"),
        default="drop",
        help="bags: where the bag's clock jumps back, drop the messages recorded again over the "
        "same time (default) or stop reading at the jump; either way it is reported",
    )
    parser.add_argument(
        "--until-error",
        action="store_true",
        help="a bag corrupt part-way: map the data before the damage and write the report "
        "(the damage is reported) instead of failing",
    )
    parser.add_argument(
        "--save-session",
        default=None,
        metavar="FILE",
        help="bags: save the whole SLAM state at the end of the data, to continue it later with "
        "--resume (see docs/sessions.md)",
    )
    parser.add_argument(
        "--save-events",
        default=None,
        metavar="FILE",
        help="save the map events of the run (the front end's) at the end of the data as an "
        "event file (.events.npz), which cogmap sweep takes instead of a bag",
    )
    parser.add_argument(
        "--resume",
        default=None,
        metavar="FILE",
        help="continue a saved session on BAG: the robot starts BAG where the session ended; "
        "map options given here replace the session's (its maps are rebuilt)",
    )
    add_map_arguments(parser)
    add_frontend_arguments(parser)
    add_topic_arguments(parser)
    parser.set_defaults(func=_run)
