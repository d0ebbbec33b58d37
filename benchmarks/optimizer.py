"""Optimiser benchmark: our pyceres optimiser against GTSAM Levenberg-Marquardt, side by side.

For every 2D g2o graph in the data folder (default ``../shared/posegraph`` next to the repo) it
prints our final cost and wall time, GTSAM's (timed in this same process when ``gtsam`` is
installed -- ``pip install gtsam`` -- else taken from ``REFERENCE.md``), and the ratios the issue
sets targets on:

- final cost within 0.1 % of GTSAM's on every graph GTSAM converges on (ours / GTSAM <= 1.001);
- wall time ratio ours / GTSAM LM <= 1.0 on ``input_M3500_g2o.g2o`` and ``intel.g2o``.

Wall times are medians of ``--repeat`` runs. Ours is measured from the parsed graph to the
optimised poses (initialisation, Ceres problem set-up and solve); GTSAM's is ``optimize()`` plus
the optimiser's construction, as in REFERENCE.md.

Usage: ``python benchmarks/optimizer.py [--data DIR] [--repeat N]``
"""

from __future__ import annotations

import argparse
import re
import statistics
import time
from pathlib import Path

from cogmap_core.g2o import read_g2o
from cogmap_core.optimizer import OptimizerOptions, optimize_pose_graph

TIME_TARGETS = {"input_M3500_g2o.g2o", "intel.g2o"}
NOT_CONVERGED = {"input_M3500b_g2o.g2o", "MIT.g2o"}  # REFERENCE.md: LM stalls / local minimum


def reference_table(data: Path) -> dict[str, tuple[float, float]]:
    """GTSAM final cost and LM wall time per file, parsed from REFERENCE.md."""
    table: dict[str, tuple[float, float]] = {}
    path = data / "REFERENCE.md"
    if not path.exists():
        return table
    for line in path.read_text().splitlines():
        m = re.match(
            r"\|\s*([\w.]+\.g2o)\s*\|\s*([\d.e+]+)\s*\|\s*([\d.e+]+)[^|]*\|\s*([\d.]+) s", line
        )
        if m:
            table[m.group(1)] = (float(m.group(3)), float(m.group(4)))
    return table


def time_gtsam(path: Path, repeat: int) -> tuple[float, float, int] | None:
    """(final cost, median wall s, iterations) of GTSAM LM with default parameters, or None."""
    try:
        import gtsam  # type: ignore[import-not-found]
    except ImportError:
        return None
    walls = []
    cost = 0.0
    iterations = 0
    for _ in range(repeat):
        graph, initial = gtsam.readG2o(str(path), False)
        graph.add(
            gtsam.PriorFactorPose2(0, initial.atPose2(0), gtsam.noiseModel.Isotropic.Sigma(3, 1e-6))
        )
        started = time.perf_counter()
        optimizer = gtsam.LevenbergMarquardtOptimizer(
            graph, initial, gtsam.LevenbergMarquardtParams()
        )
        result = optimizer.optimize()
        walls.append(time.perf_counter() - started)
        cost = graph.error(result)
        iterations = optimizer.iterations()
    return cost, statistics.median(walls), iterations


def main() -> None:
    """Run the benchmark and print one table."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    default = Path(__file__).resolve().parents[2] / "shared" / "posegraph"
    parser.add_argument("--data", type=Path, default=default)
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    reference = reference_table(args.data)
    files = sorted(p for p in args.data.glob("*.g2o"))
    if not files:
        raise SystemExit(f"no .g2o files in {args.data}; pass --data DIR")
    header = (
        f"{'graph':22} {'V':>5} {'E':>5} {'our cost':>12} {'GTSAM cost':>12} {'cost ratio':>10} "
        f"{'our it':>6} {'our s':>7} {'GTSAM s':>8} {'time ratio':>10}  targets"
    )
    print(header)
    print("-" * len(header))
    all_ok = True
    for path in files:
        graph = read_g2o(path)
        options = OptimizerOptions(initialization="auto")
        walls = []
        result = None
        for _ in range(args.repeat):
            result = optimize_pose_graph(graph, options)
            walls.append(result.wall_s)
        assert result is not None
        ours = statistics.median(walls)
        measured = time_gtsam(path, args.repeat)
        if measured is not None:
            gt_cost, gt_wall, _ = measured
            source = "measured"
        elif path.name in reference:
            gt_cost, gt_wall = reference[path.name]
            source = "REFERENCE.md"
        else:
            gt_cost = gt_wall = float("nan")
            source = "none"
        cost_ratio = result.final_cost / gt_cost
        time_ratio = ours / gt_wall
        notes = []
        if path.name not in NOT_CONVERGED:
            ok = cost_ratio <= 1.001
            notes.append(f"cost {'OK' if ok else 'FAIL'}")
            all_ok &= ok
        else:
            notes.append("GTSAM did not converge: lower is better")
        if path.name in TIME_TARGETS:
            ok = time_ratio <= 1.0
            notes.append(f"time {'OK' if ok else 'FAIL'}")
            all_ok &= ok
        print(
            f"{path.name:22} {graph.num_vertices:5d} {graph.num_edges:5d} "
            f"{result.final_cost:12.4f} "
            f"{gt_cost:12.4f} {cost_ratio:10.5f} {result.iterations:6d} {ours:7.3f} {gt_wall:8.3f} "
            f"{time_ratio:10.3f}  {', '.join(notes)} (GTSAM {source})"
        )
    print("all targets met" if all_ok else "SOME TARGETS MISSED")


if __name__ == "__main__":
    main()
