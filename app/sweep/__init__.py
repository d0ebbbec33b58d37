"""``cogmap sweep``'s engine: events once per bag, one map per task on Dask, results as they come.

A sweep folder ``DIR`` holds

- ``sweep.json`` -- what the sweep is (its settings, bags, map, a digest of its cells) and its
  status (``running``, ``complete``, ``incomplete``, ``interrupted``, ``failed``);
- ``events/<bag>-<key>.events.npz`` -- the front end's events of each bag (the versioned event
  file of :mod:`cogmap_core.event_file`), keyed by the bag's identity (name, size, modification
  time) and the front-end settings; a copy is kept in ``$COGMAP_CACHE/events/`` so a sweep into
  another folder skips the front end too;
- ``results.csv`` -- one row per finished cell, appended (and flushed to disk) the moment the
  cell finishes: a cell's settings, its figures or its error, the run that computed it and the
  worker. Re-running the same command reads it and computes only the cells without a good row;
- ``pareto.png`` (with ``pareto.svg``) and ``best.json`` -- written when every cell has a row.

Cells run on ``dask.distributed``: a local cluster sized to the machine (one single-threaded
worker process per core: the map build holds the GIL) or an existing cluster
(``scheduler="tcp://host:port"``). Each worker loads a bag's events once and keeps them.
Workers get the events either shipped from here (scattered once to every worker; the default)
or by reading ``DIR/events/`` themselves (a path every worker can reach).

One module per concern:

- :mod:`app.sweep.manifest` -- the folder: file names, ``sweep.json``, the lock, resuming;
- :mod:`app.sweep.events` -- each bag's events in ``DIR/events`` (the user-wide cache they share
  with the benchmarks is :mod:`app.events_cache`);
- :mod:`app.sweep.cells` -- the cells and the task that builds one;
- :mod:`app.sweep.dask_backend` -- running the tasks on a local or remote Dask cluster;
- :mod:`app.sweep.results` -- ``results.csv`` and the Pareto figure;
- :mod:`app.sweep.engine` -- :class:`Sweep`, which runs them in order.
"""

from app.events_cache import BagSource, bag_source
from app.sweep.cells import Cell, cell_key, compute_cell, plan_cells, run_serially
from app.sweep.dask_backend import (
    QUIET_WORKERS,
    DaskConnection,
    check_worker_paths,
    connect_local,
    connect_remote,
    default_workers,
    run_on_dask,
)
from app.sweep.engine import CellProgress, Sweep, SweepOptions, SweepResult
from app.sweep.errors import FailedCells, SchedulerLost, SweepError
from app.sweep.events import BagEvents, prepare_events
from app.sweep.manifest import (
    BEST_FILE,
    MANIFEST_FILE,
    PARETO_FILE,
    RESULTS_FILE,
    SWEEP_FORMAT,
    SWEEP_VERSION,
)
from app.sweep.results import RESULT_COLUMNS, ResultsTable, pareto_figure

__all__ = [
    "BEST_FILE",
    "MANIFEST_FILE",
    "PARETO_FILE",
    "QUIET_WORKERS",
    "RESULTS_FILE",
    "RESULT_COLUMNS",
    "SWEEP_FORMAT",
    "SWEEP_VERSION",
    "BagEvents",
    "BagSource",
    "Cell",
    "CellProgress",
    "DaskConnection",
    "FailedCells",
    "ResultsTable",
    "SchedulerLost",
    "Sweep",
    "SweepError",
    "SweepOptions",
    "SweepResult",
    "bag_source",
    "cell_key",
    "check_worker_paths",
    "compute_cell",
    "connect_local",
    "connect_remote",
    "default_workers",
    "pareto_figure",
    "plan_cells",
    "prepare_events",
    "run_on_dask",
    "run_serially",
]
