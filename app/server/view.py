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
"""

from __future__ import annotations

import html
import math
import threading
import time
import warnings
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
import viser
from numpy.typing import NDArray

from app.server.figures import FalseEdges, false_link_label, layout_radius_label
from app.server.map_layer import LAYERS
from app.server.params import ALL_SLIDERS, format_value
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
from app.server.scene import (
    FALSE_LOOP_COLOR,
    GROUND_TRUTH_COLOR,
    MAP_COLORS,
    ODOMETRY_COLOR,
    PINNED_COLOR,
    SELECTION_COLOR,
    Grid,
    cluster_color,
)
from app.server.scene_style import (
    COLOURINGS,
    ERROR_RAMP_CSS,
    ERROR_SCALE_MAX,
    TIME_RAMP_CSS,
    Box,
    edge_error,
    edge_segments,
    grid_spacing,
    span_of,
    union,
)
from app.server.validation import GuiGate, boolean, choice, click
from cogmap_core.cognitive_map import CognitiveMap, EdgeKind, MapMode
from cogmap_core.config import MapParams
from cogmap_core.map_graph import MapSnapshot

if TYPE_CHECKING:
    from contextlib import AbstractContextManager

    from app.server.replay import Replay
    from app.server.routes import RouteWorker
    from app.server.scene import SceneStreamer

MODE_NAMES: tuple[str, ...] = tuple(m.value for m in MapMode)
COLOURING_LABELS: dict[str, str] = {
    "cluster": "loop closures by cluster",
    "time": "time",
    "error": "error (residual)",
}
#: Layer checkboxes (labels short enough for one line of the panel's label column).
LAYER_LABELS: dict[str, str] = {
    "vertices": "vertices",
    "sequential": "sequential",
    "loop": "loop closures",
    "false_loops": "false loops",
    "truth": "ground truth",
    "odometry": "odometry",
    "grid": "metric grid",
}
PIN_DISPLAYS: tuple[str, ...] = ("beside", "under")

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
#: What the route panel says before a route is asked for.
ROUTE_HELP = (
    "Click route, then the start and the goal in the scene: the shortest route on the shown "
    "map is drawn, with the standard map's and the true shortest path, their lengths compared "
    "here."
)
#: While the replay plays, a route follows the maps at most this often (s).
ROUTE_FOLLOW_S = 3.0


def rgb(color: tuple[int, int, int]) -> str:
    """CSS colour."""
    return f"rgb({color[0]},{color[1]},{color[2]})"


def swatch(color: tuple[int, int, int]) -> str:
    """A small coloured square (legends)."""
    return f'<span class="cogmap-swatch" style="background:{rgb(color)}"></span>'


@dataclass(frozen=True)
class ViewState:
    """What one viewer looks at."""

    mode: MapMode = MapMode.COMPACT
    compare: bool = False
    compare_mode: MapMode = MapMode.STANDARD
    colouring: str = "cluster"
    layers: dict[str, bool] = field(
        default_factory=lambda: {
            "vertices": True,
            "sequential": True,
            "loop": True,
            "false_loops": True,
            "truth": True,
            "odometry": False,
            "grid": True,
        }
    )
    follow: bool = True
    pin_display: str = "beside"

    @property
    def shown(self) -> tuple[MapMode, ...]:
        """The displayed map and, side by side, the compared one."""
        if self.compare and self.compare_mode is not self.mode:
            return (self.mode, self.compare_mode)
        return (self.mode,)


@dataclass
class PinnedMap:
    """A copy of a map kept to compare with the live one."""

    mode: MapMode
    params: MapParams
    snapshot: MapSnapshot
    stats: dict[str, str]
    frames: int
    data_time: float
    bag: str


@dataclass(frozen=True, slots=True)
class Pick:
    """What a click selected: a vertex or an edge of a shown map."""

    mode: MapMode
    kind: str  # "vertex" or "edge"
    index: int  # into the snapshot's vertices or edges
    html: str
    segment: NDArray[np.float64]  # (2, 2) the edge's ends, or the vertex twice
    summary: str = ""  # one line, written beside it in the scene


class ViewHost(Protocol):
    """What a tab's view uses of the app that made it (:class:`~app.server.app.CogmapApp`).

    The shared state it reads (the server, the replay, the streamed scene and its lock, the
    route worker), the page's shared folders its controls go into, and the four things it asks
    of the app: that the views changed, a pick on the maps, a map's figures, a cluster log.
    """

    server: viser.ViserServer
    replay: Replay
    streamer: SceneStreamer
    scene_lock: AbstractContextManager[Any]
    stats_version: int
    routes: RouteWorker[ClientView]
    view_folder: viser.GuiFolderHandle
    inspect_folder: viser.GuiFolderHandle
    route_folder: viser.GuiFolderHandle
    compare_folder: viser.GuiFolderHandle
    clusters_folder: viser.GuiFolderHandle

    def views_changed(self) -> None:
        """Stream what the views show (a view changed); the shown maps rebuild first."""

    def pick(self, view: ClientView, point: NDArray[np.float64], tolerance: float) -> Pick | None:
        """The vertex or edge of the view's maps nearest to ``point`` (world x, y)."""

    def map_figures(self, mode: MapMode, cmap: CognitiveMap) -> dict[str, str]:
        """A map's figures as the page writes them."""

    def cluster_log_html(self, mode: MapMode, cmap: CognitiveMap) -> str:
        """The cluster colour legend and the optimisation log of one map (a view's)."""


class ClientView:
    """The view of one browser tab (module doc)."""

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
        # the route (issue 26): which click comes next ("start", "goal" or None), the places
        # clicked, the routes computed for them (by the app's route worker) and their nodes
        self.route_stage: str | None = None
        self.route_places: tuple[Place, ...] = ()
        self.route_plan: RoutePlan | None = None
        self._route_nodes: list[viser.SceneNodeHandle] = []
        self._route_key: tuple[Any, ...] | None = None
        self._route_asked = -math.inf  # monotonic time the routes were last asked for
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
        app = self.app
        s = self.state
        with app.view_folder:
            self.mode_dropdown = gui.add_dropdown("map", MODE_NAMES, initial_value=s.mode.value)
            self.compare_checkbox = gui.add_checkbox("side by side", s.compare)
            self.compare_dropdown = gui.add_dropdown(
                "compare with", MODE_NAMES, initial_value=s.compare_mode.value
            )
            self.colouring_dropdown = gui.add_dropdown(
                "colour edges by",
                tuple(COLOURING_LABELS.values()),
                initial_value=COLOURING_LABELS["cluster"],
            )
            with gui.add_folder("Layers", expand_by_default=False):
                self.layer_checkboxes = {
                    name: gui.add_checkbox(label, s.layers[name])
                    for name, label in LAYER_LABELS.items()
                }
            self.follow_checkbox = gui.add_checkbox(
                "follow the map", s.follow, hint="re-frame the camera as the map grows"
            )
            self.top_button = gui.add_button("plan view", icon=viser.Icon.MAP_2)
            self.view3d_button = gui.add_button("3-D view", icon=viser.Icon.VIEW_360)
            self.legend_html = gui.add_html("")
        with app.inspect_folder:
            self.inspect_html = gui.add_html(
                '<div class="cogmap-note" id="cogmap-inspect">Click a vertex or an edge of '
                "the map to see what it is.</div>"
            )
            self.clear_button = gui.add_button("clear selection", icon=viser.Icon.X)
        with app.route_folder:
            self.route_button = gui.add_button(
                "route", icon=viser.Icon.ROUTE, hint="then click the start and the goal"
            )
            self.clear_route_button = gui.add_button("clear route", icon=viser.Icon.ROUTE_OFF)
            self.route_html = gui.add_html(message_html(ROUTE_HELP))
        with app.compare_folder:
            self.pin_button = gui.add_button("pin the shown map", icon=viser.Icon.PIN)
            self.pin_dropdown = gui.add_dropdown(
                "pinned map", PIN_DISPLAYS, initial_value=s.pin_display
            )
            self.unpin_button = gui.add_button("unpin", icon=viser.Icon.PINNED_OFF)
            self.compare_html = gui.add_html(
                '<div class="cogmap-note" id="cogmap-compare">Pin the shown map, change the '
                "parameters, and compare the two here and in the scene.</div>"
            )
        with app.clusters_folder:
            self.log_html = gui.add_html("")
        for handle in (
            self.mode_dropdown,
            self.compare_checkbox,
            self.compare_dropdown,
            self.colouring_dropdown,
            self.follow_checkbox,
            self.pin_dropdown,
            *self.layer_checkboxes.values(),
        ):
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
        gate.guard(self.mode_dropdown, choice(MODE_NAMES))
        gate.guard(self.compare_dropdown, choice(MODE_NAMES))
        gate.guard(self.colouring_dropdown, choice(tuple(COLOURING_LABELS.values())))
        gate.guard(self.pin_dropdown, choice(PIN_DISPLAYS))
        checkboxes = (self.compare_checkbox, self.follow_checkbox, *self.layer_checkboxes.values())
        for handle in checkboxes:
            gate.guard(handle, boolean())
        for button in (
            self.top_button,
            self.view3d_button,
            self.clear_button,
            self.pin_button,
            self.unpin_button,
            self.route_button,
            self.clear_route_button,
        ):
            gate.guard(button, click())

    def _read_controls(self) -> None:
        if getattr(self._setting, "on", False):
            return
        old = self.state
        labels = {v: k for k, v in COLOURING_LABELS.items()}
        s = ViewState(
            mode=MapMode(self.mode_dropdown.value),
            compare=bool(self.compare_checkbox.value),
            compare_mode=MapMode(self.compare_dropdown.value),
            colouring=labels.get(self.colouring_dropdown.value, "cluster"),
            layers={name: bool(box.value) for name, box in self.layer_checkboxes.items()},
            follow=bool(self.follow_checkbox.value),
            pin_display=self.pin_dropdown.value,
        )
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
        s = self.state
        parts = [
            " ".join(f"{swatch(MAP_COLORS[m])}{m.value} vertices" for m in s.shown),
        ]
        if s.colouring == "cluster":
            parts.append(
                "sequential edges in their map's colour · loop-closure edges coloured by "
                "cluster (see <i>Clusters &amp; optimisations</i>)"
            )
        elif s.colouring == "time":
            parts.append(
                f'edges by creation time: 0 s <span class="cogmap-ramp" '
                f'style="background:{TIME_RAMP_CSS}"></span> end of the data'
            )
        else:
            parts.append(
                f'edges by error (whitened residual ‖S r‖): 0 <span class="cogmap-ramp" '
                f'style="background:{ERROR_RAMP_CSS}"></span> ≥ {ERROR_SCALE_MAX:g} σ'
            )
        parts.append(
            f"{swatch(FALSE_LOOP_COLOR)}loop closures the ground truth calls false "
            f"({false_link_label(self.app.replay.session.evaluation)})"
        )
        parts.append(
            f"{swatch(GROUND_TRUTH_COLOR)}ground truth, aligned to each map by the rigid "
            "transform of the ATE (least squares over the vertices)"
        )
        if s.layers["odometry"]:
            parts.append(f"{swatch(ODOMETRY_COLOR)}dead-reckoned odometry (the map's frame)")
        if s.layers["grid"]:
            g = self.grid
            parts.append(
                f"grid: {g.cell:g} m cells, {g.section:g} m sections (scale bar: {g.section:g} m, "
                "bottom right); each map's name above it"
            )
        parts.append(f"{swatch((15, 15, 15))}robot")
        pinned = self.pinned  # read once: another thread may unpin meanwhile
        if pinned is not None:
            parts.append(f"{swatch(PINNED_COLOR)}pinned {pinned.mode.value} map ({s.pin_display})")
        return '<div class="cogmap-note" id="cogmap-legend">' + "<br>".join(parts) + "</div>"

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
                self.log_html.content = app.cluster_log_html(self.state.mode, cmap)
            if self.pinned is not None:
                ckey = (id(cmap), cmap.num_vertices, cmap.num_edges, len(cmap.optimizations),
                        app.stats_version, self.state.mode)  # fmt: skip
                if ckey != self._compare_key:
                    self._compare_key = ckey
                    self.compare_html.content = self._compare_table(cmap)
            self.follow_route()
            with self._lock:
                self._place()  # the maps grow: side by side they stay clear of each other
                self.update_grid()
                legend = self._legend()
                if self.legend_html.content != legend:
                    self.legend_html.content = legend
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
        self.select(self.app.pick(self, point[:2], PICK_PX * per_pixel))

    # ================================================================== route (issue 26)
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
        key: tuple[Any, ...] = (self.state.shown, app.stats_version, app.replay.cursor)
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

    def select(self, pick: Pick | None) -> None:
        """Show ``pick`` (None: clear the selection)."""
        with self.app.replay.lock, self.app.scene_lock, self._lock:
            for node in self._selection:
                node.remove()
            self._selection = []
            self.pick = pick
            if pick is None:
                self.inspect_html.content = (
                    '<div class="cogmap-note" id="cogmap-inspect">Click a vertex or an edge of '
                    "the map to see what it is.</div>"
                )
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
            stats = app.map_figures(mode, cmap)
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
            self.compare_html.content = (
                '<div class="cogmap-note" id="cogmap-compare">Pin the shown map, change the '
                "parameters, and compare the two here and in the scene.</div>"
            )
        if not quiet:
            self.apply()

    def _send_pinned(self) -> None:
        assert self.pinned is not None
        snap = self.pinned.snapshot
        scene = self.client.scene
        self._pinned_frame = scene.add_frame("/pinned", show_axes=False)
        n = snap.vertex_ids.shape[0]
        points = np.zeros((n, 3), dtype=np.float32)
        points[:, :2] = snap.poses[:, :2]
        if n:
            self._pinned_nodes.append(
                scene.add_point_cloud(
                    "/pinned/vertices",
                    points,
                    colors=PINNED_COLOR,
                    point_size=self.app.streamer.marker,
                    point_shape="circle",
                    point_shading="flat",
                )
            )
            top_left = (float(points[:, 0].min()), float(points[:, 1].max()))
            self._pinned_nodes.append(
                scene.add_label(
                    "/pinned/name",
                    f"pinned {self.pinned.mode.value.replace('_', ' ')}",
                    position=(top_left[0], top_left[1] + 0.06 * self.grid.section * 4, 0.009),
                    anchor="bottom-left",
                    font_screen_scale=1.25,
                )
            )
        if snap.edge_from.shape[0]:
            loop = snap.edge_kind == EdgeKind.LOOP_CLOSURE
            colors = np.where(loop[:, None], (40, 90, 130), PINNED_COLOR).astype(np.uint8)
            self._pinned_nodes.append(
                scene.add_line_segments(
                    "/pinned/edges",
                    edge_segments(snap),
                    colors=np.repeat(colors[:, None, :], 2, axis=1),
                    thickness=2.0,
                    thickness_units="screen",
                )
            )

    def _compare_table(self, cmap: CognitiveMap) -> str:
        pinned = self.pinned
        assert pinned is not None
        app = self.app
        live_params = app.replay.params
        live = app.map_figures(self.state.mode, cmap)
        rows = []
        for spec in ALL_SLIDERS:
            a = getattr(live_params, spec.name)
            b = getattr(pinned.params, spec.name)
            cls = ' class="cogmap-diff"' if a != b else ""
            rows.append(
                f"<tr><td>{html.escape(spec.label)}</td><td{cls}>{format_value(a)}</td>"
                f"<td{cls}>{format_value(b)}</td></tr>"
            )
        rows.append('<tr class="cogmap-section"><td colspan="3">figures</td></tr>')
        radius = layout_radius_label(self.app.replay.session.evaluation)
        for key, label in (
            ("vertices", "vertices"),
            ("edges", "edges"),
            ("loops", "loop-closure edges"),
            ("ate", "ATE (m)"),
            ("completeness", f"completeness ({radius})"),
            ("correctness", f"correctness ({radius})"),
        ):
            rows.append(
                f'<tr><td>{label}</td><td id="cogmap-compare-live-{key}">{live[key]}</td>'
                f'<td id="cogmap-compare-pinned-{key}">{pinned.stats[key]}</td></tr>'
            )
        t = pinned.data_time
        when = "–" if math.isnan(t) else f"{t:.0f} s"
        return (
            '<table class="cogmap-table" id="cogmap-compare">'
            f"<thead><tr><th></th><th>live {self.state.mode.value}</th>"
            f"<th>pinned {pinned.mode.value}</th></tr></thead><tbody>"
            + "".join(rows)
            + "</tbody></table>"
            f'<div class="cogmap-note">pinned at {when} of {html.escape(pinned.bag)} '
            f"({pinned.frames} frames); differing parameters in bold</div>"
        )

    def close(self) -> None:
        """The tab went away."""
        self.closed = True


def _extent_width(snap: MapSnapshot) -> float:
    if snap.poses.shape[0] == 0:
        return 1.0
    return float(snap.poses[:, 0].max() - snap.poses[:, 0].min())


def describe_vertex(cmap: CognitiveMap, snap: MapSnapshot, index: int) -> str:
    """What the page says about vertex ``index`` of ``snap``."""
    vid = int(snap.vertex_ids[index])
    x, y, theta = snap.poses[index]
    graph = cmap.graph
    degree = len(graph.adjacency[vid]) if vid < len(graph.adjacency) else 0
    loops = int(
        np.count_nonzero(
            (snap.edge_kind == EdgeKind.LOOP_CLOSURE)
            & ((snap.edge_from == vid) | (snap.edge_to == vid))
        )
    )
    rows = [
        ("map", cmap.mode.value),
        ("vertex id", str(vid)),
        ("created at", f"{snap.vertex_time[index]:.2f} s"),
        ("pose", f"x {x:.3f} m, y {y:.3f} m, θ {math.degrees(theta):.1f}°"),
        ("view template", f"#{int(snap.vertex_view[index])}"),
        ("edges", f"{degree} ({loops} loop closure{'s' if loops != 1 else ''})"),
    ]
    return _info_table("vertex", rows)


def describe_edge(
    cmap: CognitiveMap, snap: MapSnapshot, index: int, false_edges: FalseEdges = frozenset()
) -> str:
    """What the page says about edge ``index`` of ``snap`` (with its residual)."""
    kind = "loop closure" if snap.edge_kind[index] == EdgeKind.LOOP_CLOSURE else "sequential"
    dx, dy, dtheta = snap.edge_rel[index]
    residual = edge_error(snap, index, cmap.params.link_sigmas())
    rows = [
        ("map", cmap.mode.value),
        ("edge", f"{int(snap.edge_from[index])} → {int(snap.edge_to[index])} ({kind})"),
        ("created at", f"{snap.edge_time[index]:.2f} s"),
        ("measured", f"{math.hypot(dx, dy):.3f} m, turn {math.degrees(dtheta):.1f}°"),
        ("residual", f"{residual:.2f} σ (whitened ‖S r‖ at the current poses)"),
    ]
    if kind == "loop closure":
        cid = int(snap.edge_cluster[index])
        rows.insert(3, ("cluster", f"{swatch(cluster_color(cid))}{cid}"))
        false = (float(snap.edge_time[index]), int(snap.edge_to[index])) in false_edges
        rows.append(("ground truth", "<b>false loop closure</b>" if false else "true loop closure"))
    return _info_table("edge", rows)


def _info_table(kind: str, rows: list[tuple[str, str]]) -> str:
    body = "".join(f"<tr><td>{k}</td><td>{v}</td></tr>" for k, v in rows)
    return (
        f'<table class="cogmap-table" id="cogmap-inspect" data-kind="{kind}">'
        f"<tbody>{body}</tbody></table>"
    )


def nearest_pick(
    cmap: CognitiveMap,
    mode: MapMode,
    point: NDArray[np.float64],
    tolerance: float,
    false_edges: FalseEdges,
    vertex_radius: float = 0.0,
) -> tuple[float, Pick] | None:
    """The vertex or edge of ``cmap`` nearest to ``point`` within ``tolerance``.

    An edge counts only away from its ends (by ``vertex_radius``, the drawn dot, at most a
    quarter of its length): a click on a vertex's dot selects the vertex, a click along an
    edge between two vertices the edge. Ties go to the vertex.
    """
    snap = cmap.snapshot()
    if snap.vertex_ids.shape[0] == 0:
        return None
    d = np.hypot(snap.poses[:, 0] - point[0], snap.poses[:, 1] - point[1])
    k = int(np.argmin(d))
    gap_e, e = math.inf, -1
    if snap.edge_from.shape[0]:
        first, second = snap.edge_ends()
        a, b = snap.poses[first, :2], snap.poses[second, :2]
        ab = b - a
        length = np.hypot(ab[:, 0], ab[:, 1])
        denom = np.where(length > 0, length * length, 1.0)
        t = np.clip(np.einsum("ij,ij->i", point - a, ab) / denom, 0, 1)
        gap = np.hypot(*(point - (a + ab * t[:, None])).T)
        zone = np.minimum(0.25 * length, vertex_radius)
        gap[np.minimum(t, 1 - t) * length < zone] = np.inf  # at an end: that vertex's
        e = int(np.argmin(gap))
        gap_e = float(gap[e])
    name = mode.value.replace("_", " ")
    if gap_e <= tolerance and gap_e < d[k]:
        seg = np.array([a[e], b[e]])
        loop = snap.edge_kind[e] == EdgeKind.LOOP_CLOSURE
        false = (float(snap.edge_time[e]), int(snap.edge_to[e])) in false_edges
        summary = f"{name}: edge {int(snap.edge_from[e])} → {int(snap.edge_to[e])}" + (
            " (loop closure" + (", false)" if false else ")") if loop else ""
        )
        html_ = describe_edge(cmap, snap, e, false_edges)
        return gap_e, Pick(mode, "edge", e, html_, seg, summary)
    if d[k] <= tolerance:
        seg = np.array([snap.poses[k, :2], snap.poses[k, :2]])
        summary = f"{name}: vertex {int(snap.vertex_ids[k])} ({snap.vertex_time[k]:.1f} s)"
        return float(d[k]), Pick(mode, "vertex", k, describe_vertex(cmap, snap, k), seg, summary)
    return None
