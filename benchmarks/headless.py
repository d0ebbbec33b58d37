"""Headless-mode targets on the default dataset, printed as measured figures and ratios.

Runs ``cogmap run`` (default dataset, paper parameters) in a child process, then checks:

- compact / standard vertices and edges <= 0.15 (the paper reached 0.127 and 0.116), always
  beside layout fidelity: completeness and correctness of every map >= 0.98 at 8 cm (standard
  >= 0.99), edges per vertex of the standard map <= 1.5;
- every map's ATE <= 0.5 x the dead-reckoning ATE;
- scene_integration and compact ATE / standard ATE <= 1.2;
- loop-closure precision >= 0.95;
- the compact map's size changes by at most +-3 % from the end of lap 3 to the end of lap 6
  (the standard map grows); ``benchmarks/map_layouts.py`` also sets exploration apart;
- realtime factor >= 50 (data seconds per wall second, whole pipeline incl. JPEG decoding);
- peak memory of the run <= 500 MB;
- clustering pays off: optimisations and optimisation time against one optimisation per
  loop-closure edge (the maps rebuilt from the cached front-end events with T_interval -> 0).

The front end runs once: the benchmarked ``cogmap run`` saves its events (``--save-events``, into
a temporary folder, never the shared event cache) and the per-edge comparison replays them.

Usage: ``python benchmarks/headless.py [--out DIR] [--per-edge-seconds S]``
"""

from __future__ import annotations

import argparse
import csv
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from cogmap_core.cognitive_map import CognitiveMap, MapMode
from cogmap_core.config import MapParams
from cogmap_core.datasets.cache import DEFAULT_CONFIG, default_dataset_path
from cogmap_core.datasets.generator import plan_dataset
from cogmap_core.event_file import KIND_LINK, load_event_file
from cogmap_core.event_log import EventLog


def check(label: str, value: float, target: str, ok: bool) -> bool:
    """Print one target line."""
    print(f"  {label:58} {value:10.4f}   target {target:10} {'OK' if ok else 'MISSED'}")
    return ok


def lap_growth(sizes: Path, lap_times: tuple[float, ...]) -> dict[str, float]:
    """Relative vertex change of each map between the end of lap 3 and the end of lap 6."""
    with sizes.open() as handle:
        rows = list(csv.DictReader(handle))
    times = np.array([float(r["time"]) for r in rows])
    growth = {}
    for mode in MapMode:
        v = np.array([int(r[f"{mode.value}_vertices"]) for r in rows])
        start = v[max(np.searchsorted(times, lap_times[3], side="right") - 1, 0)]
        end = v[max(np.searchsorted(times, lap_times[6], side="right") - 1, 0)]
        growth[mode.value] = (end - start) / start
    return growth


def per_edge_optimisation(
    events_file: Path, seconds: float
) -> list[tuple[str, int, float, int, float]]:
    """Clustered vs one-optimisation-per-loop-edge on the first ``seconds`` of data.

    ``events_file``: the front end's events, as the benchmarked run saved them.

    Returns rows (map, clustered optimisations, clustered optimise s, per-edge optimisations,
    per-edge optimise s).
    """
    full = EventLog.from_recording(load_event_file(events_file))
    log = full.truncated(int(np.searchsorted(full.frame_time, seconds, side="right")))
    events = log.events
    rows = []
    for mode in MapMode:
        timings = []
        for params in (MapParams(), MapParams(t_interval=1e-9)):
            cmap = CognitiveMap(mode, params)
            cmap.apply_all(events)
            cmap.finish(log.frame_time[-1])
            timings.append((len(cmap.optimizations), sum(o.wall_s for o in cmap.optimizations)))
        rows.append((mode.value, *timings[0], *timings[1]))
    links = int(np.count_nonzero(log.columns()["kind"] == KIND_LINK))
    print(f"  ({links} loop-closure events in the first {seconds:.0f} s)")
    return rows


def main() -> None:
    """Run the benchmark."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, default=None, help="report folder (default: temp)")
    parser.add_argument(
        "--per-edge-seconds",
        type=float,
        default=240.0,
        help="data seconds used for the one-optimisation-per-edge comparison (default 240)",
    )
    args = parser.parse_args()
    bag = default_dataset_path()
    out = args.out or Path(tempfile.mkdtemp(prefix="cogmap-bench-")) / "run"
    # the run's own front-end pass gives the events of the per-edge comparison
    events = Path(tempfile.mkdtemp(prefix="cogmap-bench-events-")) / "run.events.npz"
    command = [sys.executable, "-m", "app", "run", str(bag), "--out", str(out), "--force"]
    command += ["--save-events", str(events)]
    started = time.perf_counter()
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    elapsed = time.perf_counter() - started
    peak_mb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0
    summary = json.loads((out / "summary.json").read_text())
    maps = summary["maps"]
    std, cmp_ = maps["standard"], maps["compact"]
    lap_times = plan_dataset(DEFAULT_CONFIG).trajectory.lap_times
    growth = lap_growth(out / "sizes.csv", lap_times)

    print(
        f"default dataset {bag.name}: {summary['frames']} frames, "
        f"{summary['data_duration_s']:.0f} s of data"
    )
    print(f"report in {out} (cogmap run took {elapsed:.1f} s incl. start-up)")
    dead_reckoning = summary["dead_reckoning_ate_m"]
    print(f"  dead reckoning ATE {dead_reckoning:.4f} m")
    for name, m in maps.items():
        print(
            f"  {name:18} vertices {m['vertices']:5d} edges {m['edges']:5d} "
            f"(E/V {m['edges_per_vertex']:.2f}) loop edges {m['loop_edges']:5d} "
            f"clusters {m['clusters']:4d} optimisations {m['optimizations']:4d} "
            f"({m['optimize_wall_s']:.2f} s) ATE {m['ate_m']:.4f} m "
            f"completeness {m['completeness']:.3f} correctness {m['correctness']:.3f}"
        )
    ok = True
    print("targets:")
    ok &= check(
        "compact / standard vertices",
        cmp_["vertices"] / std["vertices"],
        "<= 0.15",
        cmp_["vertices"] / std["vertices"] <= 0.15,
    )
    ok &= check(
        "compact / standard edges",
        cmp_["edges"] / std["edges"],
        "<= 0.15",
        cmp_["edges"] / std["edges"] <= 0.15,
    )
    for name, m in maps.items():
        floor = 0.99 if name == "standard" else 0.98
        fidelity = min(m["completeness"], m["correctness"])
        ok &= check(
            f"{name} min(completeness, correctness)", fidelity, f">= {floor}", fidelity >= floor
        )
        ok &= check(
            f"{name} ATE / dead-reckoning ATE",
            m["ate_m"] / dead_reckoning,
            "<= 0.5",
            m["ate_m"] <= 0.5 * dead_reckoning,
        )
    ok &= check(
        "standard edges per vertex",
        std["edges_per_vertex"],
        "<= 1.5",
        std["edges_per_vertex"] <= 1.5,
    )
    for name in ("scene_integration", "compact"):
        ratio = maps[name]["ate_m"] / std["ate_m"]
        ok &= check(f"{name} ATE / standard ATE", ratio, "<= 1.2", ratio <= 1.2)
    precision = summary["loop_closures"]["precision"]
    ok &= check("loop-closure precision", precision, ">= 0.95", precision >= 0.95)
    ok &= check(
        "compact vertex change, end of lap 3 to end of lap 6",
        growth["compact"],
        "+-0.03",
        abs(growth["compact"]) <= 0.03,
    )
    for name in ("standard", "scene_integration"):
        print(f"  {'(' + name + ' vertex change, laps 3-6)':58} {growth[name]:10.4f}")
    rtf = summary["realtime_factor"]
    ok &= check("realtime factor (data s / wall s)", rtf, ">= 50", rtf >= 50)
    ok &= check("peak memory of cogmap run (MB)", peak_mb, "<= 500", peak_mb <= 500)
    print(
        "clustering against one optimisation per loop-closure edge "
        f"(first {args.per_edge_seconds:.0f} s):"
    )
    for name, n_c, t_c, n_e, t_e in per_edge_optimisation(events, args.per_edge_seconds):
        print(
            f"  {name:18} clustered {n_c:4d} optimisations {t_c:7.2f} s | per edge {n_e:5d} "
            f"optimisations {t_e:7.2f} s | ratio count {n_c / max(n_e, 1):.3f} "
            f"time {t_c / max(t_e, 1e-9):.3f}"
        )
    print("all targets met" if ok else "SOME TARGETS MISSED")


if __name__ == "__main__":
    main()
