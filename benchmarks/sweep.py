"""Parameter sweep on Dask against the same cells built serially, on the default dataset.

The default dataset's front-end events are recorded once (cached as an event file, as
``cogmap sweep`` does); then a grid of delta x T_interval (default 20 x 10 = 200 settings, plus
the paper's setting) is built twice in the same run:

- serially: every cell in this one process, one after the other;
- on a Dask local cluster sized to the machine (one single-threaded worker process per core),
  through ``cogmap sweep``'s engine (results appended to ``results.csv`` as they finish, then
  ``pareto.png`` and ``best.json``).

Printed: both wall times and their ratio (with and without the cluster's start-up), the cost of
one cell (build + measures, and the serial total per cell), whether every cell's figures are
identical in the two runs, and the Pareto front (which settings beat the paper's).

Targets (issue "Parameter sweeps on Dask"): Dask >= 1.7x faster than serial with identical
figures per cell; one compact-map cell <= 1 s with cached events.

Usage: ``python benchmarks/sweep.py [--delta 2:8:20] [--t-interval 0.5:5:10] [--out DIR]``
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import psutil

from app.cmd_sweep import figures_text, setting_text
from app.sweep import (
    ResultsTable,
    Sweep,
    SweepOptions,
    bag_source,
    connect_local,
    default_workers,
    prepare_events,
    run_serially,
)
from cogmap_core.datasets import BagTopics
from cogmap_core.datasets.cache import default_dataset_path
from cogmap_core.datasets.profile import frontend_config_for
from cogmap_core.sweep import FIGURE_COLUMNS, sweep_spec


class CpuMeter:
    """Busy CPU seconds of the whole machine and of this process tree over a phase.

    Other processes' share tells whether something else competed for the cores (the machine may
    be shared): a phase's ratio is only meaningful when it is near zero.
    """

    def __init__(self) -> None:
        """Start measuring."""
        self.wall = time.perf_counter()
        self.system = self._system_busy()
        self.own = self._own()

    @staticmethod
    def _system_busy() -> float:
        t = psutil.cpu_times()
        return float(sum(t) - t.idle - getattr(t, "iowait", 0.0))

    @staticmethod
    def _own() -> float:
        total = 0.0
        me = psutil.Process()
        for proc in [me, *me.children(recursive=True)]:
            try:
                c = proc.cpu_times()
                total += c.user + c.system
            except psutil.Error:
                pass
        return total

    def stop(self) -> tuple[float, float, float]:
        """(wall s, own busy cores, other processes' busy cores) since the start."""
        wall = time.perf_counter() - self.wall
        system = self._system_busy() - self.system
        own = self._own() - self.own
        return wall, own / wall, max(system - own, 0.0) / wall


def main() -> None:
    """Run the benchmark."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--delta", default="2:8:20", help="delta values (default 2:8:20)")
    parser.add_argument("--t-interval", default="0.5:5:10", help="T_interval (default 0.5:5:10)")
    parser.add_argument("--out", type=Path, default=None, help="sweep folder (default: temp)")
    args = parser.parse_args()

    bag = default_dataset_path()
    source = bag_source(bag, frontend_config_for(bag), BagTopics())
    out = args.out or Path(tempfile.mkdtemp(prefix="cogmap-sweep-bench-"))
    started = time.perf_counter()
    events = prepare_events(source, out)
    print(
        f"default dataset: {events.frames} frames, {events.duration_s:.0f} s of data, "
        f"{events.events} events ({events.origin}, {time.perf_counter() - started:.1f} s); "
        f"dead-reckoning ATE {events.dead_reckoning_ate_m:.3f} m (the baseline every map's ATE "
        "below must beat)"
    )
    spec = sweep_spec({"delta": args.delta, "t_interval": args.t_interval})
    options = SweepOptions(spec=spec)
    sweep = Sweep([source], out, options)  # planned once: run serially, then on Dask below
    cells = sweep.cells
    print(f"{len(sweep.settings)} settings of delta x T_interval + the paper's: {len(cells)} cells")

    # ---- serially, in this process
    serial: dict[str, dict[str, Any]] = {}
    meter = CpuMeter()
    run_serially(cells, {source.key: events}, lambda c, o: serial.update({c.key: o}))
    serial_s, serial_own, serial_other = meter.stop()
    failed = [k for k, o in serial.items() if o["status"] != "ok"]
    per_cell = [o["build_wall_s"] + o["evaluate_wall_s"] for o in serial.values()]
    build = [o["build_wall_s"] for o in serial.values()]

    # ---- on a Dask local cluster, through the sweep engine
    started = time.perf_counter()
    connection = connect_local()
    startup_s = time.perf_counter() - started
    try:
        sweep.client = connection.client  # the same cells, now on the cluster
        meter = CpuMeter()
        result = sweep.run()
        dask_s, dask_own, dask_other = meter.stop()
    finally:
        connection.close()
    rows = ResultsTable(out / "results.csv").latest()
    mismatched = [
        key
        for key, outcome in serial.items()
        if any(rows[key][c] != outcome[c] for c in FIGURE_COLUMNS)
    ]

    ratio = serial_s / dask_s
    print(f"\nserial, one process:      {serial_s:7.1f} s ({serial_s / len(cells):.3f} s per cell)")
    print(
        f"Dask, {default_workers()} worker processes: {dask_s:7.1f} s "
        f"(+ {startup_s:.1f} s cluster start-up; {result.computed} cells computed)"
    )
    print(f"speed-up: {ratio:.2f}x ({serial_s / (dask_s + startup_s):.2f}x counting the start-up)")
    print(
        f"busy cores, this benchmark / other processes: serial {serial_own:.2f} / "
        f"{serial_other:.2f}, Dask {dask_own:.2f} / {dask_other:.2f}"
    )
    print(
        f"one cell: build + measures median {statistics.median(per_cell):.3f} s, max "
        f"{max(per_cell):.3f} s (map build median {statistics.median(build):.3f} s)"
    )
    print(
        f"figures identical per cell (serial vs Dask, {len(FIGURE_COLUMNS)} figures): "
        f"{len(cells) - len(mismatched)}/{len(cells)}; failed cells: {len(failed)}"
    )

    best = result.best  # what best.json holds
    swept = best["swept"]
    paper = best["paper"]
    print(f"\nPareto front on the default dataset ({out / 'pareto.png'}):")
    print(f"  paper's setting      {setting_text(paper, swept):36} {figures_text(paper)}")
    smallest = best["smallest_complete"]
    if smallest:
        print(f"  smallest, compl>=.98 {setting_text(smallest, swept):36} {figures_text(smallest)}")
    print(f"  front vertices vs ATE ({len(best['front_ate'])} settings):")
    for entry in best["front_ate"]:
        print(f"    {setting_text(entry, swept):53} {figures_text(entry)}")
    print(f"  front vertices vs completeness ({len(best['front_completeness'])} settings):")
    for entry in best["front_completeness"]:
        print(f"    {setting_text(entry, swept):53} {figures_text(entry)}")
    beat = best["beat_paper"]
    print(
        f"  {len(beat)} settings have fewer vertices than the paper's and no worse ATE, "
        "completeness and correctness; the 10 smallest:"
    )
    for entry in beat[:10]:
        print(f"    {setting_text(entry, swept):53} {figures_text(entry)}")

    quiet = max(serial_other, dask_other) < 0.15
    checks = [
        (f"Dask >= 1.7x faster than serial ({ratio:.2f}x)", ratio >= 1.7),
        ("identical figures per cell", not mismatched and not failed),
        (f"one cell <= 1 s (max {max(per_cell):.3f} s)", max(per_cell) <= 1.0),
    ]
    print()
    for label, ok in checks:
        print(f"{'OK    ' if ok else 'MISSED'} {label}")
    if not quiet:
        print("NOTE   other processes used the cores during the run: the speed-up is unreliable")


if __name__ == "__main__":
    main()
