"""``cogmap make-log OUT_PREFIX``: generate an odometry + place-recognition log and its truth."""

from __future__ import annotations

import argparse

from cogmap_core.datasets.log_generator import (
    DRIFT_LEVELS,
    GeneratedLog,
    LogGeneratorConfig,
    generate_log,
)
from cogmap_core.datasets.log_routes import PATTERN_SPEED, PATTERNS
from cogmap_core.datasets.log_writer import LOG_FORMATS, check_outputs, output_paths, write_log
from cogmap_core.errors import ParameterError


def drift_value(text: str) -> str | float:
    """A drift level's name, or a dead-reckoning ATE in metres (validated by the config)."""
    if text in DRIFT_LEVELS:
        return text
    try:
        return float(text)
    except ValueError:
        raise ParameterError(
            f"drift {text!r} is neither a level ({', '.join(DRIFT_LEVELS)}) nor a "
            "dead-reckoning ATE in metres"
        ) from None


def config_from_args(args: argparse.Namespace) -> LogGeneratorConfig:
    """The generation settings given on the command line (validated)."""
    return LogGeneratorConfig(
        pattern=args.pattern,
        seed=args.seed,
        duration=args.duration,
        speed=args.speed,
        drift=drift_value(args.drift),
        false_fraction=args.false_fraction,
        structured_fraction=args.structured_fraction,
        near_fraction=args.near_fraction,
        score_threshold=args.score_threshold,
        keyframe_period=args.keyframe_period,
        detection_probability=args.detection,
        opposite_probability=args.opposite,
        trailing_loops=args.trailing_loops,
    )


def describe(log: GeneratedLog, paths: list[str], fmt: str) -> str:
    """The summary printed after writing: files, run, odometry and loop candidates."""
    cfg = log.config
    c = log.counts()
    minutes, seconds = divmod(round(log.duration), 60)
    e = log.errors
    drift = cfg.drift if isinstance(cfg.drift, str) else "target"
    share = c["false"] / c["usable"] if c["usable"] else 0.0
    lines = [
        f"wrote {', '.join(paths)} ({fmt})",
        f"  pattern {cfg.pattern}, seed {cfg.seed}: {minutes} min {seconds} s, "
        f"{log.path_length:.1f} m driven at {cfg.cruise_speed:g} m/s cruise, "
        f"{log.odometry.shape[0]} odometry samples, {log.ground_truth.shape[0]} ground-truth "
        "poses",
        f"  odometry: drift {drift} {e.target_ate:.1f} m -> dead-reckoning ATE "
        f"{log.dead_reckoning_ate:.2f} m (scale error {e.scale * 100:+.2f} %, yaw-rate bias "
        f"{e.bias:+.5f} rad/s, noise {e.sigma_v:.3f} m/s, {e.sigma_w:.4f} rad/s)",
        f"  loop candidates: {c['candidates']} from {c['queries']} queries; usable (score >= "
        f"{cfg.score_threshold:g}, not recent) {c['usable']}: {c['true']} true, {c['false']} "
        f"false ({share * 100:.1f} %: {c['structured']} structured, {c['near']} near misses, "
        f"{c['false'] - c['structured'] - c['near']} far)",
    ]
    if log.dead_reckoning_ate < 0.95 * e.target_ate:
        lines.append(
            f"  note: the drift target {e.target_ate:.1f} m is beyond what this route's area "
            "allows dead reckoning (its error curls back); a larger pattern reaches it"
        )
    return "\n".join(lines)


def _make_log(args: argparse.Namespace) -> int:
    config = config_from_args(args)
    check_outputs(output_paths(args.out, args.format), args.force)  # before the work
    log = generate_log(config)
    paths = write_log(log, args.out, args.format, force=args.force)
    print(describe(log, [str(p) for p in paths], args.format))
    return 0


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``make-log``."""
    d = LogGeneratorConfig()
    parser = subparsers.add_parser(
        "make-log",
        help="generate an odometry + place-recognition log with ground truth (TUC or CSV)",
        description="Simulate a wheeled robot driving a pattern and write its wheel odometry "
        "(10 Hz, biased and noisy), its place recognition's loop candidates (true, false and "
        "structured false matches, with scores) and the ground truth (5 Hz) in the TUC "
        "dataset's format or as CSV. The same options and seed give the same files. "
        "Patterns: " + ", ".join(f"{p} ({PATTERN_SPEED[p]:g} m/s)" for p in PATTERNS) + ".",
    )
    parser.add_argument(
        "out",
        metavar="OUT_PREFIX",
        help="start of the files' names: PREFIX_Input.txt and PREFIX_GT.txt (tuc), or "
        "PREFIX_odometry.csv, PREFIX_loops.csv, PREFIX_ground_truth.csv (csv)",
    )
    parser.add_argument(
        "--pattern",
        default=d.pattern,
        choices=PATTERNS,
        metavar="NAME",
        help=f"driving pattern: {', '.join(PATTERNS)} (default {d.pattern})",
    )
    parser.add_argument("--seed", type=int, default=d.seed, help=f"random seed (default {d.seed})")
    parser.add_argument(
        "--format", default="tuc", choices=LOG_FORMATS, help="file format (default tuc)"
    )
    parser.add_argument(
        "--duration",
        type=float,
        default=d.duration,
        metavar="S",
        help=f"seconds of data, 60-14400 (default {d.duration:g})",
    )
    parser.add_argument(
        "--speed",
        type=float,
        default=None,
        metavar="V",
        help="mean cruise speed in m/s, 0.3-1.5 (default: the pattern's)",
    )
    levels = ", ".join(f"{k} {lo:g}-{hi:g} m" for k, (lo, hi) in DRIFT_LEVELS.items())
    parser.add_argument(
        "--drift",
        default=d.drift,
        metavar="LEVEL|METRES",
        help=f"odometry drift: a level ({levels}; each seed draws its target in the range) or "
        f"the dead-reckoning ATE to aim at in metres (default {d.drift})",
    )
    parser.add_argument(
        "--false-fraction",
        type=float,
        default=d.false_fraction,
        metavar="F",
        help="share of false matches among the usable loop candidates (score at or above the "
        f"threshold), 0-0.9 (default {d.false_fraction:g})",
    )
    parser.add_argument(
        "--structured-fraction",
        type=float,
        default=d.structured_fraction,
        metavar="F",
        help="share of those false matches that are structured (the same wrong place again "
        f"and again), 0-1 (default {d.structured_fraction:g})",
    )
    parser.add_argument(
        "--near-fraction",
        type=float,
        default=d.near_fraction,
        metavar="F",
        help="share of near misses (1.2-4 m off) among the other false matches, 0-1 "
        f"(default {d.near_fraction:g}; the rest are far)",
    )
    parser.add_argument(
        "--score-threshold",
        type=float,
        default=d.score_threshold,
        metavar="S",
        help=f"score from which a candidate is usable (default {d.score_threshold:g}, the "
        "log reader's)",
    )
    parser.add_argument(
        "--keyframe-period",
        type=float,
        default=d.keyframe_period,
        metavar="S",
        help=f"mean seconds between place-recognition queries (default {d.keyframe_period:g})",
    )
    parser.add_argument(
        "--detection",
        type=float,
        default=d.detection_probability,
        metavar="P",
        help=f"chance a true match is found (default {d.detection_probability:g})",
    )
    parser.add_argument(
        "--opposite",
        type=float,
        default=d.opposite_probability,
        metavar="P",
        help="chance a place seen from the opposite direction is recognised "
        f"(default {d.opposite_probability:g})",
    )
    parser.add_argument(
        "--trailing-loops",
        type=float,
        default=d.trailing_loops,
        metavar="S",
        help="let the last query lie up to S seconds (at most 0.5) after the last odometry "
        "line, as some real logs do (default 0: none)",
    )
    parser.add_argument(
        "--force", action="store_true", help="replace existing files of these names"
    )
    parser.set_defaults(func=_make_log)
