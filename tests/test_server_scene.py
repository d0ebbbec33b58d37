"""Incremental scene streaming: only changed chunks are sent, exact counts."""

from __future__ import annotations

import math

import numpy as np
import pytest
import viser

from app.server.panels.inspect import describe_edge
from app.server.scene import (
    MAP_COLORS,
    VERTEX_FRACTION,
    ChunkedNodes,
    MapExtras,
    MapLayer,
    SceneStreamer,
    StreamStats,
    cluster_color,
    nice,
)
from app.server.scene_nodes import CHUNK
from app.server.scene_style import LOOP_Z, SEQUENTIAL_Z, edge_error, edge_errors, edge_segments
from cogmap_core.cognitive_map import CognitiveMap, MapMode
from cogmap_core.config import MapParams
from cogmap_core.events import CreateVertex, LinkToVertex, MapEvent, Odometry
from cogmap_core.slam import SlamSession
from tests import test_server_support as support
from tests.test_server_support import make_server

short_bag = support.short_bag
reference = support.reference


class FakeNode:
    def __init__(self, log: list[str], name: str) -> None:
        self.log, self.name = log, name

    def remove(self) -> None:
        self.log.append(f"remove {self.name}")


def test_chunked_nodes_send_only_changed_chunks() -> None:
    log: list[str] = []

    def factory(name: str, part: np.ndarray, colors: np.ndarray | None) -> FakeNode:
        log.append(f"send {name} {part.shape[0]}")
        return FakeNode(log, name)

    stats = StreamStats()
    nodes = ChunkedNodes("/x", factory, stats, chunk=4)  # type: ignore[arg-type]
    items = np.arange(30, dtype=np.float32).reshape(10, 3)
    assert nodes.sync(items) == 3
    assert log == ["send /x/c0000 4", "send /x/c0001 4", "send /x/c0002 2"]
    log.clear()
    assert nodes.sync(items) == 0 and log == []
    grown = np.concatenate([items, np.ones((1, 3), dtype=np.float32)])
    assert nodes.sync(grown) == 1 and log == ["send /x/c0002 3"]
    log.clear()
    grown = np.concatenate([grown, 2 * np.ones((3, 3), dtype=np.float32)])
    assert nodes.sync(grown) == 2 and log == ["send /x/c0002 4", "send /x/c0003 2"]
    log.clear()
    moved = grown.copy()
    moved[5, 0] += 1.0
    assert nodes.sync(moved) == 1 and log == ["send /x/c0001 4"]
    log.clear()
    assert nodes.sync(moved[:5]) == 1
    assert log == ["send /x/c0001 1", "remove /x/c0002", "remove /x/c0003"]
    assert nodes.num_chunks == 2 and nodes.num_items == 5
    assert stats.chunks_sent == 3 + 1 + 2 + 1 + 1 and stats.chunks_removed == 2
    log.clear()
    nodes.clear()
    assert log == ["remove /x/c0000", "remove /x/c0001"] and nodes.num_items == 0


def test_a_changed_chunk_is_updated_in_place_by_the_updater() -> None:
    log: list[str] = []

    def factory(name: str, part: np.ndarray, colors: np.ndarray | None) -> FakeNode:
        log.append(f"send {name} {part.shape[0]}")
        return FakeNode(log, name)

    def updater(handle: FakeNode, part: np.ndarray, colors: np.ndarray | None) -> None:
        log.append(f"update {handle.name} {part.shape[0]}")

    nodes = ChunkedNodes("/x", factory, StreamStats(), chunk=4, updater=updater)  # type: ignore[arg-type]
    items = np.arange(18, dtype=np.float32).reshape(6, 3)
    assert nodes.sync(items) == 2
    first = list(nodes._handles)
    log.clear()
    grown = np.concatenate([items, np.ones((1, 3), dtype=np.float32)])
    assert nodes.sync(grown) == 1
    assert log == ["update /x/c0001 3"]  # the node is kept, not made again
    assert nodes._handles == first
    np.testing.assert_array_equal(nodes.items(), grown)


def circle_events(vertices: int, laps: int = 2, start: int = 0) -> list[MapEvent]:
    """A robot driving laps of a 14 m circle, a vertex every step (0.05 s apart); from the second
    lap on every 10th vertex closes a loop on the first lap's vertex at that place."""
    per_lap = vertices // laps
    events: list[MapEvent] = []
    for k in range(start, vertices):
        t = 0.05 * (k + 1)
        events.append(Odometry(t, 14.0 / per_lap, 2 * math.pi / per_lap))
        events.append(CreateVertex(t, k, k % per_lap))
        if k >= per_lap and k % 10 == 0:
            events.append(LinkToVertex(t, k % per_lap, 0.0))
    return events


def _scaled(event: MapEvent, factor: float) -> MapEvent:
    """``event`` with its odometry's translation scaled (a map ``factor`` times as large)."""
    if isinstance(event, Odometry):
        return Odometry(event.time, event.translation * factor, event.rotation)
    return event


@pytest.fixture
def server() -> viser.ViserServer:
    s = make_server()
    yield s
    s.stop()


def test_map_layer_streams_appends_incrementally_and_optimisations_fully(
    server: viser.ViserServer,
) -> None:
    stats = StreamStats()
    layer = MapLayer(server, MapMode.STANDARD, stats)
    cmap = CognitiveMap(MapMode.STANDARD, MapParams())
    cmap.apply_all(circle_events(1200, laps=1))
    assert cmap.num_vertices == 1200 and not cmap.optimizations
    assert layer.update(cmap)
    assert stats.chunks_sent == 3 + 3  # vertices (1200) and sequential edges (1199)
    assert layer.vertices.num_items == 1200 and layer.sequential.num_items == 1199
    # a frame later: one more vertex and edge -> only the last chunk of each is sent again
    before = stats.copy()
    events = circle_events(2400, laps=2)
    cmap.apply_all(events[2400 : 2400 + 2])  # vertex 1200: odometry, create
    assert layer.update(cmap)
    assert stats.chunks_sent - before.chunks_sent == 2
    assert stats.items_sent - before.items_sent == (1201 - 2 * CHUNK) + (1200 - 2 * CHUNK)
    # nothing changed but the robot: no chunk, one robot update
    before = stats.copy()
    cmap.apply(Odometry(0.05 * 1201 + 0.01, 0.01, 0.0))
    assert not layer.update(cmap)
    assert stats.chunks_sent == before.chunks_sent
    assert stats.robot_updates == before.robot_updates + 1
    # the second lap closes loops; the cluster's optimisation moves every vertex
    cmap.apply_all([e for e in events if e.time > 0.05 * 1201 + 0.02])
    cmap.finish()
    assert cmap.optimizations and cmap.num_loop_edges > 0
    before = stats.copy()
    layer.update(cmap)
    vertex_chunks = math.ceil(cmap.num_vertices / CHUNK)
    assert stats.chunks_sent - before.chunks_sent >= vertex_chunks
    assert layer.vertices.num_items == cmap.num_vertices
    assert layer.loops.num_items == cmap.num_loop_edges
    assert layer.sequential.num_items == cmap.num_edges - cmap.num_loop_edges


def test_a_10000_vertex_map_grows_by_one_chunk_per_update(server: viser.ViserServer) -> None:
    streamer = SceneStreamer(server)
    streamer.show((MapMode.STANDARD,))
    cmap = CognitiveMap(MapMode.STANDARD)
    events = circle_events(10_000, laps=1)
    cmap.apply_all(events[:-2])
    streamer.publish({MapMode.STANDARD: cmap})
    assert streamer.layers[MapMode.STANDARD].vertices.num_items == 9_999
    before = streamer.stats.copy()
    cmap.apply_all(events[-2:])
    streamer.publish({MapMode.STANDARD: cmap})
    sent = streamer.stats.items_sent - before.items_sent
    assert streamer.stats.chunks_sent - before.chunks_sent == 2
    assert sent == (10_000 - 19 * CHUNK) + (9_999 - 19 * CHUNK)
    assert streamer.layers[MapMode.STANDARD].vertices.num_items == 10_000


def test_side_by_side_shows_the_second_map_beside_the_first(server: viser.ViserServer) -> None:
    streamer = SceneStreamer(server)
    maps = {m: CognitiveMap(m) for m in MapMode}
    for cmap in maps.values():
        cmap.apply_all(circle_events(400, laps=1))
    streamer.show((MapMode.COMPACT,))
    streamer.publish(maps)
    layers = streamer.layers
    assert layers[MapMode.COMPACT].visible and not layers[MapMode.STANDARD].visible
    assert layers[MapMode.STANDARD].vertices.num_items == 0  # hidden maps are not streamed
    streamer.show((MapMode.COMPACT, MapMode.STANDARD))
    streamer.publish(maps)
    assert layers[MapMode.STANDARD].visible
    assert layers[MapMode.STANDARD].vertices.num_items == 400
    extent = layers[MapMode.COMPACT].extent
    assert extent is not None
    assert layers[MapMode.STANDARD].offset >= extent[1] - extent[0] + 0.5
    assert layers[MapMode.COMPACT].offset == 0.0
    streamer.show((MapMode.STANDARD,), show_ground_truth=False)
    assert layers[MapMode.STANDARD].offset == 0.0 and not layers[MapMode.COMPACT].visible
    assert not layers[MapMode.STANDARD].groups["truth"].visible


# (the cluster colours are checked in tests/test_palette.py, for every vision)


def test_edge_colourings_are_streamed_only_when_a_viewer_uses_them(
    server: viser.ViserServer,
) -> None:
    streamer = SceneStreamer(server)
    cmap = CognitiveMap(MapMode.STANDARD)
    cmap.apply_all(circle_events(800, laps=2))
    cmap.finish()
    streamer.show((MapMode.STANDARD,))
    streamer.publish({MapMode.STANDARD: cmap}, duration=40.0)
    layer = streamer.layers[MapMode.STANDARD]
    loops, sequential = cmap.num_loop_edges, cmap.num_edges - cmap.num_loop_edges
    assert layer.edges["loop/cluster"].num_items == loops > 0
    assert layer.edges["sequential/cluster"].num_items == sequential
    assert layer.edges["loop/time"].num_items == 0 and layer.edges["loop/error"].num_items == 0
    colors = layer.edges["sequential/cluster"].colors()
    assert colors is not None and (colors == MAP_COLORS[MapMode.STANDARD]).all()  # its map's
    loop_colors = layer.edges["loop/cluster"].colors()
    snap = cmap.snapshot()
    clusters = snap.edge_cluster[snap.edge_kind == 1]
    assert loop_colors is not None
    for k, cid in enumerate(clusters.tolist()):
        assert tuple(loop_colors[k, 0]) == cluster_color(cid)
    streamer.set_needed({MapMode.STANDARD}, {"time", "error"}, False)
    streamer.publish({MapMode.STANDARD: cmap}, duration=40.0)
    assert layer.edges["loop/time"].num_items == loops
    assert layer.edges["sequential/error"].num_items == sequential
    errors = edge_errors(cmap)
    assert errors.shape == (cmap.num_edges,) and np.isfinite(errors).all()
    # time colours go from the start colour to the end colour of the ramp
    time_colors = layer.edges["sequential/time"].colors()
    assert time_colors is not None
    assert not np.array_equal(time_colors[0, 0], time_colors[-1, 0])


def test_false_loop_closures_truth_alignment_and_vertex_size(server: viser.ViserServer) -> None:
    streamer = SceneStreamer(server)
    dense = CognitiveMap(MapMode.STANDARD)
    dense.apply_all(circle_events(800, laps=2))
    dense.finish()
    snap = dense.snapshot()
    loops = snap.edge_kind == 1
    pairs = list(zip(snap.edge_time[loops].tolist(), snap.edge_to[loops].tolist(), strict=True))
    false = frozenset(pairs[::3])  # (time, end vertex)
    extras = MapExtras((0.3, 1.0, -2.0), false)
    streamer.show((MapMode.STANDARD,))
    streamer.publish({MapMode.STANDARD: dense}, extras={MapMode.STANDARD: extras})
    layer = streamer.layers[MapMode.STANDARD]
    assert layer.false_count == layer.false_loops.num_items == len(false)
    assert tuple(layer.truth_frame.position) == (1.0, -2.0, 0.0)
    w, x, y, z = layer.truth_frame.wxyz
    assert np.isclose(2 * np.arctan2(z, w), 0.3)
    # vertices are sized by the extent mapped (issue 25: a 4.5 m circle), not by the map's
    # density (which the parameters change): a dense and a sparse map of it alike
    extent = layer.extent
    assert extent is not None and extent[1] - extent[0] == pytest.approx(4.46, abs=0.05)
    span = max(extent[1] - extent[0], extent[3] - extent[2])
    assert layer.point_size == streamer.marker == nice(span * VERTEX_FRACTION) == 0.015
    sparse = CognitiveMap(MapMode.STANDARD)
    sparse.apply_all(circle_events(40, laps=1))
    streamer.show((MapMode.COMPACT,))
    streamer.publish({MapMode.COMPACT: sparse})
    assert streamer.layers[MapMode.COMPACT].point_size == layer.point_size
    # ten times the extent, ten times the size (both rounded); the robot's arrow follows
    big = SceneStreamer(server)
    wide = CognitiveMap(MapMode.STANDARD)
    wide.apply_all([_scaled(e, 10.0) for e in circle_events(200, laps=1)])
    big.show((MapMode.STANDARD,))
    big.publish({MapMode.STANDARD: wide})
    assert big.marker == pytest.approx(10 * layer.point_size, rel=0.34)
    assert big.layers[MapMode.STANDARD].point_size == big.marker


def test_one_edges_residual_is_the_whole_graphs_to_the_last_bit(
    reference: SlamSession, monkeypatch: pytest.MonkeyPatch
) -> None:
    identity = CognitiveMap(MapMode.STANDARD, MapParams(edge_noise_model=0.0))
    identity.apply_all(circle_events(300, laps=2))
    identity.finish()  # optimised: the residuals are not all zero
    maps = [*reference.maps.maps.values(), identity]
    expected = [(cmap, cmap.snapshot(), edge_errors(cmap)) for cmap in maps]
    assert identity.params.link_sigmas() is None and reference.params.link_sigmas() is not None
    assert max(float(errors.max()) for _, _, errors in expected) > 0.05  # not all near zero
    monkeypatch.setattr(CognitiveMap, "to_pose_graph", None)  # one edge needs no pose graph
    for cmap, snap, errors in expected:
        assert errors.shape[0] == snap.edge_from.shape[0] and np.any(errors > 0)
        sigmas = cmap.params.link_sigmas()
        for k in range(errors.shape[0]):
            assert edge_error(snap, k, sigmas) == errors[k]
        for k in (0, int(np.argmax(errors)), errors.shape[0] - 1):
            text = describe_edge(cmap, snap, k)
            assert f"<td>residual</td><td>{errors[k]:.2f} σ (whitened" in text


def test_edge_segments_join_each_edges_vertices_at_its_height(server: viser.ViserServer) -> None:
    cmap = CognitiveMap(MapMode.STANDARD)
    cmap.apply_all(circle_events(300, laps=2))
    cmap.finish()
    snap = cmap.snapshot()
    rows = {int(v): k for k, v in enumerate(snap.vertex_ids)}
    flat = edge_segments(snap)
    assert flat.shape == (cmap.num_edges, 2, 3) and flat.dtype == np.float32
    for k, (a, b) in enumerate(zip(snap.edge_from.tolist(), snap.edge_to.tolist(), strict=True)):
        expected = np.float32(snap.poses[[rows[a], rows[b]], :2])
        np.testing.assert_array_equal(flat[k, :, :2], expected)
    assert (flat[:, :, 2] == 0).all()
    assert edge_segments(CognitiveMap(MapMode.STANDARD).snapshot(), 1.0).shape == (0, 2, 3)
    # the layer draws the same segments, sequential and loop-closure edges at their heights
    layer = MapLayer(server, MapMode.STANDARD, StreamStats())
    layer.update(cmap)
    is_loop = snap.edge_kind == 1
    for name, chosen, z in (("sequential", ~is_loop, SEQUENTIAL_Z), ("loop", is_loop, LOOP_Z)):
        drawn = layer.edges[f"{name}/cluster"].items()
        assert drawn is not None
        np.testing.assert_array_equal(drawn[:, :, :2], flat[chosen, :, :2])
        assert (drawn[:, :, 2] == np.float32(z)).all()
