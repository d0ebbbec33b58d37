"""``cogmap serve [FILE]``: the live web app -- replay a bag or log, tune the maps in a browser."""

from __future__ import annotations

import argparse
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
    input_options_from_args,
    map_changes_from_args,
)
from app.inputs import BagSource, GenerationProgress, InputOptions
from app.server.access import page_url
from app.server.files import default_export_dir
from cogmap_core.config import MapParams
from cogmap_core.datasets.cache import cache_dir
from cogmap_core.errors import CogmapError, InputFileError, ParameterError
from cogmap_core.session_file import describe, resume_session
from cogmap_core.sources.detect import (
    KINDS,
    InputKind,
    check_companions,
    check_sessions_allowed,
    input_map_params,
    open_source,
)

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


def display_url(host: str, port: int, token: str | None = None) -> str:
    """The URL to open for a server bound to ``host``:``port`` (see :func:`page_url`)."""
    return page_url(host, port, token)


def _folders(args: argparse.Namespace) -> tuple[Path, list[Path]]:
    """The export folder and the data folders (checked: one line when one is not a folder)."""
    export = Path(args.export_dir).expanduser() if args.export_dir else default_export_dir()
    if export.exists() and not export.is_dir():
        raise ParameterError(f"--export-dir {export} is not a folder; give a folder")
    data: list[Path] = []
    for given in args.data_dir or []:
        folder = Path(given).expanduser()
        if not folder.is_dir():
            raise ParameterError(f"--data-dir {folder} is not a folder; give a folder of bags")
        data.append(folder)
    if not data:  # the served input's folder (the cache's for the built-in dataset)
        data = [Path(args.bag).parent if args.bag is not None else cache_dir()]
    return export, data


def _network_warning(host: str, port: int, token: str | None) -> str:
    who = (
        "anyone who has the URL below"
        if token is not None
        else "anyone (--no-token: no token is asked)"
    )
    where = "every network interface" if host in ("0.0.0.0", "::", "") else host
    return (
        f"cogmap serve: warning: listening on {where}, port {port}: {who} and can reach this "
        "machine can watch and steer the replay, open the bags of the data folders and save "
        "replays in the export folder; see docs/security.md"
    )


def _input_defaults(kind: InputKind, bag: str | None, options: InputOptions) -> MapParams:
    """The input's default map parameters: a log's are measured from it (its odometry scale).

    A log that cannot be read gets its kind's; the page then says what is wrong with it.
    """
    if kind.has_camera or bag is None:
        return kind.map_params
    try:
        with open_source(Path(bag), kind.name, log=options.log) as reader:
            return input_map_params(kind, reader)
    except CogmapError:
        return kind.map_params


def _serve(args: argparse.Namespace) -> int:
    changes = map_changes_from_args(args)  # read and validated once, before anything starts
    companions = args.loops is not None or args.ground_truth is not None
    if args.bag is not None and (Path(args.bag).exists() or args.format != "auto" or companions):
        kind = input_kind(args, Path(args.bag))  # (a missing file with companions: an error)
    else:  # the built-in dataset, or a missing bag (reported on the page, as for any bag)
        kind = KINDS["bag"]
        check_companions("bag", args.loops, args.ground_truth)
    if kind.has_camera:
        frontend_from_args(args, Path("-"))  # validate --frontend overrides now (no profile)
    # (each input's front end its own: its profile, then --frontend; each camera input's visual
    # odometry takes those settings too, InputOptions.camera_for; a log's --frontend settings
    # are validated here)
    input_options = input_options_from_args(
        args, kind, lambda bag_path: frontend_from_args(args, bag_path)
    )
    defaults = _input_defaults(kind, args.bag, input_options)
    params = defaults.with_changes(**changes)
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
        resume = resume_session(args.resume, frontend_from_args(args, bag_path), 1, changes)
        print(f"cogmap serve: resuming {args.resume}: {describe(*resume)}", file=sys.stderr)
    from app.server.access import guarded_server, is_loopback, policy_for
    from app.server.app import CogmapApp

    export_dir, data_dirs = _folders(args)
    policy = policy_for(args.host, require_token=args.require_token, no_token=args.no_token)
    bag: BagSource = Path(args.bag) if args.bag is not None else default_dataset
    # every request passes the gate; viser's banner is not printed (its URL has no token): the
    # one URL to open is ours, on stdout
    server = guarded_server(args.host, args.port, policy, verbose=False, quiet=True)
    port = server.get_port()
    if port != args.port:
        print(f"cogmap serve: port {args.port} is busy; using {port}", file=sys.stderr)
    if not is_loopback(args.host):
        print(_network_warning(args.host, port, policy.token), file=sys.stderr)
    url = display_url(args.host, port, policy.token)
    app = CogmapApp(
        server,
        bag,
        params=params,
        input_options=input_options,
        speed=args.speed,
        autoplay=not args.paused,
        static_dir=Path(args.static) if args.static else None,
        rebuild_workers=min(2, os.cpu_count() or 1),
        wait_for_viewer=not args.no_wait,
        defaults=defaults,
        resume=resume,
        export_dir=export_dir,
        data_dirs=data_dirs,
    )
    folders = ", ".join(str(d) for d in data_dirs)
    print(
        f"cogmap serve: replays are saved in {export_dir}; bags are listed from {folders}",
        file=sys.stderr,
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
        help="folder of web-facing assets (default: static/)",
    )
    parser.add_argument(
        "--export-dir",
        default=None,
        metavar="DIR",
        help="the one folder the page saves HTML replays into (default: $COGMAP_CACHE/exports, "
        "i.e. ~/.cache/cogmap/exports); visitors choose only a file name",
    )
    parser.add_argument(
        "--data-dir",
        action="append",
        default=None,
        metavar="DIR",
        help="a folder whose bags, videos, image folders and logs 'open another bag' lists "
        "(repeatable; default: the served input's folder); visitors choose from that list only",
    )
    token = parser.add_mutually_exclusive_group()
    token.add_argument(
        "--no-token",
        action="store_true",
        help="do not ask for a token when listening beyond this machine (anyone who can reach "
        "the port controls the app; see docs/security.md)",
    )
    token.add_argument(
        "--require-token",
        action="store_true",
        help="ask for a token on loopback too (a machine shared with other users)",
    )
    add_input_arguments(parser)
    add_map_arguments(parser)
    add_frontend_arguments(parser)
    add_topic_arguments(parser)
    parser.set_defaults(func=_serve)
