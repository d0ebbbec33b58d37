"""``cogmap sweep [BAG ...] --out DIR``: a map's size-fidelity trade-off over many settings.

The front end runs once per bag (its events are saved and reused); every cell -- one setting on
one bag -- builds one map on Dask and is appended to ``DIR/results.csv`` as it finishes; at the
end ``DIR/pareto.png`` and ``DIR/best.json`` show the Pareto front. See :mod:`app.sweep`.
"""

from __future__ import annotations

import argparse
import json
import sys
import tomllib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from app.cli_common import (
    add_frontend_arguments,
    add_topic_arguments,
    frontend_from_args,
    resolve_bag,
    topics_from_args,
)
from app.progress import ProgressBar
from app.sweep import (
    RESULTS_FILE,
    CellProgress,
    Sweep,
    SweepOptions,
    SweepResult,
    bag_source,
)
from cogmap_core.cognitive_map import MapMode
from cogmap_core.errors import InputFileError, ParameterError
from cogmap_core.parameter_table import flag_name
from cogmap_core.sweep import (
    MIN_COMPLETENESS,
    PARAMETER_NAMES,
    SPEC_FILE_KEYS,
    SweepSpec,
    parameter_name,
    sweep_spec,
)


def read_spec_file(path: Path) -> dict[str, Any]:
    """The content of a spec file: TOML (``.toml``), YAML (``.yaml``/``.yml``) or JSON."""
    if not path.is_file():
        raise InputFileError(f"{path}: no such spec file")
    suffix = path.suffix.lower()
    try:
        text = path.read_text()
        if suffix == ".toml":
            data = tomllib.loads(text)
        elif suffix in (".yaml", ".yml"):
            try:
                import yaml
            except ImportError:
                raise InputFileError(
                    f"{path}: reading YAML needs PyYAML (pip install pyyaml); or write TOML"
                ) from None
            data = yaml.safe_load(text)
        elif suffix == ".json":
            data = json.loads(text)
        else:
            raise InputFileError(f"{path}: spec files are .toml, .yaml, .yml or .json")
    except InputFileError:
        raise
    except Exception as exc:  # OSError, and TOML, YAML (not a ValueError) and JSON errors
        message = " ".join(str(exc).split())
        raise InputFileError(f"{path}: not a readable spec file ({message})") from None
    if not isinstance(data, dict):
        raise InputFileError(f'{path}: expected a table of parameters, e.g. delta = "2:8:13"')
    return data


def spec_from_args(args: argparse.Namespace) -> SweepSpec:
    """The sweep's settings: the spec file (if any), then the command-line parameters."""
    file_values: dict[str, Any] = {}
    samples = None
    seed = 0
    if args.spec is not None:
        path = Path(args.spec)
        data = read_spec_file(path)
        table = data.get("parameters", {})
        if not isinstance(table, dict):
            raise ParameterError(f"{path}: 'parameters' must be a table of parameter = values")
        items = list(table.items()) + [
            (k, v) for k, v in data.items() if k not in SPEC_FILE_KEYS and k != "parameters"
        ]
        for key, value in items:
            try:
                name = parameter_name(str(key))
            except ParameterError as exc:
                raise ParameterError(f"{path}: {exc}") from None
            file_values[name] = value
        samples = data.get("samples")
        seed = data.get("seed", 0)
    cli_values: dict[str, str] = {}
    for name in PARAMETER_NAMES:
        text = getattr(args, f"sweep_{name}")
        if text is not None:
            cli_values[name] = text
    for item in args.param:
        raw, sep, text = item.partition("=")
        if not sep:
            raise ParameterError(f"--param {item!r}: write NAME=VALUES, e.g. --param delta=2:8:13")
        name = parameter_name(raw)
        if name in cli_values:
            raise ParameterError(f"{name} is given twice on the command line; give it once")
        cli_values[name] = text
    if args.samples is not None:
        samples = args.samples
    if args.seed is not None:
        seed = args.seed
    return sweep_spec({**file_values, **cli_values}, samples, seed)


def _options(args: argparse.Namespace, spec: SweepSpec) -> SweepOptions:
    if args.workers is not None and args.workers < 1:
        raise ParameterError(f"--workers {args.workers}: give at least 1")
    if args.scheduler is not None and args.workers is not None:
        raise ParameterError("--workers sizes a local cluster; drop it with --scheduler")
    if not args.connect_timeout > 0:
        raise ParameterError(f"--connect-timeout {args.connect_timeout}: give seconds > 0")
    if not 0 < args.min_completeness <= 1:
        raise ParameterError(f"--min-completeness {args.min_completeness}: give a value in (0, 1]")
    return SweepOptions(
        spec=spec,
        mode=MapMode(args.map),
        scheduler=args.scheduler,
        workers=args.workers,
        connect_timeout=args.connect_timeout,
        ship_events=args.worker_events == "ship",
        min_completeness=args.min_completeness,
    )


def _say(text: str) -> None:
    print(f"cogmap sweep: {text}", file=sys.stderr, flush=True)


def _sweep(args: argparse.Namespace) -> int:
    spec = spec_from_args(args)  # validate before any work
    options = _options(args, spec)
    topics = topics_from_args(args)
    frontend_from_args(args, Path("-"))  # validate --frontend overrides now
    paths = [resolve_bag(b, logs=False) for b in args.bags] if args.bags else [resolve_bag(None)]
    sources = []
    for path in paths:
        frontend = None if path.suffix == ".npz" else frontend_from_args(args, path)
        sources.append(bag_source(path, frontend, topics))

    def frame_progress(label: str) -> ProgressBar:  # (prepare_events closes it)
        return ProgressBar(f"cogmap sweep: {label}")

    sweep = Sweep(sources, Path(args.out), options, say=_say, frame_progress=frame_progress)
    progress = CellProgress(len(sweep.cells))
    sweep.on_result = progress.update
    try:
        result = sweep.run()
    except KeyboardInterrupt:
        progress.close()
        _say(
            f"stopped; finished cells are saved in {Path(args.out) / RESULTS_FILE}: re-run the "
            "same command to compute the rest"
        )
        raise
    finally:
        progress.close()
    print(summary_text(result))
    return 0


def setting_text(entry: Mapping[str, Any], swept: Sequence[str]) -> str:
    """One setting of ``best.json`` as its swept parameters, e.g. ``delta=3.746 t_interval=2``.

    Args:
        entry: an entry of ``best.json`` (its ``params`` holds every map parameter).
        swept: the parameters to show, in order (``best.json``'s ``swept``).

    """
    return " ".join(f"{name}={entry['params'][name]:.4g}" for name in swept)


def figures_text(entry: Mapping[str, Any]) -> str:
    """The figures of an entry of ``best.json``: vertices, ATE, completeness and correctness.

    A figure the entry lacks (``None``) is shown as ``-``.
    """

    def fmt(value: float | None, spec: str) -> str:
        return "-" if value is None else format(value, spec)

    return (
        f"{entry['vertices']:5.0f} vertices, ATE {fmt(entry['ate_m'], '.4f')} m, completeness "
        f"{fmt(entry['completeness'], '.4f')}, correctness {fmt(entry['correctness'], '.4f')}"
    )


def summary_text(result: SweepResult) -> str:
    """What a finished sweep found: the paper's setting, the smallest complete map, the front."""
    best = result.best
    swept = list(best["swept"])
    paper = best.get("paper")
    smallest = best.get("smallest_complete")
    front = best["front_ate"]
    shown = front if len(front) <= 12 else front[:6] + front[-6:]
    entries = [e for e in [paper, smallest, *shown] if e]
    width = max([len(setting_text(e, swept)) for e in entries] + [10])
    label = f"smallest, compl >= {best['min_completeness']:g}"
    pad = max(len(label), 8)
    lines = [
        f"{result.cells} cells: {result.computed} computed now, {result.skipped} from earlier "
        f"runs ({best['map']} map, {best['settings']} settings of {' x '.join(swept)}"
        + ("" if best["paper_in_grid"] else " and the paper's")
        + ")"
    ]
    if paper:
        lines.append(
            f"{'paper':{pad}}  {setting_text(paper, swept):{width}}  {figures_text(paper)}"
        )
    if smallest:
        lines.append(
            f"{label:{pad}}  {setting_text(smallest, swept):{width}}  {figures_text(smallest)}"
        )
    else:
        lines.append(f"{label:{pad}}  none reaches it")
    lines.append(f"Pareto front, vertices vs ATE ({len(front)} settings):")
    for k, entry in enumerate(shown):
        if len(front) > 12 and k == 6:
            lines.append(f"{'':{pad}}  ... {len(front) - 12} more in best.json")
        lines.append(f"{'':{pad}}  {setting_text(entry, swept):{width}}  {figures_text(entry)}")
    beat = best["beat_paper"]
    lines.append(
        f"{len(beat)} settings have fewer vertices than the paper's and no worse ATE, "
        "completeness and correctness"
        + (f" (smallest: {setting_text(beat[0], swept)})" if beat else "")
    )
    lines.append(f"written: {', '.join(str(p) for p in result.files)}")
    return "\n".join(lines)


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``cogmap sweep``."""
    parser = subparsers.add_parser(
        "sweep",
        help="parameter sweep on Dask: map size against accuracy and layout fidelity",
        description="Build a map for every setting of a grid (or a random search) of map "
        "parameters on one or more bags (default: the built-in dataset), on a local Dask "
        "cluster or an existing one. The front end runs once per bag. Each finished cell is "
        "appended to DIR/results.csv; re-running the same command computes only the missing "
        "cells. DIR/pareto.png and DIR/best.json show the Pareto front of vertices against "
        "ATE and completeness. Values: LOW:HIGH:COUNT (numpy.linspace; :log for geomspace), "
        "A,B,C or a single value; with --samples, LOW:HIGH is drawn uniformly.",
    )
    parser.add_argument(
        "bags",
        nargs="*",
        metavar="BAG",
        help="iRat-layout ROS bags or recorded event files (*.npz); default: the built-in dataset",
    )
    parser.add_argument("--out", required=True, metavar="DIR", help="sweep folder")
    group = parser.add_argument_group(
        "map parameters", "values of any map parameter: LOW:HIGH:COUNT, A,B,C or a single value"
    )
    for name in PARAMETER_NAMES:
        group.add_argument(flag_name(name), dest=f"sweep_{name}", default=None, metavar="VALUES")
    group.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="NAME=VALUES",
        help="the same for any parameter by name (repeatable), e.g. --param delta=2:8:13",
    )
    group.add_argument(
        "--spec",
        default=None,
        metavar="FILE",
        help="a TOML, YAML or JSON file of parameter = values (and samples, seed); "
        "command-line values override it",
    )
    group.add_argument(
        "--samples", type=int, default=None, metavar="N", help="random search: N settings"
    )
    group.add_argument(
        "--seed", type=int, default=None, metavar="S", help="seed of the random search (0)"
    )
    parser.add_argument(
        "--map",
        choices=[m.value for m in MapMode],
        default=MapMode.COMPACT.value,
        help="which map each cell builds (default compact)",
    )
    parser.add_argument(
        "--min-completeness",
        type=float,
        default=MIN_COMPLETENESS,
        help=f"completeness the smallest map of best.json must reach (default {MIN_COMPLETENESS})",
    )
    dask = parser.add_argument_group("Dask")
    dask.add_argument(
        "--scheduler",
        default=None,
        metavar="tcp://HOST:PORT",
        help="run on this existing Dask cluster (default: a local cluster)",
    )
    dask.add_argument(
        "--workers",
        type=int,
        default=None,
        metavar="N",
        help="local cluster: N single-threaded worker processes (default: one per core)",
    )
    dask.add_argument(
        "--worker-events",
        choices=("ship", "path"),
        default="ship",
        help="ship: send each bag's events to the workers (default); path: workers read "
        "DIR/events themselves (DIR on a shared filesystem)",
    )
    dask.add_argument(
        "--connect-timeout",
        type=float,
        default=10.0,
        metavar="S",
        help="seconds to reach the scheduler and find workers (default 10)",
    )
    add_frontend_arguments(parser)
    # no --no-ground-truth: a sweep measures every map against the ground truth
    add_topic_arguments(parser, ground_truth_optional=False)
    parser.set_defaults(func=_sweep)
