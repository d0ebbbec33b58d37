"""Rebuilding maps for new parameters: worker processes, a cache, and exact shortcuts.

A parameter change rebuilds maps from the session's cached front-end events (see
:mod:`app.server.replay`). Three things make that fast without changing a single number of the
result -- every map is exactly what ``CognitiveMap(mode, params)`` fed the same events gives, as
``SlamSession.rebuild`` and ``cogmap run`` do:

- :class:`ProcessBuilder`: the maps are rebuilt in worker processes (one per core), each of which
  holds a copy of the events (sent once, then only the new ones), so only the parameters go out
  and the finished map (a pickle of a few hundred kB) comes back. The displayed map is started
  first; two maps build at the same time on two cores; the page's process stays free to serve
  the browsers. A newer request abandons the builds in flight within one chunk of events.
- :class:`MapCache`: maps built for parameters met before (a slider moved back, "reset to paper
  values") are kept and reused.
- :func:`~cogmap_core.schedule.same_schedule`: the clustering thresholds ``T_interval`` and
  ``T_total`` act on a map only through the schedule of loop-closure clusters (which links form
  a cluster, at which event it closes and the map is optimised). When that schedule over the
  events so far is the same for the old and the new values, the map is the same and is kept.

:class:`ThreadBuilder` does the same work on the calling thread (no worker processes). Each map
is built by :func:`cogmap_core.map_build.build_map`, the path ``SlamSession.rebuild`` takes too
(interrupted between chunks of events, resumed from the states kept at its clusters' closes when
only ``T_interval`` and ``T_total`` changed: :func:`~cogmap_core.schedule.schedule_shared`).
"""

from __future__ import annotations

import atexit
import multiprocessing.connection
import os
import pickle
import signal
import socket
import subprocess
import sys
import threading
import time
import traceback
from collections import OrderedDict
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from cogmap_core import compiled_replay
from cogmap_core.cognitive_map import CognitiveMap, MapMode
from cogmap_core.config import MapParams
from cogmap_core.event_log import EventLog
from cogmap_core.events import MapEvent
from cogmap_core.map_build import (  # re-exported: the rebuilds' names
    COMPILED_CHUNK,
    MAX_CHECKPOINTS,
    REBUILD_CHUNK,
    Abandoned,
    BuildTask,
    Checkpoints,
    CheckpointStore,
    Interrupted,
    build_map,
)

#: How often (s) a waiting builder checks whether its request was superseded.
POLL_S = 0.005


@dataclass(frozen=True, slots=True)
class Built:
    """A finished build: the map and how long it took (s) where it was built.

    ``resumed_at``: the events it did not replay again, resumed from a map state kept at a
    cluster's close (:class:`Checkpoints`); 0 when built from the first event.
    """

    task: BuildTask
    cmap: CognitiveMap
    compute_s: float
    resumed_at: int = 0


# ---------------------------------------------------------------------------------- cache
CacheKey = tuple[MapMode, tuple[tuple[str, float], ...], int, bool, int]


class MapCache:
    """Maps built before, by map, the parameters it uses, frames and end-of-data state.

    A map in the cache is never the session's current map (which playback extends): maps enter
    when they are replaced and leave when they are adopted again.
    """

    def __init__(self, size: int = 4, uses: dict[MapMode, frozenset[str]] | None = None) -> None:
        """Keep at most ``size`` maps per mode; ``uses``: the parameters each map depends on."""
        self.size = size
        self.uses = uses or {}
        self._maps: OrderedDict[CacheKey, CognitiveMap] = OrderedDict()

    def key(
        self, mode: MapMode, params: MapParams, frames: int, finish: bool, log: int
    ) -> CacheKey:
        """The cache key of a map (only the parameters the map uses count)."""
        names = self.uses.get(mode) or frozenset(params.to_dict())
        values = tuple(sorted((n, float(getattr(params, n))) for n in names))
        return (mode, values, frames, finish, log)

    def put(self, key: CacheKey, cmap: CognitiveMap) -> None:
        """Keep ``cmap`` (the oldest map of its mode goes when the mode has ``size``)."""
        self._maps[key] = cmap
        self._maps.move_to_end(key)
        same = [k for k in self._maps if k[0] == key[0]]
        for old in same[: max(0, len(same) - self.size)]:
            del self._maps[old]

    def take(self, key: CacheKey) -> CognitiveMap | None:
        """Remove and return the map stored under ``key`` (None when there is none)."""
        return self._maps.pop(key, None)

    def clear(self) -> None:
        """Forget every map."""
        self._maps.clear()

    def __len__(self) -> int:
        """Maps held."""
        return len(self._maps)


# ---------------------------------------------------------------------------------- builders
class ThreadBuilder:
    """Builds maps one after the other on the calling thread (keeping their cluster states)."""

    workers = 0

    def __init__(self) -> None:
        """No map built yet."""
        self._log: EventLog | None = None
        self._checkpoints: CheckpointStore = {}

    def build(
        self, log: EventLog, tasks: Sequence[BuildTask], interrupted: Interrupted
    ) -> Iterator[Built]:
        """Build ``tasks`` in order, yielding each map when done.

        Raises:
            Abandoned: ``interrupted()`` became true.

        """
        if log is not self._log:
            self._log, self._checkpoints = log, {}
        for task in tasks:
            started = time.perf_counter()
            cmap, resumed = build_map(log, task, interrupted, None, self._checkpoints)
            yield Built(task, cmap, time.perf_counter() - started, resumed)

    def prepare(self, log: EventLog) -> None:
        """Nothing to send."""

    def close(self) -> None:
        """Nothing to stop."""


def _worker_main(conn: multiprocessing.connection.Connection) -> None:
    """A rebuild worker: holds a copy of the event log and builds maps on request.

    While it builds, a ``("cancel",)`` message makes it drop the build (checked between chunks).
    """
    compiled_replay.available()  # loads (or compiles) the compiled replay before any request
    log = EventLog()
    events: list[MapEvent] = []  # the log's events as objects, made once as they arrive
    checkpoints: CheckpointStore = {}  # the states of the maps built here (their latest build)

    def cancelled() -> bool:
        if conn.poll(0):
            message = conn.recv()
            return bool(message[0] == "cancel")
        return False

    while True:
        try:
            message = conn.recv()
        except (EOFError, OSError, KeyboardInterrupt):
            return
        kind = message[0]
        if kind == "stop":
            return
        if kind == "reset":
            log, events, checkpoints = EventLog(), [], {}
        elif kind == "append":
            _, columns, frame_end, frame_time = message
            log.extend(columns, frame_end, frame_time)
            if not compiled_replay.available():  # the compiled replay reads the columns
                events.extend(log.events[len(events) :])
        elif kind == "build":
            _, task_id, task = message
            started = time.perf_counter()
            try:
                cmap, resumed = build_map(log, task, cancelled, events, checkpoints)
            except Abandoned:
                conn.send(("abandoned", task_id))
                continue
            except Exception as exc:  # reported to the app, which shows it
                conn.send(("error", task_id, f"{type(exc).__name__}: {exc}"))
                continue
            payload = pickle.dumps(cmap, protocol=pickle.HIGHEST_PROTOCOL)
            conn.send(("done", task_id, payload, time.perf_counter() - started, resumed))
        # ("cancel",) arriving while idle: the build it meant is over already


class _Worker:
    """One worker process (``python -m app.server.rebuild``) and the log it holds."""

    def __init__(self) -> None:
        parent, child = socket.socketpair()
        env = dict(os.environ)
        paths = [p for p in sys.path if p]
        env["PYTHONPATH"] = os.pathsep.join(paths)
        self.process = subprocess.Popen(
            [sys.executable, "-m", "app.server.rebuild", str(child.fileno())],
            pass_fds=[child.fileno()],
            stdin=subprocess.DEVNULL,
            env=env,
        )
        child.close()
        self.conn = multiprocessing.connection.Connection(parent.detach())
        self.log: EventLog | None = None  # the log whose events it holds
        self.events = 0  # events of that log sent so far
        self.frames = 0
        self.busy: int | None = None  # task id in flight
        self.modes: set[MapMode] = set()  # the maps whose latest build it made

    @property
    def alive(self) -> bool:
        return self.process.poll() is None

    def stop(self) -> None:
        try:
            self.conn.send(("stop",))
        except (OSError, ValueError):
            pass
        try:
            self.process.wait(2.0)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait(2.0)
        self.conn.close()


class WorkerPool:
    """Rebuild worker processes, started once per process and shared by every builder."""

    def __init__(self, size: int) -> None:
        """Start ``size`` workers in the background (the first build waits for them)."""
        self.size = size
        self.workers: list[_Worker] = []
        self.failed: str | None = None
        self.lock = threading.Lock()  # one build at a time
        self._ready = threading.Event()
        threading.Thread(target=self._start, name="cogmap-rebuild-start", daemon=True).start()

    def _start(self) -> None:
        try:
            self.workers = [_Worker() for _ in range(self.size)]
        except Exception as exc:  # no worker processes: builds run on the calling thread
            self.failed = f"{type(exc).__name__}: {exc}"
            print(f"cogmap serve: rebuild workers unavailable ({self.failed})", file=sys.stderr)
        finally:
            self._ready.set()

    @property
    def ready(self) -> bool:
        """Whether the workers were started (successfully or not)."""
        return self._ready.is_set()

    def available(self) -> bool:
        """Whether the workers run (waits for them to start)."""
        self._ready.wait()
        return self.failed is None and bool(self.workers) and all(w.alive for w in self.workers)

    def close(self) -> None:
        """Stop the workers."""
        self._ready.wait()
        for worker in self.workers:
            worker.stop()
        self.workers = []


_POOL: WorkerPool | None = None
_POOL_LOCK = threading.Lock()


def worker_pool(size: int) -> WorkerPool:
    """The process's pool of at least ``size`` rebuild workers (started on first use)."""
    global _POOL
    with _POOL_LOCK:
        if _POOL is None or _POOL.size < size or (_POOL.ready and not _POOL.available()):
            if _POOL is not None:
                _POOL.close()
            _POOL = WorkerPool(size)
            atexit.register(_POOL.close)
        return _POOL


class ProcessBuilder:
    """Builds maps in worker processes, at most one map per worker at a time (module doc).

    Args:
        workers: worker processes to use (the machine's cores, for a start).

    """

    def __init__(self, workers: int = 2) -> None:
        """Use (and start, the first time) the process's worker pool."""
        self.workers = workers
        self.pool = worker_pool(workers)
        self._next_task = 0

    def _pool_workers(self) -> list[_Worker]:
        return self.pool.workers[: self.workers]

    def prepare(self, log: EventLog) -> None:
        """Send every worker the events of ``log`` it does not have yet (while nothing builds)."""
        if not self.pool.ready or not self.pool.lock.acquire(blocking=False):
            return
        try:
            if self.pool.available():
                for worker in self._pool_workers():
                    self._sync(worker, log)
        finally:
            self.pool.lock.release()

    @staticmethod
    def _sync(worker: _Worker, log: EventLog) -> None:
        if worker.log is not log or worker.frames > log.frames:  # another log: start over
            worker.conn.send(("reset",))
            worker.log, worker.events, worker.frames = log, 0, 0
            worker.modes = set()
        frames = log.frames
        if worker.frames == frames:
            return
        end = log.frame_end[frames - 1] if frames else 0
        columns = {name: column[worker.events : end] for name, column in log.columns(end).items()}
        worker.conn.send(
            (
                "append",
                columns,
                np.array(log.frame_end[worker.frames : frames]),
                np.array(log.frame_time[worker.frames : frames]),
            )
        )
        worker.events, worker.frames = end, frames

    def build(
        self, log: EventLog, tasks: Sequence[BuildTask], interrupted: Interrupted
    ) -> Iterator[Built]:
        """Build ``tasks`` on the workers (in order of priority), yielding maps as they finish.

        Raises:
            Abandoned: ``interrupted()`` became true (the workers drop what they build).
            RuntimeError: a worker failed.

        """
        if not tasks:
            return
        if not self.pool.available():
            yield from ThreadBuilder().build(log, tasks, interrupted)
            return
        with self.pool.lock:
            yield from self._build(log, tasks, interrupted)

    def _build(
        self, log: EventLog, tasks: Sequence[BuildTask], interrupted: Interrupted
    ) -> Iterator[Built]:
        workers = self._pool_workers()
        pending = list(tasks)
        running: dict[int, tuple[_Worker, BuildTask]] = {}
        try:
            while pending or running:
                for worker, task in self._assign(workers, pending):
                    self._sync(worker, log)
                    self._next_task += 1
                    worker.busy = self._next_task
                    worker.conn.send(("build", self._next_task, task))
                    running[self._next_task] = (worker, task)
                if interrupted():
                    raise Abandoned
                ready = multiprocessing.connection.wait(
                    [w.conn for w, _ in running.values()], timeout=POLL_S
                )
                for conn in ready:
                    worker = next(w for w in workers if w.conn is conn)
                    reply = self._receive(worker)
                    worker.busy = None
                    _, task = running.pop(reply[1])
                    if reply[0] == "done":
                        yield Built(task, pickle.loads(reply[2]), float(reply[3]), int(reply[4]))
                    elif reply[0] == "error":
                        raise RuntimeError(f"rebuild of the {task.mode.value} map: {reply[2]}")
                    else:  # abandoned: only after a cancel, which was raised already
                        raise Abandoned
        except BaseException:
            self._cancel(workers)
            raise

    @staticmethod
    def _assign(
        workers: list[_Worker], pending: list[BuildTask]
    ) -> list[tuple[_Worker, BuildTask]]:
        """Free workers and the tasks they take now (removed from ``pending``), in order.

        A map goes to the worker that built it last when that one is free (it keeps the map's
        cluster states, :class:`Checkpoints`), else to a free worker whose own maps no other
        pending task needs.
        """
        out = []
        for task in list(pending):
            free = [w for w in workers if w.busy is None and all(w is not o for o, _ in out)]
            if not free:
                break
            worker = next((w for w in free if task.mode in w.modes), None)
            if worker is None:
                others = {t.mode for t in pending if t is not task}
                worker = next((w for w in free if not w.modes & others), free[0])
            pending.remove(task)
            for other in workers:
                other.modes.discard(task.mode)
            worker.modes.add(task.mode)
            out.append((worker, task))
        return out

    def _receive(self, worker: _Worker) -> tuple[Any, ...]:
        try:
            return worker.conn.recv()  # type: ignore[no-any-return]
        except (EOFError, OSError):
            raise RuntimeError("a rebuild worker exited; restart the server") from None

    @staticmethod
    def _cancel(workers: list[_Worker]) -> None:
        """Make the busy workers drop their builds, and wait for each one's reply."""
        for worker in workers:
            if worker.busy is not None:
                try:
                    worker.conn.send(("cancel",))
                except (OSError, ValueError):
                    worker.busy = None
        for worker in workers:
            if worker.busy is None:
                continue
            try:
                if worker.conn.poll(30.0):
                    worker.conn.recv()
            except (EOFError, OSError):
                pass
            worker.busy = None

    def close(self) -> None:
        """Stop using the workers (they stay for the next builder of this process)."""


Builder = ThreadBuilder | ProcessBuilder


def make_builder(workers: int) -> Builder:
    """Worker processes when ``workers`` > 0 and they can start, else the calling thread."""
    if workers <= 0:
        return ThreadBuilder()
    try:
        return ProcessBuilder(workers)
    except Exception:
        traceback.print_exc(file=sys.stderr)
        return ThreadBuilder()


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m app.server.rebuild FD``: a worker talking over the socket ``FD``."""
    args = sys.argv[1:] if argv is None else list(argv)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the server stops its workers itself
    _worker_main(multiprocessing.connection.Connection(int(args[0])))
    return 0


__all__ = [
    "COMPILED_CHUNK",
    "MAX_CHECKPOINTS",
    "REBUILD_CHUNK",
    "Abandoned",
    "BuildTask",
    "Built",
    "CheckpointStore",
    "Checkpoints",
    "Interrupted",
    "MapCache",
    "ProcessBuilder",
    "ThreadBuilder",
    "build_map",
    "make_builder",
]


if __name__ == "__main__":
    sys.exit(main())
