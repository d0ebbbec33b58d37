"""The batch solves of an exact rebuild: Python cost functions against compiled ones.

An exact rebuild runs every optimisation of its cluster schedule again (``rebuild_floor.py``:
the solves are most of a full rebuild). cogmap's optimiser (``cogmap_core/optimizer.py``) hands
Ceres Python cost functions, vectorised over chunks of vertices (pyceres: a Python call per
residual block and evaluation; dynamic sparsity for the chunks' mostly-zero Jacobian blocks).
This benchmark records every graph each map's rebuild of the default dataset (or a bag given)
optimises and times three solvers on the same graphs, in the same schedule:

- **cogmap**: ``optimize_pose_graph`` as the maps call it (set-up, IRLS rounds, Ceres);
- **Ceres, C++ costs**: the anchor ``benchmarks/anchors/ceres_se2_irls.cc`` -- one residual block
  per edge with automatic derivatives, static sparsity, the same IRLS rounds (Geman-McClure weights
  of the loop closures, Huber on the other edges, the recorded options' scales, tolerance and
  iteration limits). It needs a C++ compiler and Ceres' headers (Debian: ``apt install g++
  libceres-dev``); cogmap itself installs with neither, so this is what compiled cost functions
  would give, not a path cogmap can take. Skipped, with the reason, when it cannot be built;
- **GTSAM**: Levenberg-Marquardt with the same robust noise models on every graph (one solve per
  graph; ``pip install gtsam``, the ``bench`` extra), when importable.

It prints per map the Ceres solves, iterations and milliseconds of each, and the ratios, then
the time each map's rebuild spends on its solves against the issue-27 targets (exact map within
400 ms after a T_interval or T_total change on the standard and scene-integration maps, within
200 ms on the compact map; ``--target-ms 2000`` for a 60-lap bag). Times are the best of
``--repeat`` runs. The last line reads
``solve floor: N ms cogmap, M ms Ceres with C++ costs, G ms GTSAM (standard map, K graphs)``.

    python benchmarks/solve_floor.py [BAG] [--repeat 3] [--target-ms MS]
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import pyceres  # noqa: E402
from solve_speed import Call, recorded_solves  # noqa: E402

from app.cli_common import resolve_bag  # noqa: E402
from app.events_cache import cached_bag_events  # noqa: E402
from cogmap_core import optimizer  # noqa: E402
from cogmap_core.cognitive_map import MapMode  # noqa: E402
from cogmap_core.datasets.cache import cache_dir  # noqa: E402
from cogmap_core.event_log import EventLog  # noqa: E402
from cogmap_core.map_modes import ALL_MODES  # noqa: E402
from cogmap_core.robust import IRLS_ITERATIONS  # noqa: E402

ANCHOR_SOURCE = ROOT / "benchmarks" / "anchors" / "ceres_se2_irls.cc"
#: issue 27: the exact map after a schedule change (standard, scene integration), any change
#: (compact)
TARGET_MS = {MapMode.STANDARD: 400.0, MapMode.SCENE_INTEGRATION: 400.0, MapMode.COMPACT: 200.0}


def time_cogmap(calls: list[Call], repeat: int) -> tuple[float, int, int]:
    """Best seconds of cogmap's optimiser on the calls, and its Ceres solves and iterations."""
    counts = [0, 0]
    real = pyceres.solve

    def counted(options: object, problem: object, summary: pyceres.SolverSummary) -> None:
        real(options, problem, summary)
        counts[0] += 1
        counts[1] += summary.num_successful_steps + summary.num_unsuccessful_steps - 1

    best = float("inf")
    pyceres.solve = counted  # the optimiser calls it as pyceres.solve
    try:
        for _ in range(repeat + 1):  # the first run warms up
            counts[:] = [0, 0]
            started = time.perf_counter()
            for graph, options, given in calls:
                optimizer.optimize_pose_graph(graph, options, **given)
            best = min(best, time.perf_counter() - started)
    finally:
        pyceres.solve = real
    return best, counts[0], counts[1]


def write_graphs(calls: list[Call], path: Path) -> None:
    """The anchor's input file (its source describes the layout)."""
    options = calls[0][1]
    model = options.loop_model
    header = [
        len(calls),
        options.huber_scale if options.huber_scale is not None else 1e300,
        model.scale if model is not None else 1e300,
        model.tolerance if model is not None else 1e-5,
        IRLS_ITERATIONS,
        options.max_iterations,
        options.function_tolerance,
    ]
    with path.open("wb") as out:
        np.asarray(header, dtype=np.float64).tofile(out)
        for graph, _, _ in calls:
            information = graph.information
            diagonal = information[:, [0, 1, 2], [0, 1, 2]]
            if np.count_nonzero(information) != np.count_nonzero(diagonal):
                raise SystemExit("the anchor takes diagonal information only")
            parts = [
                [graph.num_vertices, graph.num_edges],
                graph.poses,
                graph.fixed,
                np.stack([graph.edge_from, graph.edge_to], axis=1),
                graph.measurements,
                np.sqrt(diagonal),
                graph.loop_closures(),
            ]
            for part in parts:
                np.asarray(part, dtype=np.float64).tofile(out)


def build_anchor() -> tuple[Path | None, str]:
    """The anchor's executable (built once into the cache), or None and why not."""
    compiler = shutil.which("c++") or shutil.which("g++")
    if compiler is None:
        return None, "no C++ compiler (Debian: apt install g++ libceres-dev)"
    target = cache_dir() / "bench" / "ceres_se2_irls"
    source_time = ANCHOR_SOURCE.stat().st_mtime
    if target.exists() and target.stat().st_mtime >= source_time:
        return target, ""
    target.parent.mkdir(parents=True, exist_ok=True)
    partial = target.with_suffix(".partial")
    command = [compiler, "-O2", "-std=c++17", "-I/usr/include/eigen3", str(ANCHOR_SOURCE)]
    command += ["-o", str(partial), "-lceres", "-lglog"]
    built = subprocess.run(command, capture_output=True, text=True)
    if built.returncode != 0:
        first = (built.stderr.strip().splitlines() or ["?"])[0]
        return None, f"cannot build the anchor ({first}; Debian: apt install libceres-dev)"
    partial.replace(target)
    return target, ""


def time_anchor(executable: Path, graphs: Path, repeat: int) -> tuple[float, int, int]:
    """Best milliseconds of the anchor's solves (set-up included), its solves and iterations."""
    best = (float("inf"), 0, 0)
    for _ in range(repeat):
        line = subprocess.run(
            [str(executable), str(graphs)], check=True, capture_output=True, text=True
        ).stdout.split()
        figures = dict(zip(line[::2], line[1::2], strict=True))
        ms = float(figures["setup_ms"]) + float(figures["solve_ms"])
        if ms < best[0]:
            best = (ms, int(figures["solves"]), int(figures["iterations"]))
    return best


def time_gtsam(calls: list[Call], repeat: int) -> tuple[float, int] | None:
    """Best milliseconds of GTSAM's Levenberg-Marquardt on the graphs (set-up excluded)."""
    try:
        import gtsam  # type: ignore[import-not-found]
    except ImportError:
        return None
    robust, noise = gtsam.noiseModel.Robust, gtsam.noiseModel.mEstimator
    problems = []
    for graph, options, _ in calls:
        factors = gtsam.NonlinearFactorGraph()
        fixed = np.flatnonzero(graph.fixed).tolist() or [0]
        for vertex in fixed:
            prior = gtsam.noiseModel.Isotropic.Sigma(3, 1e-9)
            factors.add(gtsam.PriorFactorPose2(vertex, gtsam.Pose2(*graph.poses[vertex]), prior))
        loops = graph.loop_closures()
        for k in range(graph.num_edges):
            base = gtsam.noiseModel.Gaussian.Information(graph.information[k])
            if loops[k] and options.loop_model is not None:
                base = robust.Create(noise.GemanMcClure.Create(options.loop_model.scale), base)
            elif options.huber_scale is not None:
                base = robust.Create(noise.Huber.Create(options.huber_scale), base)
            z = gtsam.Pose2(*graph.measurements[k])
            factors.add(
                gtsam.BetweenFactorPose2(int(graph.edge_from[k]), int(graph.edge_to[k]), z, base)
            )
        start = gtsam.Values()
        for vertex in range(graph.num_vertices):
            start.insert(vertex, gtsam.Pose2(*graph.poses[vertex]))
        problems.append((factors, start, options.function_tolerance))
    best, iterations = float("inf"), 0
    for _ in range(repeat):
        total, count = 0.0, 0
        for factors, start, tolerance in problems:
            params = gtsam.LevenbergMarquardtParams()
            params.setRelativeErrorTol(tolerance)
            started = time.perf_counter()
            solver = gtsam.LevenbergMarquardtOptimizer(factors, start, params)
            solver.optimize()
            total += time.perf_counter() - started
            count += solver.iterations()
        if total < best:
            best, iterations = total, count
    return 1000.0 * best, iterations


def main() -> int:
    """Time each map's recorded solves with cogmap's optimiser and the anchors."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("file", nargs="?", help="bag (default: the default dataset)")
    parser.add_argument("--repeat", type=int, default=3, help="runs of each (best kept)")
    parser.add_argument(
        "--target-ms",
        type=float,
        help="one target for every map (issue 27 on 60 laps: 2000); default: the default "
        "dataset's (400 ms standard and scene integration, 200 ms compact)",
    )
    args = parser.parse_args()
    bag = resolve_bag(args.file)
    log = EventLog.from_recording(cached_bag_events(bag, print))
    executable, why_not = build_anchor()
    print(f"{bag.name}: each map's rebuild solves, best of {args.repeat}")
    if executable is None:
        print(f"  (Ceres with C++ costs skipped: {why_not})")
    print(
        f"{'map':18s} {'graphs':>6s} | {'cogmap ms':>9s} {'solves':>6s} {'iters':>5s} | "
        f"{'C++ ms':>7s} {'solves':>6s} {'iters':>5s} {'ratio':>6s} | {'GTSAM ms':>8s} "
        f"{'iters':>5s} {'ratio':>6s}"
    )
    figures: dict[MapMode, tuple[int, float, float, float]] = {}
    with tempfile.TemporaryDirectory(prefix="cogmap-solve-floor-") as folder:
        for mode in ALL_MODES:
            calls = recorded_solves(log, mode)
            seconds, solves, iterations = time_cogmap(calls, args.repeat)
            ours = 1000.0 * seconds
            row = f"{mode.value:18s} {len(calls):6d} | {ours:9.0f} {solves:6d} {iterations:5d} | "
            compiled = gtsam_ms = float("nan")
            if executable is not None:
                graphs = Path(folder) / f"{mode.value}.bin"
                write_graphs(calls, graphs)
                compiled, c_solves, c_iterations = time_anchor(executable, graphs, args.repeat)
                row += f"{compiled:7.0f} {c_solves:6d} {c_iterations:5d} {ours / compiled:6.2f} | "
            else:
                row += f"{'-':>7s} {'-':>6s} {'-':>5s} {'-':>6s} | "
            gtsam = time_gtsam(calls, args.repeat)
            if gtsam is not None:
                gtsam_ms, g_iterations = gtsam
                row += f"{gtsam_ms:8.0f} {g_iterations:5d} {ours / gtsam_ms:6.2f}"
            else:
                row += f"{'(no gtsam)':>8s}"
            print(row)
            figures[mode] = (len(calls), ours, compiled, gtsam_ms)
    print("against the issue-27 targets for an exact map (the solves alone, no replay or drawing):")
    for mode, (_, ours, compiled, _) in figures.items():
        target = args.target_ms or TARGET_MS[mode]
        print(
            f"  {mode.value:18s} target {target:4.0f} ms: cogmap's solves {ours:5.0f} ms"
            f" ({ours / target:.2f} x), C++ costs {compiled:5.0f} ms ({compiled / target:.2f} x)"
        )
    count, ours, compiled, gtsam_ms = figures[MapMode.STANDARD]
    print(
        f"solve floor: {ours:.0f} ms cogmap, {compiled:.0f} ms Ceres with C++ costs, "
        f"{gtsam_ms:.0f} ms GTSAM (standard map, {count} graphs)"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
