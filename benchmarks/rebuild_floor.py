"""What an exact rebuild costs at least: the event replay alone against the whole rebuild.

A parameter change on the page rebuilds a map exactly as ``cogmap run`` builds it (see
``app/server/rebuild.py``): every front-end event is applied again and every batch optimisation
of the cluster schedule runs again. This benchmark splits that cost in two for each map, with
the compiled replay (``cogmap_core/compiled_replay.py``, numba) and with the map's Python code
(``COGMAP_COMPILED_REPLAY=0``), measured in the same process:

- **full**: the rebuild as the page does it (``cogmap_core.map_build.build_map``: the events and
  the Ceres solves);
- **events only**: the same replay with every solve skipped (the optimiser returns its start
  poses, so the maps differ; only the time counts). No exact rebuild can be faster than this:
  an α, β or δ change alters the compact map from its first proposal on, and a T_interval or
  T_total change alters every map from the first cluster whose schedule moves. Beside it, *Py
  search*: the same with the relocalisation test's path search in Python instead of compiled
  (:mod:`cogmap_core.compiled_search`), what that compiled search saves.

It also counts the optimisations each map runs. Their number is set by the cluster schedule,
and scene integration decides after each one which vertices to remove (the paper: "we remove
revisited vertices after optimization"), so its solves cannot be skipped or merged without
changing the map.

    python benchmarks/rebuild_floor.py [BAG] [--long BAG60]

Times are the best of ``--repeat`` runs in this process (the compiled code is loaded or compiled
before timing). The last line reads ``events-only floor: N ms compiled, M ms Python (MAP, BAG)``
for the last bag measured (the ``--long`` bag when one is given).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
import time
from collections.abc import Iterator
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import cogmap_core.cognitive_map as cognitive_map  # noqa: E402
from app.cli_common import resolve_bag  # noqa: E402
from app.events_cache import cached_bag_events  # noqa: E402
from cogmap_core import compiled_replay, compiled_search  # noqa: E402
from cogmap_core.cognitive_map import MapMode  # noqa: E402
from cogmap_core.config import MapParams  # noqa: E402
from cogmap_core.event_log import EventLog  # noqa: E402
from cogmap_core.events import MapEvent  # noqa: E402
from cogmap_core.map_build import BuildTask, build_map  # noqa: E402
from cogmap_core.optimizer import OptimizationResult, OptimizerOptions  # noqa: E402
from cogmap_core.posegraph import PoseGraph  # noqa: E402

#: A compact-map parameter change (as a δ slider move makes it); the other maps do not use δ.
CHANGED = MapParams().with_changes(delta=4.5)


def _start_poses(
    graph: PoseGraph, options: OptimizerOptions | None = None, **_: object
) -> OptimizationResult:
    """An optimiser that returns its start poses at no cost (events-only timing)."""
    return OptimizationResult(graph.poses.copy(), 0.0, 0.0, 0, 0.0, "SKIPPED")


@contextlib.contextmanager
def python_path_search() -> Iterator[None]:
    """The compiled replay's gate answers by the map's Python search instead of the compiled one."""
    compiled = compiled_search.PathSearch.__call__

    def reference(self: compiled_search.PathSearch, source: int, target: int, limit: float) -> bool:
        return self.graph.python_distance_below(source, target, limit)

    compiled_search.PathSearch.__call__ = reference  # type: ignore[method-assign]
    try:
        yield
    finally:
        compiled_search.PathSearch.__call__ = compiled  # type: ignore[method-assign]


@contextlib.contextmanager
def solves_skipped() -> Iterator[None]:
    """Every batch optimisation of the maps built inside returns its start poses."""
    real = cognitive_map.optimize_pose_graph
    cognitive_map.optimize_pose_graph = _start_poses
    try:
        yield
    finally:
        cognitive_map.optimize_pose_graph = real


def build_seconds(
    log: EventLog, mode: MapMode, repeat: int, compiled: bool, events: list[MapEvent] | None
) -> tuple[float, int]:
    """Best time (s) of the page's rebuild (``build_map``) of ``mode``, and its optimisations."""
    task = BuildTask(mode, CHANGED, log.frames, finish=True)
    best, count = float("inf"), 0
    os.environ[compiled_replay.ENV_SWITCH] = "1" if compiled else "0"
    try:
        for _ in range(repeat):
            started = time.perf_counter()
            cmap, _ = build_map(log, task, events=events)
            best = min(best, time.perf_counter() - started)
            count = len(cmap.optimizations)
    finally:
        os.environ.pop(compiled_replay.ENV_SWITCH, None)
    return best, count


def measure(bag: Path, repeat: int) -> tuple[float, float, MapMode]:
    """Print the table for one bag; return its lowest events-only floor (compiled, Python)."""
    log = EventLog.from_recording(cached_bag_events(bag, print))
    print(f"{bag.name}: {log.frames} frames, {log.event_count} events")
    header = (
        ("full ms", 9),
        ("(Python)", 9),
        ("events only ms", 15),
        ("(Py search)", 12),
        ("(Python)", 9),
        ("ratio", 6),
        ("optimisations", 14),
    )
    print(f"{'map':18s} " + " ".join(f"{name:>{width}s}" for name, width in header))
    events = list(log.events)  # made into objects once, as the page's workers hold them
    floors: list[tuple[float, float, MapMode]] = []
    for mode in (MapMode.COMPACT, MapMode.SCENE_INTEGRATION, MapMode.STANDARD):
        full, count = build_seconds(log, mode, repeat, True, None)
        full_py, _ = build_seconds(log, mode, repeat, False, events)
        with solves_skipped():
            events_only, _ = build_seconds(log, mode, repeat, True, None)
            with python_path_search():
                events_py_search, _ = build_seconds(log, mode, repeat, True, None)
            events_py, _ = build_seconds(log, mode, repeat, False, events)
        floors.append((events_only, events_py, mode))
        print(
            f"{mode.value:18s} {1000 * full:9.0f} {1000 * full_py:9.0f} {1000 * events_only:15.1f} "
            f"{1000 * events_py_search:12.1f} {1000 * events_py:9.1f} {events_only / full:6.2f} "
            f"{count:14d}"
        )
    return min(floors, key=lambda f: f[0])


def main() -> int:
    """Measure the default dataset (and a long bag when given)."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("bag", nargs="?", help="bag (default: the built-in default dataset)")
    parser.add_argument("--long", metavar="BAG", help="also a long bag (e.g. 60 laps)")
    parser.add_argument("--repeat", type=int, default=2, help="runs per figure (best kept)")
    args = parser.parse_args()
    bags = [resolve_bag(args.bag)] + ([Path(args.long)] if args.long else [])
    if not compiled_replay.available():
        raise SystemExit(f"no compiled replay: {compiled_replay.unavailable_reason()}")
    floor = [measure(bag, args.repeat) for bag in bags][-1]
    print(
        f"events-only floor: {1000 * floor[0]:.0f} ms compiled, {1000 * floor[1]:.0f} ms Python "
        f"({floor[2].value}, {bags[-1].name})"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
