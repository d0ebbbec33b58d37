"""The batch optimiser's time on a map rebuild's solves, against a recorded git revision of it.

A map rebuild runs one Ceres solve per cluster of the schedule (``cogmap_core/optimizer.py``).
This benchmark builds each map of the default dataset (or a bag or log given) once, as the page
rebuilds it (``cogmap_core.map_build.build_map``), recording every graph the map hands to
:func:`~cogmap_core.optimizer.optimize_pose_graph`; then it solves the recorded graphs with the
optimiser of this working tree (*new*) and with ``cogmap_core/optimizer.py`` as it was at a git
revision (*old*, ``--baseline``, loaded from ``git show`` into this process), alternating the
two, ``--repeat`` times each (best kept). It prints per map the two times, their ratio and the
largest difference between the two results (positions in metres, headings in radians), which
must stay below 1e-6. The last line reads
``solve time old/new: R (standard map, N solves: A ms -> B ms)``.

    python benchmarks/solve_speed.py [FILE] [--baseline REV] [--repeat N]
"""

from __future__ import annotations

import argparse
import importlib.util
import inspect
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from types import ModuleType

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import cogmap_core.cognitive_map as cognitive_map  # noqa: E402
from app.cli_common import resolve_bag  # noqa: E402
from app.events_cache import cached_bag_events  # noqa: E402
from cogmap_core import optimizer  # noqa: E402
from cogmap_core.cognitive_map import MapMode  # noqa: E402
from cogmap_core.config import MapParams  # noqa: E402
from cogmap_core.event_log import EventLog  # noqa: E402
from cogmap_core.map_build import BuildTask, build_map  # noqa: E402
from cogmap_core.map_modes import ALL_MODES  # noqa: E402

#: The optimiser before the solves were made faster (issue 27, part 3).
BASELINE = "58bc9db"

Call = tuple[object, object, dict[str, object]]


def optimizer_at(revision: str) -> ModuleType:
    """``cogmap_core/optimizer.py`` at a git revision, as a module of its own."""
    source = subprocess.run(
        ["git", "-C", str(ROOT), "show", f"{revision}:cogmap_core/optimizer.py"],
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    with tempfile.TemporaryDirectory(prefix="cogmap-optimizer-") as folder:
        path = Path(folder) / "optimizer_baseline.py"
        path.write_text(source)
        spec = importlib.util.spec_from_file_location("optimizer_baseline", path)
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = module  # dataclasses look their module up
        spec.loader.exec_module(module)
    return module


def recorded_solves(log: EventLog, mode: MapMode) -> list[Call]:
    """Every (graph, options, keyword arguments) the map's rebuild hands to the optimiser."""
    calls: list[Call] = []
    real = cognitive_map.optimize_pose_graph

    def record(graph, options=None, **given):  # noqa: ANN001, ANN003, ANN202
        kept = {name: None if value is None else value.copy() for name, value in given.items()}
        calls.append((graph.copy(), options, kept))
        return real(graph, options, **given)

    cognitive_map.optimize_pose_graph = record
    try:
        build_map(log, BuildTask(mode, MapParams(), log.frames, finish=True))
    finally:
        cognitive_map.optimize_pose_graph = real
    return calls


def accepted_arguments(module: ModuleType, calls: list[Call]) -> tuple[list[Call], list[str]]:
    """The calls with only the keyword arguments ``module``'s optimiser takes, and those left out.

    An older optimiser may not know an argument the maps pass now (``clusters``,
    ``merged_on``); it then solves without it, and the two results may differ where that
    argument decides (the largest difference says so).
    """
    known = inspect.signature(module.optimize_pose_graph).parameters
    left_out = sorted({name for _, _, given in calls for name in given if name not in known})
    kept = [
        (graph, options, {name: value for name, value in given.items() if name in known})
        for graph, options, given in calls
    ]
    return kept, left_out


def solve_all(module: ModuleType, calls: list[Call]) -> tuple[float, list]:
    """Seconds to solve every recorded graph with ``module``'s optimiser, and the results."""
    started = time.perf_counter()
    results = [module.optimize_pose_graph(g, o, **given) for g, o, given in calls]
    return time.perf_counter() - started, results


def largest_difference(old: list, new: list) -> float:
    """The largest difference between two lists of results (metres or radians)."""
    worst = 0.0
    for a, b in zip(old, new, strict=True):
        position = np.abs(a.poses[:, :2] - b.poses[:, :2]).max(initial=0.0)
        heading = np.abs(np.angle(np.exp(1j * (a.poses[:, 2] - b.poses[:, 2])))).max(initial=0.0)
        worst = max(worst, float(position), float(heading))
    return worst


def main() -> int:
    """Time the solves of the three maps' rebuilds, old against new."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("file", nargs="?", help="bag or log (default: the default dataset)")
    parser.add_argument("--baseline", default=BASELINE, help=f"git revision (default {BASELINE})")
    parser.add_argument("--repeat", type=int, default=5, help="runs of each (best kept)")
    args = parser.parse_args()
    bag = resolve_bag(args.file)
    log = EventLog.from_recording(cached_bag_events(bag, print))
    old = optimizer_at(args.baseline)
    print(f"{bag.name}: old = optimizer.py at {args.baseline}, new = this tree")
    print(
        f"{'map':18s} {'solves':>6s} {'old ms':>8s} {'new ms':>8s} {'old/new':>8s} {'max diff':>9s}"
    )
    figures: dict[MapMode, tuple[int, float, float]] = {}
    for mode in ALL_MODES:
        calls = recorded_solves(log, mode)
        old_calls, left_out = accepted_arguments(old, calls)
        if left_out:
            print(f"  ({mode.value}: the old optimiser solves without {', '.join(left_out)})")
        solve_all(old, old_calls)  # warm both up (imports, caches)
        solve_all(optimizer, calls)
        best_old = best_new = float("inf")
        diff = 0.0
        for _ in range(args.repeat):  # alternating: the machine's load hits both alike
            t_old, r_old = solve_all(old, old_calls)
            t_new, r_new = solve_all(optimizer, calls)
            best_old, best_new = min(best_old, t_old), min(best_new, t_new)
            diff = max(diff, largest_difference(r_old, r_new))
        figures[mode] = (len(calls), best_old, best_new)
        print(
            f"{mode.value:18s} {len(calls):6d} {1000 * best_old:8.0f} {1000 * best_new:8.0f} "
            f"{best_old / best_new:8.2f} {diff:9.1e}"
        )
    count, best_old, best_new = figures[MapMode.STANDARD]
    print(
        f"solve time old/new: {best_old / best_new:.2f} (standard map, {count} solves: "
        f"{1000 * best_old:.0f} ms -> {1000 * best_new:.0f} ms)"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
