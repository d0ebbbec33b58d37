"""Every stateful class saves its own state (``state_dict``) and restores it (``load_state``).

A restored object holds exactly the state it was made from, and goes on exactly as the original
does: the maps over the recorded event streams (``tests/data``), restored again and again part
way (right after a link too, before its set-current event); the front end over generated
frames. Session files (:mod:`cogmap_core.session_file`) only lay these states out.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from cogmap_core.clustering import LoopClosureClusterer
from cogmap_core.cognitive_map import CognitiveMap, MapMode, OptimizationRecord
from cogmap_core.config import MapParams
from cogmap_core.errors import StateError
from cogmap_core.event_file import load_event_file
from cogmap_core.event_log import EventLog
from cogmap_core.events import CreateVertex, LinkToVertex, MapEvent, Odometry, SetCurrentVertex
from cogmap_core.frames import Frame
from cogmap_core.frontend import FrontEnd, FrontEndConfig
from cogmap_core.frontend.local_view import LocalViewCells
from cogmap_core.frontend.pose_cells import PoseCellNetwork
from cogmap_core.map_graph import EdgeKind, MapGraph
from cogmap_core.relocalisation import RelocalisationCheck, RelocalisationGate
from cogmap_core.scene_integration import KnownEdges, RevisitRun, SceneIntegration
from tests.conftest import DATA
from tests.test_frontend_frontend import CELL, CONFIG, ORS, place

#: A strict relocalisation test: many refusals, and acceptances by consensus.
STRICT = MapParams(gate_position=0.02, gate_heading=0.05, gate_consensus=3.0)


def assert_same(a: Any, b: Any, where: str = "state") -> None:
    """``a`` and ``b`` are the same plain data: types, keys in order, values bit for bit."""
    assert type(a) is type(b), f"{where}: {type(a).__name__} vs {type(b).__name__}"
    if isinstance(a, dict):
        assert list(a) == list(b), where
        for key in a:
            assert_same(a[key], b[key], f"{where}.{key}")
    elif isinstance(a, list | tuple):
        assert len(a) == len(b), where
        for k, (x, y) in enumerate(zip(a, b, strict=True)):
            assert_same(x, y, f"{where}[{k}]")
    elif isinstance(a, np.ndarray):
        assert (a.dtype, a.shape) == (b.dtype, b.shape), where
        assert a.tobytes() == b.tobytes(), where
    elif isinstance(a, float):
        assert repr(a) == repr(b), where  # NaN, infinities and -0.0 alike
    else:
        assert a == b, where


def without_wall_times(state: dict[str, Any]) -> dict[str, Any]:
    """A map's state with its optimisations' wall times (measurements, not state) zeroed."""
    return {
        **state,
        "optimizations": [{**r, "wall_s": 0.0} for r in state["optimizations"]],
    }


@pytest.fixture(scope="module")
def logs() -> dict[str, EventLog]:
    return {
        name: EventLog.from_recording(load_event_file(DATA / f"{name}.events.npz"))
        for name in ("figure_eight_3laps", "junction_dead_end_2laps")
    }


def cuts(events: list[MapEvent]) -> list[int]:
    """Where to restore a map: every 600 events, and right after some links."""
    links = [k + 1 for k, e in enumerate(events) if type(e) is LinkToVertex]
    return sorted({*range(600, len(events), 600), *links[::40]})


# ------------------------------------------------------------------ small parts, exactly
def small_graph() -> MapGraph:
    graph = MapGraph()
    graph.new_id(0, 0.0, 3)
    graph.add_vertex(0, (0.0, 0.0, 0.0))
    graph.new_id(1, 1.0, 4)
    graph.add_vertex(1, (1.0, 0.0, 0.5))
    graph.add_edge(0, 1, (1.0, 0.0, 0.5), 1.0, EdgeKind.SEQUENTIAL, -1)
    graph.new_id(2, 2.0, 4)
    graph.add_alias(2, 1, (0.25, 0.0, 0.0))
    return graph


def test_a_graph_s_state_is_its_rows_in_use_adjacency_and_aliases() -> None:
    graph = small_graph()
    state = graph.state_dict()
    assert_same(
        state,
        {
            "pose": np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.5], [0.0, 0.0, 0.0]]),
            "vertex_time": np.array([0.0, 1.0, 2.0]),
            "view": np.array([3, 4, 4], dtype=np.int64),
            "alive": np.array([True, True, False]),
            "alias": np.array([0, 1, 1], dtype=np.int64),
            "alias_offset": np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.25, 0.0, 0.0]]),
            "edge_from": np.array([0], dtype=np.int64),
            "edge_to": np.array([1], dtype=np.int64),
            "edge_rel": np.array([[1.0, 0.0, 0.5]]),
            "edge_time": np.array([1.0]),
            "edge_kind": np.array([0], dtype=np.int8),
            "edge_cluster": np.array([-1], dtype=np.int64),
            "edge_alive": np.array([True]),
            "edge_held": np.array([False]),
            "edge_cov": np.zeros((1, 3, 3)),
            "adjacency": [{1: 0}, {0: 0}, {}],
            "absorbed": [[], [2], []],
            "num_ids": 3,
            "num_edges_total": 1,
            "num_vertices": 2,
            "num_edges": 1,
            "num_loop_edges": 0,
        },
    )
    state["adjacency"][1][5] = 9  # a copy: the graph is untouched
    assert graph.adjacency[1] == {0: 0}
    restored = MapGraph()
    restored.load_state(graph.state_dict())
    assert_same(restored.state_dict(), graph.state_dict())
    assert restored.pose.shape == graph.pose.shape == (256, 3)  # a new graph's capacity
    assert restored.alias[3:].tolist() == [-1] * 253 and restored.edge_cluster[1:].max() == -1
    for g in (graph, restored):  # the same next steps
        g.new_id(3, 3.0, 5)
        g.add_vertex(3, (2.0, 0.0, 0.0))
        g.add_edge(1, 3, (1.0, 0.0, -0.5), 3.0, EdgeKind.LOOP_CLOSURE, 0)
        g.merge_vertex(1, 3, (-1.0, 0.0, 0.5))
    assert_same(restored.state_dict(), graph.state_dict())


def test_a_graph_refuses_state_whose_parts_do_not_fit() -> None:
    state = small_graph().state_dict()
    with pytest.raises(StateError, match=r"^graph\.edge_rel does not match the graph$"):
        MapGraph().load_state({**state, "edge_rel": state["edge_rel"][:0]})
    with pytest.raises(StateError, match=r"^adjacency does not match the graph$"):
        MapGraph().load_state({**state, "adjacency": state["adjacency"][:2]})
    with pytest.raises(StateError, match=r"^aliases do not match the graph$"):
        MapGraph().load_state({**state, "absorbed": state["absorbed"][:2]})
    with pytest.raises(StateError, match=r"^graph's live vertices do not match its header$"):
        MapGraph().load_state({**state, "num_vertices": 3})


def test_a_clusterer_s_state_is_its_clusters_and_whether_the_newest_is_open() -> None:
    clusterer = LoopClosureClusterer(t_interval=2.0, t_total=5.0)
    clusterer.add_edge(0.0)
    clusterer.add_edge(1.0)
    clusterer.add_edge(4.0)  # 3 s after the last: closes cluster 0, opens cluster 1
    assert clusterer.state_dict() == {
        "clusters": [
            {"start_time": 0.0, "last_time": 1.0, "edge_count": 2, "closed_time": 4.0},
            {"start_time": 4.0, "last_time": 4.0, "edge_count": 1, "closed_time": None},
        ],
        "open": True,
    }
    restored = LoopClosureClusterer(t_interval=2.0, t_total=5.0)
    restored.load_state(clusterer.state_dict())
    assert restored.clusters == clusterer.clusters
    assert restored.open_cluster is restored.clusters[-1]
    assert restored.add_edge(5.0) == clusterer.add_edge(5.0) == (1, None)
    assert restored.finish(9.5) == clusterer.finish(9.5)
    assert restored.state_dict() == clusterer.state_dict()
    assert restored.state_dict()["open"] is False


def test_records_runs_and_the_gate_round_trip() -> None:
    run = RevisitRun(start=4, opened_from=2, vertices=[7, 8], created=1.5, end=3,
                     closing=(0.1, -0.2, 0.3), closed=2.5, closed_at=7)  # fmt: skip
    assert run.state_dict() == {
        "start": 4, "opened_from": 2, "vertices": [7, 8], "created": 1.5, "end": 3,
        "closing": [0.1, -0.2, 0.3], "closed": 2.5, "closed_at": 7,
    }  # fmt: skip
    assert RevisitRun.from_state(run.state_dict()) == run
    assert math.isnan(RevisitRun.from_state(RevisitRun(start=1).state_dict()).closed)
    check = RelocalisationCheck(3.0, 5, False, 0.4, 0.1, (0.5, 0.0, -0.1))
    assert check.state_dict() == {
        "time": 3.0, "target": 5, "accepted": False, "position_error": 0.4,
        "heading_error": 0.1, "correction": [0.5, 0.0, -0.1], "by_consensus": False,
    }  # fmt: skip
    assert RelocalisationCheck.from_state(check.state_dict()) == check
    gate = RelocalisationGate()
    gate.streak = [check]
    gate.accepted_by_consensus = [RelocalisationCheck(1.0, 2, True, 0.0, 0.0, by_consensus=True)]
    restored = RelocalisationGate()
    restored.load_state(gate.state_dict())
    assert (restored.streak, restored.accepted_by_consensus) == (
        gate.streak,
        gate.accepted_by_consensus,
    )
    record = OptimizationRecord(2, 10.5, 30, 40, 7, 1.5, 0.25, 0.01, 3, 1)
    assert record.state_dict() == {
        "cluster_id": 2, "time": 10.5, "vertices": 30, "edges": 40, "iterations": 7,
        "initial_cost": 1.5, "final_cost": 0.25, "wall_s": 0.01, "integrated": 3,
        "short_edges_removed": 1,
    }  # fmt: skip
    assert OptimizationRecord.from_state(record.state_dict()) == record


def test_scene_integration_and_its_index_round_trip() -> None:
    graph = small_graph()
    integration = SceneIntegration()
    integration.on_vertex(1, 0, 1.0)
    integration.pending.append(RevisitRun(start=0, vertices=[1], created=1.0, end=0, closed=2.0))
    integration._known = KnownEdges(graph, 0.1)
    state = integration.state_dict()
    assert state["open"] == RevisitRun(start=0, vertices=[1], created=1.0).state_dict()
    assert state["relocalised_at"] is None and state["known_edges"]["tree"] is True
    assert state["known_edges"]["start"].shape == (10, 2)  # a 1 m edge in pieces of 0.1 m
    restored = SceneIntegration()
    restored.load_state(state)
    assert_same(restored.state_dict(), state)
    assert (restored.open, restored.pending) == (integration.open, integration.pending)
    for point in ([0.5, 0.05], [0.5, 0.5], [1.02, 0.0]):  # the same index answers the same
        here = np.array(point)
        assert restored._known.nearest(here, 5.0) == integration._known.nearest(here, 5.0)
    empty = KnownEdges(MapGraph(), 0.1)
    assert KnownEdges.from_state(empty.state_dict()).tree is None


def test_an_event_log_round_trips_with_its_scores_and_ground_truth() -> None:
    log = EventLog()
    log.append_frame([Odometry(0.5, 0.1, 0.0), CreateVertex(0.5, 0, 0)], 0.5, (1.0, 2.0, 0.0))
    log.append_frame(
        [Odometry(1.0, 0.1, 0.0), LinkToVertex(1.0, 0, 0.2), SetCurrentVertex(1.0, 0, 0.2)],
        1.0,
        None,
        [0.75],
    )
    state = log.state_dict()
    assert list(state) == [
        "kind", "time", "ref", "view", "value0", "value1", "score",
        "frame_end", "frame_time", "has_truth", "truth",
    ]  # fmt: skip
    assert state["frame_end"].tolist() == [2, 5] and state["has_truth"].tolist() == [True, False]
    assert state["truth"].tolist() == [[1.0, 2.0, 0.0], [0.0, 0.0, 0.0]]
    restored = EventLog.from_state(state)
    assert_same(restored.state_dict(), state)
    assert list(restored.events) == list(log.events)
    assert restored.link_scores == [0.75] and restored.ground_truth.tolist() == [[1.0, 2.0, 0.0]]
    unscored = EventLog.from_state({k: v for k, v in state.items() if k != "score"})
    assert unscored.link_scores == [None] and list(unscored.events) == list(log.events)


# ------------------------------------------------------------------ whole maps
@pytest.mark.parametrize("params", [MapParams(), STRICT], ids=["paper", "strict"])
@pytest.mark.parametrize("mode", list(MapMode))
def test_a_restored_map_is_the_same_map_and_goes_on_the_same(
    logs: dict[str, EventLog], mode: MapMode, params: MapParams
) -> None:
    """Restored part way over and over, a map ends exactly where the uninterrupted one ends."""
    seen = dict.fromkeys(
        ("open run", "pending runs", "index", "last link", "streak", "consensus"), 0
    )
    for log in logs.values():
        events = log.events_until()
        cmap, twin = CognitiveMap(mode, params), CognitiveMap(mode, params)
        done = 0
        for cut in cuts(events):
            cmap.apply_all(events[done:cut])
            twin.apply_all(events[done:cut])
            done = cut
            state = twin.state_dict()
            twin = CognitiveMap.from_state(state)
            assert_same(twin.state_dict(), state)  # exactly, wall times included
            assert_same(without_wall_times(state), without_wall_times(cmap.state_dict()))
            integration = state["integration"]
            seen["open run"] += integration["open"] is not None
            seen["pending runs"] += bool(integration["pending"])
            seen["index"] += integration["known_edges"] is not None
            seen["last link"] += state["robot"]["last_link"] is not None
            seen["streak"] += bool(state["gate"]["streak"])
            seen["consensus"] += bool(state["gate"]["accepted_by_consensus"])
        cmap.apply_all(events[done:])
        twin.apply_all(events[done:])
        cmap.finish(log.end_time)
        twin.finish(log.end_time)
        assert_same(without_wall_times(twin.state_dict()), without_wall_times(cmap.state_dict()))
        assert twin.snapshot().poses.tobytes() == cmap.snapshot().poses.tobytes()
        assert twin.gate.accepted_by_consensus == cmap.gate.accepted_by_consensus
    assert seen["last link"] and seen["streak"] and seen["consensus"]
    if mode is not MapMode.STANDARD:  # scene integration's pending work was restored too
        assert seen["open run"] and seen["pending runs"] and seen["index"]


def test_a_map_refuses_another_mode_s_state_and_counters_that_do_not_add_up(
    logs: dict[str, EventLog],
) -> None:
    cmap = CognitiveMap(MapMode.COMPACT)
    cmap.apply_all(logs["figure_eight_3laps"].events_until(1000))
    state = cmap.state_dict()
    with pytest.raises(StateError, match="a compact map's state cannot make a standard map"):
        CognitiveMap(MapMode.STANDARD).load_state(state)
    counters = {**state["counters"], "declined": state["counters"]["declined"] + 1}
    with pytest.raises(StateError, match=r"^counters do not match the graph$"):
        CognitiveMap.from_state({**state, "counters": counters})
    changed = CognitiveMap(MapMode.COMPACT)  # other parameters: the state's are adopted
    changed.load_state(state)
    assert changed.params == cmap.params and changed.clusterer.t_total == cmap.params.t_total


# ------------------------------------------------------------------ the front end
def frames() -> list[Frame]:
    """Two laps of a square of 84 places (the second seen turned), then a lap of new places."""
    out: list[Frame] = []

    def add(image: np.ndarray, translation: float = 0.0, rotation: float = 0.0) -> None:
        k = len(out)
        out.append(Frame(k, k / 17.5, image, translation, rotation, None))

    for lap, shift in ((0, 0), (1, 2), (2, 0)):
        seed = 1000 if lap == 2 else 0
        for _ in range(4):
            for _ in range(20):
                add(place(seed, shift), translation=CELL)
                seed += 1
            add(place(seed, shift), rotation=math.pi / 2)
            seed += 1
    return out


@pytest.mark.parametrize("config", [CONFIG, ORS], ids=["cogmap", "openratslam"])
def test_a_restored_front_end_is_the_same_and_goes_on_the_same(config: FrontEndConfig) -> None:
    stream = frames()
    front, twin = FrontEnd(config), FrontEnd(config)
    indexed = links = 0
    for k, frame in enumerate(stream):
        events = front.process(frame)
        assert twin.process(frame) == events
        links += any(type(e) is LinkToVertex for e in events)
        if k % 37 == 5:
            state = twin.state_dict()
            twin = FrontEnd(config)
            twin.load_state(state)
            assert_same(twin.state_dict(), state)
            assert_same(state, front.state_dict())
            indexed = max(indexed, state["local_view"]["indexed"])
    assert_same(twin.state_dict(), front.state_dict())
    assert front.template_count > 64 and indexed > 0  # the pruned search's index was rebuilt
    assert links > 20  # the second lap closed loops on the first, restored or not
    templates = front.state_dict()["local_view"]["templates"]
    assert templates.dtype == (np.uint8 if config.vt_whole_crop else np.int32)
    assert templates.shape == (front.template_count, config.template_y_size,
                               config.template_x_size)  # fmt: skip


def test_a_front_end_refuses_state_of_other_settings() -> None:
    front = FrontEnd(CONFIG)
    for frame in frames()[:10]:
        front.process(frame)
    state = front.state_dict()
    with pytest.raises(StateError, match="pose cell network does not match"):
        FrontEnd(CONFIG.with_changes(pc_dim_xy=CONFIG.pc_dim_xy + 2)).load_state(state)
    with pytest.raises(StateError, match="only be loaded into an empty template store"):
        front.local_view.load_state(state["local_view"])
    signs = -state["local_view"]["key_signs"]
    with pytest.raises(StateError, match="do not rebuild the saved index"):
        LocalViewCells(CONFIG).load_state({**state["local_view"], "key_signs": signs})
    network = PoseCellNetwork(CONFIG)
    network.load_state(state["pose_cells"]["network"])
    assert network.best == front.pose_cells.network.best
    assert network.cells.tobytes() == front.pose_cells.network.cells.tobytes()
    empty = LocalViewCells(CONFIG).state_dict()["templates"]
    assert (empty.dtype, empty.shape) == (np.uint8, (0, CONFIG.template_y_size,
                                                     CONFIG.template_x_size))  # fmt: skip
