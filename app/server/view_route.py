"""A view's route (issue 26): two places clicked in the scene, the routes between them drawn.

A part of :class:`~app.server.view.ClientView` (:class:`RouteView`): the *route* button makes the
next two clicks the start and the goal; the page's route worker computes the routes on the shown
maps, the standard map's and the true shortest path (:mod:`app.server.routes`), and the view draws
them in this tab only and lists their lengths (the route panel,
:mod:`app.server.panels.route`). While the replay plays, the routes follow the maps.
"""

from __future__ import annotations

import math
import threading
import time
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
import viser
from numpy.typing import NDArray

from app.palette import MAP_COLORS
from app.server.panels.route import ROUTE_HELP
from app.server.routes import (
    OWN_WIDTH,
    ROUTE_CASING,
    ROUTE_Z,
    STANDARD_WIDTH,
    TRUE_ROUTE_COLOR,
    TRUE_WIDTH,
    Place,
    RoutePlan,
    message_html,
    nearest_map,
    plan_html,
)
from cogmap_core.cognitive_map import MapMode

if TYPE_CHECKING:
    from contextlib import AbstractContextManager

    from app.server.figures_worker import FiguresWorker
    from app.server.panels.layers import ViewState
    from app.server.replay import Replay
    from app.server.routes import RouteWorker
    from app.server.scene import SceneStreamer

#: While the replay plays, a route follows the maps at most this often (s).
ROUTE_FOLLOW_S = 3.0


class RouteHost(Protocol):
    """What a view's route uses of the page: the replay, the scene, the figures, the worker."""

    replay: Replay
    streamer: SceneStreamer
    scene_lock: AbstractContextManager[Any]
    figures: FiguresWorker
    routes: RouteWorker[Any]


class RouteView:
    """The route part of :class:`~app.server.view.ClientView` (module doc).

    The attributes below are the view's (``route_html``: its route panel's message), and so is
    ``offsets()``, where the shown maps are.
    """

    app: RouteHost
    client: viser.ClientHandle
    state: ViewState
    closed: bool
    route_html: viser.GuiHtmlHandle
    _lock: threading.RLock

    def _init_route(self) -> None:
        # which click comes next ("start", "goal" or None), the places clicked, the routes
        # computed for them (by the app's route worker) and their nodes
        self.route_stage: str | None = None
        self.route_places: tuple[Place, ...] = ()
        self.route_plan: RoutePlan | None = None
        self._route_nodes: list[viser.SceneNodeHandle] = []
        self._route_key: tuple[Any, ...] | None = None
        self._route_asked = -math.inf  # monotonic time the routes were last asked for

    def start_route(self) -> None:
        """The *route* button: the next two clicks in the scene are the start and the goal."""
        with self.app.scene_lock, self._lock:
            self._remove_route()
            self.route_stage = "start"
            self.route_places = ()
            self.route_plan = None
            self.route_html.content = message_html("Click the start in the scene.")

    def clear_route(self) -> None:
        """Forget the route (and a route being asked for)."""
        with self.app.scene_lock, self._lock:
            self._remove_route()
            self.route_stage = None
            self.route_places = ()
            self.route_plan = None
            self._route_key = None
            self.route_html.content = message_html(ROUTE_HELP)

    def route_click(self, point: NDArray[np.float64]) -> None:
        """A click at scene point ``point`` (x, y) while a route is being asked for.

        The place is on the shown map with the nearest vertex, in that map's frame. The first
        click is the start, the second the goal; the routes are then computed by the app's
        route worker (this callback only flags the view).
        """
        app = self.app
        with app.replay.lock:
            shown = self.state.shown
            offsets = self.offsets()
            snaps = {m: app.replay.session.maps[m].snapshot() for m in shown}
        place = nearest_map(point, {m: offsets[m.value] for m in shown}, snaps)
        with app.scene_lock, self._lock:
            if self.route_stage is None:
                return
            if place is None:
                self.route_html.content = message_html(
                    "There is no map to route on yet: play the replay first.", error=True
                )
                return
            x, y = place.xy
            where = f"({x:.2f}, {y:.2f}) m on the {place.mode.value} map"
            if self.route_stage == "start":
                self.route_places = (place,)
                self.route_stage = "goal"
                self.route_html.content = message_html(f"Start at {where}: click the goal.")
            else:
                self.route_places = (*self.route_places[:1], place)
                self.route_stage = None
                self.route_html.content = message_html(f"Goal at {where}: finding the routes …")
            self._draw_route(None)
        self._route_key = None
        self._route_asked = time.monotonic()
        app.routes.request(self)

    def route_modes(self) -> tuple[MapMode, ...]:
        """The maps a route is found on: the shown ones, and the standard map."""
        shown = self.state.shown
        return shown if MapMode.STANDARD in shown else (*shown, MapMode.STANDARD)

    def show_route(self, plan: RoutePlan) -> None:
        """Draw ``plan`` and list its lengths (unless the places changed meanwhile)."""
        with self.app.scene_lock, self._lock:
            if self.closed or self.route_places != (plan.start, plan.goal):
                return  # another route was asked for: its own plan follows
            self.route_plan = plan
            self._draw_route(plan)
            self.route_html.content = plan_html(plan, self.state.mode)

    def route_failed(self, places: tuple[Place, ...], problem: str) -> None:
        """Say on the page that the routes of ``places`` could not be computed."""
        with self.app.scene_lock, self._lock:
            if self.route_places == places:
                self.route_html.content = message_html(f"no route: {problem}", error=True)

    def _remove_route(self) -> None:
        for node in self._route_nodes:
            node.remove()
        self._route_nodes = []

    def _draw_route(self, plan: RoutePlan | None) -> None:
        """The routes (and the places clicked) on each shown map, in this tab only.

        On each shown map: the true shortest path (a wide grey band), on the first shown map the
        standard map's route (medium, blue) unless it is the standard map, and the map's own
        route (narrow, in its colour, on top), each with a dark casing; the start and the goal
        as dark dots with their names. Nodes are ``/map/<mode>/route/...``: they move with the
        map's frame (side by side).
        """
        self._remove_route()
        scene = self.client.scene
        shown = self.state.shown
        marker = self.app.streamer.marker
        with self.client.atomic():
            for k, mode in enumerate(shown):
                root = f"/map/{mode.value}/route"
                lines: list[tuple[str, NDArray[np.float64] | None, tuple[int, int, int],
                                  tuple[float, float]]] = []  # fmt: skip
                if plan is not None:
                    if plan.truth is not None:
                        truth = plan.points_on(plan.truth, mode)
                        lines.append(("truth", truth, TRUE_ROUTE_COLOR, TRUE_WIDTH))
                    standard = plan.leg(MapMode.STANDARD)
                    if k == 0 and mode is not MapMode.STANDARD and standard is not None:
                        points = plan.points_on(standard, mode)
                        lines.append(("standard", points, MAP_COLORS[MapMode.STANDARD],
                                      STANDARD_WIDTH))  # fmt: skip
                    own = plan.leg(mode)
                    if own is not None:
                        lines.append(("own", plan.points_on(own, mode), MAP_COLORS[mode],
                                      OWN_WIDTH))  # fmt: skip
                z = ROUTE_Z
                for name, points, colour, (fill, casing) in lines:
                    if points is None or points.shape[0] < 2:
                        continue
                    for part, width, rgb_ in (("casing", casing, ROUTE_CASING),
                                              ("fill", fill, colour)):  # fmt: skip
                        segments = np.zeros((points.shape[0] - 1, 2, 3), dtype=np.float32)
                        segments[:, 0, :2] = points[:-1]
                        segments[:, 1, :2] = points[1:]
                        segments[:, :, 2] = z
                        z += 0.001
                        self._route_nodes.append(
                            scene.add_line_segments(
                                f"{root}/{name}_{part}",
                                segments,
                                colors=rgb_,
                                thickness=width,
                                thickness_units="screen",
                            )
                        )
                places = self.route_places if plan is None else (plan.start, plan.goal)
                for label, place in zip(("start", "goal"), places, strict=False):
                    xy = (
                        plan.place_on(place, mode)
                        if plan is not None
                        else np.array(place.xy)
                        if place.mode is mode
                        else None
                    )
                    if xy is None:
                        continue
                    at = np.array([[xy[0], xy[1], ROUTE_Z + 0.01]], dtype=np.float32)
                    self._route_nodes.append(
                        scene.add_point_cloud(
                            f"{root}/{label}",
                            at,
                            colors=ROUTE_CASING,
                            point_size=2.2 * marker,
                            point_shape="circle",
                        )
                    )
                    self._route_nodes.append(
                        scene.add_label(
                            f"{root}/{label}_label",
                            label,
                            position=(float(xy[0]), float(xy[1]), ROUTE_Z + 0.01),
                            anchor="bottom-left",
                            font_screen_scale=1.2,
                        )
                    )

    def follow_route(self) -> None:
        """Ask for the routes again when the maps changed (rate-limited while playing).

        Called with the replay's lock held (from :meth:`refresh`).
        """
        if len(self.route_places) < 2 or self.route_stage is not None:
            return
        app = self.app
        maps = app.replay.session.maps
        key: tuple[Any, ...] = (self.state.shown, app.figures.version, app.replay.cursor)
        for mode in self.route_modes():
            cmap = maps[mode]
            key += (id(cmap), cmap.num_vertices, cmap.num_edges, len(cmap.optimizations))
        if key == self._route_key:
            return
        now = time.monotonic()
        if app.replay.playing and now - self._route_asked < ROUTE_FOLLOW_S:
            return
        self._route_key = key
        self._route_asked = now
        app.routes.request(self)
