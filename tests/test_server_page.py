"""The page's behaviour without a browser: typed values, chart, playback, views, inspect, pin, bags.

Each test drives the app the way a browser does (GUI handles' values, or messages over a
websocket) and checks exact results against maps built independently (``SlamSession``).
"""

from __future__ import annotations

import html
import math
import os
import re
import shutil
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import app.server.replay as replay_module
import app.server.view as view_module
from app.server.chart import OFF_CHART, chart_data
from app.server.params import SPECS, format_value, parse_typed
from app.server.replay import PlaybackState
from app.server.validation import Refused
from cogmap_core.cognitive_map import EdgeKind, MapMode
from cogmap_core.config import MapParams
from cogmap_core.evaluation import align_rigid_2d
from cogmap_core.slam import SlamSession
from tests import test_server_support as support
from tests.test_server_support import (
    assert_same_map,
    client,
    counter,
    running_app,
    send,
    until,
    wait,
)

short_bag = support.short_bag
reference = support.reference


# ---------------------------------------------------------------------------- typed values
@pytest.mark.parametrize(
    ("name", "typed", "value", "said"),
    [
        ("delta", "8", 8.0, "δ = 8"),
        ("delta", " 8.50 ", 8.5, "δ = 8.5"),
        ("delta", "2.5e1", 25.0, "δ = 25"),
        ("delta", "1e9", 30.0, "δ = 1e9 is outside [1.05, 30]: using 30"),
        ("delta", "-5", 1.05, "δ = -5 is outside [1.05, 30]: using 1.05"),
        ("alpha", "1e308", 50.0, "α = 1e308 is outside [0, 50]: using 50"),
        ("alpha", "1e400", 50.0, "α = 1e400 is outside [0, 50]: using 50"),
        ("t_total", "+.5", 1.0, "T_total = +.5 is outside [1, 500]: using 1"),
    ],
)
def test_a_typed_number_is_that_number(name: str, typed: str, value: float, said: str) -> None:
    result = parse_typed(SPECS[name], typed)
    assert result.value == value and result.message == said


@pytest.mark.parametrize(
    ("typed", "reason"),
    [
        ("3,5", "'3,5' is not a number: write the decimal point as '.'"),
        ("abc", "'abc' is not a number"),
        ("NaN", "'NaN' is not a finite number"),
        ("inf", "'inf' is not a finite number"),
        ("-Infinity", "'-Infinity' is not a finite number"),
        ("", "the box is empty: type a number"),
        ("   ", "the box is empty: type a number"),
        ("1e", "'1e' is not a number"),
        ("0x10", "'0x10' is not a number"),
        ("8 m", "'8 m' is not a number"),
    ],
)
def test_anything_else_is_refused_with_the_reason(typed: str, reason: str) -> None:
    with pytest.raises(Refused) as info:
        parse_typed(SPECS["delta"], typed)
    assert str(info.value) == reason


def test_typed_values_over_the_websocket_apply_exactly_or_are_refused(
    short_bag: Path, reference: SlamSession
) -> None:
    with running_app(short_bag) as app:
        wait(app)
        box = app.param_boxes["delta"]
        with client(app.server.get_port()) as ws:
            until(lambda: len(app.views) == 1)
            steps = [
                ("1e9", 30.0, "30", "δ = 1e9 is outside [1.05, 30]: using 30"),
                ("3,5", 30.0, "30", "refused δ: '3,5' is not a number: write the decimal"),
                ("abc", 30.0, "30", "refused δ: 'abc' is not a number; δ stays 30"),
                ("NaN", 30.0, "30", "refused δ: 'NaN' is not a finite number; δ stays 30"),
                ("", 30.0, "30", "refused δ: the box is empty: type a number; δ stays 30"),
                ("-5", 1.05, "1.05", "δ = -5 is outside [1.05, 30]: using 1.05"),
                ("6", 6.0, "6", "δ = 6"),
            ]
            for typed, value, shown, said in steps:
                send(ws, box, value=typed)
                until(lambda s=said: s in html.unescape(app.params_md.content))
                until(lambda v=value, b=shown: app.replay.params.delta == v and box.value == b)
                wait(app)
                assert box.value == shown and app.param_sliders["delta"].value == value
        expected = reference.rebuild(MapParams(delta=6.0))[MapMode.COMPACT]
        assert_same_map(app.replay.session.maps[MapMode.COMPACT], expected)
        assert counter(app, "compact-vertices") == str(expected.num_vertices)
        # the slider updates the box, the box the slider
        app.param_sliders["alpha"].value = 12.5
        assert app.param_boxes["alpha"].value == "12.5"
        app.type_param("beta", "7.25")
        assert app.param_sliders["beta"].value == 7.25
        wait(app)
        assert app.replay.params == MapParams(alpha=12.5, beta=7.25, delta=6.0)


def test_refusal_texts_name_the_control_the_reason_and_the_value_kept(
    short_bag: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """The exact wording of each refusal: parameter note, seek note and the server log."""
    with running_app(short_bag, autoplay=False) as app:
        wait(app)
        with client(app.server.get_port()) as ws:
            until(lambda: len(app.views) == 1)
            steps = [
                (
                    app.param_sliders["alpha"],
                    {"value": "many"},
                    "α: 'many' is not a number; α stays 10.0",
                ),
                (
                    app.param_sliders["delta"],
                    {"max": 1e9},
                    "δ: property max is not the client's; δ stays 3.746",
                ),
                (app.param_boxes["beta"], {"value": "x"}, "β: 'x' is not a number; β stays 10"),
                (
                    app.param_boxes["delta"],
                    {"min": 0},
                    "δ: property min is not the client's; δ stays 3.746",
                ),
            ]
            for handle, updates, said in steps:
                send(ws, handle, **updates)
                expected = app._params_message(f"refused {said}", error=True)
                until(lambda e=expected: app.params_md.content == e, what=said)
            send(ws, app.seek_box, value="abc")
            until(lambda: "cogmap-message" in app.status_html.content)
            assert app.status_note == "refused go to (s): 'abc' is not a number; kept '0'"
            with caplog.at_level("WARNING", logger="app.server.app"):
                send(ws, app.speed_dropdown, value="bogus")
                until(lambda: "bogus" in caplog.text)
            options = ", ".join(("0.25x", "0.5x", "1x", "2x", "5x", "10x", "20x", "max"))
            assert caplog.messages[-1] == (
                f"GUI value from a client refused speed: 'bogus' is not one of {options}; "
                "kept 'max'"
            )
        app.type_param("delta", "abc")  # as a browser's box sends it, without the gate
        assert app.params_md.content == app._params_message(
            "refused δ: 'abc' is not a number; δ stays 3.746", error=True
        )


# ---------------------------------------------------------------------------- chart
def test_size_chart_in_data_seconds_with_optimisation_markers(
    short_bag: Path, reference: SlamSession
) -> None:
    with running_app(short_bag) as app:
        wait(app)
        chart = app.chart
        assert chart.scales["x"]["time"] is False  # data seconds, not 1970 clock times
        assert chart.legend["live"] is False  # values in the labels, never "--"
        x = chart.data[0]
        assert x[0] == 0.0 and x[-1] == pytest.approx(reference.log.frame_time[-1])
        labels = [s["label"] for s in chart.series]
        compact = reference.maps[MapMode.COMPACT]
        assert f"compact V {compact.num_vertices}" in labels
        assert f"compact optimisations {len(compact.optimizations)}" in labels
        top = chart.scales["y"]["range"][1]
        assert top >= 1.05 * reference.maps[MapMode.STANDARD].num_vertices
        for k, mode in enumerate((MapMode.STANDARD, MapMode.SCENE_INTEGRATION, MapMode.COMPACT)):
            marker = chart.data[7 + k]
            times = [o.time for o in reference.maps[mode].optimizations]
            at = np.isin(x, times)
            assert at.sum() == len(set(times)) > 0
            t, v, _ = reference.maps[mode].size_history()
            for time_ in times:  # the map's size right after the optimisation
                index = np.searchsorted(t, time_, side="right") - 1
                assert marker[x == time_][0] == v[index]
            assert (marker[~at] == OFF_CHART).all() and (marker[~at] < 0).all()
        assert not any(np.isnan(series).any() for series in chart.data)
    data = chart_data({}, math.nan)
    assert len(data) == 10 and data[0][-1] == pytest.approx(1e-3)


# ---------------------------------------------------------------------------- playback
def test_playback_status_play_at_the_end_seek_follows_and_frame_numbers(
    short_bag: Path, reference: SlamSession
) -> None:
    with running_app(short_bag, autoplay=False, speed=10.0) as app:
        wait(app)
        r = app.replay
        assert "paused" in app.status_html.content and "10×" not in app.status_html.content
        app.play_button.value = True
        until(lambda: r.state is PlaybackState.PLAYING and r.frame_time > 2.0)
        app._update_status(force=True)
        assert "10×" in app.status_html.content  # the speed shows while playing ...
        assert app.seek_slider.value > 0 and float(app.seek_box.value) > 0  # ... and follows
        app.speed_dropdown.value = "max"
        wait(app)
        assert r.state is PlaybackState.ENDED
        assert "ended</b> · t = " in app.status_html.content  # ... not when it ended
        end = round(reference.log.frame_time[-1], 1)
        assert app.seek_slider.value == end and app.seek_box.value == format_value(end)
        # a seek, then a step: the caption numbers frames of the bag, not of the pass
        app.seek_box.value = "30"
        wait(app)
        k = r.cursor
        app.step_button.value = True
        wait(app)
        assert r.cursor == k + 1
        assert f"frame {k + 1} / {reference.log.frames}" in app.template_md.content
        assert app.seek_box.value == format_value(round(r.frame_time, 1))
        # play at the end plays again from the start
        app.seek_box.value = "1e9"  # clamped to the end
        wait(app)
        app.play_button.value = True  # (play from here: to the end)
        wait(app)
        assert r.state is PlaybackState.ENDED and app.play_button.label == "play"
        restarts = r.cursor
        app.play_button.value = True
        until(lambda: r.cursor < restarts or r.state is PlaybackState.PLAYING, 10)
        wait(app)
        assert r.state is PlaybackState.ENDED and r.cursor == reference.log.frames
        for mode in MapMode:
            assert_same_map(r.session.maps[mode], reference.maps[mode])


def test_a_seek_note_lasts_until_the_next_typed_seek(short_bag: Path) -> None:
    with running_app(short_bag) as app:
        wait(app)
        with client(app.server.get_port()) as ws:
            until(lambda: len(app.views) == 1)
            send(ws, app.seek_box, value="abc")
            until(lambda: "cogmap-message" in app.status_html.content)
            assert "abc" in html.unescape(app.status_html.content)
            send(ws, app.seek_box, value="1")  # a valid seek: the refusal is no longer news
            until(lambda: app.replay.frame_time <= 1.05)
            app._update_status(force=True)
            assert "cogmap-message" not in app.status_html.content


def test_a_tab_closed_while_its_page_is_built_leaves_no_view_and_no_error(
    short_bag: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
) -> None:
    building, leave = threading.Event(), threading.Event()
    real_apply = view_module.ClientView.apply

    def slow_first_apply(self: view_module.ClientView, *args: object, **kwargs: object) -> None:
        if not building.is_set():
            building.set()
            leave.wait(10)  # the tab closes here, while the page is being built
        real_apply(self, *args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(view_module.ClientView, "apply", slow_first_apply)
    with running_app(short_bag) as app:
        wait(app)
        capfd.readouterr()
        with client(app.server.get_port()):
            assert building.wait(10)
        until(lambda: not app.server.get_clients())
        leave.set()
        until(lambda: not app._connect_lock.locked())
        time.sleep(0.2)  # (viser prints a failed callback from its own thread)
        assert app.views == {}  # no view kept for a tab that is gone
        printed = capfd.readouterr()
        assert "Task failed" not in printed.out + printed.err
        assert "removed" not in printed.out + printed.err
        with client(app.server.get_port()):  # the next tab gets its page
            until(lambda: len(app.views) == 1)


def test_the_status_never_waits_for_the_replays_lock(short_bag: Path) -> None:
    """The replay thread updates the status holding its condition; a viewer's change holds the
    replay's lock and waits for that condition (set_priority): the status must not take the
    lock, or the two wait for each other forever (seen as a hung test run)."""
    with running_app(short_bag) as app:
        wait(app)
        done = threading.Event()

        def status_as_the_replay_thread_gives_it() -> None:
            with app.replay._cond:
                app.update_status(force=True)
            done.set()

        with app.replay.lock:  # as a viewer's change holds it
            thread = threading.Thread(target=status_as_the_replay_thread_gives_it, daemon=True)
            thread.start()
            finished = done.wait(5)
        thread.join(5)
        assert finished


def test_the_replay_waits_for_the_first_viewer(short_bag: Path) -> None:
    with running_app(short_bag, wait_for_viewer=True) as app:
        until(lambda: app.replay.state is PlaybackState.PAUSED)
        time.sleep(0.3)
        app._update_status(force=True)
        assert "waiting for the first viewer" in app.status_html.content
        assert app.replay.cursor == 0
        with client(app.server.get_port()):
            until(lambda: app.replay.cursor > 0)
            assert app.replay.playing


# ---------------------------------------------------------------------------- views
def test_a_viewers_change_counts_while_its_view_sets_controls_on_another_thread(
    short_bag: Path,
) -> None:
    with running_app(short_bag) as app:
        wait(app)
        with client(app.server.get_port()) as ws:
            until(lambda: len(app.views) == 1)
            view = next(iter(app.views.values()))
            setting, release = threading.Event(), threading.Event()

            def the_view_setting_a_control() -> None:  # e.g. _on_camera unticking "follow"
                view._setting.on = True
                setting.set()
                release.wait(10)
                view._setting.on = False

            worker = threading.Thread(target=the_view_setting_a_control)
            worker.start()
            try:
                assert setting.wait(10)
                send(ws, view.layer_checkboxes["odometry"], value=True)  # the viewer, meanwhile
                until(lambda: view.state.layers["odometry"])
            finally:
                release.set()
                worker.join()


def test_each_viewer_has_its_own_view(short_bag: Path, reference: SlamSession) -> None:
    with running_app(short_bag) as app:
        wait(app)
        port = app.server.get_port()
        with client(port) as first:
            until(lambda: len(app.views) == 1)
            mine = next(iter(app.views.values()))
            with client(port):
                until(lambda: len(app.views) == 2)
                other = next(v for v in app.views.values() if v is not mine)
                send(first, mine.mode_dropdown, value="standard")
                send(first, mine.compare_checkbox, value=True)
                send(first, mine.compare_dropdown, value="compact")
                send(first, mine.colouring_dropdown, value="time")
                send(first, mine.layer_checkboxes["odometry"], value=True)
                until(lambda: mine.state.layers["odometry"])
                until(lambda: mine.state.colouring == "time")
                layer = app.streamer.layers[MapMode.STANDARD]
                until(lambda: layer.odometry.num_items > 0)
                assert mine.state.shown == (MapMode.STANDARD, MapMode.COMPACT)
                assert other.state.shown == (MapMode.COMPACT,)  # untouched
                assert other.mode_dropdown.value == "compact"
                # the first viewer's shadows show standard at 0 and compact beside it
                width = np.ptp(reference.maps[MapMode.STANDARD].snapshot().poses[:, 0])
                visible, x = mine._shadow_state["/map/compact"]
                assert visible and x >= width + 0.5
                assert mine._shadow_state["/map/standard"] == (True, 0.0)
                assert mine._shadow_state["/map/compact/loop/time"] == (True, 0.0)
                assert mine._shadow_state["/map/compact/loop/cluster"] == (False, 0.0)
                assert other._shadow_state["/map/compact"] == (True, 0.0)
                assert other._shadow_state["/map/standard"] == (False, 0.0)
                # what is streamed: the union of what the viewers show
                assert app.streamer.needed >= {MapMode.STANDARD, MapMode.COMPACT}
                assert app.streamer.colourings == {"cluster", "time"}
                assert layer.edges["loop/time"].num_items == (
                    reference.maps[MapMode.STANDARD].num_loop_edges
                )
                assert layer.odometry.num_items == reference.log.frames - 1
                assert app.replay._priority[:2] == (MapMode.STANDARD, MapMode.COMPACT)
                # the ground truth lies under every map, aligned to it as the ATE aligns it
                for mode in (MapMode.STANDARD, MapMode.COMPACT):
                    snap = reference.maps[mode].snapshot()
                    truth = reference.log.truth_at(snap.vertex_time)
                    t = align_rigid_2d(truth, snap.poses)
                    frame = app.streamer.layers[mode].truth_frame
                    assert tuple(frame.position) == pytest.approx((t.tx, t.ty, 0.0))
                    assert app.streamer.layers[mode].truth.num_items == reference.log.frames - 1
            until(lambda: len(app.views) == 1)


def test_the_shown_after_line_describes_the_latest_parameter_change(short_bag: Path) -> None:
    with running_app(short_bag) as app:
        wait(app)
        with client(app.server.get_port()):
            until(lambda: len(app.views) == 1)
            view = next(iter(app.views.values()))
            for delta in (5.0, 6.0):
                app.replay.set_params(MapParams(delta=delta))
                wait(app)
                last = app.replay.last_completed_rebuild()
                assert last is not None and last.params.delta == delta
                shown = ", ".join(
                    f"{m.value} {last.latency(m) * 1000:.0f} ms ({last.how[m]})"
                    for m in last.published
                )
                # the view's log follows the change whose maps are all shown, not the one before
                until(lambda shown=shown: f"shown after: {shown}<" in view.log_html.content)


def test_inspect_pin_and_compare(short_bag: Path, reference: SlamSession) -> None:
    with running_app(short_bag) as app:
        wait(app)
        with client(app.server.get_port()):
            until(lambda: len(app.views) == 1)
            view = next(iter(app.views.values()))
            compact = reference.maps[MapMode.COMPACT]
            snap = compact.snapshot()
            # a click near a vertex selects it
            k = snap.vertex_ids.shape[0] // 2
            pick = app.pick(view, snap.poses[k, :2] + 0.004, 0.02)
            assert pick is not None and pick.kind == "vertex"
            text_ = " ".join(html.unescape(re.sub("<[^>]+>", " ", pick.html)).split())
            assert f"vertex id {snap.vertex_ids[k]}" in text_
            assert f"view template #{snap.vertex_view[k]}" in text_
            assert f"created at {snap.vertex_time[k]:.2f} s" in text_
            # ... and near the middle of a loop-closure edge, that edge (residual, cluster)
            view.set_mode(MapMode.STANDARD)
            snap = reference.maps[MapMode.STANDARD].snapshot()
            ends = snap.poses[np.searchsorted(snap.vertex_ids, snap.edge_from), :2]
            other = snap.poses[np.searchsorted(snap.vertex_ids, snap.edge_to), :2]
            middle = (ends + other) / 2
            gaps = np.array([np.hypot(*(snap.poses[:, :2] - m).T).min() for m in middle])
            is_loop = snap.edge_kind == EdgeKind.LOOP_CLOSURE
            loop = int(np.argmax(np.where(is_loop, gaps, -1.0)))  # clear of every vertex
            assert is_loop[loop] and gaps[loop] > 0.001
            pick = app.pick(view, middle[loop], 0.01)
            assert pick is not None and pick.kind == "edge" and pick.index == loop
            text_ = " ".join(html.unescape(re.sub("<[^>]+>", " ", pick.html)).split())
            assert "loop closure" in text_ and f"cluster {snap.edge_cluster[loop]}" in text_
            assert "σ (whitened" in text_ and "ground truth" in text_
            view.select(pick)
            assert view.inspect_html.content == pick.html
            assert app.pick(view, np.array([50.0, 50.0]), 0.05) is None
            # pin, change delta, compare
            view.set_mode(MapMode.COMPACT)
            view.pin()
            assert view.pinned is not None and view.pinned.params == MapParams()
            app.type_param("delta", "8")
            wait(app)
            view.refresh()
            table = html.unescape(view.compare_html.content)
            changed = reference.rebuild(MapParams(delta=8.0))[MapMode.COMPACT]
            live = re.search(r'id="cogmap-compare-live-vertices">(\d+)<', table)
            pinned = re.search(r'id="cogmap-compare-pinned-vertices">(\d+)<', table)
            assert live and pinned
            assert int(live.group(1)) == changed.num_vertices
            assert int(pinned.group(1)) == compact.num_vertices != changed.num_vertices
            assert '<td class="cogmap-diff">8</td><td class="cogmap-diff">3.746</td>' in table
            assert view.offsets()["pinned"] > 0
            view.pin_dropdown.value = "under"
            assert view.offsets()["pinned"] == 0.0
            view.unpin()
            assert view.pinned is None and "pinned" not in view.offsets()


def test_cluster_log_is_an_html_table(short_bag: Path, reference: SlamSession) -> None:
    with running_app(short_bag) as app:
        wait(app)
        compact = reference.maps[MapMode.COMPACT]
        page = app.cluster_log_html(MapMode.COMPACT, app.replay.session.maps[MapMode.COMPACT])
        heads = re.findall(r"<th>([^<]*)</th>", page)
        assert heads == ["t (s)", "cluster", "links", "V", "iters", "ms", "merged", "short"]
        rows = re.findall(r"<tr><td>", page)
        assert len(rows) == min(12, len(compact.optimizations))


# ---------------------------------------------------------------------------- bags, exports
def test_open_another_bag_from_the_page(
    short_bag: Path, reference: SlamSession, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    data = tmp_path / "data"
    (data / "sub").mkdir(parents=True)
    other = data / "copy.recording"  # a ROS 1 bag is one whatever its name (as for serve)
    shutil.copy(short_bag, other)
    shutil.copy(short_bag.with_suffix(".frontend.json"), other.with_suffix(".frontend.json"))
    (data / "notes.txt").write_text("not a bag")
    (data / "broken.bag").write_bytes(b"#ROSBAG V2.0\n" + b"\0" * 100)
    (data / "sub" / "fake.bag").write_text("a text file named like a bag")
    with running_app(short_bag, data_dirs=[data]) as app:
        wait(app)
        first = app.replay
        # the page lists the bags of the data folder, by their paths relative to it
        assert tuple(app.bag_dropdown.options) == ("broken.bag", "copy.recording", "sub/fake.bag")
        for chosen, said in (
            ("broken.bag", "not opened: broken.bag has a damaged bag header; it is corrupt"),
            ("sub/fake.bag", "not opened: sub/fake.bag is not a ROS bag"),
            (str(data / "nope.bag"), f"not opened: {str(data / 'nope.bag')!r} is not one of"),
        ):
            assert app.open_bag(chosen) is False
            message = html.unescape(app.open_md.content)
            assert said in message and "cogmap-error" in message, chosen
            assert str(tmp_path) not in message.replace(repr(str(data / "nope.bag")), "")
            assert app.replay is first and first.alive
        opened_by_replays: list[Path] = []
        real_open_source = replay_module.open_source

        def counting_open_source(path: Path, *args: object, **kwargs: object) -> object:
            opened_by_replays.append(Path(path))
            return real_open_source(path, *args, **kwargs)  # type: ignore[arg-type]

        monkeypatch.setattr(replay_module, "open_source", counting_open_source)
        app.bag_dropdown.value = "copy.recording"
        app.open_button.value = True  # (opened on a thread of its own)
        opening = app._opening
        assert opening is not None
        opening.join(30)
        assert "opened copy.recording (" in html.unescape(app.open_md.content)
        assert app.replay is not first and not first.alive
        # readers that took `app.replay.lock` before the swap held the new replay's lock too
        assert app.replay.lock is first.lock
        wait(app)
        assert app.replay.bag_path == other and app.replay.state is PlaybackState.ENDED
        assert opened_by_replays == []  # the page's check opened it; the replay used that reader
        for mode in MapMode:
            assert_same_map(app.replay.session.maps[mode], reference.maps[mode])
        assert "copy.recording" in app.status_html.content


def test_html_replay_is_titled_captioned_quiet_and_normally_readable(
    short_bag: Path, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    with running_app(short_bag, export_dir=tmp_path / "out") as app:
        wait(app)
        app.replay_path.value = "replay.html"  # a name: the replay goes to the export folder
        capfd.readouterr()
        umask = os.umask(0o022)
        try:
            saving = app._save_replay(None)
            assert saving is not None
            saving.join(120)
        finally:
            os.umask(umask)
        printed = capfd.readouterr()
        assert "Server stopped" not in printed.out + printed.err  # (viser's own server)
        assert "saved the HTML replay as replay.html in the export folder" in (
            app.export_md.content
        )
        out = tmp_path / "out" / "replay.html"
        assert out.stat().st_mode & 0o777 == 0o644
        page = out.read_text()
        assert "<title>cogmap replay · figure_eight_1lap.bag</title>" in page
        assert 'id="cogmap-replay-caption"' in page and "δ 3.746" in page
