"""Running a sweep's cells on ``dask.distributed``: a local cluster or an existing one.

A local cluster has one single-threaded worker process per core (the map build holds the GIL);
an existing cluster is reached at ``tcp://host:port`` and its workers checked (same cogmap,
same event format). Each bag's event file is scattered once to every worker, or read by the
workers from the sweep folder (a path every worker can reach).
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import threading
import urllib.request
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from app.sweep.cells import Cell, Record, compute_cell, worker_check
from app.sweep.errors import SchedulerLost, SweepError
from app.sweep.events import BagEvents
from cogmap_core import __version__
from cogmap_core.event_file import FORMAT_VERSION


def run_on_dask(
    client: Any,
    cells: Sequence[Cell],
    events: Mapping[str, BagEvents],
    record: Record,
    ship_events: bool = True,
) -> None:
    """Run the cells as Dask tasks; ``record`` every outcome the moment it arrives.

    With ``ship_events`` each bag's event file is scattered once to every worker; otherwise
    workers read ``DIR/events`` at the same path. On Ctrl-C the cells already finished are still
    recorded, the others cancelled.
    """
    from distributed import as_completed

    data: dict[str, Any] = {}
    for key in {c.bag.key for c in cells}:
        path = events[key].events_path
        if ship_events:
            data[key] = client.scatter(path.read_bytes(), broadcast=True, hash=False)
        else:
            data[key] = str(path.resolve())
    futures = {
        client.submit(
            compute_cell,
            cell.bag.key,
            data[cell.bag.key],
            cell.mode.value,
            cell.params.to_dict(),
            key=f"cogmap-cell-{cell.key}",
            pure=False,
        ): cell
        for cell in cells
    }
    recorded: set[Any] = set()
    lost = 0
    try:
        for future in as_completed(futures):
            recorded.add(future)
            outcome = _outcome(future)
            if outcome is None:
                lost += 1
                continue
            record(futures[future], outcome)
    except KeyboardInterrupt:
        for future, cell in futures.items():  # keep what finished meanwhile
            if future not in recorded and future.status == "finished":
                with contextlib.suppress(Exception):
                    record(cell, future.result(timeout=5))
        raise
    finally:
        with contextlib.suppress(Exception):
            client.cancel([f for f in futures if not f.done()])
    if lost:
        raise SchedulerLost(
            f"{lost} cells were cancelled (the Dask scheduler or its workers went away); the "
            "finished cells are saved: re-run the same command to compute the rest"
        )


def _outcome(future: Any) -> dict[str, Any] | None:
    """A finished future's figures, an error outcome, or ``None`` when it was cancelled."""
    if future.status == "cancelled":
        return None
    if future.status == "error":
        exc = future.exception()
        message = " ".join(f"{type(exc).__name__}: {exc}".split())
        return {"status": "error", "error": message[:500], "worker": ""}
    return future.result()


@dataclass
class DaskConnection:
    """A Dask client and, for a local cluster, the cluster it owns."""

    client: Any
    cluster: Any | None
    description: str
    dashboard: str | None

    def close(self) -> None:
        """Close the client and the local cluster (if any)."""
        with contextlib.suppress(Exception):
            self.client.close()
        if self.cluster is not None:
            with contextlib.suppress(Exception):
                self.cluster.close()


def default_workers() -> int:
    """One worker per usable core."""
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except AttributeError:  # pragma: no cover - not Linux
        return max(os.cpu_count() or 1, 1)


def _import_distributed() -> Any:
    try:
        import distributed
    except ImportError:
        raise SweepError(
            "cogmap sweep runs on Dask, which is not installed: pip install '.[sweep]' in "
            "cogmap's folder"
        ) from None
    return distributed


QUIET_WORKERS: dict[str, Any] = {
    # A cell holds the GIL for its whole build; every wake-up of a worker's event loop thread
    # takes it away. Dask's defaults wake it every 20 ms (tick), sample the stack every 10 ms
    # (profiler) and poll the system every 0.5 s: measured on 2 cores, they made each cell ~10 %
    # slower than in a plain process. These settings bring the workers within ~2 % of one.
    "distributed.worker.profile.enabled": False,
    "distributed.admin.tick.interval": "1s",
    "distributed.admin.system-monitor.interval": "2s",
}


def dashboard_link(client: Any) -> str | None:
    """The scheduler's dashboard URL when it serves one (it needs bokeh there), else ``None``."""
    try:
        link = client.dashboard_link
        with urllib.request.urlopen(link, timeout=2) as response:  # noqa: S310 - http(s) only
            page = response.read(4096)
            ok = response.status == 200 and b"needs bokeh" not in page
    except (OSError, ValueError, KeyError):
        return None
    return str(link) if ok else None


def connect_local(workers: int | None = None, processes: bool = True) -> DaskConnection:
    """A local Dask cluster: ``workers`` single-threaded workers (default: one per core).

    Raises:
        SweepError: Dask is not installed.

    """
    distributed = _import_distributed()
    n = workers or default_workers()
    # Ctrl-C reaches every process of the terminal's group: worker processes inherit an
    # ignored SIGINT, so only this process stops (and saves what finished), with no
    # tracebacks from the workers.
    previous = None
    if processes and threading.current_thread() is threading.main_thread():
        previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    import dask

    try:
        with dask.config.set(QUIET_WORKERS):
            cluster = distributed.LocalCluster(
                n_workers=n,
                threads_per_worker=1,
                processes=processes,
                dashboard_address=":0",
                silence_logs=logging.CRITICAL,  # workers stopped by Ctrl-C log no shutdown noise
            )
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous)
    client = distributed.Client(cluster)
    client.run(worker_check)  # workers import cogmap now, not in their first cell
    dashboard = dashboard_link(client)
    kind = "processes" if processes else "threads"
    return DaskConnection(
        client, cluster, f"local Dask cluster, {n} worker {kind} x 1 thread", dashboard
    )


def connect_remote(scheduler: str, timeout: float = 10.0) -> DaskConnection:
    """A client of the Dask cluster at ``scheduler``, its workers checked.

    Raises:
        SweepError: Dask is missing, the scheduler cannot be reached or has no workers, or a
            worker cannot import this cogmap version.

    """
    distributed = _import_distributed()
    try:
        client = distributed.Client(scheduler, timeout=timeout)
    except (OSError, TimeoutError, ValueError, TypeError) as exc:
        raise SweepError(
            f"cannot reach the Dask scheduler at {scheduler} ({type(exc).__name__}: "
            f"{' '.join(str(exc).split())}); start it (dask scheduler) or omit --scheduler"
        ) from None
    connection = DaskConnection(client, None, f"Dask scheduler {scheduler}", None)
    try:
        try:
            client.wait_for_workers(1, timeout=timeout)
        except (TimeoutError, OSError):
            raise SweepError(
                f"the Dask scheduler at {scheduler} has no workers; start some "
                f"(dask worker {scheduler}) with cogmap installed"
            ) from None
        reports = _worker_reports(client, ())
        for address, report in reports.items():
            if report["cogmap"] != __version__ or report["event_format"] != FORMAT_VERSION:
                raise SweepError(
                    f"worker {address} runs cogmap {report['cogmap']}, this is {__version__}; "
                    "install the same version on every worker"
                )
        connection.dashboard = dashboard_link(client)
        connection.description = f"Dask scheduler {scheduler}, {len(reports)} workers"
    except BaseException:
        connection.close()
        raise
    return connection


def _worker_reports(client: Any, paths: Sequence[str]) -> dict[str, dict[str, Any]]:
    try:
        return dict(client.run(worker_check, list(paths)))
    except Exception as exc:
        raise SweepError(
            f"the Dask workers cannot run cogmap ({type(exc).__name__}: "
            f"{' '.join(str(exc).split())}); pip install '.[sweep]' of cogmap {__version__} on "
            "every worker"
        ) from None


def check_worker_paths(client: Any, paths: Sequence[str]) -> None:
    """Make sure every worker can read the event files at ``paths`` (``--worker-events path``).

    Raises:
        SweepError: a worker cannot (the message says how to fix it).

    """
    for address, report in _worker_reports(client, paths).items():
        if report["missing"]:
            raise SweepError(
                f"worker {address} cannot read {report['missing'][0]}; put the sweep folder on "
                "a path every worker shares, or ship the events (--worker-events ship)"
            )
