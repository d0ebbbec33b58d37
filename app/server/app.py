"""The live web app: a viser page around the replay worker, the scene streamer and each viewer.

:class:`CogmapApp` composes the page from its panels (:mod:`app.server.panels`, one builder
each), implements the worker's :class:`~app.server.replay.ReplayListener` and rate-limits what it
sends: the map at most ``scene_hz`` times per second during playback (always at once after a
rebuild, a seek, a step or the end), counters and the camera image likewise, the size chart and
the accuracy figures once per second (:class:`~app.server.figures_worker.FiguresWorker`).

What is shared and what is each viewer's:

- **shared** (the page's global GUI, one state for every browser): playback, the map parameters,
  the status, the live counters of the three maps, the size chart, exports, opening a bag;
- **each viewer's** (:class:`~app.server.view.ClientView`): which map is shown (side by side or
  not), layers, edge colours, the camera, inspection, the pinned map to compare with, the
  cluster legend and optimisation log of the shown map.

Callbacks only ask: the replay worker, the figures worker, the route worker and the threads that
save a replay or open a bag do the work, and the page follows them.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import threading
import time
import traceback
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import viser

from app.inputs import BagSource, InputOptions, ReplayInput
from app.server.assets import head_html, help_markdown
from app.server.figures_worker import FiguresWorker
from app.server.files import DataFile, DataFolders, ExportFolder, Scrubber, default_export_dir
from app.server.panels import PanelHandle, ViewFolders, set_content
from app.server.panels.export import ExportControls, build_export
from app.server.panels.inspect import Pick
from app.server.panels.live_figures import (
    build_live,
    build_size_chart,
    cluster_log_html,
    counters_content,
    show_camera,
    show_links,
    show_network,
    update_chart,
)
from app.server.panels.open import InputChooser
from app.server.panels.parameters import (
    ParameterControls,
    build_parameters,
    built_content,
    params_message,
)
from app.server.panels.playback import PlaybackControls, build_playback, status_content
from app.server.params import ADVANCED_SLIDERS, SLIDERS, SliderSpec, clamp_to_slider
from app.server.rebuild import make_builder
from app.server.replay import PlaybackState, Replay
from app.server.routes import RouteWorker, TruthGraphs, plan_routes, route_inputs, route_problem
from app.server.scene import MapExtras, SceneStreamer
from app.server.timing import RateLimit
from app.server.validation import Adjustment, GuiGate, Refusal
from app.server.view import ClientView
from cogmap_core.cognitive_map import CognitiveMap, MapMode
from cogmap_core.config import MapParams
from cogmap_core.datasets.cache import cache_dir
from cogmap_core.errors import CogmapError
from cogmap_core.frames import EventStep, Frame
from cogmap_core.session_file import SessionMeta
from cogmap_core.slam import SlamSession
from cogmap_core.sources.detect import KINDS, LogOptions, Source, input_map_params

__all__ = ["ADVANCED_SLIDERS", "SLIDERS", "CogmapApp", "SliderSpec", "clamp_to_slider"]

log = logging.getLogger(__name__)

#: The smallest extent the scene's sizes and framing are chosen for, in layout radii.
SPAN_PER_RADIUS = 40.0
#: A viewer joining after this much data was replayed is told so (s).
LATE_JOIN_S = 5.0


def _log_refusal(note: Refusal | Adjustment) -> None:
    log.warning("GUI value from a client %s", note.message)


class CogmapApp:
    """The page and its behaviour for one replay (module doc).

    Args:
        server: the viser server to build the page on.
        bag: the bag (or a function generating the built-in one).
        params: initial map parameters (the paper's by default).
        input_options: how inputs are read (:class:`~app.inputs.InputOptions`: the kind of
            ``bag`` -- None: detected from the content --, the front end or a function of the
            bag choosing it -- default: the bag's profile, as ``cogmap run`` --, a bag's topics
            and JPEG scale, how to read a log, a camera's odometry and frame rate). Another
            input opened from the page is read alike (its own kind, a log with default
            options).
        speed: initial playback speed.
        autoplay: start playing as soon as the bag is open.
        static_dir: folder of the page's assets.
        scene_hz: maximum map updates per second during playback.
        rebuild_workers: worker processes that rebuild maps after a parameter change
            (:mod:`app.server.rebuild`; 0: on the replay's thread).
        wait_for_viewer: with ``autoplay``, start playing when the first browser connects.
        defaults: what "reset" returns to (default: the paper's values; for logs, the
            defaults of that kind of input).
        resume: a loaded session to show and continue on the bag (see :class:`Replay`); its
            parameters are the sliders' initial values.
        export_dir: the folder "save HTML replay" writes into (default
            ``$COGMAP_CACHE/exports``; see :mod:`app.server.files`).
        data_dirs: the folders whose bags, videos, image folders and logs "open another bag"
            lists (default: the bag's folder; the cache's for the built-in dataset).

    """

    # the panels' handles and doings by the names scripts and tests use (each lives in its panel)
    play_button = PanelHandle("playback.panel")
    speed_dropdown = PanelHandle("playback.panel")
    step_button = PanelHandle("playback.panel")
    restart_button = PanelHandle("playback.panel")
    seek_slider = PanelHandle("playback.panel")
    seek_box = PanelHandle("playback.panel")
    progress = PanelHandle("playback.panel")
    status_note = PanelHandle("playback")
    restart = PanelHandle("playback")
    param_sliders = PanelHandle("parameters.panel")
    param_boxes = PanelHandle("parameters.panel")
    reset_button = PanelHandle("parameters.panel")
    params_md = PanelHandle("parameters.panel")
    type_param = PanelHandle("parameters")
    current_slider_params = PanelHandle("parameters")
    request_params = PanelHandle("parameters")
    reset_params = PanelHandle("parameters")
    _params_message = staticmethod(params_message)
    camera_image = PanelHandle("live")
    template_md = PanelHandle("live")
    links_html = PanelHandle("live")
    built_html = PanelHandle("live")
    counters_html = PanelHandle("live")
    network_html = PanelHandle("live")
    template_image = PanelHandle("live")
    match_html = PanelHandle("live")
    pose_cells_image = PanelHandle("live")
    pose_cells_html = PanelHandle("live")
    _figures = PanelHandle("figures", "figures")
    g2o_button = PanelHandle("export.panel")
    summary_button = PanelHandle("export.panel")
    sizes_button = PanelHandle("export.panel")
    replay_path = PanelHandle("export.panel")
    replay_button = PanelHandle("export.panel")
    export_md = PanelHandle("export.panel")
    _save_replay = PanelHandle("export", "save_replay")
    bag_dropdown = PanelHandle("opener.panel")
    refresh_button = PanelHandle("opener.panel")
    open_button = PanelHandle("opener.panel")
    open_md = PanelHandle("opener.panel")
    refresh_bags = PanelHandle("opener")
    open_bag = PanelHandle("opener")
    _opening = PanelHandle("opener", "opening")

    def __init__(
        self,
        server: viser.ViserServer,
        bag: BagSource,
        *,
        params: MapParams | None = None,
        input_options: InputOptions | None = None,
        speed: float = 1.0,
        autoplay: bool = True,
        static_dir: Path | None = None,
        scene_hz: float = 10.0,
        rebuild_workers: int = 2,
        wait_for_viewer: bool = False,
        defaults: MapParams | None = None,
        resume: tuple[SlamSession, SessionMeta] | None = None,
        export_dir: Path | None = None,
        data_dirs: Sequence[Path] | None = None,
    ) -> None:
        """Build the page; call :meth:`start` to begin the replay."""
        self.input_options = input_options or InputOptions()
        self.defaults = defaults or MapParams()
        self.exports = ExportFolder(export_dir if export_dir is not None else default_export_dir())
        if data_dirs is None:
            data_dirs = [bag.parent if isinstance(bag, Path) else cache_dir()]
        self.data = DataFolders(data_dirs)
        self.scrubber: Scrubber = self.data.scrubber(self.exports)
        self.server = server
        self.static_dir = static_dir
        self.scene_lock = threading.RLock()
        self._scene_limit = RateLimit(scene_hz)
        self._status_limit = RateLimit(4.0)
        self._image_limit = RateLimit(scene_hz)
        self._chart_limit = RateLimit(1.0)
        self._pose_cells_limit = RateLimit(4.0)
        self._rebuild_shown: tuple[MapParams, tuple[MapMode, ...]] | None = None
        self._state_shown: PlaybackState | None = None
        self._views_limit = RateLimit(2.0)
        self._odometry_key: tuple[int, int] | None = None
        self._odometry = np.zeros((0, 3))
        self._pending_frame: tuple[Frame | EventStep, int | None, int] | None = None
        self._default_modes: tuple[MapMode, ...] = (MapMode.COMPACT,)
        self.views: dict[int, ClientView] = {}
        self._workers = rebuild_workers
        self._waiting_for_viewer = autoplay and wait_for_viewer
        self._switch_lock = threading.Lock()
        # one lock for every replay this app makes: `with self.replay.lock` stays right while
        # switch_input swaps self.replay (the swap happens under it)
        self._replay_lock = threading.RLock()
        self._connect_lock = threading.Lock()
        self.figures = FiguresWorker(
            lambda: self.replay, self.scene_lock, self._show_figures, self._refresh_views
        )
        # routes (issue 26): a view's callbacks flag it, this worker computes and draws
        self._truth_graphs = TruthGraphs()
        self.routes: RouteWorker[ClientView] = RouteWorker(self._route_work)
        self.started_at = time.monotonic()
        self.replay = self._make_replay(
            ReplayInput(bag, self.input_options),
            params,
            speed,
            autoplay and not wait_for_viewer,
            resume=resume,
        )
        if resume is not None:
            params = resume[0].params
        self.streamer = SceneStreamer(server)
        self._build_gui(params or MapParams(), speed, autoplay)
        self._guard_inputs()
        server.on_client_connect(self._on_connect)
        server.on_client_disconnect(self._on_disconnect)
        self.show_maps(MapMode.COMPACT)

    def _make_replay(
        self,
        source: ReplayInput,
        params: MapParams | None,
        speed: float,
        autoplay: bool,
        resume: tuple[SlamSession, SessionMeta] | None = None,
        opened: Source | None = None,
    ) -> Replay:
        return Replay(
            source,
            self,
            params=params,
            speed=speed,
            autoplay=autoplay,
            builder=make_builder(self._workers),
            resume=resume,
            lock=self._replay_lock,
            opened=opened,
        )

    # ================================================================== lifecycle
    def start(self) -> None:
        """Start replaying."""
        self.replay.start()

    def wait_idle(self, timeout: float = 60.0) -> bool:
        """Wait until the replay is idle and the page caught up with it (scripts and tests)."""
        deadline = time.monotonic() + timeout
        if not self.replay.wait_idle(timeout):
            return False
        while time.monotonic() < deadline:
            if self.figures.idle() and self.routes.idle():
                return True
            time.sleep(0.01)
        return False

    def stop(self) -> None:
        """Stop the replay worker (the server is stopped by its owner)."""
        self.replay.stop()
        self.routes.stop()
        self.figures.stop()

    # ================================================================== the page
    def _build_gui(self, params: MapParams, speed: float, autoplay: bool) -> None:
        """Compose the page from its panels, in the page's order."""
        gui = self.server.gui
        gui.configure_theme(
            control_width="large",
            show_share_button=False,
            brand_color=(30, 140, 60),
        )
        gui.set_panel_label("cogmap · compact cognitive map")
        # docked at the right: the scene's canvas ends where the panel begins, so nothing of the
        # map lies under the panel, whatever the window, the screen's pixel ratio or the
        # resolution viser renders at (a floating panel covered a part nobody could compute)
        gui.main_panel.dock_right()
        self.head_html = gui.add_html(head_html(self.static_dir))
        self.status_html = gui.add_html(
            status_content(self.replay, self._waiting_for_viewer, "", self.scrubber)
        )
        # each viewer's panels (ClientView); what a click picked comes first: it shows next to
        # the map, never below the fold
        inspect = gui.add_folder("Inspect — yours")
        route = gui.add_folder("Route — yours")
        view = gui.add_folder("View — yours")
        compare = gui.add_folder("Compare with a pinned map — yours")
        self.playback = PlaybackControls(build_playback(gui, speed, autoplay), self)
        self.live = build_live(gui)
        self.parameters = ParameterControls(build_parameters(gui, params, self.defaults), self)
        with gui.add_folder("Help", expand_by_default=False):
            self.help_md = gui.add_markdown(help_markdown(self.static_dir))
        self.chart = build_size_chart(gui)
        clusters = gui.add_folder("Clusters & optimisations — yours")
        self.folders = ViewFolders(inspect, route, view, compare, clusters)
        self.export = ExportControls(build_export(gui), self)
        self.opener = InputChooser(gui, self.data, self.scrubber, self)

    def _guard_inputs(self) -> None:
        """Check every value a client can send before viser applies it (see validation.py)."""
        gate = self.gate = GuiGate(self.server, note=_log_refusal)
        for panel in (self.playback, self.parameters, self.export, self.opener):
            panel.guard(gate)

    # ------------------------------------------------------------------ default view
    def show_maps(self, *modes: MapMode) -> None:
        """The view of the page before (or without) a viewer of its own: scripts and tests."""
        self._default_modes = tuple(modes) or (MapMode.COMPACT,)
        with self.replay.lock, self.scene_lock:
            self.streamer.show(self._default_modes)
            self.views_changed()
        self.export.follow_view(modes[0])

    def views_changed(self) -> None:
        """Stream what the views show (a view changed); the shown maps rebuild first."""
        with self.replay.lock, self.scene_lock:
            views = list(self.views.values())
            shown: list[MapMode] = []
            for modes in [v.state.shown for v in views] + [self._default_modes]:
                for mode in modes:
                    if mode not in shown:
                        shown.append(mode)
            colourings = {v.state.colouring for v in views}
            odometry = any(v.state.layers["odometry"] for v in views)
            self.streamer.set_needed(shown, colourings, odometry)
            self.replay.set_priority(tuple(shown))
            self._publish_scene()

    def modes_of(self, client: viser.ClientHandle | None) -> tuple[MapMode, ...]:
        """The maps ``client`` shows (the default view's without a view of its own)."""
        view = self.views.get(getattr(client, "client_id", -1))
        if view is not None:
            return view.state.shown
        return self._default_modes

    # ------------------------------------------------------------------ viewers
    def _on_connect(self, client: viser.ClientHandle) -> None:
        if self._waiting_for_viewer:
            self._waiting_for_viewer = False
            self.replay.play()
            self.playback.sync_play_button()
        with self._connect_lock:  # (the shared folders are entered to place the view's controls)
            try:
                view = ClientView(self, client)
            except RuntimeError:  # viser refuses updates to a tab that has gone
                if self._connected(client):
                    raise
                return
            if not self._connected(client):  # it left while its page was built
                view.close()
                return
            self.views[client.client_id] = view
        r = self.replay
        if not math.isnan(r.frame_time) and r.frame_time > LATE_JOIN_S and r.playing:
            started = time.monotonic() - self.started_at
            with self._connect_lock, self.folders.view:
                client.gui.add_html(
                    f'<div class="cogmap-note" id="cogmap-late">This replay started '
                    f"{started:.0f} s ago and is at t = {r.frame_time:.0f} s of the data: "
                    "<b>restart</b> (Playback) to watch it from the beginning.</div>",
                    order=-1.0,
                )
        self.update_status(force=True)

    def _connected(self, client: viser.ClientHandle) -> bool:
        return client.client_id in self.server.get_clients()

    def _on_disconnect(self, client: viser.ClientHandle) -> None:
        with self._connect_lock:  # a view being built is registered (or dropped) first
            view = self.views.pop(client.client_id, None)
        if view is not None:
            view.close()
            self.views_changed()

    def pick(self, view: ClientView, point: np.ndarray, tolerance: float) -> Pick | None:
        """The vertex or edge of the view's maps nearest to ``point`` (world x, y)."""
        return view.pick_at(point, tolerance)

    def cluster_log_html(self, mode: MapMode, cmap: CognitiveMap) -> str:
        """The cluster colour legend and the optimisation log of one map (a view's)."""
        return cluster_log_html(mode, cmap, self.replay.last_completed_rebuild())

    def _refresh_views(self) -> None:
        """Refresh every open view; each takes the replay lock for what it reads (call unlocked)."""
        for view in list(self.views.values()):
            try:
                view.refresh()
            except Exception:  # a tab that went away must not stop the others
                if not view.closed and self._connected(view.client):
                    traceback.print_exc()

    # ================================================================== listener (worker thread)
    def on_status(self, replay: Replay) -> None:
        """Playback state changed (rate-limited except for state changes and rebuilds)."""
        rebuilding = replay.rebuilding
        forced = (
            replay.state is not PlaybackState.PLAYING
            or replay.state is not self._state_shown
            or rebuilding != self._rebuild_shown
        )
        if self._status_limit.due(forced=forced):
            self.update_status()

    def on_frame(self, replay: Replay, frame: Frame | EventStep, view_template: int | None) -> None:
        """Show the camera image (rate-limited; the latest one is shown when playback stops)."""
        self._pending_frame = (frame, view_template, replay.cursor - 1)
        if self._image_limit.due(not replay.playing):
            self._show_frame()

    def _show_frame(self) -> None:
        pending = self._pending_frame
        if pending is None:
            return
        self._pending_frame = None
        frame, view_template, index = pending
        if isinstance(frame, EventStep):  # a log: no camera; the latest links' scores instead
            show_links(self.live, self.replay, frame)
            return
        r = self.replay
        show_camera(self.live, frame, view_template, index, r.total_frames)
        show_network(self.live, r, frame, view_template, index, self._pose_cells_limit)

    def on_maps(self, replay: Replay, modes: tuple[MapMode, ...], forced: bool) -> None:
        """Stream the maps (rate-limited during playback)."""
        if not self._scene_limit.due(forced):
            return
        if forced:
            self._show_frame()
        with replay.lock, self.scene_lock:
            self.figures.request(forced, modes)
            self._update_counters()  # first: the browser shows text at once, geometry later
            self._publish_scene()
            if self._chart_limit.due(forced):
                self._update_chart()
        if self._views_limit.due(forced):
            self._refresh_views()
        self.update_status()

    # ------------------------------------------------------------------ page content
    def _show_figures(self) -> None:
        """New figures (with the replay's and the scene's lock): the scene and the counters."""
        self._publish_scene()  # the truth's alignment, the false loop closures
        self._update_counters()

    def _update_counters(self) -> None:
        content = counters_content(self.replay, self.figures.figures, self.figures.links)
        set_content(self.live.counters_html, content)

    def _update_chart(self) -> None:
        maps = dict(self.replay.session.maps.maps)
        # (session time: bag time unless resuming)
        update_chart(self.server, self.chart, maps, self.replay.data_time)

    def update_status(self, force: bool = False) -> None:
        """Show the replay's state: the status line, what the maps were built with, playback."""
        r = self.replay
        self._state_shown = r.state
        note = self.playback.status_note
        set_content(
            self.status_html, status_content(r, self._waiting_for_viewer, note, self.scrubber)
        )
        rebuilding = r.rebuilding
        self._rebuild_shown = rebuilding
        # Not under the replay's lock: the replay thread calls this holding its condition, while
        # a viewer's change holds that lock and waits for the condition (Replay.set_priority).
        # Copies of the dicts are taken whole instead (one C-level copy each, under the GIL).
        previews = {mode: p.description for mode, p in dict(r.previews).items()}
        last = r.rebuilds[-1] if r.rebuilds else None
        differences = dict(last.preview_difference) if last is not None else {}
        content = built_content(r.session.maps.maps, rebuilding, previews, differences)
        set_content(self.live.built_html, content)
        self.playback.follow(force)

    _update_status = update_status  # (the name tests use)

    def sync_play_button(self) -> None:
        """Label the play button for what a click does now."""
        self.playback.sync_play_button()

    def _route_work(self, view: ClientView) -> None:
        """Find and draw the routes of ``view``'s two places (on the route worker's thread).

        The maps, the alignments the scene shows and the true path so far are copied under the
        replay's lock; the routes are computed without it (:mod:`app.server.routes`).
        """
        if view.closed:
            return
        places = view.route_places
        if len(places) < 2:
            return
        modes = view.route_modes()
        with self.replay.lock:
            maps = self.replay.session.maps
            snapshots = {mode: maps[mode].snapshot() for mode in modes}
            params = maps[modes[0]].params  # one set for all the maps of a session
            transforms = {
                mode: None if (f := self.figures.get(mode)) is None else f.truth_transform
                for mode in modes
            }
            log_ = self.replay.session.log
            truth = None
            key: tuple[int, ...] = ()
            if log_.has_ground_truth():
                count = min(self.replay.cursor, len(log_.ground_truth))
                truth = np.array(log_.ground_truth[:count, :2])
                key = (id(log_), count)
        try:
            inputs = route_inputs(snapshots, transforms, truth, key, params)
            graph = None
            if inputs.truth is not None:
                graph = self._truth_graphs.get(inputs.truth, inputs.truth_key)
            plan = plan_routes(inputs, places[0], places[1], modes, graph)
        except Exception as exc:
            if not isinstance(exc, CogmapError):
                traceback.print_exc()
            view.route_failed(places, self.scrubber.scrub(route_problem(exc)))
            return
        view.show_route(plan)

    def _dead_reckoning(self) -> np.ndarray:
        log_ = self.replay.session.log
        key = (id(log_), log_.frames)  # the whole log's path, cut at the cursor on every call:
        if key != self._odometry_key:  # a replay behind its log (after a seek) reuses it
            self._odometry_key = key
            self._odometry = log_.dead_reckoning()
        return self._odometry[: min(self.replay.cursor, log_.frames)]

    def _publish_scene(self) -> None:
        session = self.replay.session
        log_ = session.log
        # sizes, the grid and the framing suit the kind of input: a maze (8 cm layout radius:
        # at least 3.2 m) or a building (50 cm: at least 20 m)
        self.streamer.min_span = SPAN_PER_RADIUS * session.evaluation.layout_radius
        truth = log_.ground_truth if len(log_.ground_truth) else None
        count = min(self.replay.cursor, len(log_.ground_truth))
        extras = {
            mode: MapExtras(figures.truth_transform, figures.false_edges)
            for mode, figures in self.figures.figures.items()
        }
        odometry = self._dead_reckoning() if self.streamer.show_odometry else None
        self.streamer.publish(
            self.replay.shown_maps(),  # (a map being rebuilt may be drawn by its preview)
            truth,
            count,
            extras,
            odometry,
            self.replay.duration,
            previewed=tuple(self.replay.previews),
        )

    # ------------------------------------------------------------------ another input
    def switch_input(self, chosen: DataFile, reader: Source) -> None:
        """Replay ``chosen`` (already open as ``reader``, checked) instead, for everyone.

        An input whose default parameters differ from the current input's (a camera input
        after a log, a log after one, another log: each log's odometry scale is its own) starts
        from its defaults; what each tab picked or routed was the old input's and is dropped.
        """
        kind = KINDS[chosen.kind]
        with self._switch_lock:
            old = self.replay
            params = old.params
            speed = old.speed
            chosen_defaults = input_map_params(kind, reader)
            switched = chosen_defaults != self.defaults
            if switched:  # a log's (or a video's) map parameters are not a bag's: its own
                params = self.defaults = chosen_defaults
            old.stop()  # joins its worker, which may be waiting for the replay lock
            with self._replay_lock, self.scene_lock:
                self.streamer.reset()
                self.figures.forget()
                self._odometry_key = None
                options = dataclasses.replace(
                    self.input_options, format=chosen.kind, log=LogOptions()
                )
                self.replay = self._make_replay(  # (opened here: not sniffed again)
                    ReplayInput(chosen.path, options), params, speed, True, opened=reader
                )
                self.started_at = time.monotonic()
                self.live.links_html.content = ""  # (a log's latest links)
            self.views_changed()
            self.replay.start()
        for view in list(self.views.values()):  # what a tab picked was the old input's
            view.select(None)
            view.clear_route()
        if switched:
            self.parameters.defaults_changed()
