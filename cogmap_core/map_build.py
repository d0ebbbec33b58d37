"""Building one map from an event log: the one path every rebuild of a map takes.

A map for other parameters is built again from the front end's events kept in an
:class:`~cogmap_core.event_log.EventLog` (the bag is not read again): ``CognitiveMap(mode,
params)`` fed the events of the first ``frames`` frames, then, when asked, the end-of-data
optimisation. :meth:`SlamSession.rebuild <cogmap_core.slam.SlamSession.rebuild>` builds each of
its maps here, and so does the web app (``app/server/rebuild.py``, in worker processes or on a
thread), which also asks to be interrupted when a newer request arrives and keeps map states to
resume from:

- the events are applied by the compiled replay (:mod:`cogmap_core.compiled_replay`) from the
  log's columns when it is available, else by the map's Python code; both give the same map,
  in chunks between which ``interrupted()`` is asked (:class:`Abandoned`);
- with a :data:`CheckpointStore`, a build keeps the map's states at its clusters' closes
  (:class:`Checkpoints`) and a later build of the same map continues from the latest state its
  events share with them, which a :data:`Divergence` rule tells (by default the cluster
  schedule's, :func:`~cogmap_core.schedule.schedule_shared`: parameters that differ only in
  ``T_interval`` and ``T_total`` share the events before their schedules part;
  :func:`identical_params` shares them only between identical parameters). The map is the same
  either way.
"""

from __future__ import annotations

import pickle
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from cogmap_core import compiled_replay
from cogmap_core.cognitive_map import CognitiveMap, MapMode
from cogmap_core.config import MapParams
from cogmap_core.event_log import EventLog
from cogmap_core.events import MapEvent
from cogmap_core.schedule import schedule_shared

#: Events applied between two checks for a newer request during a rebuild.
REBUILD_CHUNK = 1000
#: The same with the compiled replay (:mod:`cogmap_core.compiled_replay`), which also checks
#: after every event the map's Python code applies (each optimisation among them).
COMPILED_CHUNK = 20000

#: At most this many map states kept per build (:class:`Checkpoints`); past it, every other one
#: is dropped (60 laps close some 240 clusters, each state a pickle of up to a few MB).
MAX_CHECKPOINTS = 48

#: Whether a newer request arrived (asked between chunks of events).
Interrupted = Callable[[], bool]


class Abandoned(Exception):
    """A newer request arrived while a map was being built."""


@dataclass(frozen=True, slots=True)
class BuildTask:
    """One map to build: ``mode`` with ``params`` from the first ``frames`` frames of the log.

    Attributes:
        mode: which map.
        params: its parameters.
        frames: frames of the event log to apply.
        finish: run the end-of-data optimisation afterwards.

    """

    mode: MapMode
    params: MapParams
    frames: int
    finish: bool


@dataclass(slots=True)
class Checkpoints:
    """A built map's states at its clusters' closes, to resume a later build from.

    Two parameter sets build the same map up to the first event at which they act differently
    (a :data:`Divergence` rule says where), so a map for the new ones continues from the latest
    state kept before that event instead of from the first event.

    Attributes:
        params: the parameters the states were built with.
        states: (events applied, the map pickled) after each event at which a cluster closed,
            in order (every other one dropped whenever there are more than
            :data:`MAX_CHECKPOINTS`).

    """

    params: MapParams
    states: list[tuple[int, bytes]]


#: Per map, the states its latest build kept (:class:`Checkpoints`), where it was built.
CheckpointStore = dict[MapMode, Checkpoints]

#: ``rule(log, end, old, new)``: how many of the first ``end`` events maps built with ``old`` and
#: ``new`` apply alike; None when a map built with ``old`` is no start for ``new`` at all (then
#: the build keeps no states: the next one starts from the first event).
Divergence = Callable[[EventLog, int, MapParams, MapParams], int | None]


def identical_params(log: EventLog, end: int, old: MapParams, new: MapParams) -> int | None:
    """The :data:`Divergence` rule that knows nothing of the events: identical parameters.

    Only identical parameters build alike (all ``end`` events); any change starts over.
    """
    return end if old == new else None


def build_map(
    log: EventLog,
    task: BuildTask,
    interrupted: Interrupted | None = None,
    events: Sequence[MapEvent] | None = None,
    checkpoints: CheckpointStore | None = None,
    divergence: Divergence = schedule_shared,
    finish_time: float | None = None,
) -> tuple[CognitiveMap, int]:
    """Build ``task``'s map from ``log``; return it and the events it resumed after (0: none).

    Args:
        log: the event log.
        task: which map, its parameters, how many frames, whether to finish.
        interrupted: asked between chunks of events (and after every event the map's Python
            code applies, on the compiled path): True abandons the build.
        events: the log's events already made into objects (at least those the task uses), to
            skip making them again from the log's columns (the Python path only).
        checkpoints: map states kept by earlier builds of this log (compiled path only): a build
            resumes from the latest state of its map's previous build that ``divergence`` says
            its events share, and keeps its own states there (none when ``divergence`` says
            the previous build is no start at all).
        divergence: the rule that says how many events two parameter sets apply alike.
        finish_time: data time of the end-of-data optimisation (default: the last frame's).

    Raises:
        Abandoned: ``interrupted()`` returned True.

    """
    end = int(log.frame_end[task.frames - 1]) if task.frames else 0
    if compiled_replay.available():
        cmap, start, states = _start(log, task, end, checkpoints, divergence)
        columns = log.columns(end)
        replayer = compiled_replay.CompiledReplay(cmap)
        closed = _closed_clusters(cmap)

        def after_python(k: int) -> None:  # a cluster closes only in the map's Python code
            nonlocal closed
            if interrupted is not None and interrupted():
                raise Abandoned  # (between two optimisations: a long bag's chunk takes seconds)
            now = _closed_clusters(cmap)
            if now != closed and states is not None:
                closed = now
                states.append((k + 1, pickle.dumps(cmap, protocol=pickle.HIGHEST_PROTOCOL)))
                if len(states) > MAX_CHECKPOINTS:  # every other one goes: memory stays bounded
                    states[:] = states[::2]

        watch = after_python if interrupted is not None or states is not None else None
        for lo in range(start, end, COMPILED_CHUNK):
            if interrupted is not None and interrupted():
                raise Abandoned
            replayer.apply(columns, lo, min(lo + COMPILED_CHUNK, end), watch)
        if checkpoints is not None:
            checkpoints[task.mode] = Checkpoints(task.params, states or [])
    else:
        start = 0
        cmap = CognitiveMap(task.mode, task.params)
        source = log.events if events is None else events
        for lo in range(0, end, REBUILD_CHUNK):
            if interrupted is not None and interrupted():
                raise Abandoned
            cmap.apply_all(source[lo : min(lo + REBUILD_CHUNK, end)])
    if task.finish and task.frames:
        cmap.finish(log.frame_time[task.frames - 1] if finish_time is None else finish_time)
    if interrupted is not None and interrupted():
        raise Abandoned
    return cmap, start


def _closed_clusters(cmap: CognitiveMap) -> int:
    """How many of a map's loop-closure clusters are closed."""
    return len(cmap.clusterer.clusters) - (cmap.clusterer.open_cluster is not None)


def _start(
    log: EventLog,
    task: BuildTask,
    end: int,
    checkpoints: CheckpointStore | None,
    divergence: Divergence,
) -> tuple[CognitiveMap, int, list[tuple[int, bytes]] | None]:
    """The map to continue from, the events it holds, and the states kept up to there.

    The states are None when the build keeps none: ``divergence`` says the map's previous build
    is no start for it (for the web app: an α, β or δ change of the compact map, where a pickle
    per cluster would cost a tenth of the build); the next build then starts from the first
    event and keeps them again.
    """
    if checkpoints is None:
        return CognitiveMap(task.mode, task.params), 0, None
    held = checkpoints.get(task.mode)
    if held is not None:
        diverge = divergence(log, end, held.params, task.params)
        if diverge is None:
            return CognitiveMap(task.mode, task.params), 0, None
        usable = [state for state in held.states if state[0] <= diverge]
        if usable:
            start, blob = usable[-1]
            cmap: CognitiveMap = pickle.loads(blob)
            cmap.set_params(task.params)
            return cmap, start, usable
    return CognitiveMap(task.mode, task.params), 0, []


__all__ = [
    "COMPILED_CHUNK",
    "MAX_CHECKPOINTS",
    "REBUILD_CHUNK",
    "Abandoned",
    "BuildTask",
    "CheckpointStore",
    "Checkpoints",
    "Divergence",
    "Interrupted",
    "build_map",
    "identical_params",
]
