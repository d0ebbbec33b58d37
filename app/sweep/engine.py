"""One sweep, start to end: plan the cells, record the events, run what is missing, analyse.

:class:`Sweep` ties the package together: the folder and its manifest
(:mod:`app.sweep.manifest`), each bag's events (:mod:`app.sweep.events`), the cells
(:mod:`app.sweep.cells`) run on Dask (:mod:`app.sweep.dask_backend`), and the results table, the
Pareto figure and ``best.json`` (:mod:`app.sweep.results`).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

from app.events_cache import BagSource, FrameProgress
from app.params_file import BEST_FORMAT
from app.progress import ProgressBar
from app.report_figures import save_figure
from app.sweep.cells import Cell, cells_digest, plan_cells, result_row
from app.sweep.dask_backend import (
    DaskConnection,
    check_worker_paths,
    connect_local,
    connect_remote,
    run_on_dask,
)
from app.sweep.errors import FailedCells, SweepError
from app.sweep.events import BagEvents, prepare_events
from app.sweep.manifest import (
    BEST_FILE,
    MANIFEST_FILE,
    PARETO_FILE,
    RESULTS_FILE,
    SWEEP_FORMAT,
    SWEEP_VERSION,
    locked_folder,
    manifest_bag_records,
    write_json,
)
from app.sweep.results import ResultsTable, pareto_figure
from cogmap_core import __version__
from cogmap_core.cognitive_map import MapMode
from cogmap_core.config import MapParams
from cogmap_core.evaluation import LAYOUT_RADIUS
from cogmap_core.sweep import (
    GROWTH_FRACTION,
    MIN_COMPLETENESS,
    SettingFigures,
    SweepSpec,
    aggregate_settings,
    beats,
    front_ate,
    front_completeness,
    smallest_complete,
)


class CellProgress(ProgressBar):
    """``cogmap sweep [#####.....]  45.0% 90/200 cells  1 failed  34 s  ~41 s left`` on stderr."""

    def __init__(
        self, total: int, label: str = "cogmap sweep", stream: TextIO | None = None
    ) -> None:
        """A bar for ``total`` cells."""
        super().__init__(label, stream)
        self.total = total
        self.started = time.monotonic()

    def update(self, done: int, failed: int) -> None:
        """Redraw (at most 8 times a second, and always at the end)."""
        elapsed = time.monotonic() - self.started
        left = ""
        if 0 < done < self.total:
            left = f"  ~{elapsed / done * (self.total - done):.0f} s left"
        failures = f"  {failed} failed" if failed else ""
        self.draw(done, self.total, f"{done}/{self.total} cells{failures}  {elapsed:.0f} s{left}  ")


# --------------------------------------------------------------------------- the sweep
@dataclass
class SweepOptions:
    """How to run a sweep (besides the bags and the folder).

    Attributes:
        spec: the settings to try.
        mode: which map each cell builds.
        scheduler: ``tcp://host:port`` of an existing Dask cluster, or ``None`` for a local one.
        workers: local cluster size (default: one per core).
        processes: local workers as processes (``False``: threads in this process, for tests).
        connect_timeout: seconds to reach a scheduler and find workers.
        ship_events: send the events to the workers (else they read ``DIR/events``).
        min_completeness: completeness the smallest complete map must reach.

    """

    spec: SweepSpec
    mode: MapMode = MapMode.COMPACT
    scheduler: str | None = None
    workers: int | None = None
    processes: bool = True
    connect_timeout: float = 10.0
    ship_events: bool = True
    min_completeness: float = MIN_COMPLETENESS


@dataclass
class SweepResult:
    """What a finished sweep produced.

    Attributes:
        out_dir: the sweep folder.
        cells: cells of the sweep.
        computed: cells computed by this run.
        skipped: cells found finished in ``results.csv``.
        failed: cells whose last attempt failed.
        best: the content of ``best.json``.
        files: files written.

    """

    out_dir: Path
    cells: int
    computed: int
    skipped: int
    failed: int
    best: dict[str, Any] = field(default_factory=dict)
    files: list[Path] = field(default_factory=list)


class Sweep:
    """One sweep: plan the cells, record the events, run what is missing, analyse.

    ``run()`` reads as the steps it performs. ``on_result(done, failed)`` is called after each
    recorded cell (the progress bar; tests use it to interrupt a sweep part-way).
    """

    def __init__(
        self,
        bags: Sequence[BagSource],
        out_dir: Path,
        options: SweepOptions,
        say: Callable[[str], None] | None = None,
        frame_progress: Callable[[str], FrameProgress | None] | None = None,
        on_result: Callable[[int, int], None] | None = None,
        client: Any | None = None,
    ) -> None:
        """Plan a sweep of ``bags`` into ``out_dir`` (nothing is written yet).

        Args:
            bags: the bags (see :func:`bag_source`).
            out_dir: the sweep folder.
            options: settings, map, cluster.
            say: where to print one-line notes (default: nowhere).
            frame_progress: a progress callback factory for the front end, per bag.
            on_result: called with (cells done, cells failed) after each recorded cell.
            client: an existing ``distributed.Client`` to use instead of connecting.

        """
        keys = [b.key for b in bags]
        if len(set(keys)) != len(keys):
            raise SweepError("the same bag is given twice; give each bag once")
        if not bags:
            raise SweepError("no bag given")
        self.bags = list(bags)
        self.out_dir = Path(out_dir)
        self.options = options
        self.say = say or (lambda _text: None)
        self.frame_progress = frame_progress
        self.on_result = on_result
        self.client = client
        self.settings = options.spec.settings()
        self.paper = options.spec.paper_params()
        self._all_settings = list(self.settings)
        if self.paper not in set(self._all_settings):
            self._all_settings.append(self.paper)  # the reference, built beside the grid
        self.cells = plan_cells(self.bags, self._all_settings, options.mode)
        self.digest = cells_digest(self.cells)
        self.events: dict[str, BagEvents] = {}
        self._manifest_bags: dict[str, dict[str, Any]] = {}  # the folder's records, by bag key
        self.files: list[Path] = []

    # ------------------------------------------------------------------ steps
    def run(self) -> SweepResult:
        """Run the sweep (resuming a folder of the same sweep); return what it produced."""
        with locked_folder(self.out_dir, self.digest) as previous:
            # kept before the first write replaces them: a finished sweep reuses its figures
            self._manifest_bags = manifest_bag_records(previous)
            self._write_manifest("running")
            connection: DaskConnection | None = None
            try:
                table = ResultsTable(self.out_dir / RESULTS_FILE)
                todo, skipped = self._missing_cells(table)
                client = self.client
                if todo and client is None and self.options.scheduler is not None:
                    # an unreachable cluster is reported before any front end runs
                    connection = connect_remote(
                        self.options.scheduler, self.options.connect_timeout
                    )
                self._record_events(every_cell_done=not todo)
                if todo and client is None:
                    if connection is None:
                        connection = connect_local(self.options.workers, self.options.processes)
                    self._announce(connection, len(todo))
                    client = connection.client
                if todo and not self.options.ship_events:
                    check_worker_paths(client, self._event_paths())
                computed = self._compute(table, todo, client)
                if connection is not None:
                    connection.close()
                    connection = None
                result = self._analyse(table, computed, skipped)
            except KeyboardInterrupt:
                self._write_manifest("interrupted")
                raise
            except FailedCells:
                raise  # the manifest says "incomplete" already
            except BaseException as exc:
                self._write_manifest("failed", str(exc))
                raise
            finally:
                if connection is not None:
                    connection.close()
            return result

    def _announce(self, connection: DaskConnection, cells: int) -> None:
        self.say(f"running {cells} cells on a {connection.description}")
        if connection.dashboard:
            self.say(f"Dask dashboard: {connection.dashboard}")
        elif connection.cluster is not None:
            self.say("Dask dashboard: off (pip install bokeh to get one)")

    def _manifest(self, status: str, message: str = "") -> dict[str, Any]:
        spec = self.options.spec
        return {
            "format": SWEEP_FORMAT,
            "version": SWEEP_VERSION,
            "cogmap": __version__,
            "status": status,
            "message": message,
            "digest": self.digest,
            "map": self.options.mode.value,
            "spec": spec.to_dict(),
            "swept": list(spec.swept),
            "settings": len(self.settings),
            "paper": self.paper.to_dict(),
            "cells": len(self.cells),
            "layout_radius_m": LAYOUT_RADIUS,
            "size_change_window": f"last {GROWTH_FRACTION:g} of the data",
            "bags": [self._bag_record(b) for b in self.bags],
        }

    def _write_manifest(self, status: str, message: str = "") -> None:
        path = self.out_dir / MANIFEST_FILE
        write_json(path, self._manifest(status, " ".join(message.split())))
        if path not in self.files:
            self.files.append(path)

    def _bag_record(self, bag: BagSource) -> dict[str, Any]:
        """A bag's entry in ``sweep.json``: its figures once known (this run's or the folder's)."""
        if bag.key in self.events:
            return self.events[bag.key].to_dict()
        earlier = self._manifest_bags.get(bag.key)
        if earlier is not None:  # kept until this run knows them (e.g. it fails before)
            return earlier
        return {"bag": str(bag.path), "label": bag.label, "key": bag.key}

    def _record_events(self, every_cell_done: bool = False) -> None:
        """Each bag's events and figures (:class:`BagEvents`), then the manifest with them.

        ``every_cell_done``: nothing is left to compute, so a bag whose figures the folder's
        ``sweep.json`` holds is not loaded at all (an older manifest without them: it is).
        """
        for bag in self.bags:
            events = None
            if every_cell_done and bag.key in self._manifest_bags:
                events = BagEvents.from_manifest_record(
                    bag, self.out_dir, self._manifest_bags[bag.key]
                )
            if events is None:
                events = prepare_events(bag, self.out_dir, self.frame_progress, self.say)
            self.events[bag.key] = events
            note = {
                "front end": "front end run, events saved",
                "cache": "events from the cache",
                "folder": "events from the sweep folder",
                "event file": "recorded event file",
                "manifest": "every cell done, events not loaded",
            }[events.origin]
            self.say(
                f"{bag.label}: {events.frames} frames, {events.duration_s:.0f} s of data, "
                f"{events.events} events ({note}: {events.events_path})"
            )
        self._write_manifest("running")

    def _missing_cells(self, table: ResultsTable) -> tuple[list[Cell], int]:
        latest = table.latest()
        todo = [c for c in self.cells if latest.get(c.key, {}).get("status") != "ok"]
        return todo, len(self.cells) - len(todo)

    def _compute(self, table: ResultsTable, todo: Sequence[Cell], client: Any) -> int:
        if not todo:
            self.say(f"all {len(self.cells)} cells are already in {table.path}; nothing to compute")
            return 0
        run = max((int(r["run"]) for r in table.rows if r.get("run") is not None), default=0) + 1
        done = len(self.cells) - len(todo)
        failed = 0
        if done:
            self.say(f"{done} of {len(self.cells)} cells already finished; computing {len(todo)}")
        computed = 0

        def record(cell: Cell, outcome: dict[str, Any]) -> None:
            nonlocal done, failed, computed
            table.append(result_row(cell, run, outcome))
            done += 1
            computed += 1
            failed += outcome.get("status") != "ok"
            if self.on_result is not None:
                self.on_result(done, failed)

        run_on_dask(client, todo, self.events, record, self.options.ship_events)
        return computed

    def _event_paths(self) -> list[str]:
        return [str(self.events[b.key].events_path.resolve()) for b in self.bags]

    def _analyse(self, table: ResultsTable, computed: int, skipped: int) -> SweepResult:
        latest = table.latest()
        rows = [latest[c.key] for c in self.cells if c.key in latest]
        missing = len(self.cells) - len(rows)
        if missing:
            raise SweepError(
                f"{missing} of {len(self.cells)} cells have no result; re-run the same command "
                "to compute them"
            )
        good = [r for r in rows if r["status"] == "ok"]
        failed = [r for r in rows if r["status"] != "ok"]
        setting_figures = aggregate_settings(good, len(self.bags))
        best = self._best(setting_figures, len(failed))
        write_json(self.out_dir / BEST_FILE, best)
        self.files.append(self.out_dir / BEST_FILE)
        figure = pareto_figure(best, list(setting_figures.values()), self._title(len(failed)))
        self.files += save_figure(figure, self.out_dir / PARETO_FILE)  # and pareto.svg
        result = SweepResult(
            self.out_dir, len(self.cells), computed, skipped, len(failed), best, list(self.files)
        )
        if failed:
            self._write_manifest("incomplete", f"{len(failed)} cells failed")
            first = failed[0]
            raise FailedCells(
                f"{len(failed)} of {len(self.cells)} cells failed (first: {first['error']}); "
                f"their errors are in {table.path}, best.json and pareto.png leave them out; "
                "re-run the same command to retry them"
            )
        self._write_manifest("complete")
        return result

    def _title(self, failed: int) -> str:
        names = ", ".join(b.label for b in self.bags)
        swept = " x ".join(self.options.spec.swept)
        note = f"  INCOMPLETE: {failed} cells failed" if failed else ""
        mode = self.options.mode.value
        extra = "" if len(self._all_settings) == len(self.settings) else " + the paper's"
        return f"{mode} map, {len(self.settings)} settings of {swept}{extra} on {names}{note}"

    def _best(self, figures: Mapping[MapParams, SettingFigures], failed: int) -> dict[str, Any]:
        swept = self.options.spec.swept
        # every setting built, the paper's included (when it is not in the grid it is one more)
        candidates = [figures[p] for p in self._all_settings if p in figures]
        paper = figures.get(self.paper)
        smallest = smallest_complete(candidates, self.options.min_completeness)
        beat = [] if paper is None else [s for s in candidates if beats(s, paper)]
        beat.sort(key=lambda s: (s.vertices, s.ate_m))

        def entry(s: SettingFigures | None) -> dict[str, Any] | None:
            return None if s is None else s.to_dict(swept)

        return {
            "format": BEST_FORMAT,
            "version": SWEEP_VERSION,
            "complete": failed == 0,
            "map": self.options.mode.value,
            "bags": [b.label for b in self.bags],
            "swept": list(swept),
            "cells": {"total": len(self.cells), "failed": failed},
            "settings": len(self.settings),
            "paper_in_grid": len(self._all_settings) == len(self.settings),
            "min_completeness": self.options.min_completeness,
            "paper": entry(paper),
            "smallest_complete": entry(smallest),
            "front_ate": [entry(s) for s in front_ate(candidates)],
            "front_completeness": [entry(s) for s in front_completeness(candidates)],
            "beat_paper": [entry(s) for s in beat],
            "notes": (
                "vertices, edges and ATE are means over the bags, completeness and correctness "
                "the worst bag's; front_ate: no setting has fewer vertices and lower ATE; "
                "front_completeness: no setting has fewer vertices and higher completeness; "
                "smallest_complete: fewest vertices with completeness >= min_completeness; "
                "beat_paper: fewer vertices than the paper's setting and no worse ATE, "
                "completeness or correctness. cogmap serve --params best.json opens "
                "smallest_complete; best.json#front_ate/0 (etc.) picks another entry."
            ),
        }
