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
"""

from __future__ import annotations

import contextlib
import csv
import hashlib
import io
import json
import logging
import math
import os
import signal
import tempfile
import threading
import time
import urllib.request
from collections import OrderedDict
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, TextIO

from app.params_file import BEST_FORMAT
from app.progress import ProgressBar
from app.report_figures import save_figure
from cogmap_core import __version__
from cogmap_core.cognitive_map import MapMode
from cogmap_core.config import MapParams
from cogmap_core.datasets import BagTopics, open_bag
from cogmap_core.errors import CogmapError, InputFileError
from cogmap_core.evaluation import LAYOUT_RADIUS
from cogmap_core.event_file import (
    FORMAT_VERSION,
    EventRecording,
    load_event_file,
    save_event_file,
)
from cogmap_core.fileio import write_bytes_atomic
from cogmap_core.frontend import FrontEndConfig
from cogmap_core.slam import EventLog, SlamSession
from cogmap_core.sweep import (
    FIGURE_COLUMNS,
    GROWTH_FRACTION,
    MIN_COMPLETENESS,
    PARAMETER_NAMES,
    TIMING_COLUMNS,
    SettingFigures,
    SweepSpec,
    aggregate_settings,
    beats,
    evaluate_cell,
    front_ate,
    front_completeness,
    smallest_complete,
)

try:  # POSIX advisory locks: one sweep writes a folder at a time
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None  # type: ignore[assignment]

SWEEP_FORMAT = "cogmap-sweep"
SWEEP_VERSION = 1
IMAGE_SCALE = 1  # as cogmap run: full size, for OpenRatSLAM's whole-pixel template blocks
CELL_VERSION = 1  # bump when a cell's figures change meaning: old rows are then not reused

RESULTS_FILE = "results.csv"
MANIFEST_FILE = "sweep.json"
BEST_FILE = "best.json"
PARETO_FILE = "pareto.png"
EVENTS_DIR = "events"
LOCK_FILE = ".sweep.lock"

ID_COLUMNS: tuple[str, ...] = ("key", "run", "bag", "bag_key", "map", "status", "error")
RESULT_COLUMNS: tuple[str, ...] = (
    ID_COLUMNS + PARAMETER_NAMES + FIGURE_COLUMNS + TIMING_COLUMNS + ("worker",)
)
_INT_COLUMNS = frozenset(
    ("run", "vertices", "edges", "loop_edges", "clusters", "optimizations", "exploration_vertices")
)
_STR_COLUMNS = frozenset(("key", "bag", "bag_key", "map", "status", "error", "worker"))


class SweepError(CogmapError):
    """A sweep cannot start or finish (bad folder, unreachable cluster, failed cells, ...)."""


# --------------------------------------------------------------------------- small file helpers
def _json_clean(value: Any) -> Any:
    """NaN and infinities become ``None`` (strict JSON)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _json_clean(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_json_clean(v) for v in value]
    return value


def write_json(path: Path, payload: Mapping[str, Any]) -> None:
    """Write strict JSON atomically."""
    text = json.dumps(_json_clean(dict(payload)), indent=2, allow_nan=False) + "\n"
    write_bytes_atomic(path, text.encode())


# --------------------------------------------------------------------------- events per bag
@dataclass(frozen=True, slots=True)
class BagSource:
    """A bag (or a recorded event file) of the sweep and the identity of its events.

    Attributes:
        path: the bag as given (or an ``.npz`` event file).
        label: its name in the results (the file name).
        key: identity of its events: bag name, size, modification time, front-end settings,
            topics (or, for an event file, a hash of its content).
        frontend: the front-end settings (``None`` for an event file).
        topics: the bag's topics.

    """

    path: Path
    label: str
    key: str
    frontend: FrontEndConfig | None
    topics: BagTopics

    @property
    def is_event_file(self) -> bool:
        """True when the input is an already recorded event file."""
        return self.frontend is None

    @property
    def events_name(self) -> str:
        """File name of its event file in ``DIR/events``: ``<bag name>-<key>.events.npz``."""
        if self.is_event_file:
            stem = self.path.name.removesuffix(".npz").removesuffix(".events")
        else:
            stem = self.path.stem
        return f"{stem}-{self.key}.events.npz"


def bag_source(path: Path, frontend: FrontEndConfig | None, topics: BagTopics) -> BagSource:
    """The identity of a bag's events (no bag is read; an event file is hashed).

    ``frontend`` is ``None`` for a recorded event file (``*.npz``).
    """
    path = Path(path)
    if not path.exists():
        raise InputFileError(f"{path}: no such bag; give an existing .bag file or event file")
    if frontend is None:
        digest = hashlib.sha1(path.read_bytes()).hexdigest()[:16]
        return BagSource(path, path.name, digest, None, topics)
    stat = path.stat()
    identity = {
        "event_format": FORMAT_VERSION,
        "name": path.name,
        "size": stat.st_size,
        "mtime_ns": stat.st_mtime_ns,
        "frontend": frontend.to_dict(),
        "topics": asdict(topics),
        "image_scale": IMAGE_SCALE,
    }
    digest = hashlib.sha1(json.dumps(identity, sort_keys=True).encode()).hexdigest()[:16]
    return BagSource(path, path.name, digest, frontend, topics)


@dataclass(frozen=True, slots=True)
class BagEvents:
    """A bag's recorded events, ready for the cells.

    Attributes:
        source: the bag.
        events_path: its event file in ``DIR/events``.
        frames: camera frames.
        duration_s: data duration.
        events: number of events.
        dead_reckoning_ate_m: ATE of the odometry alone (the baseline).
        origin: where the events came from this time: ``front end``, ``cache``, ``folder``,
            ``event file``, or ``manifest`` (not loaded: the figures of the bag's record in
            ``sweep.json``, see :meth:`from_manifest_record`).

    """

    source: BagSource
    events_path: Path
    frames: int
    duration_s: float
    events: int
    dead_reckoning_ate_m: float
    origin: str

    def to_dict(self) -> dict[str, Any]:
        """JSON form (for ``sweep.json``)."""
        return {
            "bag": str(self.source.path),
            "label": self.source.label,
            "key": self.source.key,
            "events_file": str(Path(EVENTS_DIR) / self.events_path.name),
            "frames": self.frames,
            "duration_s": self.duration_s,
            "events": self.events,
            "dead_reckoning_ate_m": self.dead_reckoning_ate_m,
            "frontend": None if self.source.frontend is None else self.source.frontend.to_dict(),
        }

    @classmethod
    def from_manifest_record(
        cls, source: BagSource, out_dir: Path, record: Mapping[str, Any]
    ) -> BagEvents | None:
        """The bag's figures as an earlier run recorded them in ``sweep.json``, events unread.

        For a sweep with nothing left to compute, whose analysis needs only these figures.

        Args:
            source: the bag.
            out_dir: the sweep folder.
            record: the bag's entry in ``sweep.json``'s ``bags`` (see :meth:`to_dict`).

        Returns:
            The figures (``origin`` ``"manifest"``), or ``None`` when the record is not of these
            events, lacks a figure (an older or cut-short manifest) or its event file is gone:
            then the events must be loaded (:func:`prepare_events`).

        """
        events_path = out_dir / EVENTS_DIR / source.events_name
        figures = ("frames", "duration_s", "events", "dead_reckoning_ate_m")
        if record.get("key") != source.key or any(name not in record for name in figures):
            return None
        if not events_path.is_file():
            return None
        dead_reckoning = record["dead_reckoning_ate_m"]  # None: NaN, written as strict JSON
        try:
            return cls(
                source=source,
                events_path=events_path,
                frames=int(record["frames"]),
                duration_s=float(record["duration_s"]),
                events=int(record["events"]),
                dead_reckoning_ate_m=float("nan")
                if dead_reckoning is None
                else float(dead_reckoning),
                origin="manifest",
            )
        except (TypeError, ValueError):  # a hand-edited record: load the events instead
            return None


def manifest_bag_records(manifest: object) -> dict[str, dict[str, Any]]:
    """The per-bag records of a parsed ``sweep.json``, by bag key (``{}`` if there are none)."""
    bags = manifest.get("bags") if isinstance(manifest, dict) else None
    if not isinstance(bags, list):
        return {}
    return {
        str(record["key"]): record
        for record in bags
        if isinstance(record, dict) and "key" in record
    }


def shared_events_dir() -> Path:
    """The user-wide copy of recorded events (``$COGMAP_CACHE/events``)."""
    from cogmap_core.datasets.cache import cache_dir

    return cache_dir() / EVENTS_DIR


FrameProgress = Callable[[int, int, float], None]


def prepare_events(
    source: BagSource,
    out_dir: Path,
    progress: Callable[[str], FrameProgress | None] | None = None,
    say: Callable[[str], None] | None = None,
) -> BagEvents:
    """The bag's events in ``out_dir/events``: found there, copied from the cache, or recorded.

    Recording runs the front end over the whole bag once and saves its events (atomically) in
    ``out_dir/events`` and in :func:`shared_events_dir`.

    Raises:
        CogmapError: the bag cannot be read, or has no ground truth (one line naming the bag).

    """
    target = out_dir / EVENTS_DIR / source.events_name
    target.parent.mkdir(parents=True, exist_ok=True)
    recording = None
    origin = "folder"
    if target.exists():
        with contextlib.suppress(InputFileError):  # a damaged copy is recorded again
            recording = load_event_file(target)
    if recording is None:
        shared = source.path if source.is_event_file else shared_events_dir() / source.events_name
        if shared.exists():
            try:
                recording = load_event_file(shared)
            except InputFileError:
                if source.is_event_file:
                    raise
            else:
                write_bytes_atomic(target, shared.read_bytes())
                origin = "cache" if not source.is_event_file else "event file"
    if recording is None:
        if say is not None:
            say(f"{source.label}: running the front end once (its events are then cached)")
        bar = progress("front end " + source.label) if progress else None
        try:
            recording = _record(source, bar)
        finally:
            close = getattr(bar, "close", None)
            if callable(close):
                close()
        save_event_file(target, recording)
        with contextlib.suppress(OSError):  # the cache is a convenience
            shared_events_dir().mkdir(parents=True, exist_ok=True)
            write_bytes_atomic(shared_events_dir() / source.events_name, target.read_bytes())
        origin = "front end"
    recorded_from = recording.meta.get("input_format", "bag")
    if recorded_from != "bag":
        raise SweepError(
            f"{source.path}: these events were recorded from a {recorded_from} odometry log, "
            "whose maps are set and judged differently; a sweep takes bags and their event files"
        )
    if recording.ground_truth is None:
        raise SweepError(
            f"{source.path}: the data has no ground truth; a sweep measures every map against it "
            "(check --gt-topic)"
        )
    log = EventLog.from_recording(recording)
    dead_reckoning = log.dead_reckoning_ate()
    return BagEvents(
        source=source,
        events_path=target,
        frames=recording.frames,
        duration_s=float(recording.frame_time[-1] - recording.frame_time[0])
        if recording.frames
        else 0.0,
        events=len(recording.events),
        dead_reckoning_ate_m=float("nan") if dead_reckoning is None else dead_reckoning,
        origin=origin,
    )


def cached_bag_events(
    path: Path,
    say: Callable[[str], None] | None = None,
    frontend_changes: Mapping[str, float] | None = None,
) -> EventRecording:
    """A bag's front-end events (its profile's settings) from the user-wide cache.

    ``frontend_changes`` alter the profile's settings (e.g.
    :data:`~cogmap_core.frontend.config.COGMAP_ARITHMETIC`); they are part of the cache key.

    The cache sweeps fill (``$COGMAP_CACHE/events``, keyed by the bag's name, size, time and
    the front-end settings); the front end runs once when the bag is not in it. A damaged
    cached copy is recorded again.
    """
    from cogmap_core.datasets.profile import frontend_config_for

    config = frontend_config_for(path).with_changes(**(frontend_changes or {}))
    source = bag_source(path, config, BagTopics())
    cached = shared_events_dir() / source.events_name
    if cached.exists():
        with contextlib.suppress(InputFileError):
            return load_event_file(cached)
    if say is not None:
        say(f"{source.label}: running the front end once (events cached in {cached})")
    recording = _record(source, None)
    cached.parent.mkdir(parents=True, exist_ok=True)
    save_event_file(cached, recording)
    return recording


def _record(source: BagSource, progress: FrameProgress | None) -> EventRecording:
    """Run the front end over the bag; return its :class:`EventRecording`."""
    assert source.frontend is not None
    started = time.perf_counter()
    session = SlamSession(frontend_config=source.frontend, modes=())
    try:
        with open_bag(source.path, source.topics, image_scale=IMAGE_SCALE) as reader:
            total = reader.info.frame_count
            for frame in reader.frames():
                session.process(frame)
                if progress is not None:
                    progress(frame.index + 1, total, frame.time)
    except CogmapError as exc:
        message = str(exc)
        if str(source.path) not in message:
            message = f"{source.path}: {message}"
        raise SweepError(message) from None
    except MemoryError:
        raise SweepError(f"{source.path}: out of memory while running the front end") from None
    except Exception as exc:  # a damaged bag can fail in many ways; name the bag
        raise SweepError(
            f"{source.path}: the front end failed ({type(exc).__name__}: {exc}); check the bag "
            "with cogmap dataset info --scan"
        ) from None
    if session.log.frames == 0:
        raise SweepError(f"{source.path}: no decodable camera frame; nothing to map")
    recording = session.log.recording(str(source.path), source.frontend.to_dict())
    recording.meta.update(
        {
            "frontend_wall_s": time.perf_counter() - started,
            "key": source.key,
            "topics": asdict(source.topics),
            "image_scale": IMAGE_SCALE,
            "recorded_by": f"cogmap {__version__} sweep",
        }
    )
    return recording


# --------------------------------------------------------------------------- cells
@dataclass(frozen=True, slots=True)
class Cell:
    """One map to build: a bag's events with one setting.

    Attributes:
        key: identity of the cell (events, map, setting, measure settings).
        bag: the bag's source.
        params: the setting.
        mode: which map.

    """

    key: str
    bag: BagSource
    params: MapParams
    mode: MapMode


def cell_key(bag_key: str, params: MapParams, mode: MapMode) -> str:
    """Identity of a cell: the same events, map, setting and measures give the same key."""
    identity = {
        "version": CELL_VERSION,
        "events": bag_key,
        "map": mode.value,
        "params": params.to_dict(),
        "layout_radius": LAYOUT_RADIUS,
        "growth_fraction": GROWTH_FRACTION,
    }
    return hashlib.sha1(json.dumps(identity, sort_keys=True).encode()).hexdigest()[:16]


def plan_cells(
    bags: Sequence[BagSource], settings: Sequence[MapParams], mode: MapMode
) -> list[Cell]:
    """Every (bag, setting) cell, bag by bag, settings in order."""
    return [Cell(cell_key(b.key, p, mode), b, p, mode) for b in bags for p in settings]


def cells_digest(cells: Sequence[Cell]) -> str:
    """Identity of a whole sweep (its set of cells)."""
    return hashlib.sha1("\n".join(sorted(c.key for c in cells)).encode()).hexdigest()[:16]


# --------------------------------------------------------------------------- the results table
def _format(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return repr(value)
    return str(value)


def _parse(column: str, text: str) -> Any:
    if column in _STR_COLUMNS:
        return text
    if text == "":
        return None
    if column in _INT_COLUMNS:
        return int(text)
    return float(text)


class ResultsTable:
    """``results.csv``: one row per finished cell, appended and flushed as each cell finishes.

    A row is written with one ``write`` of a whole line and then ``fsync``: a kill can at worst
    cut the last line short, and that line is dropped (the file rewritten atomically) when the
    table is opened again. A cell may have several rows (a failed attempt, then a good one);
    the last one counts.
    """

    def __init__(self, path: Path) -> None:
        """Open (or create) the table at ``path``; repair a cut-short last line."""
        self.path = path
        self.rows: list[dict[str, Any]] = []
        if not path.exists():
            write_bytes_atomic(path, (",".join(RESULT_COLUMNS) + "\n").encode())
            return
        with path.open(newline="") as handle:
            text = handle.read()
        if text and not text.endswith("\n"):
            text = text[: text.rfind("\n") + 1]  # the last line was cut short by a kill
            write_bytes_atomic(path, text.encode())
        reader = csv.reader(io.StringIO(text, newline=""))
        header = next(reader, None)
        if header is None:
            write_bytes_atomic(path, (",".join(RESULT_COLUMNS) + "\n").encode())
            return
        if tuple(header) != RESULT_COLUMNS:
            raise SweepError(
                f"{path}: its columns are not this cogmap's sweep table; choose another --out"
            )
        for number, fields_ in enumerate(reader, start=2):
            if len(fields_) != len(RESULT_COLUMNS):
                raise SweepError(
                    f"{path}: line {number} is malformed; fix or remove that line, or choose "
                    "another --out"
                )
            try:
                self.rows.append(
                    {c: _parse(c, v) for c, v in zip(RESULT_COLUMNS, fields_, strict=True)}
                )
            except ValueError:
                raise SweepError(
                    f"{path}: line {number} holds a value that is not a number; fix or remove "
                    "that line"
                ) from None

    def latest(self) -> dict[str, dict[str, Any]]:
        """The last row of every cell, by cell key."""
        return {row["key"]: row for row in self.rows}

    def append(self, row: Mapping[str, Any]) -> None:
        """Append one row and flush it to disk before returning."""
        buffer = io.StringIO()
        csv.writer(buffer, lineterminator="\n").writerow(
            [_format(row.get(c)) for c in RESULT_COLUMNS]
        )
        with self.path.open("a", newline="") as handle:
            handle.write(buffer.getvalue())
            handle.flush()
            os.fsync(handle.fileno())
        self.rows.append({c: row.get(c) for c in RESULT_COLUMNS})


# --------------------------------------------------------------------------- the task
_LOGS: OrderedDict[str, EventLog] = OrderedDict()
_LOGS_LOCK = threading.Lock()
_LOGS_KEEP = 4


def worker_event_log(key: str, data: bytes | str) -> EventLog:
    """The event log of ``key`` in this process, loaded once from a path or shipped bytes."""
    with _LOGS_LOCK:
        log = _LOGS.get(key)
        if log is not None:
            _LOGS.move_to_end(key)
            return log
        if isinstance(data, bytes):
            with tempfile.TemporaryDirectory(prefix="cogmap-events-") as tmp:
                path = Path(tmp) / f"{key}.events.npz"
                path.write_bytes(data)
                recording = load_event_file(path)
        else:
            recording = load_event_file(data)
        log = EventLog.from_recording(recording)
        _LOGS[key] = log
        while len(_LOGS) > _LOGS_KEEP:
            _LOGS.popitem(last=False)
        return log


def _worker_name() -> str:
    try:
        from distributed import get_worker

        return str(get_worker().name)
    except (ImportError, ValueError):
        return f"pid {os.getpid()}"


def compute_cell(
    events_key: str, data: bytes | str, mode: str, params: Mapping[str, float]
) -> dict[str, Any]:
    """The task: build one map from a bag's events and return its figures (or its error).

    ``data`` is the event file's path (readable where the task runs) or its content. Errors are
    returned, not raised: a failed cell is recorded and the sweep goes on.
    """
    try:
        log = worker_event_log(events_key, data)
        figures: dict[str, Any] = evaluate_cell(log, MapParams(**params), MapMode(mode))
        figures["status"] = "ok"
        figures["error"] = ""
    except Exception as exc:
        message = " ".join(f"{type(exc).__name__}: {exc}".split())
        figures = {"status": "error", "error": message[:500]}
    figures["worker"] = _worker_name()
    return figures


def worker_check(paths: Sequence[str] = ()) -> dict[str, Any]:
    """What a worker reports before a sweep: cogmap's version and which event files it sees."""
    return {
        "cogmap": __version__,
        "event_format": FORMAT_VERSION,
        "missing": [p for p in paths if not os.path.isfile(p)],
    }


def result_row(cell: Cell, run: int, outcome: Mapping[str, Any]) -> dict[str, Any]:
    """A results-table row: the cell's identity and setting, then the task's outcome."""
    row: dict[str, Any] = {
        "key": cell.key,
        "run": run,
        "bag": cell.bag.label,
        "bag_key": cell.bag.key,
        "map": cell.mode.value,
    }
    row.update(cell.params.to_dict())
    row.update(outcome)
    return row


# --------------------------------------------------------------------------- executing
Record = Callable[[Cell, dict[str, Any]], None]


def run_serially(cells: Sequence[Cell], events: Mapping[str, BagEvents], record: Record) -> None:
    """Build every cell in this process, one after the other (the reference for the speed-up)."""
    for cell in cells:
        path = str(events[cell.bag.key].events_path)
        record(cell, compute_cell(cell.bag.key, path, cell.mode.value, cell.params.to_dict()))


class FailedCells(SweepError):
    """Every cell has a result, but some failed (their errors are in ``results.csv``)."""


class SchedulerLost(SweepError):
    """The connection to the Dask scheduler was lost during the sweep."""


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


# --------------------------------------------------------------------------- progress
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
        with self._locked_folder() as previous:
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

    @contextlib.contextmanager
    def _locked_folder(self) -> Iterator[dict[str, Any] | None]:
        """Check the folder is this sweep's (or new) and lock it; yields its parsed manifest."""
        out = self.out_dir
        previous: dict[str, Any] | None = None
        if out.exists() and not out.is_dir():
            raise SweepError(f"{out} exists and is not a folder; choose another --out")
        manifest = out / MANIFEST_FILE
        if out.is_dir() and any(out.iterdir()):
            if not manifest.exists():
                ours = {EVENTS_DIR, LOCK_FILE}
                if any(p.name not in ours for p in out.iterdir()):
                    raise SweepError(f"{out} is not empty and holds no sweep; choose another --out")
            else:
                try:
                    previous = json.loads(manifest.read_text())
                except (OSError, ValueError):
                    raise SweepError(
                        f"{manifest} is not readable JSON; choose another --out"
                    ) from None
                if (
                    not isinstance(previous, dict)
                    or previous.get("format") != SWEEP_FORMAT
                    or previous.get("digest") != self.digest
                ):
                    raise SweepError(
                        f"{out} holds another sweep (other settings, bags, map or bag "
                        "contents); choose another --out, or re-run that sweep's own command"
                    )
        out.mkdir(parents=True, exist_ok=True)
        handle = (out / LOCK_FILE).open("a")
        try:
            if fcntl is not None:
                try:
                    fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
                except BlockingIOError:
                    raise SweepError(
                        f"another cogmap sweep is writing {out}; wait for it or choose "
                        "another --out"
                    ) from None
            yield previous
        finally:
            handle.close()

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


# --------------------------------------------------------------------------- the figure
def pareto_figure(best: Mapping[str, Any], settings: Sequence[SettingFigures], title: str) -> Any:
    """``pareto.png``: vertices against ATE (left) and completeness (right).

    Every setting is a grey dot, the Pareto fronts staircases in the swept map's colour, the
    paper's setting a diamond, the smallest complete map ringed
    (:func:`app.report_figures.pareto_figure`, a matplotlib figure).
    """
    from app.report_figures import pareto_figure as draw

    return draw(
        best,
        [s.vertices for s in settings],
        [_nan(s.ate_m) for s in settings],
        [_nan(s.completeness) for s in settings],
        title,
        float(best.get("min_completeness", MIN_COMPLETENESS)),
    )


def _nan(value: Any) -> float:
    return float("nan") if value is None else float(value)
