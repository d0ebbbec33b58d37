"""Map rebuilds for new parameters: worker processes, the cache and the cluster-schedule shortcut.

Every rebuilt map must be exactly the map ``SlamSession.rebuild`` and a headless ``cogmap run``
build for the same parameters.
"""

from __future__ import annotations

import itertools
import random
import time
from pathlib import Path

import numpy as np
import pytest

import app.server.replay_rebuilds as replay_module
from app.pipeline import HeadlessPipeline, RunOptions
from app.server.export import g2o_bytes
from app.server.rebuild import (
    Abandoned,
    BuildTask,
    MapCache,
    ProcessBuilder,
    ThreadBuilder,
)
from cogmap_core.clustering import LoopClosureClusterer, cluster_schedule
from cogmap_core.cognitive_map import CognitiveMap, MapMode
from cogmap_core.config import MapParams
from cogmap_core.event_log import EventLog
from cogmap_core.events import LinkToVertex, MapEvent, Odometry
from cogmap_core.schedule import same_schedule
from cogmap_core.slam import SlamSession
from tests import test_server_support as support
from tests.test_server_support import assert_same_map, running_app

short_bag = support.short_bag
reference = support.reference


def clusterer_schedule(
    events: list[MapEvent], end: int, finish: bool, t_interval: float, t_total: float
) -> tuple[tuple[int, int, int], ...]:
    """The schedule as the map's own clusterer makes it (event by event, as CognitiveMap.apply)."""
    clusterer = LoopClosureClusterer(t_interval, t_total)
    first: dict[int, int] = {}
    last: dict[int, int] = {}
    close: dict[int, int] = {}
    for k, event in enumerate(events[:end]):
        if clusterer.open_cluster is not None:
            closed = clusterer.due(event.time)
            if closed is not None:
                close[closed.cluster_id] = k
        if type(event) is LinkToVertex:
            cid, _ = clusterer.add_edge(event.time)
            first.setdefault(cid, k)
            last[cid] = k
    if finish and clusterer.open_cluster is not None:
        close[clusterer.open_cluster.cluster_id] = end
    return tuple((first[c], last[c], close.get(c, -1)) for c in sorted(first))


def random_events(rng: random.Random, n: int) -> list[MapEvent]:
    t = 0.0
    out: list[MapEvent] = []
    for _ in range(n):
        t += rng.choice((0.0, 0.05, 0.1, 0.5, 1.0, 1.9, 2.0, 2.1, 3.0))  # ties and near-ties
        if rng.random() < 0.3:
            out.append(LinkToVertex(t, 0, 0.0))
        else:
            out.append(Odometry(t, 0.01, 0.0))
    return out


def test_cluster_schedule_is_the_clusterers(reference: SlamSession) -> None:
    rng = random.Random(5)
    streams = [random_events(rng, 400) for _ in range(20)] + [reference.log.events]
    for events in streams:
        times = np.array([e.time for e in events])
        links = np.array([k for k, e in enumerate(events) if type(e) is LinkToVertex])
        for t_interval, t_total, finish in itertools.product(
            (0.1, 1.0, 2.0, 3.0), (1.0, 5.0, 100.0), (False, True)
        ):
            for end in (len(events), len(events) // 2, 0):
                assert cluster_schedule(times, links, end, finish, t_interval, t_total) == (
                    clusterer_schedule(events, end, finish, t_interval, t_total)
                )


def test_same_schedule_means_the_same_map(reference: SlamSession) -> None:
    log = reference.log
    frames = log.frames
    paper = MapParams()
    same, different = [], []
    for t_total in (1.0, 3.0, 10.0, 50.0, 400.0):
        new = paper.with_changes(t_total=t_total)
        (same if same_schedule(log, frames, True, paper, new) else different).append(new)
    assert same and different  # both cases occur on this bag
    for new in same:
        rebuilt = reference.rebuild(new)
        for mode in MapMode:
            assert_same_map(rebuilt[mode], reference.maps[mode])
    for new in different:
        rebuilt = reference.rebuild(new)
        assert len(rebuilt[MapMode.STANDARD].optimizations) != len(
            reference.maps[MapMode.STANDARD].optimizations
        ) or not np.array_equal(
            rebuilt[MapMode.STANDARD].snapshot().poses,
            reference.maps[MapMode.STANDARD].snapshot().poses,
        )
    # any other parameter: never "the same schedule"
    assert not same_schedule(log, frames, True, paper, paper.with_changes(delta=5.0))
    assert same_schedule(log, frames, True, paper, paper)


def test_worker_processes_build_exactly_the_sessions_maps(reference: SlamSession) -> None:
    params = MapParams(delta=6.0, t_interval=1.0)
    builder = ProcessBuilder(2)
    try:
        tasks = [BuildTask(m, params, reference.log.frames, True) for m in MapMode]
        built = list(builder.build(reference.log, tasks, lambda: False))
        assert [b.task.mode for b in built] != []
        assert sorted(b.task.mode for b in built) == sorted(MapMode)
        expected = reference.rebuild(params)
        for b in built:
            assert_same_map(b.cmap, expected[b.task.mode])
            assert b.compute_s > 0
        # part of the log, not finished, as a seek does
        half = reference.log.frames // 2
        (partial,) = builder.build(
            reference.log, [BuildTask(MapMode.COMPACT, params, half, False)], lambda: False
        )
        assert_same_map(
            partial.cmap, reference.rebuild(params, frames=half, finish=False)[MapMode.COMPACT]
        )
        # a newer request abandons the builds in flight; the workers stay usable
        started = time.monotonic()
        with pytest.raises(Abandoned):
            for _ in builder.build(reference.log, tasks, lambda: time.monotonic() > started):
                pass
        again = list(builder.build(reference.log, tasks[:1], lambda: False))
        assert_same_map(again[0].cmap, expected[tasks[0].mode])
    finally:
        builder.close()


def test_the_thread_builder_is_the_same(reference: SlamSession) -> None:
    params = MapParams(alpha=20.0)
    tasks = [BuildTask(MapMode.COMPACT, params, reference.log.frames, True)]
    (built,) = ThreadBuilder().build(reference.log, tasks, lambda: False)
    assert_same_map(built.cmap, reference.rebuild(params)[MapMode.COMPACT])
    with pytest.raises(Abandoned):
        list(ThreadBuilder().build(reference.log, tasks, lambda: True))


def test_map_cache_keys_on_the_parameters_a_map_uses() -> None:
    uses = {MapMode.STANDARD: frozenset({"t_interval"})}
    cache = MapCache(size=2, uses=uses)
    a, b, c = (CognitiveMap(MapMode.STANDARD) for _ in range(3))
    key = cache.key(MapMode.STANDARD, MapParams(), 10, True, 1)
    assert key == cache.key(MapMode.STANDARD, MapParams(delta=9.0), 10, True, 1)  # unused
    assert key != cache.key(MapMode.STANDARD, MapParams(t_interval=3.0), 10, True, 1)
    assert key != cache.key(MapMode.STANDARD, MapParams(), 11, True, 1)
    assert key != cache.key(MapMode.STANDARD, MapParams(), 10, False, 1)
    assert key != cache.key(MapMode.STANDARD, MapParams(), 10, True, 2)  # another session
    cache.put(key, a)
    cache.put(cache.key(MapMode.STANDARD, MapParams(t_interval=3.0), 10, True, 1), b)
    cache.put(cache.key(MapMode.STANDARD, MapParams(t_interval=4.0), 10, True, 1), c)
    assert len(cache) == 2  # the oldest went
    assert cache.take(key) is None
    assert cache.take(cache.key(MapMode.STANDARD, MapParams(t_interval=4.0), 10, True, 1)) is c
    assert cache.take(cache.key(MapMode.STANDARD, MapParams(t_interval=4.0), 10, True, 1)) is None


def test_the_app_rebuilds_exactly_what_cogmap_run_builds(
    short_bag: Path, reference: SlamSession, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    changes = {"delta": 6.0, "t_interval": 1.0, "t_total": 40.0}
    params = MapParams(**changes)
    headless = HeadlessPipeline(short_bag, tmp_path / "run", RunOptions(param_changes=changes))
    headless.run()
    with running_app(short_bag) as app:
        assert app.wait_idle(60)
        assert app.replay.builder.workers == 2
        first_new = len(app.replay.rebuilds)
        for name in ("delta", "t_interval", "t_total"):
            app.param_sliders[name].value = getattr(params, name)
        assert app.wait_idle(60)
        # The three values may reach the worker in one rebuild or in several (one per slider, as
        # they arrive); a later one keeps a map an earlier one built when its schedule is the same.
        records = app.replay.rebuilds[first_new:]
        assert records and records[-1].completed
        for mode in MapMode:
            assert any(r.how.get(mode) == "built" for r in records)
            assert {r.how.get(mode) for r in records} <= {"built", "kept", None}
        rebuilt = reference.rebuild(params)
        for mode in MapMode:
            shown = app.replay.session.maps[mode]
            assert_same_map(shown, rebuilt[mode])
            assert_same_map(shown, headless.session.maps[mode])
            written = (tmp_path / "run" / f"{mode.value}.g2o").read_bytes()
            assert g2o_bytes(shown) == written
        # back to the paper's values: every map comes from the cache, exactly the first ones
        app.reset_params()
        assert app.wait_idle(60)
        record = app.replay.rebuilds[-1]
        assert record.how == {m: "cached" for m in MapMode}
        for mode in MapMode:
            assert_same_map(app.replay.session.maps[mode], reference.maps[mode])
            # a T_total that gives the same cluster schedule keeps every map
            log = app.replay.session.log
        kept = next(
            t
            for t in (400.0, 300.0, 200.0, 150.0)
            if same_schedule(log, log.frames, True, MapParams(), MapParams(t_total=t))
        )
        before = dict(app.replay.session.maps.maps)
        schedules: list[float] = []

        def counted(*args: object) -> bool:
            schedules.append(args[-1].t_total)  # type: ignore[attr-defined]
            return same_schedule(*args)  # type: ignore[arg-type]

        monkeypatch.setattr(replay_module, "same_schedule", counted)
        app.param_sliders["t_total"].value = kept
        assert app.wait_idle(60)
        assert app.replay.rebuilds[-1].how == {m: "kept" for m in MapMode}
        assert schedules == [kept]  # compared once for the three maps' shared parameters
        for mode in MapMode:
            assert app.replay.session.maps[mode] is before[mode]
            assert app.replay.session.maps[mode].params.t_total == kept
            assert_same_map(before[mode], reference.rebuild(MapParams(t_total=kept))[mode])


def test_a_log_copy_kept_in_step_by_columns_is_the_log(reference: SlamSession) -> None:
    """What a worker holds (EventLog.extend, two pieces) has the log's events and frames."""
    log = reference.log
    copy = EventLog()
    half = log.frames // 2
    for lo, hi in ((0, half), (half, log.frames)):
        start = int(log.frame_end[lo - 1]) if lo else 0
        end = int(log.frame_end[hi - 1])
        columns = {k: v[start:end] for k, v in log.columns(end).items()}
        copy.extend(columns, log.frame_end[lo:hi], log.frame_time[lo:hi])
    assert copy.frames == log.frames and copy.event_count == log.event_count
    assert list(copy.events) == list(log.events)
    assert np.array_equal(copy.frame_time, log.frame_time)
    with pytest.raises(ValueError, match="frame ends"):
        copy.extend(log.columns(3), [2, 1], [1.0, 2.0])
