"""One map build path (``cogmap_core.map_build``): ``SlamSession.rebuild`` and the app's rebuilds.

Each caller keeps its own end-of-data time: ``SlamSession.rebuild`` finishes at the session's
last frame whatever ``frames`` (its documented behaviour), the app's builds at the last frame
built; on all frames the two are the same. A build resumes from kept cluster states only where
its :data:`~cogmap_core.map_build.Divergence` rule says the events are shared (by default: the
same parameters).
"""

from __future__ import annotations

import pytest

from app.server import rebuild
from cogmap_core import compiled_replay, map_build
from cogmap_core.cognitive_map import CognitiveMap, MapMode
from cogmap_core.config import MapParams
from cogmap_core.event_file import load_event_file
from cogmap_core.event_log import EventLog
from cogmap_core.map_build import Abandoned, BuildTask, build_map, identical_params
from cogmap_core.slam import SlamSession
from tests.conftest import DATA
from tests.test_state_dicts import assert_same, without_wall_times

CHANGED = MapParams(delta=6.0, t_interval=1.0)


@pytest.fixture(scope="module")
def log() -> EventLog:
    return EventLog.from_recording(load_event_file(DATA / "figure_eight_3laps.events.npz"))


def session_of(log: EventLog) -> SlamSession:
    session = SlamSession()
    session.log = log
    session.finished = True
    return session


def same(a: CognitiveMap, b: CognitiveMap) -> None:
    assert_same(without_wall_times(a.state_dict()), without_wall_times(b.state_dict()))


def python_map(log: EventLog, mode: MapMode, params: MapParams, frames: int) -> CognitiveMap:
    """The reference: the map's own Python code fed the events of the first ``frames`` frames."""
    cmap = CognitiveMap(mode, params)
    cmap.apply_all(log.events_until(frames))
    return cmap


def test_the_session_s_rebuild_is_the_one_build_path(log: EventLog) -> None:
    session = session_of(log)
    maps = session.rebuild(CHANGED)
    for mode in MapMode:
        built, resumed = build_map(log, BuildTask(mode, CHANGED, log.frames, True))
        assert resumed == 0
        same(maps[mode], built)
        expected = python_map(log, mode, CHANGED, log.frames)
        expected.finish(log.end_time)
        same(maps[mode], expected)
        assert maps[mode].clusters[-1].closed_time == log.end_time == log.frame_time[-1]
    # the app's names are the same build (with the cluster schedule's resume rule)
    assert rebuild.BuildTask is BuildTask and rebuild.Abandoned is Abandoned
    assert rebuild.build_map is build_map
    same(rebuild.build_map(log, BuildTask(MapMode.COMPACT, CHANGED, log.frames, True))[0],
         maps[MapMode.COMPACT])  # fmt: skip


def open_cluster_frame(log: EventLog, params: MapParams) -> int:
    """The first frame past half the log after which the standard map has an open cluster."""
    cmap = CognitiveMap(MapMode.STANDARD, params)
    events, done = log.events_until(), 0
    for k, end in enumerate(log.frame_end.tolist(), 1):
        cmap.apply_all(events[done:end])
        done = end
        if k >= log.frames // 2 and cmap.clusterer.open_cluster is not None:
            return k
    raise AssertionError("no open cluster")


def test_each_caller_keeps_its_end_of_data_time(log: EventLog) -> None:
    k = open_cluster_frame(log, CHANGED)
    assert log.frame_time[k - 1] < log.end_time
    session = session_of(log)
    finished_late = session.rebuild(CHANGED, frames=k, finish=True)[MapMode.STANDARD]
    task = BuildTask(MapMode.STANDARD, CHANGED, k, True)
    finished_there = build_map(log, task)[0]
    # the same events, the last cluster closed at the session's end or at the k-th frame
    assert finished_late.clusters[-1].closed_time == log.end_time
    assert finished_there.clusters[-1].closed_time == float(log.frame_time[k - 1])
    expected = python_map(log, MapMode.STANDARD, CHANGED, k)
    expected.finish(log.end_time)
    same(finished_late, expected)
    same(build_map(log, task, finish_time=log.end_time)[0], expected)
    # not finished (a seek), the default when only part of the frames is rebuilt
    partial = session.rebuild(CHANGED, frames=k)[MapMode.STANDARD]
    same(partial, python_map(log, MapMode.STANDARD, CHANGED, k))
    assert partial.clusterer.open_cluster is not None
    # no frame: an empty map, finished or not
    for frames in (0, -3):
        empty = session.rebuild(CHANGED, frames=frames, finish=True)[MapMode.COMPACT]
        same(empty, CognitiveMap(MapMode.COMPACT, CHANGED))


@pytest.mark.skipif(not compiled_replay.available(), reason="checkpoints need the compiled replay")
def test_the_identical_params_rule_resumes_only_the_same_parameters(log: EventLog) -> None:
    store: map_build.CheckpointStore = {}
    mode = MapMode.SCENE_INTEGRATION
    first, resumed = build_map(
        log, BuildTask(mode, MapParams(), log.frames, True), None, None, store
    )
    kept = [k for k, _ in store[mode].states]
    assert resumed == 0 and kept and kept == sorted(kept)
    again, resumed = build_map(
        log, BuildTask(mode, MapParams(), log.frames, True), None, None, store
    )
    assert resumed == kept[-1]  # all events shared: from the latest state
    same(again, first)
    other = MapParams(t_total=20.0)  # the schedule's rule would resume it; this one does not
    assert identical_params(log, log.event_count, MapParams(), other) is None
    built, resumed = build_map(
        log, BuildTask(mode, other, log.frames, True), None, None, store, identical_params
    )
    assert resumed == 0 and store[mode].states == []  # no start: none kept
    expected = python_map(log, mode, other, log.frames)
    expected.finish(log.end_time)
    same(built, expected)
    built, resumed = build_map(
        log, BuildTask(mode, other, log.frames, True), None, None, store, identical_params
    )
    assert resumed == 0 and store[mode].states  # kept again


@pytest.mark.skipif(not compiled_replay.available(), reason="checkpoints need the compiled replay")
def test_a_rule_says_how_far_a_build_resumes(log: EventLog) -> None:
    store: map_build.CheckpointStore = {}
    mode = MapMode.COMPACT
    build_map(log, BuildTask(mode, MapParams(), log.frames, True), None, None, store)
    kept = [k for k, _ in store[mode].states]
    asked: list[tuple[int, MapParams, MapParams]] = []

    def halfway(log: EventLog, end: int, old: MapParams, new: MapParams) -> int:
        asked.append((end, old, new))
        return end // 2

    params = MapParams(delta=5.0)  # (the rule is trusted: here it is not even true)
    cmap, resumed = build_map(
        log, BuildTask(mode, params, log.frames, False), None, None, store, halfway
    )
    assert asked == [(log.event_count, MapParams(), params)]
    assert resumed == max(k for k in kept if k <= log.event_count // 2) > 0
    assert [k for k, _ in store[mode].states][: kept.index(resumed) + 1] == kept[
        : kept.index(resumed) + 1
    ]
    assert cmap.params == params


def test_an_interrupted_build_is_abandoned_on_either_path(
    log: EventLog, monkeypatch: pytest.MonkeyPatch
) -> None:
    task = BuildTask(MapMode.STANDARD, MapParams(), log.frames, True)
    with pytest.raises(Abandoned):
        build_map(log, task, lambda: True)
    monkeypatch.setattr(compiled_replay, "available", lambda: False)  # the Python path
    asked: list[bool] = []

    def third(asked: list[bool] = asked) -> bool:
        asked.append(True)
        return len(asked) >= 3

    with pytest.raises(Abandoned):
        build_map(log, task, third)
    assert len(asked) == 3  # between chunks of REBUILD_CHUNK events
    assert log.event_count > 2 * map_build.REBUILD_CHUNK
    cmap, resumed = build_map(log, task)
    expected = python_map(log, MapMode.STANDARD, MapParams(), log.frames)
    expected.finish(log.end_time)
    same(cmap, expected)
