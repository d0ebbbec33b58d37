"""Each viewer's own view: which map, side by side, layers, colours, camera, inspection, pin.

Parameters and playback are shared by everyone viewing a server; what a viewer *looks at* is
theirs. A :class:`ClientView` is made for every browser tab when it connects:

- its controls are client-scoped GUI elements placed in the page's shared folders (viser shows
  them to that tab only), checked by their own :class:`~app.server.validation.GuiGate`;
- the maps are streamed once for everyone (:mod:`app.server.scene`); a view shows, hides and
  places them with *client-scoped frames of the same names* (viser lets a client's node of a
  name shadow the shared one for that client only): ``/map/<mode>`` (shown? where?), its layer
  frames and colouring frames, ``/grid``;
- the camera frames what the view shows, left of the control panel, and follows the map as it
  grows until the viewer moves the camera;
- a click on the map selects the nearest vertex or edge and shows what is known about it;
- "pin" keeps a copy of the shown map (with its parameters and figures) drawn beside or under
  the live one, with a table comparing the two.

The view's panels (layers and view, inspect, route, pin and compare, its cluster log) are built
by :mod:`app.server.panels`; the view uses of the page only what :class:`ViewHost` lists.
"""

from __future__ import annotations

import math
import threading
import warnings
from dataclasses import replace
from typing import Any, Protocol

import numpy as np
import viser
from numpy.typing import NDArray

from app.palette import SELECTION_COLOR
from app.server.map_layer import LAYERS
from app.server.panels import PanelHandle, ViewFolders, set_content
from app.server.panels.compare import (
    COMPARE_HELP,
    PinnedMap,
    build_compare,
    compare_table,
    guard_compare,
    send_pinned,
)
from app.server.panels.inspect import INSPECT_HELP, Pick, build_inspect, guard_inspect, nearest_pick
from app.server.panels.layers import (
    ViewState,
    build_layers,
    guard_layers,
    legend_html,
    read_state,
)
from app.server.panels.live_figures import build_cluster_log, cluster_log_html, figure_texts
from app.server.panels.route import ROUTE_HELP, build_route, guard_route
from app.server.scene import Grid
from app.server.scene_style import COLOURINGS, Box, grid_spacing, span_of, union
from app.server.validation import GuiGate
from app.server.view_route import RouteHost, RouteView
from cogmap_core.cognitive_map import CognitiveMap, MapMode
from cogmap_core.map_graph import MapSnapshot

__all__ = ["PLAN_FOV", "ROUTE_HELP", "VIEW_FOV", "ClientView", "ViewHost"]


# A tab can close while its view is being updated; viser then warns that the message will not
# be delivered. That is expected here, not a problem worth a warning.
warnings.filterwarnings(
    "ignore", message=r"Queued a \w+ on a closed connection", category=UserWarning
)
#: Margin kept free around what the camera frames, as a share of the canvas's height (the axes
#: gizmo at the bottom left). The control panel is docked beside the canvas, not over it.
MARGIN = 0.07
#: The plan view (the default): the camera looks straight down, north (+y) up, from far away
#: through a narrow field of view -- viser has no orthographic camera, and at 3 degrees a
#: perspective camera draws the flat map at one scale to within 0.1 %.
PLAN_FOV = math.radians(3.0)
#: The 3-D view's field of view.
VIEW_FOV = math.radians(50.0)
#: A click selects what lies within this many pixels.
PICK_PX = 10.0


class ViewHost(RouteHost, Protocol):
    """What a tab's view uses of the page that made it (:class:`~app.server.app.CogmapApp`).

    The shared state it reads -- the server, the replay, the streamed scene and its lock, the
    maps' figures, the route worker (:class:`~app.server.view_route.RouteHost`) -- and the page's
    folders its panels go into; and the one thing it tells the page: that the views changed.
    """

    server: viser.ViserServer
    folders: ViewFolders

    def views_changed(self) -> None:
        """Stream what the views show (a view changed); the shown maps rebuild first."""


class ClientView(RouteView):
    """The view of one browser tab (module doc)."""

    # the panels' handles by the names scripts and tests use (each lives in its panel)
    mode_dropdown = PanelHandle("layers_panel")
    compare_checkbox = PanelHandle("layers_panel")
    compare_dropdown = PanelHandle("layers_panel")
    colouring_dropdown = PanelHandle("layers_panel")
    layer_checkboxes = PanelHandle("layers_panel")
    follow_checkbox = PanelHandle("layers_panel")
    top_button = PanelHandle("layers_panel")
    view3d_button = PanelHandle("layers_panel")
    legend_html = PanelHandle("layers_panel")
    inspect_html = PanelHandle("inspect_panel")
    clear_button = PanelHandle("inspect_panel")
    route_button = PanelHandle("route_panel")
    clear_route_button = PanelHandle("route_panel")
    route_html = PanelHandle("route_panel")
    pin_button = PanelHandle("compare_panel")
    pin_dropdown = PanelHandle("compare_panel")
    unpin_button = PanelHandle("compare_panel")
    compare_html = PanelHandle("compare_panel")

    def __init__(self, app: ViewHost, client: viser.ClientHandle) -> None:
        """Build the tab's controls and shadows, and frame its camera."""
        self.app = app
        self.client = client
        self.state = ViewState()
        self.pinned: PinnedMap | None = None
        self.pick: Pick | None = None
        self._lock = threading.RLock()
        self._shadows: dict[str, viser.FrameHandle] = {}
        self._shadow_state: dict[str, tuple[bool, float]] = {}
        self._pinned_nodes: list[viser.SceneNodeHandle] = []
        self._pinned_frame: viser.FrameHandle | None = None
        self._selection: list[viser.SceneNodeHandle] = []
        self._framed: tuple[float, float, float, float] | None = None
        self._camera_expected: NDArray[np.float64] | None = None
        self._camera_acknowledged = False
        self._log_key: tuple[Any, ...] | None = None
        self._compare_key: tuple[Any, ...] | None = None
        self._init_route()
        # set while this thread changes a control itself (its callback must not act on it); per
        # thread: viser runs viewers' callbacks on a pool, and a viewer's own change arriving
        # meanwhile on another thread must still count
        self._setting = threading.local()
        self.closed = False
        self.plan = True  # the plan view (else the 3-D view)
        self.grid = Grid(client.scene, "/view/grid")  # this tab's grid: under all it shows
        self._frame_box: Box | None = None
        self._build_gui()
        self._guard()
        self.client.scene.on_click()(self._on_click)
        self.client.camera.on_update(self._on_camera)
        self.apply(reframe=True)

    # ================================================================== controls
    def _build_gui(self) -> None:
        gui = self.client.gui
        folders = self.app.folders
        s = self.state
        self.layers_panel = build_layers(gui, folders.view, s)
        self.inspect_panel = build_inspect(gui, folders.inspect)
        self.route_panel = build_route(gui, folders.route)
        self.compare_panel = build_compare(gui, folders.compare, s.pin_display)
        self.log_html = build_cluster_log(gui, folders.clusters)
        for handle in (*self.layers_panel.inputs(), self.compare_panel.pin_dropdown):
            handle.on_update(lambda _: self._read_controls())
        self.top_button.on_click(lambda _: self.frame_camera(top=True))
        self.view3d_button.on_click(lambda _: self.frame_camera(top=False))
        self.clear_button.on_click(lambda _: self.select(None))
        self.route_button.on_click(lambda _: self.start_route())
        self.clear_route_button.on_click(lambda _: self.clear_route())
        self.pin_button.on_click(lambda _: self.pin())
        self.unpin_button.on_click(lambda _: self.unpin())

    def _guard(self) -> None:
        gate = self.gate = GuiGate(self.app.server, gui=self.client.gui)
        guard_layers(gate, self.layers_panel)
        guard_inspect(gate, self.inspect_panel)
        guard_route(gate, self.route_panel)
        guard_compare(gate, self.compare_panel)

    def _read_controls(self) -> None:
        if getattr(self._setting, "on", False):
            return
        old = self.state
        s = read_state(self.layers_panel, self.pin_dropdown.value)
        self.state = s  # one assignment: other threads see the old state or the new, whole
        refollow = s.follow and not old.follow
        moved = (old.shown, old.pin_display) != (s.shown, s.pin_display)
        self.apply(reframe=refollow or (s.follow and moved))

    def set_mode(self, mode: MapMode, compare: MapMode | None = None) -> None:
        """Show ``mode`` (and ``compare`` beside it); as if the viewer chose it."""
        self._setting.on = True
        try:
            self.mode_dropdown.value = mode.value
            self.compare_checkbox.value = compare is not None
            if compare is not None:
                self.compare_dropdown.value = compare.value
        finally:
            self._setting.on = False
        self._read_controls()

    # ================================================================== scene
    def offsets(self) -> dict[str, float]:
        """Shift along x (m) of each shown map, and of the pinned map (``"pinned"``)."""
        shown = self.state.shown
        streamer = self.app.streamer
        step = streamer.side_by_side_step(shown)
        out = {mode.value: step * k for k, mode in enumerate(shown)}
        pinned = self.pinned  # read once: another thread may unpin meanwhile
        if pinned is not None:
            if self.state.pin_display == "under":
                out["pinned"] = 0.0
            else:
                section, _ = grid_spacing(streamer.span())
                width = _extent_width(pinned.snapshot) + 0.5 * section
                out["pinned"] = step * (len(shown) - 1) + max(
                    step, math.ceil(width / section) * section
                )
        return out

    def _place(self) -> None:
        """Shift the shown maps (and the pinned one) to where :meth:`offsets` has them now."""
        offsets = self.offsets()
        with self.client.atomic():
            for mode in self.state.shown:
                self._shadow(f"/map/{mode.value}", True, offsets[mode.value])
            if self._pinned_frame is not None:
                position = (offsets.get("pinned", 0.0), 0.0, -0.002)
                if tuple(self._pinned_frame.position) != position:
                    self._pinned_frame.position = position

    def update_grid(self) -> None:
        """Lay this tab's grid under everything it shows (maps side by side, the pinned one)."""
        content = self.content_extent()
        self._frame_box = self.grid.cover(content, self.app.streamer.span())
        visible = self.state.layers["grid"]
        if self.grid.frame.visible != visible:
            self.grid.frame.visible = visible

    def apply(self, reframe: bool = False) -> None:
        """Bring the tab's shadows, legend and the streamer's needs up to date."""
        if self.closed:
            return
        with self.app.replay.lock, self.app.scene_lock, self._lock:
            s = self.state
            offsets = self.offsets()
            wanted: dict[str, tuple[bool, float]] = {}
            for mode in MapMode:
                root = f"/map/{mode.value}"
                wanted[root] = (mode in s.shown, offsets.get(mode.value, 0.0))
                for layer in LAYERS:
                    wanted[f"{root}/{layer}"] = (s.layers[layer], 0.0)
                for kind in ("sequential", "loop"):
                    for colouring in COLOURINGS:
                        wanted[f"{root}/{kind}/{colouring}"] = (colouring == s.colouring, 0.0)
            wanted["/grid"] = (False, 0.0)  # the default view's grid: this tab has its own
            with self.client.atomic():
                for name, (visible, x) in wanted.items():
                    self._shadow(name, visible, x)
                if self._pinned_frame is not None:
                    self._pinned_frame.position = (offsets.get("pinned", 0.0), 0.0, -0.002)
                self.update_grid()
            self.legend_html.content = self._legend()
            self.app.views_changed()
            self._log_key = None
            self._compare_key = None
        self.refresh()
        if reframe or (s.follow and self._framed is None):
            self.frame_camera()

    def _shadow(self, name: str, visible: bool, x: float) -> None:
        if self._shadow_state.get(name) == (visible, x):
            return
        handle = self._shadows.get(name)
        if handle is None:
            self._shadows[name] = self.client.scene.add_frame(
                name, show_axes=False, visible=visible, position=(x, 0.0, 0.0)
            )
        else:
            if handle.visible != visible:
                handle.visible = visible
            if tuple(handle.position) != (x, 0.0, 0.0):
                handle.position = (x, 0.0, 0.0)
        self._shadow_state[name] = (visible, x)

    def _legend(self) -> str:
        pinned = self.pinned  # read once: another thread may unpin meanwhile
        return legend_html(
            self.state,
            self.app.replay.session.evaluation,
            (self.grid.cell, self.grid.section),
            None if pinned is None else pinned.mode,
        )

    # ================================================================== camera
    def content_extent(self) -> Box | None:
        """What the view shows (maps with their truth and shifts, and the pinned map beside)."""
        offsets = self.offsets()
        shown = self.state.shown
        box = self.app.streamer.extent(shown, [offsets[m.value] for m in shown])
        pinned = self.pinned  # read once: another thread may unpin meanwhile
        if pinned is not None and pinned.snapshot.poses.shape[0]:
            p = pinned.snapshot.poses
            x = offsets.get("pinned", 0.0)
            pbox = (
                float(p[:, 0].min()) + x,
                float(p[:, 0].max()) + x,
                float(p[:, 1].min()),
                float(p[:, 1].max()),
            )
            box = union(box, pbox)
        return box

    def frame_box(self) -> Box:
        """What the camera frames: the content with the scale bar and the names, or more.

        Never less than the streamer's ``min_span`` across: the first vertices of a map are
        not framed as if they were the whole map.
        """
        box = self._frame_box or self.grid.cover(self.content_extent(), self.app.streamer.span())
        if box is None:
            box = (-0.5, 3.5, -0.5, 2.5)
        x0, x1, y0, y1 = box
        least = self.app.streamer.min_span
        if x1 - x0 < least:
            x0, x1 = (x0 + x1 - least) / 2, (x0 + x1 + least) / 2
        if y1 - y0 < least * 0.6:
            y0, y1 = (y0 + y1 - least * 0.6) / 2, (y0 + y1 + least * 0.6) / 2
        return (x0, x1, y0, y1)

    def frame_camera(self, top: bool | None = None) -> None:
        """Point the camera at what the view shows, left of the control panel.

        ``top``: the plan view (straight down, north up, a narrow field of view: as good as
        orthographic); False: the 3-D view; None: the view in use.
        """
        with self._lock:  # (see follow)
            if top is not None:
                self.plan = top
            top = self.plan
            self.update_grid()
            box = self.frame_box()
            camera = self.client.camera
            width = camera.image_width or 1280
            height = camera.image_height or 800
            fov = PLAN_FOV if top else VIEW_FOV
            # (the canvas's size in its own pixels, whatever their size on the screen: only the
            # ratio of the two matters)
            margin = MARGIN * height
            usable_w = max(0.5 * width, width - 2 * margin)
            usable_h = max(0.5 * height, height - 2 * margin)
            x0, x1, y0, y1 = box
            w, h = max(x1 - x0, 0.5), max(y1 - y0, 0.5)
            tan = math.tan(fov / 2.0)
            # the vertical field spans `height` pixels at 2 d tan(fov / 2) metres
            distance = max(h * height / usable_h, w * height / usable_w) / (2.0 * tan)
            cx = (x0 + x1) / 2
            cy = (y0 + y1) / 2
            if top:
                position = (cx, cy - 1e-4 * distance, distance)
                near, far = 0.2 * distance, 5.0 * distance
            else:
                position = (cx + 0.35 * distance, cy - 0.75 * distance, 0.65 * distance)
                near, far = max(1e-3, 1e-3 * distance), 50.0 * distance
            self._camera_expected = np.array(position)
            self._camera_acknowledged = False
            self._framed = self.content_extent()
            with self.client.atomic():
                if camera.max_orbit_distance < 4.0 * distance:
                    camera.max_orbit_distance = 4.0 * distance
                camera.fov = fov
                camera.near = near
                camera.far = far
                camera.up_direction = (0.0, 0.0, 1.0)
                camera.position = position
                camera.look_at = (cx, cy, 0.0)

    def follow(self) -> None:
        """Re-frame when the map grew out of the framed box or shrank to a fraction of it.

        (By 3 % of the framed extent, at least of the streamer's ``min_span``: a map that grows
        a little at a time is framed again now and then, not at every vertex.)

        Runs under the view's own lock: the replay's worker and the figures thread both call it,
        and two framings at once would each take the other's camera pose for the viewer's move.
        """
        with self._lock:
            if not self.state.follow:
                return
            extent = self.content_extent()
            framed = self._framed
            if extent is None:
                return
            if framed is not None:
                slack = 0.03 * max(span_of(framed), self.app.streamer.min_span)
                grew = (
                    extent[0] < framed[0] - slack
                    or extent[1] > framed[1] + slack
                    or extent[2] < framed[2] - slack
                    or extent[3] > framed[3] + slack
                )
                area = (extent[1] - extent[0]) * (extent[3] - extent[2])
                framed_area = (framed[1] - framed[0]) * (framed[3] - framed[2])
                if not grew and area >= 0.4 * framed_area:
                    return
            self.frame_camera()  # (the lock is re-entered; the view in use)

    def _on_camera(self, camera: viser.CameraHandle) -> None:
        """A camera report: the viewer moved the camera (not the view): stop following the map.

        Reports before the browser shows the pose the view set are its way there; after it,
        a different pose is the viewer's doing.
        """
        expected = self._camera_expected
        if expected is None or not self.state.follow:
            return
        position = np.asarray(camera.position, dtype=float)
        close = bool(
            np.allclose(position, expected, rtol=1e-3, atol=1e-3 * (1 + np.abs(expected).max()))
        )
        if not self._camera_acknowledged:
            self._camera_acknowledged = close
            return
        if close:
            return
        self.state = replace(self.state, follow=False)  # replaced whole, as _read_controls does
        self._setting.on = True
        try:
            self.follow_checkbox.value = False
        finally:
            self._setting.on = False

    # ================================================================== per-update content
    def refresh(self) -> None:
        """What follows the maps: cluster log, comparison, camera (the app rate-limits it)."""
        if self.closed:
            return
        app = self.app
        with app.replay.lock:
            cmap = app.replay.session.maps[self.state.mode]
            key = (id(cmap), len(cmap.optimizations), len(cmap.clusters), cmap.num_loop_edges,
                   id(app.replay.last_completed_rebuild()))  # fmt: skip
            if key != self._log_key:
                self._log_key = key
                self.log_html.content = cluster_log_html(
                    self.state.mode, cmap, app.replay.last_completed_rebuild()
                )
            if self.pinned is not None:
                ckey = (id(cmap), cmap.num_vertices, cmap.num_edges, len(cmap.optimizations),
                        app.figures.version, self.state.mode)  # fmt: skip
                if ckey != self._compare_key:
                    self._compare_key = ckey
                    self.compare_html.content = self._compare_table(cmap)
            self.follow_route()
            with self._lock:
                self._place()  # the maps grow: side by side they stay clear of each other
                self.update_grid()
                set_content(self.legend_html, self._legend())
        self.follow()

    # ================================================================== inspect
    def _on_click(self, event: Any) -> None:
        origin = np.asarray(event.ray_origin, dtype=float)
        direction = np.asarray(event.ray_direction, dtype=float)
        if abs(direction[2]) < 1e-9:
            return
        t = -origin[2] / direction[2]
        if t <= 0:
            return
        point = origin + t * direction
        camera = self.client.camera
        height = camera.image_height or 800
        fov = camera.fov if camera.fov > 0 else math.radians(50.0)
        per_pixel = 2.0 * t * float(np.linalg.norm(direction)) * math.tan(fov / 2.0) / height
        if self.route_stage is not None:  # a route's start or goal, not a pick
            self.route_click(point[:2])
            return
        self.select(self.pick_at(point[:2], PICK_PX * per_pixel))

    def pick_at(self, point: NDArray[np.float64], tolerance: float) -> Pick | None:
        """The vertex or edge of the shown maps nearest to ``point`` (world x, y)."""
        app = self.app
        offsets = self.offsets()
        best = None
        with app.replay.lock:
            for mode in self.state.shown:
                local = point - np.array([offsets[mode.value], 0.0])
                figures = app.figures.get(mode)
                found = nearest_pick(
                    app.replay.session.maps[mode],
                    mode,
                    local,
                    tolerance,
                    frozenset() if figures is None else figures.false_edges,
                    app.streamer.layers[mode].point_size / 2,
                )
                if found is not None and (best is None or found[0] < best[0]):
                    best = found
        return None if best is None else best[1]

    def select(self, pick: Pick | None) -> None:
        """Show ``pick`` (None: clear the selection)."""
        with self.app.replay.lock, self.app.scene_lock, self._lock:
            for node in self._selection:
                node.remove()
            self._selection = []
            self.pick = pick
            if pick is None:
                self.inspect_html.content = INSPECT_HELP
                return
            self.inspect_html.content = pick.html
            name = f"/map/{pick.mode.value}/selection"
            seg = np.zeros((1, 2, 3), dtype=np.float32)
            seg[0, :, :2] = pick.segment
            seg[0, :, 2] = 0.012
            scene = self.client.scene
            if pick.kind == "edge":
                self._selection.append(
                    scene.add_line_segments(
                        name, seg, colors=SELECTION_COLOR, thickness=9.0, thickness_units="screen"
                    )
                )
            else:
                self._selection.append(
                    scene.add_point_cloud(
                        name,
                        seg[0, :1],
                        colors=SELECTION_COLOR,
                        point_size=1.8 * self.app.streamer.marker,
                        point_shape="circle",
                    )
                )
            # what was picked, written beside it (the Inspect panel has the details)
            self._selection.append(
                scene.add_label(
                    f"{name}_label",
                    pick.summary,
                    position=(float(seg[0, 1, 0]), float(seg[0, 1, 1]), 0.012),
                    anchor="bottom-left",
                    font_screen_scale=1.2,
                )
            )

    # ================================================================== pin and compare
    def pin(self) -> None:
        """Keep a copy of the shown map to compare with."""
        app = self.app
        mode = self.state.mode
        with app.replay.lock:
            cmap = app.replay.session.maps[mode]
            snapshot = cmap.snapshot()
            params = app.replay.params
            stats = figure_texts(cmap, app.figures.get(mode))
            frames = app.replay.cursor
            data_time = app.replay.frame_time
        bag = app.replay.bag_path.name if app.replay.bag_path else "–"
        self.unpin(quiet=True)
        with app.replay.lock, app.scene_lock, self._lock:
            self.pinned = PinnedMap(mode, params, snapshot, stats, frames, data_time, bag)
            self._send_pinned()
        self.apply(reframe=self.state.follow)

    def unpin(self, quiet: bool = False) -> None:
        """Drop the pinned map."""
        with self.app.replay.lock, self.app.scene_lock, self._lock:
            for node in self._pinned_nodes:
                node.remove()
            self._pinned_nodes = []
            if self._pinned_frame is not None:
                self._pinned_frame.remove()
                self._pinned_frame = None
            self.pinned = None
            self.compare_html.content = COMPARE_HELP
        if not quiet:
            self.apply()

    def _send_pinned(self) -> None:
        assert self.pinned is not None
        self._pinned_frame, self._pinned_nodes = send_pinned(
            self.client.scene, self.pinned, self.app.streamer.marker, self.grid.section
        )

    def _compare_table(self, cmap: CognitiveMap) -> str:
        pinned = self.pinned
        assert pinned is not None
        app = self.app
        mode = self.state.mode
        live = figure_texts(cmap, app.figures.get(mode))
        judging = app.replay.session.evaluation
        return compare_table(pinned, mode, app.replay.params, live, judging)

    def close(self) -> None:
        """The tab went away."""
        self.closed = True


def _extent_width(snap: MapSnapshot) -> float:
    if snap.poses.shape[0] == 0:
        return 1.0
    return float(snap.poses[:, 0].max() - snap.poses[:, 0].min())
