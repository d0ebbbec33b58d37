"""Issue 25: the scene a viewer reads at a glance (plan view, one grid, names, sizes), on a
real server with a client connected as a browser connects (no browser: the browser test drives
the same in Chromium)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from app.server.scene import VERTEX_FRACTION, grid_spacing, nice
from app.server.view import PLAN_FOV, VIEW_FOV, ClientView
from cogmap_core.cognitive_map import MapMode
from cogmap_core.sources.odometry_log import LOG_MAP_PARAMS
from tests import test_server_support as support
from tests.test_server_support import client, running_app, until, wait

short_bag = support.short_bag
false_log = support.false_log


def _view(app: object) -> ClientView:
    until(lambda: len(app.views) == 1, 10, "the viewer")  # type: ignore[attr-defined]
    return next(iter(app.views.values()))  # type: ignore[attr-defined]


def test_the_plan_view_is_the_default_and_3d_is_one_click_away(short_bag: Path) -> None:
    with running_app(short_bag) as app, client(app.server.get_port()):
        wait(app)
        view = _view(app)
        view.frame_camera()
        camera = view.client.camera
        assert view.plan and camera.fov == pytest.approx(PLAN_FOV)
        position, look_at = camera.position, camera.look_at
        assert position[2] > 10 * (view.frame_box()[1] - view.frame_box()[0])  # far away
        # straight down, north up: the camera sits a hair south of what it looks at
        dx, dy = look_at[0] - position[0], look_at[1] - position[1]
        assert dx == 0 and 0 < dy < 1e-3 * position[2]
        # every vertex of the map inside the canvas, left of the panel (projected)
        snap = app.replay.session.maps[MapMode.COMPACT].snapshot()
        width, height = camera.image_width, camera.image_height
        per_px = 2 * position[2] * math.tan(camera.fov / 2) / height
        px = width / 2 + (snap.poses[:, 0] - look_at[0]) / per_px
        py = height / 2 - (snap.poses[:, 1] - look_at[1]) / per_px
        margin = 0.07 * height  # (the panel is docked beside the canvas: all of it is free)
        assert px.min() >= margin - 1 and px.max() <= width - margin + 1
        assert py.min() >= margin - 1 and py.max() <= height - margin + 1
        assert (view.top_button.label, view.view3d_button.label) == ("plan view", "3-D view")
        view.frame_camera(top=False)
        assert not view.plan and camera.fov == pytest.approx(VIEW_FOV)
        assert camera.position[2] < 3 * (view.frame_box()[1] - view.frame_box()[0])
        view.frame_camera(top=True)
        assert view.plan and camera.fov == pytest.approx(PLAN_FOV)


def test_side_by_side_one_grid_names_and_the_pinned_map_on_it(short_bag: Path) -> None:
    with running_app(short_bag) as app, client(app.server.get_port()):
        wait(app)
        view = _view(app)
        view.set_mode(MapMode.STANDARD, MapMode.COMPACT)
        wait(app)
        offsets = view.offsets()
        standard = app.streamer.layers[MapMode.STANDARD].view_extent
        compact = app.streamer.layers[MapMode.COMPACT].view_extent
        assert standard is not None and compact is not None
        # the second map is clear of the first (truth included), on the same grid sections
        gap = compact[0] + offsets["compact"] - standard[1]
        assert gap >= 0.5 * view.grid.section
        assert offsets["compact"] % view.grid.section == pytest.approx(0.0, abs=1e-9)
        # each map's name above it
        for mode in (MapMode.STANDARD, MapMode.COMPACT):
            label = app.streamer.layers[mode].label
            box = app.streamer.layers[mode].view_extent
            assert label.visible and label.text == mode.value
            assert label.position[1] > box[3] and abs(label.position[0] - box[0]) <= 0.3
        # the view's own grid lies under both maps (the default view's grid hidden for it)
        content = view.content_extent()
        assert content is not None and content[1] >= compact[1] + offsets["compact"] - 1e-9
        plane = view.grid.scene._handle_from_node_name["/view/grid/plane"]  # (client-scoped)
        x0 = plane.position[0] - plane.width / 2
        x1 = plane.position[0] + plane.width / 2
        assert x0 <= content[0] and x1 >= content[1]
        assert not view._shadows["/grid"].visible
        # a pinned map beside: the grid reaches under it too, and it is named
        view.pin()
        wait(app)
        box = view.content_extent()
        pinned_x = offsets["compact"] + view.offsets()["pinned"] - offsets["compact"]
        assert box is not None and box[1] > compact[1] + offsets["compact"]
        plane = view.grid.scene._handle_from_node_name["/view/grid/plane"]
        assert plane.position[0] + plane.width / 2 >= box[1] and pinned_x > 0
        assert view.grid.scene._handle_from_node_name["/pinned/name"].text == "pinned standard"
        # the scale bar: one section, under the content's bottom-right corner
        bx0, bx1, by = view.grid.bar
        assert bx1 - bx0 == view.grid.section
        assert abs(bx1 - box[1]) <= view.grid.cell and by < box[2]


def test_sizes_and_grid_follow_the_extent_not_the_parameters(
    short_bag: Path, false_log: Path
) -> None:
    with running_app(short_bag) as app, client(app.server.get_port()):
        wait(app)
        view = _view(app)
        marker = app.streamer.marker
        assert marker == nice(app.streamer.span() * VERTEX_FRACTION)
        assert (view.grid.section, view.grid.cell) == (1.0, 0.1) == grid_spacing(3.2)
        app.type_param("delta", "8")
        wait(app)
        assert app.streamer.marker == marker  # δ = 8: the same dots (were 3 x larger)
        assert app.streamer.layers[MapMode.COMPACT].point_size == marker
    with (
        running_app(false_log, params=LOG_MAP_PARAMS, defaults=LOG_MAP_PARAMS) as app,
        client(app.server.get_port()),
    ):
        wait(app)
        view = _view(app)
        view.refresh()
        span = app.streamer.span()
        assert span > 30  # a building, not a maze
        assert app.streamer.marker == nice(span * VERTEX_FRACTION) >= 0.1
        assert view.grid.section >= 10 and view.grid.cell >= 1  # not a grey texture of 0.1 m
        assert f"grid: {view.grid.cell:g} m cells, {view.grid.section:g} m sections" in (
            view.legend_html.content
        )
        box = view.frame_box()
        assert box[1] - box[0] >= app.streamer.min_span == 20.0
