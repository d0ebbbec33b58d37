"""Command-line options shared by several commands (input, topics, map and front-end settings)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from app.inputs import FrontEndSource, InputOptions
from app.params_file import load_params_changes
from cogmap_core.config import MapParams
from cogmap_core.datasets.profile import read_frontend_profile
from cogmap_core.datasets.topics import GROUND_TRUTH_TOPIC, IMAGE_TOPIC, ODOMETRY_TOPIC, BagTopics
from cogmap_core.errors import InputFileError, ParameterError
from cogmap_core.frontend import FrontEndConfig
from cogmap_core.parameter_table import FLAG_PARAMETERS, flag_name
from cogmap_core.sources.detect import (
    FORMATS,
    KINDS,
    CameraOptions,
    InputKind,
    LogOptions,
    check_companions,
    resolve_format,
)
from cogmap_core.sources.odometry_log import LOG_MAP_PARAMS, LogSourceConfig
from cogmap_core.sweep import normalise_parameter_name


def add_topic_arguments(
    parser: argparse.ArgumentParser, ground_truth_optional: bool = True
) -> None:
    """``--image-topic``, ``--odom-topic``, ``--gt-topic`` and ``--no-ground-truth``.

    Args:
        parser: the command's parser.
        ground_truth_optional: offer ``--no-ground-truth``; ``False`` for a command that always
            needs the ground truth (``cogmap sweep``), whose parser then rejects the option as
            unrecognized.

    """
    parser.add_argument("--image-topic", default=IMAGE_TOPIC, help=f"(default {IMAGE_TOPIC})")
    parser.add_argument("--odom-topic", default=ODOMETRY_TOPIC, help=f"(default {ODOMETRY_TOPIC})")
    parser.add_argument(
        "--gt-topic", default=GROUND_TRUTH_TOPIC, help=f"(default {GROUND_TRUTH_TOPIC})"
    )
    if ground_truth_optional:
        parser.add_argument(
            "--no-ground-truth", action="store_true", help="ignore the ground truth"
        )


def topics_from_args(args: argparse.Namespace) -> BagTopics:
    """The topics chosen on the command line (no ``--no-ground-truth``: the ground truth's)."""
    ignore_ground_truth = getattr(args, "no_ground_truth", False)
    return BagTopics(
        image=args.image_topic,
        odometry=args.odom_topic,
        ground_truth=None if ignore_ground_truth else args.gt_topic,
    )


#: The map parameters with an option of their own: (name, flag, help), from the parameter table.
_MAP_ARGUMENTS: tuple[tuple[str, str, str], ...] = tuple(
    (p.name, flag_name(p.name), f"{p.flag_help}, {p.lower_bound_text()}") for p in FLAG_PARAMETERS
)
_PAPER_FLAGS = tuple(name for name, _, _ in _MAP_ARGUMENTS)


def add_map_arguments(parser: argparse.ArgumentParser) -> None:
    """The paper's map parameters as flags, ``--params FILE[#ENTRY]``, ``--param NAME=VALUE``.

    ``--params`` gives map parameters from a JSON file (e.g. a sweep's best.json, which names
    every one); the flags and ``--param`` override it. Unset ones stay unset (see
    :func:`map_changes_from_args`): they keep the default of the input's kind (the paper's for
    bags, :data:`~cogmap_core.sources.odometry_log.LOG_MAP_PARAMS` for logs), and a resumed
    session keeps its own values for them.
    """
    paper, log = MapParams(), LOG_MAP_PARAMS
    for name, flag, meaning in _MAP_ARGUMENTS:
        a, b = getattr(paper, name), getattr(log, name)
        default = f"default {a:g}" if a == b else f"default {a:g}; {b:g} for logs"
        parser.add_argument(
            flag,
            dest=name,
            type=float,
            default=None,
            help=f"{meaning} ({default}; or the --params file's)",
        )
    parser.add_argument(
        "--params",
        dest="params_file",
        default=None,
        metavar="FILE[#ENTRY]",
        help="start from the map parameters in a JSON file: {name: value, ...} or a sweep's "
        "best.json (its smallest_complete setting; #front_ate/0, #paper, ... pick another); "
        "options given beside it override it",
    )
    parser.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="any other map parameter (repeatable), e.g. --param integration_radius=0.08; "
        f"names: {', '.join(n for n in paper.to_dict() if n not in _PAPER_FLAGS)} "
        "(logs have their own defaults for some, see the README)",
    )


def map_changes_from_args(args: argparse.Namespace) -> dict[str, float]:
    """The map parameters given on the command line (name -> value), validated.

    Every parameter a ``--params`` file names (a sweep's best.json names all), then the flags and
    ``--param`` values over it. ``--param`` names are spelled as in sweep specs
    (:func:`~cogmap_core.sweep.normalise_parameter_name`: ``huber-scale`` is ``huber_scale``);
    unknown ones are reported together by :meth:`MapParams.with_changes`.
    """
    file = getattr(args, "params_file", None)
    changes: dict[str, float] = load_params_changes(file) if file else {}
    changes |= {
        name: getattr(args, name)
        for name, _, _ in _MAP_ARGUMENTS
        if getattr(args, name, None) is not None
    }
    for item in getattr(args, "param", []) or []:
        written_name, sep, text = item.partition("=")
        name = normalise_parameter_name(written_name)
        if not sep or not name:
            raise ParameterError(f"--param {item!r}: expected NAME=VALUE, e.g. huber_scale=0.2")
        if name in _PAPER_FLAGS:
            raise ParameterError(f"--param {name}: use {flag_name(name)} instead")
        try:
            changes[name] = float(text)
        except ValueError:
            raise ParameterError(f"--param {name}={text!r}: the value is not a number") from None
    MapParams().with_changes(**changes)  # out-of-range values name the valid range
    return changes


def add_input_arguments(parser: argparse.ArgumentParser) -> None:
    """``FILE`` (default: the built-in dataset), ``--format`` and a log's other files."""
    parser.add_argument(
        "bag",
        nargs="?",
        default=None,
        metavar="FILE",
        help="iRat-layout ROS bag, video file, folder of images, TUC input file or CSV "
        "odometry file",
    )
    parser.add_argument(
        "--format",
        choices=("auto", *FORMATS),
        default="auto",
        help="input kind (default auto: detected from the content): bag (ROS bag with camera), "
        "video (a video file, camera only), images (a folder of images, camera only), "
        "tuc (TUC SLAM dataset odom2/loop lines), csv (time,v,omega odometry)",
    )
    parser.add_argument(
        "--odometry",
        choices=("auto", "wheel", "visual"),
        default="auto",
        help="a bag's motion: its odometry topic (wheel), the camera's as RatSLAM's visual "
        "odometry computes it (visual), or auto (default: the topic if the bag has it); videos "
        "and image folders always use visual odometry (settings: --frontend camera_fov_deg=..., "
        "vtrans_scaling=..., ...)",
    )
    parser.add_argument(
        "--fps",
        type=float,
        default=None,
        metavar="HZ",
        help="frame rate of a video or image folder without a times file (default: the "
        "video's own rate; an image folder needs times.txt or this)",
    )
    parser.add_argument(
        "--loops",
        default=None,
        metavar="FILE",
        help="CSV logs: the loop candidates time,matched_time,score (default: the file named "
        "like the odometry file with 'odometry' replaced by 'loops')",
    )
    parser.add_argument(
        "--ground-truth",
        default=None,
        metavar="FILE",
        help="logs: ground truth (TUC: X_GT.txt beside X_Input.txt; CSV: time,x,y[,theta], "
        "default the 'ground_truth' companion)",
    )


def input_kind(args: argparse.Namespace, path: Path) -> InputKind:
    """The kind of ``path`` (``--format`` or detected), with its defaults."""
    name = resolve_format(path, args.format)
    check_companions(name, args.loops, args.ground_truth)
    return KINDS[name]


def camera_options_from_args(
    args: argparse.Namespace, frontend: FrontEndConfig | None = None
) -> CameraOptions:
    """How to read a camera input: ``--odometry``, ``--fps`` and the front-end settings."""
    return CameraOptions(odometry=args.odometry, fps=args.fps, frontend=frontend)


def input_options_from_args(
    args: argparse.Namespace, kind: InputKind, frontend: FrontEndSource
) -> InputOptions:
    """How to read the input the command line names: its kind, ``frontend``, topics, log, camera.

    A camera input is read with the default log options, a log with its own (``--frontend``
    overrides of its settings, its companion files).
    """
    return InputOptions(
        format=kind.name,
        frontend=frontend,
        topics=topics_from_args(args),
        log=LogOptions() if kind.has_camera else log_options_from_args(args),
        camera=camera_options_from_args(args),
    )


def log_options_from_args(args: argparse.Namespace) -> LogOptions:
    """How to read a log: ``--frontend`` overrides of its settings and its companion files."""
    return LogOptions(
        config=LogSourceConfig().with_changes(**_overrides(args.frontend)),
        loops=None if args.loops is None else Path(args.loops),
        ground_truth=None if args.ground_truth is None else Path(args.ground_truth),
        use_ground_truth=not args.no_ground_truth,
    )


def add_frontend_arguments(parser: argparse.ArgumentParser) -> None:
    """``--frontend KEY=VALUE`` overrides of the front-end configuration."""
    parser.add_argument(
        "--frontend",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a front-end setting (repeatable), e.g. --frontend vt_match_threshold=0.03; "
        "applied after the iRat defaults and the bag's <name>.frontend.json profile; for logs "
        "the log's settings, e.g. --frontend score_threshold=0.9",
    )


def _overrides(items: list[str]) -> dict[str, float]:
    overrides: dict[str, float] = {}  # an integer literal stays an int (integer settings)
    for item in items:
        key, sep, value = item.partition("=")
        if not sep:
            raise ParameterError(
                f"--frontend {item!r}: write KEY=VALUE, e.g. vt_match_threshold=0.03"
            )
        try:
            text = value.strip()
            overrides[key.strip()] = int(text) if text.lstrip("+-").isdigit() else float(text)
        except ValueError:
            raise ParameterError(f"--frontend {item!r}: {value!r} is not a number") from None
    return overrides


def frontend_from_args(args: argparse.Namespace, bag: Path) -> FrontEndConfig:
    """The front-end config: iRat defaults, the bag's profile, then ``--frontend`` overrides."""
    overrides: dict[str, float] = dict(read_frontend_profile(bag))
    overrides.update(_overrides(args.frontend))
    try:
        return FrontEndConfig().with_changes(**overrides)
    except TypeError as exc:
        raise ParameterError(f"--frontend: {exc}") from None


def resolve_bag(bag: str | None, logs: bool = True) -> Path:
    """The input to use: the given path, or the built-in default dataset (generated on first use).

    ``logs``: the command also takes logs of odometry and place recognition (named in the error).
    """
    if bag is not None:
        path = Path(bag)
        if not path.exists():
            if not logs:
                raise InputFileError(f"{path}: no such bag; give an existing .bag file or omit BAG")
            raise InputFileError(
                f"{path}: no such file; give an existing bag or log file, or omit it"
            )
        return path
    from cogmap_core.datasets.cache import default_dataset_path

    return default_dataset_path(progress=_generation_progress)


def _generation_progress(done: int, total: int) -> None:
    sys.stderr.write(f"\rgenerating the default dataset (first use only): {done}/{total} frames")
    if done >= total:
        sys.stderr.write("\n")
    sys.stderr.flush()
