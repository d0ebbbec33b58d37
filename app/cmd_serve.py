"""``cogmap serve [FILE]``: the live web app -- replay a bag or log, tune the maps in a browser."""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
import threading
import webbrowser
from pathlib import Path
from types import FrameType

from app.cli_common import (
    add_frontend_arguments,
    add_input_arguments,
    add_map_arguments,
    add_topic_arguments,
    frontend_from_args,
    input_kind,
    log_options_from_args,
    map_changes_from_args,
    topics_from_args,
)
from app.server.replay import BagSource, GenerationProgress
from cogmap_core.errors import InputFileError, ParameterError
from cogmap_core.session_file import describe, resume_session
from cogmap_core.sources.detect import KINDS, check_companions, check_sessions_allowed

DEFAULT_PORT = 8080


def default_dataset(progress: GenerationProgress) -> Path:
    """The built-in dataset (generated into the cache on first use, with progress)."""
    try:
        from cogmap_core.datasets.cache import default_dataset_path
    except ImportError as exc:
        raise InputFileError(
            f"the built-in dataset is not available in this installation ({exc}); "
            "give a bag: cogmap serve BAG"
        ) from None
    return default_dataset_path(progress=progress)


def _speed(text: str) -> float:
    if text in ("max", "inf"):
        return float("inf")
    try:
        value = float(text.rstrip("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"speed {text!r} is not a number or 'max'") from None
    if not value > 0:
        raise argparse.ArgumentTypeError(f"speed {text} must be > 0")
    return value


def display_url(host: str, port: int) -> str:
    """The URL to open for a server bound to ``host``:``port``."""
    if host in ("0.0.0.0", "::", ""):
        host = "localhost"
    if ":" in host:
        host = f"[{host}]"
    return f"http://{host}:{port}"


def _serve(args: argparse.Namespace) -> int:
    changes = map_changes_from_args(args)  # read and validated once, before anything starts
    topics = topics_from_args(args)
    companions = args.loops is not None or args.ground_truth is not None
    if args.bag is not None and (Path(args.bag).exists() or args.format != "auto" or companions):
        kind = input_kind(args, Path(args.bag))  # (a missing file with companions: an error)
    else:  # the built-in dataset, or a missing bag (reported on the page, as for any bag)
        kind = KINDS["bag"]
        check_companions("bag", args.loops, args.ground_truth)
    params = kind.map_params.with_changes(**changes)
    if kind.has_camera:
        frontend_from_args(args, Path("-"))  # validate --frontend overrides now (no profile)
        log = None
    else:
        log = log_options_from_args(args)  # validates the log's --frontend settings
    if not 0 < args.port < 65536:
        raise ParameterError(f"port {args.port} is out of range; use 1-65535")
    resume = None
    if args.resume is not None:
        # before the session file is even read
        check_sessions_allowed(kind.name, args.bag, "--resume", "serve it without --resume")
        if args.bag is None:
            raise ParameterError(
                "--resume needs a bag to continue on: cogmap serve BAG --resume FILE"
            )
        bag_path = Path(args.bag)
        if not bag_path.exists():  # (not resolve_bag's error: its "or omit BAG" is refused here)
            raise InputFileError(
                f"{bag_path}: no such bag; --resume continues on an existing .bag file"
            )
        resume = resume_session(args.resume, frontend_from_args(args, bag_path), 4, changes)
        print(f"cogmap serve: resuming {args.resume}: {describe(*resume)}", file=sys.stderr)
    import viser

    from app.server.app import CogmapApp

    bag: BagSource = Path(args.bag) if args.bag is not None else default_dataset
    with contextlib.redirect_stdout(sys.stderr):  # viser's banner: keep stdout for our URL
        server = viser.ViserServer(host=args.host, port=args.port, label="cogmap")
    port = server.get_port()
    if port != args.port:
        print(f"cogmap serve: port {args.port} is busy; using {port}", file=sys.stderr)
    url = display_url(args.host, port)
    app = CogmapApp(
        server,
        bag,
        params=params,
        speed=args.speed,
        autoplay=not args.paused,
        static_dir=Path(args.static) if args.static else None,
        frontend=lambda bag_path: frontend_from_args(args, bag_path),
        topics=topics,
        rebuild_workers=min(2, os.cpu_count() or 1),
        wait_for_viewer=not args.no_wait,
        fmt=kind.name,
        log=log,
        defaults=kind.map_params,
        resume=resume,
    )
    stop = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set()

    # Ctrl-C and SIGTERM (docker stop) both stop cleanly, even where SIGINT was inherited as
    # ignored (a background job of a script).
    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        app.start()
        print(f"cogmap serve: {url}  (Ctrl-C to stop)", flush=True)
        if args.open:
            threading.Thread(target=webbrowser.open, args=(url,), daemon=True).start()
        while not stop.wait(0.5):
            pass
    except KeyboardInterrupt:
        pass
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        print("cogmap serve: stopping", file=sys.stderr, flush=True)
        app.stop()
        server.stop()
    print("cogmap serve: stopped", file=sys.stderr, flush=True)
    return 0


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``cogmap serve``."""
    parser = subparsers.add_parser(
        "serve",
        help="live web app: replay a bag or log in the browser and tune the compact map live",
        description="Start a viser web server that replays the input (default: the built-in "
        "dataset) through the SLAM core and streams the standard, scene_integration and compact "
        "maps live to every connected browser, with sliders to tune the map parameters. The "
        "input is an iRat-layout bag, or a log of odometry and place recognition (TUC or CSV; "
        "no camera panel, the place-recognition score of each link instead).",
    )
    parser.add_argument(
        "--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)"
    )
    parser.add_argument(
        "--port",
        type=int,
        default=DEFAULT_PORT,
        help=f"port (default {DEFAULT_PORT}; the next free one is used when it is busy)",
    )
    parser.add_argument("--open", action="store_true", help="open the page in a web browser")
    parser.add_argument(
        "--speed",
        type=_speed,
        default=1.0,
        help="playback speed: data seconds per second, or 'max' (default 1)",
    )
    parser.add_argument("--paused", action="store_true", help="start paused")
    parser.add_argument(
        "--no-wait",
        action="store_true",
        help="start playing at once (default: when the first browser connects)",
    )
    parser.add_argument(
        "--resume",
        default=None,
        metavar="FILE",
        help="show a session saved by cogmap run --save-session and keep growing it with BAG "
        "(the robot starts BAG where the session ended)",
    )
    parser.add_argument(
        "--static",
        default=None,
        metavar="DIR",
        help="folder of web-facing assets; HTML replays go to DIR/replays (default: static/)",
    )
    add_input_arguments(parser)
    add_map_arguments(parser)
    add_frontend_arguments(parser)
    add_topic_arguments(parser)
    parser.set_defaults(func=_serve)
