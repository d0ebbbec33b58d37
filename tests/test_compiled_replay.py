"""The compiled map replay builds exactly the maps the Python code builds.

Each recorded stream (``tests/data/*.events.npz``, what the front end emitted on generated bags)
is replayed into every map twice -- by ``CognitiveMap.apply_all`` (the reference) and by
``cogmap_core.compiled_replay`` in chunks, as a rebuild does -- and the whole state of the two
maps is compared: graph arrays byte for byte (poses included, so well within 1e-9), adjacency in
its order, aliases, clusters, optimisation records, refused relocalisations, the gate's streak,
scene integration's runs, counters and size history.
"""

from __future__ import annotations

import dataclasses
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from app.server import rebuild
from cogmap_core import compiled_loop, compiled_replay, map_build, numba_cache
from cogmap_core.cognitive_map import CognitiveMap, MapMode
from cogmap_core.config import MapParams
from cogmap_core.errors import EventError
from cogmap_core.event_file import events_to_columns, load_event_file
from cogmap_core.event_log import EventLog
from cogmap_core.events import CreateVertex, LinkToVertex, Odometry, SetCurrentVertex
from cogmap_core.map_build import BuildTask, build_map
from cogmap_core.schedule import schedule_divergence
from tests.conftest import DATA
from tests.test_scene_integration import NO_GATE, lap_closed_by_a_false_link

pytestmark = pytest.mark.skipif(
    not compiled_replay.available(), reason=f"{compiled_replay.unavailable_reason()}"
)

#: A strict relocalisation test: many refusals, path searches and acceptances by consensus.
STRICT = MapParams(gate_position=0.02, gate_heading=0.05, gate_consensus=3.0)


@pytest.fixture(scope="module")
def logs() -> dict[str, EventLog]:
    return {
        name: EventLog.from_recording(load_event_file(DATA / f"{name}.events.npz"))
        for name in ("figure_eight_3laps", "junction_dead_end_2laps")
    }


def state(cmap: CognitiveMap) -> dict[str, object]:
    """Everything that decides what a map does next, and what it shows."""
    g = cmap.graph
    n, m = g.num_ids, g.num_edges_total
    vertex = ("pose", "vertex_time", "view", "alive", "alias", "alias_offset")
    edge = ("from", "to", "rel", "time", "kind", "cluster", "alive")
    integration = cmap.integration
    return {
        "counts": (g.num_ids, g.num_vertices, m, g.num_edges, g.num_loop_edges),
        "capacity": (g.pose.shape, g.edge_from.shape),
        "vertices": [getattr(g, a)[:n].tobytes() for a in vertex],
        "edges": [getattr(g, "edge_" + a)[:m].tobytes() for a in edge],
        "adjacency": [list(d.items()) for d in g.adjacency],
        "absorbed": g._absorbed,
        "robot": (cmap._current, cmap._accum, cmap._travelled, cmap._last_rotation),
        "time": (cmap._last_time, cmap._last_link),
        "counters": cmap.counters,
        "clusters": cmap.clusters,
        "open cluster": cmap.clusterer.open_cluster,
        "optimisations": [dataclasses.replace(o, wall_s=0.0) for o in cmap.optimizations],
        "optimised": (cmap._edges_at_last_optimization, cmap._optimized_once),
        "refused": cmap.refused,
        "gate": (cmap.gate.streak, cmap.gate.accepted_by_consensus),
        "integration": (integration.open, integration.pending, integration._relocalised_at),
        "known edges": integration._known is None,
        "history": (cmap._hist_time, cmap._hist_vertices, cmap._hist_edges),
    }


def python_map(log: EventLog, mode: MapMode, params: MapParams) -> CognitiveMap:
    cmap = CognitiveMap(mode, params)
    cmap.apply_all(list(log.events))
    cmap.finish(log.end_time)
    return cmap


def compiled_map(
    log: EventLog, mode: MapMode, params: MapParams, chunk: int = 1500
) -> tuple[CognitiveMap, int]:
    cmap = CognitiveMap(mode, params)
    replayer = compiled_replay.CompiledReplay(cmap)
    columns = log.columns()
    for lo in range(0, log.event_count, chunk):
        replayer.apply(columns, lo, min(lo + chunk, log.event_count))
    cmap.finish(log.end_time)
    return cmap, replayer.escapes


def assert_same_state(actual: CognitiveMap, expected: CognitiveMap) -> None:
    a, e = state(actual), state(expected)
    for key in e:
        assert a[key] == e[key], key


@pytest.mark.parametrize("mode", list(MapMode))
@pytest.mark.parametrize("name", ["figure_eight_3laps", "junction_dead_end_2laps"])
def test_compiled_replay_builds_the_python_maps(logs, name: str, mode: MapMode) -> None:
    log = logs[name]
    expected = python_map(log, mode, MapParams())
    actual, escapes = compiled_map(log, mode, MapParams())
    assert_same_state(actual, expected)
    # the compiled loop applies nearly every event (the Python code only the rare ones)
    assert escapes < 0.05 * log.event_count, escapes
    # the stream exercises what the map does: merges, declines, short edges, duplicates
    c = expected.counters
    assert c.duplicate_links > 0 and c.refused_relocalisations > 0
    if mode is not MapMode.STANDARD:
        assert c.integrated > 0
    if mode is MapMode.COMPACT:
        assert c.declined > 0 and c.short_edges > 0


@pytest.mark.parametrize(
    "mode, params",
    [
        (MapMode.COMPACT, MapParams(alpha=5.0, beta=20.0, delta=6.0)),
        (MapMode.STANDARD, MapParams(t_interval=1.0, t_total=30.0, gate_position=1e9)),
        (MapMode.SCENE_INTEGRATION, STRICT),
        (MapMode.COMPACT, STRICT),
    ],
)
def test_compiled_replay_follows_the_parameters(logs, mode: MapMode, params: MapParams) -> None:
    log = logs["junction_dead_end_2laps"]
    expected = python_map(log, mode, params)
    assert_same_state(compiled_map(log, mode, params, chunk=997)[0], expected)
    if params is STRICT:  # refusals, accepted by consensus in the end
        assert expected.gate.accepted_by_consensus and expected.counters.refused_relocalisations


def test_a_map_built_part_of_the_way_continues_either_way(logs) -> None:
    log = logs["junction_dead_end_2laps"]
    half = log.event_count // 2
    columns = log.columns()
    events = list(log.events)
    for mode in MapMode:
        python = CognitiveMap(mode)
        python.apply_all(events[:half])
        compiled = CognitiveMap(mode)
        compiled_replay.replay(compiled, columns, 0, half)
        assert_same_state(compiled, python)
        python.apply_all(events[half:])  # each continues with the other's way
        compiled_replay.CompiledReplay(compiled).apply(columns, half, log.event_count)
        assert_same_state(compiled, python)


def contract_breaks() -> list[list]:
    ok = [Odometry(0.1, 0.1, 0.0), CreateVertex(0.1, 0, 0), Odometry(0.2, 0.1, 0.0)]
    return [
        ok + [Odometry(0.15, 0.1, 0.0)],  # time goes backwards
        ok + [Odometry(0.3, math.nan, 0.0)],
        ok + [CreateVertex(0.3, 5, 1)],  # not the next id
        ok + [LinkToVertex(0.3, 9, 0.0)],  # unknown vertex
        ok + [SetCurrentVertex(0.3, 0, math.inf)],
        [LinkToVertex(0.1, 0, 0.0)],  # a link before any vertex
        ok + [Odometry(math.nan, 0.1, 0.0)],
    ]


@pytest.mark.parametrize("events", contract_breaks())
def test_broken_streams_raise_the_python_error(events) -> None:
    with pytest.raises(EventError) as python:
        CognitiveMap(MapMode.COMPACT).apply_all(events)
    compiled = CognitiveMap(MapMode.COMPACT)
    with pytest.raises(EventError) as raised:
        compiled_replay.replay(compiled, events_to_columns(events), 0, len(events))
    assert str(raised.value) == str(python.value)


def test_a_merge_split_again_replays_as_the_python_code_splits_it() -> None:
    """A merge split when its closing link is rejected (``test_scene_integration``'s false
    closing link), then a third lap: the compiled loop's edge table follows the split."""
    loop, _ = lap_closed_by_a_false_link()
    loop.known_lap()
    events = loop.s.events
    params = MapParams(integration_max_residual=1.0, **NO_GATE)
    expected = CognitiveMap(MapMode.SCENE_INTEGRATION, params)
    expected.apply_all(events)
    expected.finish()
    actual = CognitiveMap(MapMode.SCENE_INTEGRATION, params)
    compiled_replay.replay(actual, events_to_columns(events), 0, len(events))
    actual.finish()
    assert expected.counters.split == 1
    assert_same_state(actual, expected)


def test_without_numba_the_python_code_replays(logs, monkeypatch) -> None:
    monkeypatch.setenv(compiled_replay.ENV_SWITCH, "0")
    assert not compiled_replay.available()
    assert compiled_replay.unavailable_reason() == f"{compiled_replay.ENV_SWITCH}=0"
    log = logs["junction_dead_end_2laps"]
    cmap = CognitiveMap(MapMode.COMPACT)
    compiled_replay.replay(cmap, log.columns(), 0, log.event_count)
    cmap.finish(log.end_time)
    assert_same_state(cmap, python_map(log, MapMode.COMPACT, MapParams()))
    with pytest.raises(RuntimeError, match="no compiled replay"):
        compiled_replay.CompiledReplay(cmap)


def test_hypot_is_cpythons_to_the_last_bit() -> None:
    rng = np.random.default_rng(3)
    xs = np.concatenate([rng.normal(0, s, (20000, 2)) for s in (1e-300, 1e-4, 1.0, 1e4, 1e300)])
    xs = np.concatenate([xs, [[0.0, 0.0], [math.inf, math.nan], [math.nan, 1.0], [5e-324, 0.0]]])
    got = compiled_loop._check(xs)[:, 0]
    want = np.array([math.hypot(x, y) for x, y in xs.tolist()])
    np.testing.assert_array_equal(got, want)


def test_the_numba_cache_goes_where_it_can_be_written(tmp_path: Path) -> None:
    source = tmp_path / "site" / "__pycache__"
    home = tmp_path / "home"
    env: dict[str, str] = {}
    assert numba_cache.choose_cache(source, env, False, home) and env == {}  # beside the code
    assert source.is_dir() and numba_cache.writable_folder(source)
    user = home / ".cache" / "cogmap" / "numba"

    def only(*folders: Path):  # a read-only install: only these folders can be written
        return lambda folder: folder in folders

    assert numba_cache.choose_cache(source, env, False, home, only(user))
    assert env == {"NUMBA_CACHE_DIR": str(user)}
    env = {"XDG_CACHE_HOME": str(tmp_path / "xdg")}
    xdg = tmp_path / "xdg" / "cogmap" / "numba"
    assert numba_cache.choose_cache(source, env, False, home, only(xdg))
    assert env["NUMBA_CACHE_DIR"] == str(xdg)
    env = {}
    assert not numba_cache.choose_cache(source, env, True, home, only(user))  # numba set up
    assert not numba_cache.choose_cache(source, env, False, home, only()) and env == {}
    env = {"NUMBA_CACHE_DIR": "/elsewhere"}
    assert numba_cache.choose_cache(source, env, False, home, only())  # the user's choice
    assert env == {"NUMBA_CACHE_DIR": "/elsewhere"}


def test_a_schedule_change_resumes_from_the_last_cluster_it_shares(logs) -> None:
    log = logs["figure_eight_3laps"]
    store: dict = {}
    resumed_after = []
    for mode in (MapMode.SCENE_INTEGRATION, MapMode.COMPACT):
        first, _ = build_map(log, BuildTask(mode, MapParams(), log.frames, True), None, None, store)
        closed = [
            c for c in first.clusters if c.closed_time is not None and c.closed_time < log.end_time
        ]
        assert len(store[mode].states) == len(closed)  # a state after each cluster's close
        previous = MapParams()
        for params in (
            MapParams(t_total=20.0),  # the schedules part late
            MapParams(t_total=10.0, t_interval=3.0),  # at the first cluster
            MapParams(t_total=10.0, t_interval=3.0, delta=5.0),  # not a schedule change
        ):
            task = BuildTask(mode, params, log.frames, True)
            diverge = schedule_divergence(log, log.event_count, previous, params)
            held = [k for k, _ in store[mode].states if k <= diverge]
            if (
                previous.with_changes(t_interval=params.t_interval, t_total=params.t_total)
                != params
            ):
                held = []
            cmap, resumed = build_map(log, task, None, None, store)
            assert resumed == (held[-1] if held else 0)
            assert_same_state(cmap, python_map(log, mode, params))
            resumed_after.append(resumed)
            previous = params
        assert store[mode].states == []  # none kept after a change of more than the schedule
        params = previous.with_changes(t_total=20.0)
        cmap, resumed = build_map(log, BuildTask(mode, params, log.frames, True), None, None, store)
        assert resumed == 0 and store[mode].states  # kept again
    assert resumed_after[0] > log.event_count // 2 and resumed_after[3] > log.event_count // 2
    assert build_map(log, BuildTask(mode, MapParams(t_total=20.0), log.frames, True))[1] == 0


def test_kept_states_stay_few_and_still_resume_exactly(logs, monkeypatch) -> None:
    monkeypatch.setattr(map_build, "MAX_CHECKPOINTS", 3)  # (where the build reads it)
    log = logs["figure_eight_3laps"]
    store: dict = {}
    build_map(log, BuildTask(MapMode.COMPACT, MapParams(), log.frames, True), None, None, store)
    kept = [k for k, _ in store[MapMode.COMPACT].states]
    assert 2 <= len(kept) <= 3 and kept == sorted(kept)
    params = MapParams(t_total=20.0)
    cmap, resumed = build_map(
        log, BuildTask(MapMode.COMPACT, params, log.frames, True), None, None, store
    )
    assert resumed in kept and resumed > 0
    assert_same_state(cmap, python_map(log, MapMode.COMPACT, params))


def test_without_numba_installed_rebuilds_use_the_python_code() -> None:
    recording = str(DATA / "junction_dead_end_2laps.events.npz")
    code = (
        "import sys; sys.modules['numba'] = None\n"  # import numba raises ImportError
        "from cogmap_core import compiled_replay as c\n"
        "from cogmap_core.event_log import EventLog\n"
        "from cogmap_core.event_file import load_event_file\n"
        "from cogmap_core.map_build import BuildTask, build_map\n"
        "from cogmap_core.cognitive_map import MapMode\n"
        "from cogmap_core.config import MapParams\n"
        f"log = EventLog.from_recording(load_event_file({recording!r}))\n"
        "cmap, _ = build_map(log, BuildTask(MapMode.COMPACT, MapParams(), log.frames, True))\n"
        "print(c.available(), c.unavailable_reason(), cmap.num_vertices)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True
    ).stdout.split()
    expected = python_map(
        EventLog.from_recording(load_event_file(recording)), MapMode.COMPACT, MapParams()
    )
    assert out == ["False", "numba", "is", "not", "installed", str(expected.num_vertices)]


def test_a_newer_request_stops_a_compiled_build_between_optimisations(logs) -> None:
    log = logs["figure_eight_3laps"]
    task = BuildTask(MapMode.STANDARD, MapParams(), log.frames, True)
    asked = []

    def interrupted() -> bool:
        asked.append(True)
        return len(asked) > 5

    with pytest.raises(rebuild.Abandoned):
        build_map(log, task, interrupted)
    assert len(asked) == 6  # asked again at events the Python code applied, not only per chunk
    assert log.event_count < rebuild.COMPILED_CHUNK
