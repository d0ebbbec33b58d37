"""``cogmap optimize IN.g2o OUT.g2o``: optimise a 2D g2o/TORO pose graph like the map does."""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import dataclass
from pathlib import Path

from cogmap_core.errors import InputFileError, OutputError
from cogmap_core.fileio import check_writable, output_error
from cogmap_core.g2o import read_g2o, write_g2o
from cogmap_core.optimizer import OptimizationResult, OptimizerOptions, optimize_pose_graph
from cogmap_core.robust import DEFAULT_LOOP_KERNEL, KERNELS, LoopClosureModel


def _finite_or_none(value: float) -> float | None:
    """JSON has no infinity: an overflowing cost is written as null."""
    return value if math.isfinite(value) else None


@dataclass(frozen=True, slots=True)
class OptimizeReport:
    """What ``cogmap optimize`` prints: sizes, costs (g2o's definition), iterations, wall time."""

    vertices: int
    edges: int
    initial_cost: float
    final_cost: float
    iterations: int
    wall_s: float
    loop_closures: int | None = None
    loop_closures_rejected: int | None = None

    def to_json(self) -> str:
        """One JSON line (with ``--robust``, also the loop closures and how many it rejected)."""
        line: dict[str, object] = {
            "vertices": self.vertices,
            "edges": self.edges,
            "initial_cost": _finite_or_none(self.initial_cost),
            "final_cost": _finite_or_none(self.final_cost),
            "iterations": self.iterations,
            "wall_s": round(self.wall_s, 6),
        }
        if self.loop_closures is not None:
            line["loop_closures"] = self.loop_closures
            line["loop_closures_rejected"] = self.loop_closures_rejected
        return json.dumps(line)


def check_destination(destination: Path) -> None:
    """Refuse an output path whose folder is missing or unwritable, or that is a folder."""
    folder = destination.parent if str(destination.parent) else Path(".")
    if not folder.is_dir():
        raise InputFileError(f"{destination}: directory {folder} does not exist; create it first")
    if destination.is_dir():
        raise OutputError(f"{destination} is a folder; give the path of the .g2o file to write")
    check_writable(folder)


def optimize_file(
    source: Path, destination: Path, options: OptimizerOptions
) -> tuple[OptimizeReport, OptimizationResult]:
    """Read ``source``, optimise, write ``destination`` (only on success); return the report.

    ``destination``'s folder is checked writable before the optimisation starts; the file is
    written atomically, so a failure leaves an existing ``destination`` as it was.

    Raises:
        InputFileError: ``source`` is missing or malformed, or the folder does not exist.
        OutputError: ``destination`` cannot be written (read-only folder, full disk...).

    """
    graph = read_g2o(source)
    check_destination(destination)
    result = optimize_pose_graph(graph, options)
    try:
        write_g2o(graph.with_poses(result.poses), destination)
    except OSError as exc:
        raise output_error(destination, exc) from None
    robust = options.loop_model is not None
    report = OptimizeReport(
        vertices=graph.num_vertices,
        edges=graph.num_edges,
        initial_cost=result.initial_cost,
        final_cost=result.final_cost,
        iterations=result.iterations,
        wall_s=result.wall_s,
        loop_closures=int(graph.loop_closures().sum()) if robust else None,
        loop_closures_rejected=result.num_rejected if robust else None,
    )
    return report, result


def _run(args: argparse.Namespace) -> int:
    loop_model = None
    if args.robust is not None:
        loop_model = LoopClosureModel(
            args.robust, args.robust_scale, graduated=args.robust == "geman_mcclure" and args.gnc
        )
    options = OptimizerOptions(
        huber_scale=args.huber,
        initialization=args.init,
        max_iterations=args.max_iterations,
        loop_model=loop_model,
    )
    report, _ = optimize_file(Path(args.input), Path(args.output), options)
    print(report.to_json())
    return 0


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``cogmap optimize``."""
    parser = subparsers.add_parser(
        "optimize",
        help="optimise a 2D g2o/TORO pose graph with Ceres and print one JSON line",
        description="Optimise any 2D g2o (VERTEX_SE2/EDGE_SE2) or TORO (VERTEX2/EDGE2) pose graph "
        "with the optimiser the cognitive map uses; write the result as g2o and print "
        '{"vertices", "edges", "initial_cost", "final_cost", "iterations", "wall_s"} with '
        "cost = 1/2 sum rho(|Sigma^-1/2 r|^2) as g2o defines it.",
    )
    parser.add_argument("input", metavar="IN", help="input .g2o file")
    parser.add_argument("output", metavar="OUT", help="output .g2o file (written only on success)")
    parser.add_argument(
        "--huber",
        type=float,
        default=None,
        metavar="SCALE",
        help="robustify every edge with a Huber loss of this scale (default: plain least squares)",
    )
    parser.add_argument(
        "--robust",
        nargs="?",
        const=DEFAULT_LOOP_KERNEL,
        choices=KERNELS,
        default=None,
        metavar="KERNEL",
        help="judge the loop closures (edges between vertices whose ids are not consecutive) "
        f"with a robust kernel, solved by reweighting (default kernel {DEFAULT_LOOP_KERNEL}; "
        f"one of {', '.join(KERNELS)}); the other edges keep --huber or least squares, and the "
        "printed line adds the loop closures and how many were rejected",
    )
    parser.add_argument(
        "--robust-scale",
        type=float,
        default=1.0,
        metavar="CHI",
        help="the robust kernel's scale in standard deviations of a loop closure (default 1)",
    )
    parser.add_argument(
        "--gnc",
        action="store_true",
        help="with --robust geman_mcclure: graduated non-convexity from least squares",
    )
    parser.add_argument(
        "--init",
        choices=("auto", "lago", "none"),
        default="auto",
        help="start from a LAGO linear initialisation, from the file's poses, or (auto, default) "
        "from LAGO only when the file's poses are far from consistent with its edges",
    )
    parser.add_argument(
        "--max-iterations", type=int, default=100, help="Ceres iteration limit (default 100)"
    )
    parser.set_defaults(func=_run)
