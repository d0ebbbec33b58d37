"""Issue 26: routes on the page -- the places carried between maps and the truth by the
alignments the scene shows, the routes on the shown map, the standard map and the true path,
their lengths in the panel, unreachable goals said in one line; on hand-made maps (exact
answers) and on a real server with a client connected as a browser connects (the browser test
drives the same in Chromium)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from app.server.routes import (
    Place,
    RouteInputs,
    RouteWorker,
    carry,
    message_html,
    plan_html,
    plan_routes,
    route_inputs,
)
from app.server.view import ROUTE_HELP, ClientView
from cogmap_core.cognitive_map import MapMode
from cogmap_core.config import MapParams
from cogmap_core.evaluation import RigidTransform2D
from cogmap_core.routes import Route, RouteMap, true_path_graph
from tests import test_server_support as support
from tests.test_routes import snapshot
from tests.test_server_support import client, running_app, until, wait

short_bag = support.short_bag

# an L-shaped corridor in the truth's frame: (0,0) -> (2,0) -> (2,1), one sample per 5 cm
_LEG_A = np.column_stack([np.arange(0, 2.0001, 0.05), np.zeros(41)])
_LEG_B = np.column_stack([np.full(20, 2.0), np.arange(0.05, 1.0001, 0.05)])
TRUTH = np.vstack([_LEG_A, _LEG_B])
# each map: five vertices along the L, in its own frame (the truth moved by its alignment)
CORNERS = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [2.0, 0.5], [2.0, 1.0]])
CHAIN = [(0, 1), (1, 2), (2, 3), (3, 4)]
TO_COMPACT = RigidTransform2D(0.5, 1.0, -2.0)  # truth -> compact map
TO_STANDARD = RigidTransform2D(-1.2, -3.0, 0.5)  # truth -> standard map
# a map's route from the L's first vertex to its last: straightened inside the corner (2, 0) by
# the default link_sigma_position, each way
_INSET = MapParams().link_sigma_position / np.sqrt(2.0)
L_WAY = np.array([[0.0, 0.0], [2.0 - _INSET, _INSET], [2.0, 1.0]])
L_LENGTH = float(np.hypot(*np.diff(L_WAY, axis=0).T).sum())  # 2.958 m


def _maps() -> dict[MapMode, object]:
    return {
        MapMode.COMPACT: snapshot(TO_COMPACT.apply(CORNERS), CHAIN),
        MapMode.STANDARD: snapshot(
            TO_STANDARD.apply(CORNERS),
            [(a + 10, b + 10) for a, b in CHAIN],
            ids=[10, 11, 12, 13, 14],
        ),
    }


def _inputs(maps: dict[MapMode, object] | None = None) -> RouteInputs:
    alignments = {MapMode.COMPACT: TO_COMPACT, MapMode.STANDARD: TO_STANDARD}
    return RouteInputs(maps or _maps(), alignments, TRUTH, (1,))  # type: ignore[arg-type]


def test_a_place_is_carried_by_the_inverse_alignment_and_the_other_map_s_own() -> None:
    alignments = {MapMode.COMPACT: TO_COMPACT, MapMode.STANDARD: TO_STANDARD}
    truth_point = np.array([[1.5, 0.25]])
    on_compact = TO_COMPACT.apply(truth_point)
    np.testing.assert_allclose(
        carry(on_compact, MapMode.COMPACT, None, alignments), truth_point, atol=1e-12
    )
    np.testing.assert_allclose(
        carry(on_compact, MapMode.COMPACT, MapMode.STANDARD, alignments),
        TO_STANDARD.apply(truth_point),
        atol=1e-12,
    )
    np.testing.assert_allclose(
        carry(truth_point, None, MapMode.COMPACT, alignments), on_compact, atol=1e-12
    )
    # without ground truth every map's frame is the same
    np.testing.assert_array_equal(carry(on_compact, MapMode.COMPACT, MapMode.STANDARD, None),
                                  on_compact)  # fmt: skip


def test_routes_on_each_map_and_the_true_path_from_places_clicked_on_one_map() -> None:
    # clicked on the compact map where it draws truth (0.1, 0) and (2, 0.9)
    start = Place(MapMode.COMPACT, tuple(TO_COMPACT.apply(np.array([[0.1, 0.0]]))[0]))
    goal = Place(MapMode.COMPACT, tuple(TO_COMPACT.apply(np.array([[2.0, 0.9]]))[0]))
    plan = plan_routes(_inputs(), start, goal, (MapMode.COMPACT, MapMode.STANDARD))
    compact, standard = plan.leg(MapMode.COMPACT), plan.leg(MapMode.STANDARD)
    assert compact is not None and compact.route is not None
    assert standard is not None and standard.route is not None
    np.testing.assert_array_equal(compact.route.vertex_ids, [0, 1, 2, 3, 4])
    np.testing.assert_array_equal(standard.route.vertex_ids, [10, 11, 12, 13, 14])
    assert compact.route.length == pytest.approx(L_LENGTH, abs=1e-12)
    assert standard.route.length == pytest.approx(L_LENGTH, abs=1e-12)
    assert compact.route.start_gap == pytest.approx(0.1, abs=1e-12)
    assert standard.route.goal_gap == pytest.approx(0.1, abs=1e-12)
    # the true shortest path: samples (0.1, 0) .. (2, 0.9) along the L: 1.9 + 0.9 m
    assert plan.truth is not None and plan.truth.route is not None
    assert plan.truth.route.length == pytest.approx(2.8, abs=1e-9)
    assert (plan.truth.route.start_gap, plan.truth.route.goal_gap) == (
        pytest.approx(0.0, abs=1e-12),
        pytest.approx(0.0, abs=1e-12),
    )
    # drawn on the compact map: the standard route and the true path lie where the compact
    # map's alignment puts them
    np.testing.assert_allclose(
        plan.points_on(standard, MapMode.COMPACT), TO_COMPACT.apply(L_WAY), atol=1e-12
    )
    np.testing.assert_allclose(
        plan.points_on(plan.truth, MapMode.COMPACT),
        TO_COMPACT.apply(TRUTH[2:59]),
        atol=1e-12,
    )
    # the panel: each length and its ratio to the true shortest path
    text = plan_html(plan, MapMode.COMPACT)
    assert 'id="cogmap-route-compact-length">2.96 m<' in text
    assert 'id="cogmap-route-compact-ratio">1.056<' in text  # 2.958 / 2.8
    assert 'id="cogmap-route-standard-length">2.96 m<' in text
    assert 'id="cogmap-route-truth-length">2.80 m<' in text
    assert 'id="cogmap-route-truth-ratio">1.000<' in text
    assert "compact (shown)" in text and "cogmap-error" not in text
    assert "from (" in text and "m on the compact map" in text


def test_an_unreachable_goal_is_one_line_on_the_page_and_the_other_routes_stay() -> None:
    maps = _maps()
    maps[MapMode.COMPACT] = snapshot(TO_COMPACT.apply(CORNERS), [(0, 1), (1, 2), (3, 4)])
    start = Place(MapMode.STANDARD, tuple(TO_STANDARD.apply(CORNERS[:1])[0]))
    goal = Place(MapMode.STANDARD, tuple(TO_STANDARD.apply(CORNERS[4:])[0]))
    plan = plan_routes(_inputs(maps), start, goal, (MapMode.COMPACT, MapMode.STANDARD))
    compact = plan.leg(MapMode.COMPACT)
    assert compact is not None and compact.route is None
    assert compact.problem == (
        "no route on the compact map: no route from vertex 0 to vertex 4: they lie on "
        "separate pieces of the map (no chain of edges joins them)"
    )
    assert plan.leg(MapMode.STANDARD).route.length == pytest.approx(L_LENGTH)  # type: ignore[union-attr]
    text = plan_html(plan, MapMode.COMPACT)
    assert 'class="cogmap-note cogmap-error" id="cogmap-route"' in text
    assert "no route on the compact map: no route from vertex 0 to vertex 4" in text
    assert 'id="cogmap-route-compact-length">–<' in text
    assert 'id="cogmap-route-standard-length">2.96 m<' in text
    # an empty map says so too
    one = snapshot(np.zeros((1, 2)), [])
    maps[MapMode.COMPACT] = replace(
        one,
        vertex_ids=one.vertex_ids[:0],
        poses=one.poses[:0],
        vertex_time=one.vertex_time[:0],
        vertex_view=one.vertex_view[:0],
    )
    plan = plan_routes(_inputs(maps), start, goal, (MapMode.COMPACT,))
    assert plan.legs[0].problem == (
        "no route on the compact map: the map has no vertex yet: there is nothing to route on"
    )


def test_without_truth_or_alignments_the_frames_are_one_and_there_is_no_true_path() -> None:
    maps = _maps()
    none = route_inputs(maps, {}, None, ())  # type: ignore[arg-type]
    assert none.alignments is None and none.truth is None
    assert none.note == "No ground truth: the maps' frames are taken as one."
    waiting = route_inputs(maps, {MapMode.COMPACT: (0.5, 1.0, -2.0)}, TRUTH, (1,))  # type: ignore[arg-type]
    assert waiting.alignments is None and "not computed yet" in waiting.note
    start = Place(MapMode.COMPACT, tuple(maps[MapMode.COMPACT].poses[0, :2]))  # type: ignore[attr-defined]
    goal = Place(MapMode.COMPACT, tuple(maps[MapMode.COMPACT].poses[4, :2]))  # type: ignore[attr-defined]
    plan = plan_routes(none, start, goal, (MapMode.COMPACT,))
    assert plan.truth is None and plan.legs[0].route.length == pytest.approx(L_LENGTH)  # type: ignore[union-attr]
    text = plan_html(plan, MapMode.COMPACT)
    assert 'id="cogmap-route-compact-ratio">–<' in text and "cogmap-route-truth" not in text
    assert "No ground truth: the maps&#x27; frames are taken as one." in text
    both = route_inputs(maps, {MapMode.COMPACT: (0.5, 1.0, -2.0),
                               MapMode.STANDARD: (-1.2, -3.0, 0.5)}, TRUTH, (1,))  # type: ignore[arg-type]  # fmt: skip
    assert both.alignments == {MapMode.COMPACT: TO_COMPACT, MapMode.STANDARD: TO_STANDARD}


def test_routes_on_the_page_take_the_maps_parameters() -> None:
    start = Place(MapMode.COMPACT, tuple(TO_COMPACT.apply(CORNERS[:1])[0]))
    goal = Place(MapMode.COMPACT, tuple(TO_COMPACT.apply(CORNERS[4:])[0]))

    def route(params: MapParams | None) -> Route:  # the compact map's route with params
        inputs = route_inputs(_maps(), {}, None, (), params)  # type: ignore[arg-type]
        assert inputs.params is params
        found = plan_routes(inputs, start, goal, (MapMode.COMPACT,)).legs[0].route
        assert found is not None
        return found

    # straightened within 0.1 m (link_sigma_position): the corner cut 0.1 m each way
    inset = 0.1 / np.sqrt(2.0)
    way = np.array([[0.0, 0.0], [2.0 - inset, inset], [2.0, 1.0]])
    wide = route(MapParams(link_sigma_position=0.1))
    np.testing.assert_allclose(wide.points, TO_COMPACT.apply(way), atol=1e-12)
    # joined within 1.2 m (integration_radius): from (1, 0) straight to (2, 0.5)
    assert route(MapParams(integration_radius=1.2)).vertex_ids.tolist() == [0, 1, 3, 4]
    # without parameters, the defaults
    assert route(None).vertex_ids.tolist() == [0, 1, 2, 3, 4]
    assert route(None).length == pytest.approx(L_LENGTH, abs=1e-12)


def test_the_worker_does_the_latest_request_once() -> None:
    done: list[str] = []
    worker: RouteWorker[list[str]] = RouteWorker(lambda item: done.append(item[0]))
    item = ["a"]
    try:
        for _ in range(50):
            worker.request(item)
        until(worker.idle, 5, "the worker")
        assert 1 <= len(done) <= 50 and set(done) == {"a"}
        boom: RouteWorker[int] = RouteWorker(lambda _: 1 / 0)  # printed, never stops it
        boom.request(1)
        until(boom.idle, 5)
        boom.stop()
    finally:
        worker.stop()


# ================================================================== on a server
def _view(app: object) -> ClientView:
    until(lambda: len(app.views) == 1, 10, "the viewer")  # type: ignore[attr-defined]
    return next(iter(app.views.values()))  # type: ignore[attr-defined]


def _expected(app: object, mode: MapMode, start: Place, goal: Place) -> tuple[float, float]:
    """The route length on ``mode`` and the true shortest path, computed here on their own."""
    figures = app._figures  # type: ignore[attr-defined]
    to_truth = RigidTransform2D(*figures[start.mode].truth_transform).inverse()
    to_map = RigidTransform2D(*figures[mode].truth_transform)
    a, b = to_truth.apply(np.array([start.xy, goal.xy]))
    cmap = app.replay.session.maps[mode]  # type: ignore[attr-defined]
    length = RouteMap.of(cmap.snapshot(), params=cmap.params).route(*to_map.apply([a, b])).length
    truth = np.asarray(app.replay.session.log.ground_truth)  # type: ignore[attr-defined]
    return length, true_path_graph(truth).route(a, b).length


def test_route_on_the_page_drawn_and_compared(short_bag: Path) -> None:
    with running_app(short_bag) as app, client(app.server.get_port()):
        wait(app)
        view = _view(app)
        assert view.route_html.content == message_html(ROUTE_HELP)
        snap = app.replay.session.maps[MapMode.COMPACT].snapshot()
        n = snap.vertex_ids.shape[0]
        first, second = snap.poses[n // 5, :2], snap.poses[3 * n // 5, :2]
        view.start_route()
        assert "Click the start" in view.route_html.content
        view.route_click(first)
        assert view.route_stage == "goal" and "click the goal" in view.route_html.content
        scene = view.client.scene._handle_from_node_name
        assert "/map/compact/route/start" in scene  # the start shows at once
        view.route_click(second)
        assert view.route_stage is None
        wait(app)
        plan = view.route_plan
        assert plan is not None and plan.start.mode is MapMode.COMPACT
        assert plan.start.xy == tuple(first) and plan.goal.xy == tuple(second)
        assert [leg.mode for leg in plan.legs] == [MapMode.COMPACT, MapMode.STANDARD]
        content = view.route_html.content
        truth_length = None
        for mode in (MapMode.COMPACT, MapMode.STANDARD):
            leg = plan.leg(mode)
            assert leg is not None and leg.route is not None
            length, truth_length = _expected(app, mode, plan.start, plan.goal)
            assert leg.route.length == pytest.approx(length, abs=1e-9)
            assert f'id="cogmap-route-{mode.value}-length">{leg.route.length:.2f} m<' in content
            ratio = leg.route.length / truth_length
            assert f'id="cogmap-route-{mode.value}-ratio">{ratio:.3f}<' in content
        assert plan.truth is not None and plan.truth.route is not None
        assert plan.truth.route.length == pytest.approx(truth_length, abs=1e-9)
        assert f'id="cogmap-route-truth-length">{truth_length:.2f} m<' in content
        # the compact route drawn on the compact map, exactly through its vertices; the
        # standard route and the true path over it; the places marked
        own = scene["/map/compact/route/own_fill"]
        compact_route = plan.leg(MapMode.COMPACT).route  # type: ignore[union-attr]
        np.testing.assert_allclose(own.points[:, 0, :2], compact_route.points[:-1], atol=1e-6)
        np.testing.assert_allclose(own.points[-1, 1, :2], compact_route.points[-1], atol=1e-6)
        for name in ("truth_casing", "truth_fill", "standard_casing", "standard_fill",
                     "own_casing", "start", "goal", "start_label", "goal_label"):  # fmt: skip
            assert f"/map/compact/route/{name}" in scene, name
        assert scene["/map/compact/route/goal_label"].text == "goal"
        # clicks select again once the route is done; "clear route" removes it
        view.clear_route()
        assert not any("/route/" in name for name in scene)
        assert view.route_html.content == message_html(ROUTE_HELP)
        assert view.route_plan is None and view.route_stage is None


def test_route_side_by_side_a_click_on_the_second_map_and_a_map_in_two_pieces(
    short_bag: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    with running_app(short_bag) as app, client(app.server.get_port()):
        wait(app)
        view = _view(app)
        view.set_mode(MapMode.STANDARD, MapMode.COMPACT)
        wait(app)
        offset = view.offsets()["compact"]
        assert offset > 0
        snap = app.replay.session.maps[MapMode.COMPACT].snapshot()
        n = snap.vertex_ids.shape[0]
        a, b = snap.poses[n // 4, :2], snap.poses[n // 2, :2]
        view.start_route()
        view.route_click(a + [offset, 0.0])  # drawn beside the standard map
        view.route_click(b + [offset, 0.0])
        wait(app)
        plan = view.route_plan
        assert plan is not None and plan.start.mode is MapMode.COMPACT
        np.testing.assert_allclose(plan.start.xy, a, rtol=0, atol=1e-12)  # (offset undone)
        assert [leg.mode for leg in plan.legs] == [MapMode.STANDARD, MapMode.COMPACT]
        route = plan.leg(MapMode.COMPACT).route  # type: ignore[union-attr]
        assert route is not None
        assert route.start_gap == pytest.approx(0, abs=1e-12) == route.goal_gap
        scene = view.client.scene._handle_from_node_name
        # each shown map has its own route and the true path; the standard map's is its own
        assert "/map/compact/route/own_fill" in scene and "/map/standard/route/own_fill" in scene
        assert "/map/standard/route/standard_fill" not in scene
        # a map in two pieces: the compact map with the goal's vertex cut off -- no edge to
        # any vertex within 0.3 m of it, so that no join (0.1 m) reaches the rest either
        cmap = app.replay.session.maps[MapMode.COMPACT]
        whole = cmap.snapshot()
        goal_id = int(route.vertex_ids[-1])
        goal_xy = whole.poses[whole.vertex_ids == goal_id, :2][0]
        near = whole.vertex_ids[np.hypot(*(whole.poses[:, :2] - goal_xy).T) < 0.3]
        assert int(route.vertex_ids[0]) not in near
        keep = ~np.isin(whole.edge_from, near) & ~np.isin(whole.edge_to, near)
        pieces = snapshot(
            whole.poses,
            np.column_stack([whole.edge_from[keep], whole.edge_to[keep]]),
            ids=whole.vertex_ids,
        )
        monkeypatch.setattr(cmap, "snapshot", lambda: pieces)
        view.start_route()
        view.route_click(a + [offset, 0.0])
        view.route_click(b + [offset, 0.0])
        wait(app)
        message = view.route_html.content
        assert 'class="cogmap-note cogmap-error" id="cogmap-route"' in message
        assert (
            f"no route on the compact map: no route from vertex {int(route.vertex_ids[0])} to "
            f"vertex {goal_id}: they lie on separate pieces of the map (no chain of edges "
            "joins them)"
        ) in message
        assert 'id="cogmap-route-compact-length">–<' in message
        standard = view.route_plan.leg(MapMode.STANDARD).route  # type: ignore[union-attr]
        assert f'id="cogmap-route-standard-length">{standard.length:.2f} m<' in message
        assert "/map/compact/route/own_fill" not in scene  # nothing drawn for it
