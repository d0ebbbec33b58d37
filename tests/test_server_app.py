"""The web app driven from Python: replay, every slider, clamping, storms, seek, exports, errors.

Expected maps are computed independently with :class:`SlamSession` / ``SlamSession.rebuild`` on
the same bag, and compared exactly.
"""

from __future__ import annotations

import bisect
import contextlib
import csv
import html
import io
import json
import math
import threading
import time
import urllib.request
from collections.abc import Callable, Iterator
from pathlib import Path

import msgspec
import numpy as np
import pytest
from websockets.sync.client import ClientConnection

import app.server.figures_worker as figures_module
import app.server.view as view_module
from app.server.app import ADVANCED_SLIDERS, SLIDERS, CogmapApp
from app.server.export import g2o_bytes, save_html_replay, summary_dict, summary_inputs
from app.server.figures import compute_figures, figure_inputs, truth_transform
from app.server.replay import PARAMS_USED, PlaybackState
from cogmap_core.cognitive_map import MapMode
from cogmap_core.config import MapParams
from cogmap_core.datasets.profile import profile_path
from cogmap_core.g2o import read_g2o
from cogmap_core.slam import ALL_MODES, SlamSession
from tests import test_server_support as support
from tests.test_server_support import (
    assert_same_map,
    client,
    counter,
    make_server,
    running_app,
    send,
    until,
    wait,
)

short_bag = support.short_bag  # session fixtures shared by the web-app tests
reference = support.reference

# A value for every slider that changes at least one map on the short bag -- but the Huber
# scale: with the default loop model it holds only the odometry edges, whose residuals on this
# bag stay below even the slider's least value (it still rebuilds them, to the same maps).
INERT_ON_THE_SHORT_BAG = frozenset({"huber_scale"})
CHANGES: tuple[tuple[str, float], ...] = (
    ("alpha", 40.0),
    ("beta", 0.0),
    ("delta", 8.0),
    ("t_interval", 0.1),
    ("t_total", 1.0),
    ("huber_scale", 0.01),
    ("loop_scale", 0.2),
    ("short_edge_threshold", 0.3),
)


def differs(a: object, b: object) -> bool:
    from cogmap_core.cognitive_map import CognitiveMap

    assert isinstance(a, CognitiveMap) and isinstance(b, CognitiveMap)
    if (a.num_vertices, a.num_edges, len(a.clusters)) != (
        b.num_vertices,
        b.num_edges,
        len(b.clusters),
    ):
        return True
    return not np.allclose(a.snapshot().poses, b.snapshot().poses, rtol=0, atol=1e-9)


def test_replay_matches_the_headless_session(short_bag: Path, reference: SlamSession) -> None:
    with running_app(short_bag) as app:
        wait(app)
        r = app.replay
        assert r.state is PlaybackState.ENDED and r.message == ""
        assert r.cursor == reference.log.frames == r.total_frames
        for mode in MapMode:
            assert_same_map(r.session.maps[mode], reference.maps[mode])
        compact = reference.maps[MapMode.COMPACT]
        assert counter(app, "frames") == f"{reference.log.frames} / {reference.log.frames}"
        assert counter(app, "compact-vertices") == str(compact.num_vertices)
        assert counter(app, "compact-edges") == str(compact.num_edges)
        assert counter(app, "compact-clusters") == str(len(compact.clusters))
        assert counter(app, "compact-optimizations") == str(len(compact.optimizations))
        assert counter(app, "compact-ate") == f"{reference.ate(compact):.3f}"
        fidelity = reference.layout_fidelity(compact)
        assert counter(app, "compact-completeness") == f"{fidelity.completeness:.3f}"
        assert counter(app, "compact-correctness") == f"{fidelity.correctness:.3f}"
        for mode in MapMode:  # the page's figures are the report's, to the last bit
            figures, cmap = app._figures[mode], reference.maps[mode]
            assert figures.ate == reference.ate(cmap)
            assert figures.fidelity == reference.layout_fidelity(cmap)
            assert figures.truth_transform == truth_transform(reference.log, cmap)
        links = sum(1 for e in reference.log.events if type(e).__name__ == "LinkToVertex")
        assert counter(app, "loops-detected") == str(links)
        score = reference.loop_closure_score()
        assert counter(app, "loops-false") == str(score.false)
        for mode in MapMode:  # where the proposals went, per map
            c = reference.maps[mode].counters
            assert counter(app, f"{mode.value}-proposed") == str(c.proposed)
            assert counter(app, f"{mode.value}-declined") == str(c.declined)
            assert counter(app, f"{mode.value}-integrated") == str(c.integrated)
            assert counter(app, f"{mode.value}-short_edges") == str(c.short_edges)
            assert c.proposed - c.declined - c.integrated - c.short_edges == (
                reference.maps[mode].num_vertices
            )
        # the scene shows exactly the compact map's vertices and the whole ground truth
        layer = app.streamer.layers[MapMode.COMPACT]
        assert layer.vertices.num_items == compact.num_vertices
        shown = layer.vertices.items()
        assert shown is not None
        np.testing.assert_allclose(shown[:, :2], compact.snapshot().poses[:, :2], atol=1e-6)
        assert layer.sequential.num_items + layer.loops.num_items == compact.num_edges
        assert layer.truth.num_items == reference.log.frames - 1
        # the size chart ends at the maps' final sizes (standard V, E, ..., compact V, E)
        last = [float(series[-1]) for series in app.chart.data[1:7]]
        expected = []
        for mode in (MapMode.STANDARD, MapMode.SCENE_INTEGRATION, MapMode.COMPACT):
            expected += [reference.maps[mode].num_vertices, reference.maps[mode].num_edges]
        assert last == expected


def test_figure_inputs_view_the_true_path_which_stays_as_taken(reference: SlamSession) -> None:
    """The true path is not copied per map and round: a read-only view the log never rewrites."""
    log = reference.log.truncated(reference.log.frames)  # a log of our own to append to
    cmap = reference.maps[MapMode.COMPACT]
    inputs = figure_inputs(log, cmap)
    assert inputs.path is not None and not inputs.path.flags.writeable
    assert np.shares_memory(inputs.path, log.ground_truth)
    taken = inputs.path.copy()
    figures = compute_figures(inputs)
    for k in range(2 * log.frames + 1100):  # past the buffer's capacity: it grows (moves)
        log.append_frame([], log.end_time + 1.0, (99.0, -99.0, float(k)))
    assert not np.shares_memory(inputs.path, log.ground_truth)
    np.testing.assert_array_equal(inputs.path, taken)
    np.testing.assert_array_equal(log.ground_truth[: taken.shape[0]], taken)
    assert compute_figures(inputs) == figures
    assert figures.truth_transform == truth_transform(reference.log, cmap)


def test_every_slider_rebuilds_the_maps_it_affects(short_bag: Path, reference: SlamSession) -> None:
    paper = MapParams()
    with running_app(short_bag) as app:
        wait(app)
        for name, value in CHANGES:
            before = dict(app.replay.session.maps.maps)
            app.param_sliders[name].value = value
            wait(app)
            params = paper.with_changes(**{name: value})
            assert app.replay.params == params
            expected = reference.rebuild(params)
            for mode in MapMode:
                assert_same_map(app.replay.session.maps[mode], expected[mode])
                if name not in PARAMS_USED[mode]:  # not rebuilt at all
                    assert app.replay.session.maps[mode] is before[mode]
            changed = any(differs(before[m], expected[m]) for m in MapMode)
            assert changed is (name not in INERT_ON_THE_SHORT_BAG), name
            compact = expected[MapMode.COMPACT]
            assert counter(app, "compact-vertices") == str(compact.num_vertices)
            assert counter(app, "compact-clusters") == str(len(compact.clusters))
            assert app.streamer.layers[MapMode.COMPACT].vertices.num_items == compact.num_vertices
            record = app.replay.rebuilds[-1]
            assert record.completed and record.frames == reference.log.frames
            app.reset_params()
            wait(app)
            assert app.replay.params == paper
            for mode in MapMode:
                assert_same_map(app.replay.session.maps[mode], reference.maps[mode])
            compact = reference.maps[MapMode.COMPACT]
            assert counter(app, "compact-vertices") == str(compact.num_vertices)


@pytest.mark.parametrize(
    ("name", "value"),
    CHANGES
    + (
        ("integration_radius", 0.05),
        ("integration_max_residual", 0.01),
        ("integration_min_age", 1.0),
        ("gate_position", 0.01),
        ("edge_noise_model", 0.0),
        ("link_sigma_position", 0.3),
        ("link_sigma_heading", 0.5),
        ("integration_keeps_evidence", 0.0),
    ),
)
def test_maps_ignore_the_parameters_they_do_not_use(
    reference: SlamSession, name: str, value: float
) -> None:
    # the compact map uses every parameter but the scene-integration map's own
    assert PARAMS_USED[MapMode.COMPACT] == set(MapParams().to_dict()) - {
        "integration_keeps_evidence"
    }
    rebuilt = reference.rebuild(MapParams().with_changes(**{name: value}))
    for mode in MapMode:
        if name not in PARAMS_USED[mode]:
            assert_same_map(rebuilt[mode], reference.maps[mode])


def test_out_of_range_values_are_clamped_and_non_numbers_refused(short_bag: Path) -> None:
    with running_app(short_bag, autoplay=False) as app:
        wait(app)
        for spec in SLIDERS + ADVANCED_SLIDERS:
            slider = app.param_sliders[spec.name]
            slider.value = spec.high * 10 + 1
            assert slider.value == spec.high
            assert getattr(app.current_slider_params(), spec.name) == spec.high
            slider.value = spec.low - 100
            assert slider.value == spec.low
            slider.value = float("nan")
            assert slider.value == spec.low  # refused: back to the value in use
            assert "refused" in app.params_md.content
        wait(app)
        expected = {s.name: s.low for s in SLIDERS + ADVANCED_SLIDERS}
        assert app.replay.params == MapParams().with_changes(**expected)


def test_a_client_sending_out_of_range_values_over_the_websocket(short_bag: Path) -> None:
    with running_app(short_bag, autoplay=False) as app:
        wait(app)
        delta = app.param_sliders["delta"]
        with client(app.server.get_port()) as ws:
            until(lambda: app.server.get_clients())
            for sent, expected in ((1e9, 30.0), (-3.0, 1.05), (6.5, 6.5)):
                send(ws, delta, value=sent)
                until(lambda e=expected: app.replay.params.delta == e)
                assert delta.value == expected
                assert app.replay.params.delta == expected
        # A value slipped in without the callback (viser applies values of clients that never
        # sent their camera) is clamped when the parameters are read.
        app.param_sliders["alpha"]._impl.value = 1e7
        assert app.current_slider_params().alpha == 50.0


def test_a_slider_storm_never_queues_work(short_bag: Path, reference: SlamSession) -> None:
    with running_app(short_bag) as app:
        wait(app)
        start = len(app.replay.rebuilds)
        values = [3.0 + 0.1 * k for k in range(40)]
        for v in values:  # as fast as callbacks can come
            app.param_sliders["delta"].value = v
        wait(app)
        records = app.replay.rebuilds[start:]
        assert app.replay.params.delta == values[-1]
        assert records[-1].completed and records[-1].params.delta == values[-1]
        # never more rebuilds than requests, never an older value after a newer one
        positions = [values.index(r.params.delta) for r in records]
        assert len(records) <= len(values)
        assert positions == sorted(set(positions))
        expected = reference.rebuild(MapParams(delta=values[-1]))
        for mode in MapMode:
            assert_same_map(app.replay.session.maps[mode], expected[mode])


def test_maps_depend_on_data_time_only(short_bag: Path, reference: SlamSession) -> None:
    """Step part way, change parameters there, play on: the same maps as a fresh rebuild."""
    params = MapParams(delta=6.0, t_interval=1.0)
    with running_app(short_bag, autoplay=False) as app:
        wait(app)
        for _ in range(150):
            app.step_button.value = True
        wait(app)
        assert app.replay.cursor == 150
        assert counter(app, "frames") == f"150 / {app.replay.total_frames}"
        expected = reference.rebuild(MapParams(), frames=150, finish=False)
        for mode in MapMode:
            assert_same_map(app.replay.session.maps[mode], expected[mode])
        app.param_sliders["delta"].value = 6.0
        app.param_sliders["t_interval"].value = 1.0
        wait(app)
        app.speed_dropdown.value = "20x"  # paced playback ...
        app.replay.step(30)
        wait(app)
        app.speed_dropdown.value = "max"  # ... then as fast as possible
        app.play_button.value = True
        wait(app)
        assert app.replay.state is PlaybackState.ENDED
        final = reference.rebuild(params)
        for mode in MapMode:
            assert_same_map(app.replay.session.maps[mode], final[mode])


def test_seek_and_restart_replay_from_the_cache(short_bag: Path, reference: SlamSession) -> None:
    with running_app(short_bag) as app:
        wait(app)
        frontend_frames = app.replay.session.frontend.frames
        assert app.replay.state is PlaybackState.ENDED and app.play_button.label == "play"
        assert f"{PlaybackState.ENDED.value}</b> · t = " in app.status_html.content  # no speed
        app.replay.pause()  # a seek while playing plays on from there
        wait(app)
        assert not app.replay.playing and app.play_button.label == "play"
        for t in (20.0, 50.0, 5.0):
            app.seek_slider.value = t
            wait(app)
            k = bisect.bisect_right(reference.log.frame_time, t)
            assert app.replay.cursor == k
            expected = reference.rebuild(MapParams(), frames=k, finish=False)
            for mode in MapMode:
                assert_same_map(app.replay.session.maps[mode], expected[mode])
            assert counter(app, "frames") == f"{k} / {app.replay.total_frames}"
            assert app.streamer.layers[MapMode.COMPACT].truth.num_items == k - 1
        app.seek_slider.value = 1e9  # clamped to the end
        wait(app)
        assert app.replay.state is PlaybackState.ENDED
        assert app.seek_slider.value == round(reference.log.frame_time[-1], 1)  # follows
        # restart plays from the start (issue 25: it used to leave playback paused at frame 0)
        app.replay.set_speed(20.0)
        app.restart_button.value = True  # a click
        until(lambda: app.replay.state is PlaybackState.PLAYING, 10, "playing from the start")
        assert app.replay.cursor < reference.log.frames // 2
        app.replay.set_speed(math.inf)
        wait(app)
        assert app.replay.state is PlaybackState.ENDED
        for mode in MapMode:
            assert_same_map(app.replay.session.maps[mode], reference.maps[mode])
        # the front end never saw a frame twice: everything after the first pass was cached
        assert app.replay.session.frontend.frames == frontend_frames


def test_seek_forward_runs_the_front_end_up_to_the_target(
    short_bag: Path, reference: SlamSession
) -> None:
    with running_app(short_bag, autoplay=False) as app:
        wait(app)
        app.replay.seek(30.0)
        wait(app)
        k = bisect.bisect_right(reference.log.frame_time, 30.0)
        assert app.replay.cursor in (k, k + 1)  # stops at the first frame at or past 30 s
        assert app.replay.frame_time >= 30.0
        expected = reference.rebuild(MapParams(), frames=app.replay.cursor, finish=False)
        for mode in MapMode:
            assert_same_map(app.replay.session.maps[mode], expected[mode])
        assert app.replay.state is PlaybackState.PAUSED
        # the dead-reckoned path shown is the log's, up to the frame reached
        with app.replay.lock:
            shown = app._dead_reckoning()
        np.testing.assert_array_equal(shown, reference.log.dead_reckoning()[: app.replay.cursor])


def test_exports(short_bag: Path, reference: SlamSession, tmp_path: Path) -> None:
    with running_app(short_bag) as app:
        wait(app)
        compact = reference.maps[MapMode.COMPACT]
        path = tmp_path / "compact.g2o"
        with app.replay.lock:
            path.write_bytes(g2o_bytes(app.replay.session.maps[MapMode.COMPACT]))
            inputs = summary_inputs(app.replay)
        summary = summary_dict(inputs)  # computed outside the lock, from a copy:
        live = app.replay.session.maps[MapMode.STANDARD]
        saved_poses = live.graph.pose.copy()
        live.graph.pose[:, :2] *= 2.0  # the replay going on cannot change it
        assert summary_dict(inputs) == summary
        live.graph.pose[:] = saved_poses
        graph = read_g2o(path)
        assert graph.num_vertices == compact.num_vertices
        assert graph.num_edges == compact.num_edges
        assert summary["frames"] == reference.log.frames
        maps = summary["maps"]
        assert isinstance(maps, dict)
        for mode in MapMode:
            assert maps[mode.value]["vertices"] == reference.maps[mode].num_vertices
            assert maps[mode.value]["clusters"] == len(reference.maps[mode].clusters)
        # the download buttons send the same files to the client that clicked
        sent: list[tuple[str, bytes]] = []

        class FakeClient:
            def send_file_download(self, name: str, content: bytes, **_: object) -> None:
                sent.append((name, content))

        for what in ("g2o", "summary", "sizes"):
            app.export.download(FakeClient(), what)  # type: ignore[arg-type]
        assert [name for name, _ in sent] == ["compact.g2o", "summary.json", "sizes.csv"]
        assert sent[0][1] == path.read_bytes()
        assert json.loads(sent[1][1])["maps"] == maps
        rows = list(csv.reader(io.StringIO(sent[2][1].decode())))
        assert rows[0][0] == "time" and rows[0][-1] == "compact_edges"
        last = [int(v) for v in rows[-1][1:]]
        expected = []
        for mode in (MapMode.STANDARD, MapMode.SCENE_INTEGRATION, MapMode.COMPACT):
            expected += [reference.maps[mode].num_vertices, reference.maps[mode].num_edges]
        assert last == expected
        # a self-contained HTML replay of the session
        out = save_html_replay(app.replay, (MapMode.COMPACT,), tmp_path / "replay.html", 20, 2.0)
        page = out.read_text()
        assert "__VISER_EMBED_DATA__" in page and page.rstrip().endswith("</html>")
        with pytest.raises(Exception, match=r"\.html"):
            save_html_replay(app.replay, (MapMode.COMPACT,), tmp_path / "replay.txt")
        (tmp_path / "notes.html").write_text("<html>mine</html>")
        with pytest.raises(Exception, match="not a cogmap replay"):
            save_html_replay(app.replay, (MapMode.COMPACT,), tmp_path / "notes.html")


def _http_ok(app: CogmapApp) -> bool:
    with urllib.request.urlopen(f"http://127.0.0.1:{app.server.get_port()}/", timeout=10) as r:
        return r.status == 200 and b"<html" in r.read().lower()


def test_a_missing_bag_shows_an_error_and_the_server_keeps_serving(tmp_path: Path) -> None:
    with running_app(tmp_path / "nope.bag") as app:
        wait(app)
        assert app.replay.state is PlaybackState.ERROR
        assert "nope.bag does not exist" in app.status_html.content
        assert 'data-state="error"' in app.status_html.content
        assert _http_ok(app)
        app.param_sliders["delta"].value = 5.0  # the page stays usable
        app.replay.restart()
        wait(app)
        assert app.replay.state is PlaybackState.ERROR
        assert _http_ok(app)


def test_a_bag_corrupt_mid_replay_keeps_what_was_mapped(
    short_bag: Path, reference: SlamSession, tmp_path: Path
) -> None:
    data = bytearray(short_bag.read_bytes())
    records = [i for i in range(len(data) - 4) if data[i : i + 4] == b"op=\x02"]
    middle = records[len(records) // 2]
    data[middle + 3] = 0x09  # a message record in the middle of the bag: unknown record type
    broken = tmp_path / "broken.bag"
    broken.write_bytes(bytes(data))
    profile_path(broken).write_bytes(profile_path(short_bag).read_bytes())  # same front end
    with running_app(broken) as app:
        wait(app)
        r = app.replay
        assert r.state is PlaybackState.ERROR
        assert r.message.startswith(f"bag {broken} is corrupt near t=")
        # the page names the bag relative to its data folder, never by its server path
        shown = r.message.replace(str(broken), "broken.bag")
        assert html.escape(shown) in app.status_html.content
        assert str(tmp_path) not in app.status_html.content
        assert 0 < r.cursor < reference.log.frames
        assert counter(app, "frames") == f"{r.cursor} / {r.total_frames}"
        expected = reference.rebuild(MapParams(), frames=r.cursor, finish=False)
        for mode in MapMode:
            assert_same_map(r.session.maps[mode], expected[mode])
        assert _http_ok(app)
        cursor = r.cursor
        app.param_sliders["delta"].value = 6.0  # tuning still works on what was mapped
        wait(app)
        expected = reference.rebuild(MapParams(delta=6.0), frames=cursor, finish=False)
        assert_same_map(r.session.maps[MapMode.COMPACT], expected[MapMode.COMPACT])
        assert counter(app, "compact-vertices") == str(expected[MapMode.COMPACT].num_vertices)


def test_twenty_clients_at_once_and_abrupt_disconnects_do_not_disturb_playback(
    short_bag: Path, reference: SlamSession
) -> None:
    with running_app(short_bag, speed=30.0) as app:
        port = app.server.get_port()
        clients = [client(port) for _ in range(20)]
        received = [0] * len(clients)
        deadline = time.monotonic() + 1.0
        while time.monotonic() < deadline:
            for i, ws in enumerate(clients):
                try:
                    received[i] += len(ws.recv(timeout=0.01))
                except TimeoutError:
                    pass
        for ws in clients[::2]:  # half vanish mid-stream without a closing handshake
            ws.socket.close()
        for ws in clients[1::2]:
            ws.close()
        wait(app)
        assert min(received) > 0
        assert app.replay.state is PlaybackState.ENDED
        for mode in MapMode:
            assert_same_map(app.replay.session.maps[mode], reference.maps[mode])
        assert _http_ok(app)


def test_a_late_client_receives_the_full_current_map(
    short_bag: Path, reference: SlamSession
) -> None:
    with running_app(short_bag) as app:
        wait(app)
        app.param_sliders["short_edge_threshold"].value = 0.3  # history: chunks sent, removed
        wait(app)
        app.reset_params()
        wait(app)
        # viser sends a joining client its message buffer: the latest state of every node
        buffer = app.server._websock_server._broadcast_buffer
        with buffer.buffer_lock:
            messages = list(buffer.message_from_id.values())
        for mode in MapMode:
            prefix = f"/map/{mode.value}/vertices/"
            points: dict[str, int] = {}  # the latest state of each chunk a late client gets
            for m in messages:
                kind = type(m).__name__
                if kind == "PointCloudMessage" and m.name.startswith(prefix):
                    assert m.name not in points  # one node per chunk
                    points[m.name] = m.props.points.shape[0]
                elif kind == "SceneNodeUpdateMessage" and m.name.startswith(prefix):
                    if "points" in m.updates:  # a chunk updated in place
                        points[m.name] = len(m.updates["points"])
            total = sum(points.values())
            shown = mode is MapMode.COMPACT  # hidden maps are sent when first shown
            assert total == (reference.maps[mode].num_vertices if shown else 0)
        with client(app.server.get_port(), hello=False) as ws:
            size = 0
            try:
                while True:
                    size += len(ws.recv(timeout=1.0))
            except TimeoutError:
                pass
        assert size > reference.maps[MapMode.COMPACT].num_vertices * 3 * 4


def test_the_built_in_dataset_is_prepared_with_progress_on_the_page(
    short_bag: Path, reference: SlamSession
) -> None:
    seen: list[str] = []

    def built_in(progress: Callable[[int, int], None]) -> Path:
        for done in (100, 200):
            progress(done, 200)
        return short_bag

    server = make_server()
    app = CogmapApp(server, built_in, speed=float("inf"))
    original = app.on_status

    def record(replay: object) -> None:
        seen.append(app.replay.message)
        original(replay)  # type: ignore[arg-type]

    app.on_status = record  # type: ignore[method-assign]
    try:
        app.start()
        wait(app)
        assert "generating the built-in dataset: 100/200 frames" in seen
        assert "generating the built-in dataset: 200/200 frames" in seen
        assert app.replay.bag_path == short_bag and app.replay.state is PlaybackState.ENDED
        assert_same_map(app.replay.session.maps[MapMode.COMPACT], reference.maps[MapMode.COMPACT])
    finally:
        app.stop()
        server.stop()


# ------------------------------------------------------------------- GUI values from clients
def _gui_updates(data: bytes) -> list[tuple[str, dict]]:
    """The ``GuiUpdateMessage``s in one websocket frame of viser's wire format."""
    import zstandard

    size = int.from_bytes(data[8:16], "little")
    inner = zstandard.ZstdDecompressor().decompressobj().decompress(data[16 : 16 + size])
    payload = msgspec.msgpack.decode(inner)
    return [
        (m["uuid"], m["updates"])
        for m in payload["messages"]
        if isinstance(m, dict) and m.get("type") == "GuiUpdateMessage"
    ]


def _drain(ws: ClientConnection, seconds: float = 0.5) -> list[tuple[str, dict]]:
    seen: list[tuple[str, dict]] = []
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        try:
            seen += _gui_updates(ws.recv(timeout=0.05))  # type: ignore[arg-type]
        except TimeoutError:
            pass
    return seen


def _wait_clients(app: CogmapApp, n: int) -> None:
    until(lambda: len(app.server.get_clients()) >= n)
    assert len(app.server.get_clients()) == n


def _buffered(app: CogmapApp, handle: object) -> object:
    """The value a client joining now is sent for ``handle``."""
    buffer = app.server._websock_server._broadcast_buffer
    with buffer.buffer_lock:
        messages = list(buffer.message_from_id.values())
    uuid = handle._impl.uuid  # type: ignore[attr-defined]
    values = [
        m.updates["value"]
        for m in messages
        if type(m).__name__ == "GuiUpdateMessage" and m.uuid == uuid and "value" in m.updates
    ]
    return values[-1] if values else None


def test_bad_gui_values_are_refused_before_any_client_sees_them(
    short_bag: Path, tmp_path: Path
) -> None:
    with running_app(short_bag, autoplay=False) as app:
        wait(app)
        port = app.server.get_port()
        with client(port) as sender:
            _wait_clients(app, 1)
            (sender_id,) = app.server.get_clients()
            with client(port) as viewer:
                _wait_clients(app, 2)
                _drain(viewer)
                mine = app.views[sender_id]
                refused = app.gate.refused
                shared = [
                    (app.speed_dropdown, {"value": "bogus"}),
                    (app.seek_slider, {"value": float("inf")}),
                    (app.param_sliders["alpha"], {"value": "many"}),
                    (app.param_boxes["delta"], {"value": 12}),
                    (app.replay_path, {"value": 12}),
                    (app.play_button, {"value": False}),
                    (app.play_button, {"disabled": True}),  # not a client's to change
                    (app.param_sliders["delta"], {"max": 1e9}),
                    (app.param_boxes["delta"], {"value": "abc"}),  # last: its message stays
                ]
                own = [
                    (mine.mode_dropdown, {"value": "bogus"}),
                    (mine.colouring_dropdown, {"value": "nope"}),
                    # (viser itself would make this one True)
                    (mine.layer_checkboxes["truth"], {"value": "bogus"}),
                    (mine.pin_button, {"value": False}),
                ]
                for handle, updates in shared + own:
                    send(sender, handle, **updates)
                until(
                    lambda: (
                        app.gate.refused >= refused + len(shared) and mine.gate.refused >= len(own)
                    )
                )
                assert app.gate.refused == refused + len(shared)
                assert mine.gate.refused == len(own)
                attacked = {h._impl.uuid for h, _ in shared}  # type: ignore[attr-defined]
                seen = [(uuid, u) for uuid, u in _drain(viewer) if uuid in attacked]
                # the viewer only ever sees the values in force, sent back after each refusal
                values = {repr(u.get("value")) for _, u in seen}
                assert values and not values & {"'bogus'", "inf", "'many'", "'abc'", "12"}
                assert all(set(u) == {"value"} for _, u in seen)
                assert (
                    app.speed_dropdown.value == "max" and app.param_boxes["delta"].value == "3.746"
                )
                assert mine.mode_dropdown.value == "compact" and mine.state.layers["truth"] is True
                assert mine.colouring_dropdown.value == "loop closures by cluster"
                assert app.param_sliders["delta"].max == 30.0
                assert not app.play_button.disabled
                assert app.replay.params == MapParams()
                message = html.unescape(app.params_md.content)
                assert "refused δ: 'abc' is not a number; δ stays 3.746" in message
                # a valid value still works -- for the viewer who sent it only
                send(sender, mine.mode_dropdown, value="standard")
                until(lambda: mine.state.shown == (MapMode.STANDARD,))
                assert mine.state.shown == (MapMode.STANDARD,)
                other = next(v for cid, v in app.views.items() if cid != sender_id)
                assert other.state.shown == (MapMode.COMPACT,)
                assert "standard" not in {u.get("value") for _, u in _drain(viewer)}
                sent: list[str] = []

                class FakeClient:
                    client_id = sender_id

                    def send_file_download(self, name: str, content: bytes, **_: object) -> None:
                        sent.append(name)

                app.export.download(FakeClient(), "g2o")  # type: ignore[arg-type]
                assert sent == ["standard.g2o"]  # the map this viewer shows


def _shared_handles(app: CogmapApp) -> dict[str, object]:
    """The shared controls a rogue client tries to change, by key."""
    return {
        "alpha": app.param_sliders["alpha"],
        "delta": app.param_sliders["delta"],
        "seek": app.seek_slider,
        "speed": app.speed_dropdown,
        "box": app.param_boxes["delta"],
    }


def _shared_values(app: CogmapApp) -> dict[str, object]:
    """The values of the shared controls a rogue client tries to change."""
    return {key: h.value for key, h in _shared_handles(app).items()}  # type: ignore[attr-defined]


#: The values of :func:`_shared_handles` in force at the start, paused at t = 0.
IN_FORCE = {"alpha": 10.0, "delta": 3.746, "seek": 0.0, "speed": "max", "box": "3.746"}


def test_a_client_without_its_first_camera_message_changes_nothing(short_bag: Path) -> None:
    with running_app(short_bag, autoplay=False) as app:
        wait(app)
        handles = _shared_handles(app)
        before = _shared_values(app)
        assert before == IN_FORCE
        refused = app.gate.refused
        with client(app.server.get_port(), hello=False) as ws:  # never says hello
            send(ws, handles["alpha"], value=1e308)
            send(ws, handles["delta"], value=1.0)
            send(ws, handles["seek"], value=float("inf"))
            send(ws, handles["speed"], value="bogus")
            send(ws, handles["box"], value="5")  # valid, but not yet a client
            until(lambda: app.gate.refused >= refused + 5)
        assert app.gate.refused == refused + 5
        assert _shared_values(app) == before
        assert app.replay.params == MapParams()
        # what a client joining later receives: the values in force, sent back after each
        # refusal (the last one, the box's, just after it was counted)
        until(lambda: _buffered(app, handles["box"]) is not None, what="the box sent back")
        assert {key: _buffered(app, h) for key, h in handles.items()} == IN_FORCE
        with client(app.server.get_port()) as late:
            values = [u["value"] for _, u in _drain(late, 1.0) if "value" in u]
        assert not {1e308, 1.0, float("inf"), "bogus"} & set(values)


def _lock_is_free(lock: threading.RLock) -> bool:
    """Whether another thread can take ``lock`` now (within 2 s)."""
    taken: list[bool] = []

    def take() -> None:
        got = lock.acquire(timeout=2.0)
        if got:
            lock.release()
        taken.append(got)

    thread = threading.Thread(target=take)
    thread.start()
    thread.join()
    return taken[0]


@contextlib.contextmanager
def _idle_app_with_one_viewer(bag: Path) -> Iterator[CogmapApp]:
    """The app at the end of ``bag``, with one connected viewer, all work done."""
    with running_app(bag) as app:
        wait(app)
        with client(app.server.get_port()):
            until(lambda: len(app.views) == 1)
            wait(app)
            yield app


def test_figures_are_computed_and_views_refreshed_without_the_replay_lock(
    short_bag: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The figures' round and the per-frame update run outside the replay lock.

    Views take it briefly for what they read; the figures are computed from inputs taken under it.
    """
    with _idle_app_with_one_viewer(short_bag) as app:
        figures, links = dict(app.figures.figures), app.figures.links
        assert len(figures) == len(ALL_MODES)
        free: list[tuple[str, bool]] = []

        def spy(name: str, real: Callable[..., object]) -> Callable[..., object]:
            def call(*args: object, **kwargs: object) -> object:
                free.append((name, _lock_is_free(app.replay.lock)))
                return real(*args, **kwargs)

            return call

        monkeypatch.setattr(
            figures_module, "judge_links", spy("false links", figures_module.judge_links)
        )
        monkeypatch.setattr(
            figures_module, "compute_figures", spy("figures", figures_module.compute_figures)
        )
        monkeypatch.setattr(
            view_module.ClientView, "refresh", spy("view", view_module.ClientView.refresh)
        )
        updates = app.streamer.stats.updates
        with app.replay.lock:  # forget the figures: the next round computes them all again
            app.figures.false_key = None
            app.figures.keys.clear()
        app.figures.request(True, ALL_MODES)
        wait(app)
        # the replay has ended: only the figures' round publishes the scene
        assert app.streamer.stats.updates == updates + 1
        assert free == [("false links", True)] + [("figures", True)] * len(ALL_MODES) + [
            ("view", True)
        ]
        assert app.figures.figures == figures
        np.testing.assert_array_equal(app.figures.links.time, links.time)
        np.testing.assert_array_equal(app.figures.links.false, links.false)
        # the per-frame update refreshes each view outside the replay lock too
        free.clear()
        app.on_maps(app.replay, ALL_MODES, forced=True)
        assert free == [("view", True)]


def test_html_replay_checks_its_folder_before_rendering(
    short_bag: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import app.server.export as export
    from cogmap_core.errors import OutputError

    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    with running_app(short_bag) as app:
        wait(app)

        def never(*args: object, **kwargs: object) -> str:
            raise AssertionError("rendered although the file cannot be written")

        with monkeypatch.context() as m:
            m.setattr(export, "html_replay", never)
            with pytest.raises(OutputError, match=f"cannot create {blocker}/sub"):
                save_html_replay(app.replay, (MapMode.COMPACT,), blocker / "sub" / "r.html")
        umask = __import__("os").umask(0o022)
        try:
            out = save_html_replay(app.replay, (MapMode.COMPACT,), tmp_path / "r.html", 5, 0.5)
        finally:
            __import__("os").umask(umask)
        assert out.stat().st_mode & 0o777 == 0o644
        assert sorted(p.name for p in tmp_path.iterdir()) == ["file", "r.html"]
