"""The live web app: a viser page around the replay worker, the scene streamer and each viewer.

:class:`CogmapApp` builds the page, implements the worker's
:class:`~app.server.replay.ReplayListener` and rate-limits what it sends: the map at most
``scene_hz`` times per second during playback (always at once after a rebuild, a seek, a step or
the end), counters and the camera image likewise, the size chart and the accuracy figures once
per second.

What is shared and what is each viewer's:

- **shared** (the page's global GUI, one state for every browser): playback, the map parameters,
  the status, the live counters of the three maps, the size chart, exports, opening a bag;
- **each viewer's** (:class:`~app.server.view.ClientView`): which map is shown (side by side or
  not), layers, edge colours, the camera, inspection, the pinned map to compare with, the
  cluster legend and optimisation log of the shown map.
"""

from __future__ import annotations

import dataclasses
import html
import logging
import math
import threading
import time
import traceback
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import viser
import viser.uplot
from numpy.typing import NDArray

from app.inputs import BagSource, InputOptions, ReplayInput
from app.server.assets import head_html, help_markdown
from app.server.chart import SIZE_SERIES, chart_data, chart_options, chart_series, x_end, y_top
from app.server.export import (
    default_replay_name,
    g2o_bytes,
    save_html_replay,
    sizes_csv_bytes,
    summary_bytes,
    summary_inputs,
)
from app.server.figures import (
    NO_LINKS,
    FigureInputs,
    LinkJudgement,
    MapFigures,
    compute_figures,
    false_link_inputs,
    false_link_label,
    figure_inputs,
    judge_links,
    layout_radius_label,
)
from app.server.files import DataFile, DataFolders, ExportFolder, Scrubber, default_export_dir
from app.server.network import ACTIVITY_FLOOR, match_text, pose_cell_image, template_image
from app.server.params import (
    ADVANCED_SLIDERS,
    ALL_SLIDERS,
    SLIDERS,
    SPECS,
    SliderSpec,
    check_spec,
    clamp_to_slider,
    format_value,
    parse_typed,
    typed_check,
)
from app.server.rebuild import make_builder
from app.server.replay import PlaybackState, Replay
from app.server.routes import RouteWorker, TruthGraphs, plan_routes, route_inputs, route_problem
from app.server.scene import MapExtras, SceneStreamer, cluster_color
from app.server.validation import (
    Adjusted,
    Adjustment,
    GuiGate,
    Refusal,
    Refused,
    choice,
    click,
    number,
    text,
)
from app.server.view import ClientView, Pick, nearest_pick, swatch
from cogmap_core.cognitive_map import CognitiveMap, EdgeKind, MapMode
from cogmap_core.config import MapParams
from cogmap_core.datasets import open_bag
from cogmap_core.datasets.cache import cache_dir
from cogmap_core.errors import CogmapError
from cogmap_core.event_file import KIND_LINK
from cogmap_core.event_log import EventLog
from cogmap_core.frames import EventStep, Frame
from cogmap_core.session_file import SessionMeta
from cogmap_core.slam import ALL_MODES, SlamSession
from cogmap_core.sources.detect import KINDS, LogOptions, Source, open_source

__all__ = ["ADVANCED_SLIDERS", "SLIDERS", "CogmapApp", "SliderSpec", "clamp_to_slider"]

log = logging.getLogger(__name__)

SPEEDS: dict[str, float] = {
    "0.25x": 0.25,
    "0.5x": 0.5,
    "1x": 1.0,
    "2x": 2.0,
    "5x": 5.0,
    "10x": 10.0,
    "20x": 20.0,
    "max": math.inf,
}
#: The smallest extent the scene's sizes and framing are chosen for, in layout radii.
SPAN_PER_RADIUS = 40.0
#: A viewer joining after this much data was replayed is told so (s).
LATE_JOIN_S = 5.0
RECENT_LINKS = 8


def recent_links(log: EventLog, frames: int, count: int) -> list[tuple[float, int, float | None]]:
    """The last ``count`` links of the first ``frames`` frames: (time, target, score), in order.

    Read from the log's columns (the score is None where the link has none).
    """
    end = int(log.frame_end[frames - 1]) if frames else 0
    if count <= 0 or end <= 0:
        return []
    columns = log.columns(end)
    links = np.flatnonzero(columns["kind"] == KIND_LINK)[-count:]
    return [
        (t, r, None if math.isnan(score) else score)
        for t, r, score in zip(
            columns["time"][links].tolist(),
            columns["ref"][links].tolist(),
            columns["score"][links].tolist(),
            strict=True,
        )
    ]


def _log_refusal(note: Refusal | Adjustment) -> None:
    log.warning("GUI value from a client %s", note.message)


def camera_rgb(image: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """The camera panel's picture of a frame's image: red, green, blue ``(h, w, 3)``.

    A grey image in its three channels; a colour one (blue, green, red, as a colour camera's
    frames are in OpenRatSLAM's arithmetic) in its own colours.
    """
    rgb = image[:, :, ::-1] if image.ndim == 3 else np.repeat(image[:, :, None], 3, axis=2)
    return np.ascontiguousarray(rgb)


class _RateLimit:
    def __init__(self, hz: float) -> None:
        self.period = 1.0 / hz if hz > 0 else 0.0
        self.last = -math.inf

    def due(self, forced: bool = False) -> bool:
        now = time.monotonic()
        if forced or now - self.last >= self.period:
            self.last = now
            return True
        return False


def _share(value: float | None) -> str:
    if value is None or math.isnan(value):
        return "–"
    return f"{value:.3f}"


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
        self._bags: dict[str, DataFile] = {}
        self._busy_lock = threading.Lock()  # one HTML replay saved, one bag opened at a time
        self._saving: threading.Thread | None = None
        self._opening: threading.Thread | None = None
        for spec in ALL_SLIDERS:
            check_spec(spec)
        self.server = server
        self.static_dir = static_dir
        self.scene_lock = threading.RLock()
        self._scene_limit = _RateLimit(scene_hz)
        self._status_limit = _RateLimit(4.0)
        self._seek_box_limit = _RateLimit(1.0)
        self._image_limit = _RateLimit(scene_hz)
        self._chart_limit = _RateLimit(1.0)
        self._figures_limit = _RateLimit(1.0)
        self._pose_cells_limit = _RateLimit(4.0)
        self._rebuild_shown: tuple[MapParams, tuple[MapMode, ...]] | None = None
        self._state_shown: PlaybackState | None = None
        self._views_limit = _RateLimit(2.0)
        self._figures: dict[MapMode, MapFigures] = {}
        self._figures_key: dict[MapMode, tuple[int, ...]] = {}
        self.stats_version = 0
        self._links: LinkJudgement = NO_LINKS  # the log's links and the truth's verdicts
        self._false_key: tuple[int, int] | None = None
        self._odometry_key: tuple[int, int] | None = None
        self._odometry = np.zeros((0, 3))
        # set while the app itself sets a control (per thread: viser runs callbacks on a
        # pool, and another viewer's change must not be swallowed meanwhile)
        self._setting = threading.local()
        self._pending_frame: tuple[Frame | EventStep, int | None, int] | None = None
        self.status_note = ""
        self._typed: dict[str, tuple[str, str]] = {}  # box -> (normal text, message)
        self._default_modes: tuple[MapMode, ...] = (MapMode.COMPACT,)
        self.views: dict[int, ClientView] = {}
        self._workers = rebuild_workers
        self._autoplay = autoplay
        self._waiting_for_viewer = autoplay and wait_for_viewer
        self._switch_lock = threading.Lock()
        # one lock for every replay this app makes: `with self.replay.lock` stays right while
        # open_bag swaps self.replay (the swap happens under it)
        self._replay_lock = threading.RLock()
        self._connect_lock = threading.Lock()
        self._figures_cond = threading.Condition()
        self._figures_todo: set[MapMode] = set()
        self._figures_stop = False
        self._figures_busy = False
        threading.Thread(target=self._figures_loop, name="cogmap-figures", daemon=True).start()
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

    def _reset_label(self) -> str:
        return f"reset to {self._defaults_name()}"

    def _defaults_name(self) -> str:
        return "paper values" if self.defaults == MapParams() else "defaults"

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
            with self._figures_cond:
                done = not self._figures_todo and not self._figures_busy
            if done and self.routes.idle():
                return True
            time.sleep(0.01)
        return False

    def stop(self) -> None:
        """Stop the replay worker (the server is stopped by its owner)."""
        self.replay.stop()
        self.routes.stop()
        with self._figures_cond:
            self._figures_stop = True
            self._figures_cond.notify()

    # ================================================================== GUI
    def _build_gui(self, params: MapParams, speed: float, autoplay: bool) -> None:
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
        self.status_html = gui.add_html(self._status_content())

        # what a click picked comes first: it shows next to the map, never below the fold
        self.inspect_folder = gui.add_folder("Inspect — yours")
        self.route_folder = gui.add_folder("Route — yours")
        self.view_folder = gui.add_folder("View — yours")
        self.compare_folder = gui.add_folder("Compare with a pinned map — yours")

        with gui.add_folder("Playback — shared"):
            self.play_button = gui.add_button(
                "pause" if autoplay else "play",
                icon=viser.Icon.PLAYER_PAUSE if autoplay else viser.Icon.PLAYER_PLAY,
            )
            speed_label = next((k for k, v in SPEEDS.items() if v == speed), "1x")
            self.speed_dropdown = gui.add_dropdown(
                "speed", tuple(SPEEDS), initial_value=speed_label
            )
            self.step_button = gui.add_button("step one frame", icon=viser.Icon.PLAYER_TRACK_NEXT)
            self.restart_button = gui.add_button("restart", icon=viser.Icon.PLAYER_SKIP_BACK)
            self.seek_slider = gui.add_slider("seek (s)", 0.0, 1.0, 0.1, 0.0)
            self.seek_box = gui.add_text("go to (s)", "0", hint="type a data time, then Enter")
            self.progress = gui.add_progress_bar(0.0)
        self.play_button.on_click(lambda _: self._toggle_play())
        self.speed_dropdown.on_update(lambda _: self._on_speed())
        self.step_button.on_click(lambda _: self.replay.step())
        self.restart_button.on_click(lambda _: self.restart())
        self.seek_slider.on_update(lambda _: self._on_seek())
        self.seek_box.on_update(lambda _: self._on_seek_box())

        with gui.add_folder("Live — shared"):
            self.camera_image = gui.add_image(
                np.zeros((60, 104, 3), dtype=np.uint8), label="camera", format="jpeg"
            )
            self.template_md = gui.add_markdown("view template: –")
            self.links_html = gui.add_html("")  # logs: the latest links and their scores
            self.built_html = gui.add_html("")  # what the maps were built with; a rebuild
            self.counters_html = gui.add_html("")

        with gui.add_folder("Network behind the map — shared"):
            self.network_html = gui.add_html(
                '<div class="cogmap-note" id="cogmap-network">The front end\'s view templates '
                "and pose cells show when the replay runs.</div>"
            )
            self.template_image = gui.add_image(
                np.full((20, 60, 3), 255, np.uint8), label="current view · matched template",
                format="png",
            )  # fmt: skip
            self.match_html = gui.add_html("")
            self.pose_cells_image = gui.add_image(
                np.full((30, 42, 3), 255, np.uint8), label="pose cells (x, y, θ)", format="jpeg"
            )
            self.pose_cells_html = gui.add_html("")

        with gui.add_folder("Map parameters — shared"):
            self.param_sliders: dict[str, viser.GuiSliderHandle[float]] = {}
            self.param_boxes: dict[str, viser.GuiTextHandle] = {}
            for spec in SLIDERS:
                self._add_param(spec, params)
            with gui.add_folder("Advanced", expand_by_default=False):
                for spec in ADVANCED_SLIDERS:
                    self._add_param(spec, params)
            self.reset_button = gui.add_button(self._reset_label(), icon=viser.Icon.RESTORE)
            self.params_md = gui.add_html(self._params_message(self._defaults_name()))
        self.reset_button.on_click(lambda _: self.reset_params())

        with gui.add_folder("Help", expand_by_default=False):
            self.help_md = gui.add_markdown(help_markdown(self.static_dir))

        with gui.add_folder("Map size"):
            self.chart = gui.add_uplot(
                tuple(np.zeros(1) for _ in range(len(chart_series()))),
                chart_series(),
                title="vertices (solid), edges (dashed), optimisations (dots)",
                aspect=1.3,
                **chart_options(),  # type: ignore[arg-type]
            )

        self.clusters_folder = gui.add_folder("Clusters & optimisations — yours")

        with gui.add_folder("Export"):
            self.g2o_button = gui.add_button("download map (.g2o)", icon=viser.Icon.DOWNLOAD)
            self.summary_button = gui.add_button("download summary.json", icon=viser.Icon.DOWNLOAD)
            self.sizes_button = gui.add_button("download sizes.csv", icon=viser.Icon.DOWNLOAD)
            self.replay_path = gui.add_text(  # a file name: saved in the server's export folder
                "replay name",
                default_replay_name(MapMode.COMPACT),
                hint="a file name; the replay is saved in the server's export folder and sent "
                "to your browser",
            )
            self.replay_button = gui.add_button("save HTML replay", icon=viser.Icon.DEVICE_FLOPPY)
            self.export_md = gui.add_html("")
        self.g2o_button.on_click(lambda event: self._download(event.client, "g2o"))
        self.summary_button.on_click(lambda event: self._download(event.client, "summary"))
        self.sizes_button.on_click(lambda event: self._download(event.client, "sizes"))
        self.replay_button.on_click(lambda event: self._save_replay(event.client))

        with gui.add_folder("Open another bag or log — shared", expand_by_default=False):
            names = self._list_bags()
            self.bag_dropdown = gui.add_dropdown("bag or log", names, initial_value=names[0])
            self.refresh_button = gui.add_button("refresh the list", icon=viser.Icon.REFRESH)
            self.open_button = gui.add_button("open", icon=viser.Icon.FOLDER_OPEN)
            self.open_md = gui.add_html(
                '<div class="cogmap-note" id="cogmap-open">A bag, or a log of odometry and place '
                "recognition (TUC or CSV), of the server's data folders; the replay starts over "
                "with it, for everyone.</div>"
            )
        self.refresh_button.on_click(lambda _: self.refresh_bags())
        self.open_button.on_click(lambda _: self._open_chosen())

    def _guard_inputs(self) -> None:
        """Check every value a client can send before viser applies it (see validation.py)."""
        gate = self.gate = GuiGate(self.server, note=_log_refusal)
        gate.guard(self.speed_dropdown, choice(tuple(SPEEDS)))
        for button in (
            self.play_button,
            self.step_button,
            self.restart_button,
            self.reset_button,
            self.g2o_button,
            self.summary_button,
            self.sizes_button,
            self.replay_button,
            self.refresh_button,
            self.open_button,
        ):
            gate.guard(button, click())
        gate.guard(self.seek_slider, number(0.0, lambda: float(self.seek_slider.max)))
        gate.guard(self.seek_box, self._seek_check(), note=self._seek_note)
        for spec in ALL_SLIDERS:
            gate.guard(
                self.param_sliders[spec.name], number(spec.low, spec.high), note=self._param_note
            )
            gate.guard(
                self.param_boxes[spec.name],
                self._box_check(spec),
                label=spec.label,
                note=self._param_note,
            )
        gate.guard(self.replay_path, text(max_length=200))
        gate.guard(self.bag_dropdown, choice(lambda: tuple(self.bag_dropdown.options)))

    def _add_param(self, spec: SliderSpec, params: MapParams) -> None:
        value = clamp_to_slider(spec, getattr(params, spec.name))
        value = spec.low if value is None else value
        slider = self.server.gui.add_slider(
            spec.label,
            min=spec.low,
            max=spec.high,
            step=spec.step,
            initial_value=value,
            hint=spec.hint,
        )
        box = self.server.gui.add_text(
            f"{spec.label} =", format_value(value), hint=f"type {spec.label}, then Enter"
        )
        slider.on_update(lambda _: self._on_slider(spec))
        box.on_update(lambda _: self._on_box(spec))
        self.param_sliders[spec.name] = slider
        self.param_boxes[spec.name] = box

    # ------------------------------------------------------------------ default view
    def show_maps(self, *modes: MapMode) -> None:
        """The view of the page before (or without) a viewer of its own: scripts and tests."""
        self._default_modes = tuple(modes) or (MapMode.COMPACT,)
        with self.replay.lock, self.scene_lock:
            self.streamer.show(self._default_modes)
            self.views_changed()
        defaults = {default_replay_name(m) for m in MapMode}
        if self.replay_path.value in defaults:  # keep a name the user typed
            self.replay_path.value = default_replay_name(modes[0])

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

    # ------------------------------------------------------------------ viewers
    def _on_connect(self, client: viser.ClientHandle) -> None:
        if self._waiting_for_viewer:
            self._waiting_for_viewer = False
            self.replay.play()
            self._sync_play_button()
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
            with self._connect_lock, self.view_folder:
                client.gui.add_html(
                    f'<div class="cogmap-note" id="cogmap-late">This replay started '
                    f"{started:.0f} s ago and is at t = {r.frame_time:.0f} s of the data: "
                    "<b>restart</b> (Playback) to watch it from the beginning.</div>",
                    order=-1.0,
                )
        self._update_status(force=True)

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
        offsets = view.offsets()
        best = None
        with self.replay.lock:
            for mode in view.state.shown:
                local = point - np.array([offsets[mode.value], 0.0])
                figures = self._figures.get(mode)
                found = nearest_pick(
                    self.replay.session.maps[mode],
                    mode,
                    local,
                    tolerance,
                    frozenset() if figures is None else figures.false_edges,
                    self.streamer.layers[mode].point_size / 2,
                )
                if found is not None and (best is None or found[0] < best[0]):
                    best = found
        return None if best is None else best[1]

    # ------------------------------------------------------------------ playback
    def _toggle_play(self) -> None:
        r = self.replay
        if r.state is PlaybackState.ENDED or r.at_end:
            r.restart()  # "play" at the end plays again from the start
            r.play()
        elif r.playing:
            r.pause()
        else:
            r.play()
        self._sync_play_button()
        self._update_status(force=True)

    def _sync_play_button(self) -> None:
        playing = self.replay.playing and self.replay.state is not PlaybackState.ENDED
        label = "pause" if playing else "play"
        if self.play_button.label != label:
            self.play_button.label = label
            self.play_button.icon = viser.Icon.PLAYER_PAUSE if playing else viser.Icon.PLAYER_PLAY

    def _on_speed(self) -> None:
        speed = SPEEDS.get(self.speed_dropdown.value)
        if speed is None:  # a client sent an unknown option
            self.speed_dropdown.value = "1x"
            return
        self.replay.set_speed(speed)
        self._update_status(force=True)

    def _on_seek(self) -> None:
        if getattr(self._setting, "seek", False):
            return  # the slider following playback, not a user
        value = self.seek_slider.value
        if not math.isfinite(value):
            return
        high = self.seek_slider.max
        clamped = min(max(float(value), 0.0), float(high))
        if clamped != value:
            self.seek_slider.value = clamped
            return
        self.replay.seek(clamped)

    def _seek_check(self) -> Any:
        def check(value: object) -> object:
            self.status_note = ""  # a note is about the value typed last (set again below)
            if not isinstance(value, str):
                raise Refused(f"{value!r} is not text")
            spec = SliderSpec("seek", "seek", 0.0, float(self.seek_slider.max), 0.1, "")
            typed = parse_typed(spec, value)
            normal = format_value(round(typed.value, 1))
            return Adjusted(normal, typed.message) if normal != value else normal

        return check

    def _seek_note(self, note: Refusal | Adjustment) -> None:
        self.status_note = note.message
        self._update_status(force=True)

    def _on_seek_box(self) -> None:
        if getattr(self._setting, "seek", False):
            return
        try:
            value = float(self.seek_box.value)
        except ValueError:
            return
        if math.isfinite(value):
            self.replay.seek(min(max(value, 0.0), float(self.seek_slider.max)))

    # ------------------------------------------------------------------ parameters
    def _params_message(self, text: str, error: bool = False) -> str:
        cls = "cogmap-note cogmap-error" if error else "cogmap-note"
        return f'<div class="{cls}" id="cogmap-params-message">{html.escape(text)}</div>'

    def _param_note(self, note: Refusal | Adjustment) -> None:
        """Show what the gate did with a parameter's value.

        A refusal reads ``refused δ: 'abc' is not a number; δ stays 3.746``.
        """
        if isinstance(note, Adjustment):
            self.params_md.content = self._params_message(note.message)
            return
        kept = note.kept if isinstance(note.kept, str) else repr(note.kept)
        self.params_md.content = self._params_message(
            f"refused {note.label}: {note.reason}; {note.label} stays {kept}", error=True
        )

    def _set_quietly(self, handle: Any, value: Any) -> None:
        self._setting.params = True
        try:
            handle.value = value
        finally:
            self._setting.params = False

    def _on_slider(self, spec: SliderSpec) -> None:
        if getattr(self._setting, "params", False):
            return
        slider = self.param_sliders[spec.name]
        value = clamp_to_slider(spec, slider.value)
        if value is None:  # refuse: back to the value in use
            current = getattr(self.replay.params, spec.name)
            self.params_md.content = self._params_message(
                f"refused {spec.label} = {slider.value!r}: not a number; "
                f"{spec.label} stays {format_value(current)}",
                error=True,
            )
            self._set_quietly(slider, clamp_to_slider(spec, current) or spec.low)
            return
        if value != slider.value:
            self.params_md.content = self._params_message(
                f"{spec.label} = {slider.value!r} is outside [{format_value(spec.low)}, "
                f"{format_value(spec.high)}]: using {format_value(value)}"
            )
            self._set_quietly(slider, value)
        else:
            self.params_md.content = self._params_message(f"{spec.label} = {format_value(value)}")
        self._set_quietly(self.param_boxes[spec.name], format_value(value))
        self.request_params()

    def _box_check(self, spec: SliderSpec) -> Any:
        """The box's check, remembering how the text was read (its message names the range)."""
        check = typed_check(spec)

        def remembered(value: object) -> object:
            self._typed.pop(spec.name, None)
            result = check(value)
            if isinstance(result, Adjusted):
                self._typed[spec.name] = (result.value, result.message)
            return result

        return remembered

    def _on_box(self, spec: SliderSpec) -> None:
        if getattr(self._setting, "params", False):
            return
        box = self.param_boxes[spec.name]
        try:
            typed = parse_typed(spec, box.value)
        except Refused as exc:  # only a value set without the gate can get here
            current = getattr(self.replay.params, spec.name)
            self._param_note(Refusal(spec.label, str(exc), format_value(current)))
            self._set_quietly(box, format_value(current))
            return
        message = typed.message
        remembered = self._typed.pop(spec.name, None)
        if remembered is not None and remembered[0] == box.value:
            message = remembered[1]  # what was typed, before the gate normalised it
        self.params_md.content = self._params_message(message)
        self._set_quietly(box, format_value(typed.value))
        self._set_quietly(self.param_sliders[spec.name], typed.value)
        self.request_params()

    def type_param(self, name: str, typed: str) -> None:
        """``typed`` entered into a parameter's box, as a browser sends it (scripts and tests)."""
        spec = SPECS[name]
        box = self.param_boxes[name]
        try:
            value = self._box_check(spec)(typed)
        except Refused as exc:
            current = getattr(self.replay.params, spec.name)
            self._param_note(Refusal(spec.label, str(exc), format_value(current)))
            return
        message = None
        if isinstance(value, Adjusted):
            value, message = value.value, value.message
        if box.value == value:  # viser runs no callback for an unchanged value
            self._on_box(spec)
        else:
            box.value = value
        if message is not None and self._typed.pop(spec.name, None) is not None:
            self._param_note(Adjustment(message))  # (no callback ran)

    def current_slider_params(self) -> MapParams:
        """The parameters the controls show, each clamped into its slider's range.

        A value that is not a finite number keeps the parameter in use. (A client can set a
        slider's value without its callback running, so every slider is checked here.)
        """
        params = self.replay.params
        values: dict[str, float] = {}
        for spec in ALL_SLIDERS:
            value = clamp_to_slider(spec, self.param_sliders[spec.name].value)
            values[spec.name] = getattr(params, spec.name) if value is None else value
        return params.with_changes(**values)

    def request_params(self) -> None:
        """Rebuild the maps for the controls' values (latest wins)."""
        try:
            params = self.current_slider_params()
        except CogmapError as exc:
            self.params_md.content = self._params_message(f"refused: {exc}", error=True)
            return
        if params != self.replay.params:
            self.replay.set_params(params)

    def reset_params(self) -> None:
        """Back to the default parameter values (the paper's, or the log's; one rebuild)."""
        defaults = self.defaults
        for name, slider in self.param_sliders.items():
            self._set_quietly(slider, getattr(defaults, name))
            self._set_quietly(self.param_boxes[name], format_value(getattr(defaults, name)))
        self.params_md.content = self._params_message(self._defaults_name())
        if self.replay.params != defaults:
            self.replay.set_params(defaults)

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
            self._update_status()

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
            self._show_links(frame)
            return
        r = self.replay
        for handle in (self.camera_image, self.template_image):
            if not handle.visible:  # (hidden while a log was replayed)
                handle.visible = True
        self.camera_image.image = camera_rgb(frame.image)
        template = "–" if view_template is None else f"#{view_template}"
        self.template_md.content = (
            f"view template **{template}** · frame {index + 1} / {r.total_frames} · "
            f"t = {frame.time:.2f} s"
        )
        self._show_network(frame, view_template, index)

    def _show_network(self, frame: Frame, view_template: int | None, index: int) -> None:
        """The view template panel and the pose cells (as OpenRatSLAM shows them)."""
        r = self.replay
        frontend = r.session.frontend
        local_view = frontend.local_view
        current = local_view.make_template(frame.image)
        matched = None
        if view_template is not None and 0 <= view_template < local_view.count:
            matched = local_view.template(view_template)
        self.template_image.image = template_image(current, matched)
        k = index - r.base_frames
        error = r.view_errors[k] if 0 <= k < len(r.view_errors) else math.nan
        threshold = frontend.config.vt_match_threshold
        text = match_text(view_template, None if math.isnan(error) else error, threshold,
                          math.isnan(error))  # fmt: skip
        self.match_html.content = (
            f'<div class="cogmap-note" id="cogmap-match">{html.escape(text)} '
            f"({local_view.count} templates stored)</div>"
        )
        note = (
            '<div class="cogmap-note" id="cogmap-network">Left: the camera image as the local '
            "view cells see it (cropped, resampled, normalised); right: the view template it "
            "matched.</div>"
        )
        if self.network_html.content != note:
            self.network_html.content = note
        processed = r.session.log.frames
        if index + 1 < processed:  # replaying cached events: the front end is further on
            if self.pose_cells_image.visible:
                self.pose_cells_image.visible = False
            self.pose_cells_html.content = (
                '<div class="cogmap-note" id="cogmap-pose-cells">Pose cells: the front end last '
                f"ran at frame {processed}; this frame replays its cached events. They show "
                "again once playback passes that frame.</div>"
            )
            return
        if not self._pose_cells_limit.due(not r.playing):
            return
        activity = frontend.pose_cell_activity
        peak = frontend.pose_cell_peak
        if not self.pose_cells_image.visible:
            self.pose_cells_image.visible = True
        self.pose_cells_image.image = pose_cell_image(activity, peak)
        n_th = activity.shape[0]
        x, y, th = peak
        self.pose_cells_html.content = (
            '<div class="cogmap-note" id="cogmap-pose-cells">Activity of the '
            f"{activity.shape[2]} × {activity.shape[1]} × {n_th} pose-cell network at frame "
            f"{index + 1} (dots: cells above {ACTIVITY_FLOOR:.0%} of the peak, larger and "
            f"yellower when stronger); peak (ring) at x {x:.1f}, y {y:.1f}, θ {th:.1f} cells "
            f"({math.degrees(th * 2 * math.pi / n_th):.0f}°).</div>"
        )

    def _show_links(self, step: EventStep) -> None:
        """Hide the camera panel; list the latest place-recognition links with their scores."""
        for handle in (self.camera_image, self.template_image, self.pose_cells_image):
            if handle.visible:
                handle.visible = False
        note = (
            '<div class="cogmap-note" id="cogmap-network">No camera: this input is a log of '
            "odometry and place recognition, whose links come as they are. There is no front end "
            "here (no view templates, no pose cells); the latest links are under "
            "<i>Live</i>.</div>"
        )
        if self.network_html.content != note:
            self.network_html.content = note
            self.match_html.content = ""
            self.pose_cells_html.content = ""
        with self.replay.lock:
            recent = recent_links(self.replay.session.log, self.replay.cursor, RECENT_LINKS)
        rows = "".join(
            f"<tr><td>{t:.1f}</td><td>{target}</td><td>{'–' if score is None else f'{score:.3f}'}"
            "</td></tr>"
            for t, target, score in reversed(recent)
        )
        self.template_md.content = f"step {step.index} · t = {step.time:.2f} s"
        self.links_html.content = (
            '<div id="cogmap-links" style="font-size:0.85em"><b>place recognition</b>: latest '
            "links (score of each)"
            '<table style="width:100%;font-variant-numeric:tabular-nums">'
            "<tr><th>t (s)</th><th>to vertex</th><th>score</th></tr>"
            + (rows or '<tr><td colspan="3">none yet</td></tr>')
            + "</table></div>"
        )

    def on_maps(self, replay: Replay, modes: tuple[MapMode, ...], forced: bool) -> None:
        """Stream the maps (rate-limited during playback)."""
        if not self._scene_limit.due(forced):
            return
        if forced:
            self._show_frame()
        with replay.lock, self.scene_lock:
            self._update_figures(forced, modes)
            self._update_counters()  # first: the browser shows text at once, geometry later
            self._publish_scene()
            if self._chart_limit.due(forced):
                self._update_chart()
        if self._views_limit.due(forced):
            self._refresh_views()
        self._update_status()

    def _refresh_views(self) -> None:
        """Refresh every open view; each takes the replay lock for what it reads (call unlocked)."""
        for view in list(self.views.values()):
            try:
                view.refresh()
            except Exception:  # a tab that went away must not stop the others
                if not view.closed and self._connected(view.client):
                    traceback.print_exc()

    # ------------------------------------------------------------------ page content
    def _update_figures(self, forced: bool, modes: tuple[MapMode, ...]) -> None:
        """Ask for the accuracy figures of the maps (1 Hz; at once for rebuilt maps).

        They take some 30 ms per map (the layout fidelity most), so they are computed on their
        own thread (:meth:`_figures_loop`) after the map is shown, and the page follows.
        """
        if forced:
            todo: tuple[MapMode, ...] = modes
        elif self._figures_limit.due():
            todo = ALL_MODES
        else:
            return
        with self._figures_cond:
            self._figures_todo.update(todo)
            self._figures_cond.notify()

    def _figures_loop(self) -> None:
        while True:
            with self._figures_cond:
                while not self._figures_todo and not self._figures_stop:
                    self._figures_cond.wait(0.5)
                if self._figures_stop:
                    return
                todo = [m for m in ALL_MODES if m in self._figures_todo]
                self._figures_todo.clear()
                self._figures_busy = True
            try:
                self._compute_figures(todo)
            except Exception:  # a figure must never stop the page
                traceback.print_exc()
            finally:
                with self._figures_cond:
                    self._figures_busy = False

    def _compute_figures(self, modes: list[MapMode]) -> None:
        """Compute the figures of ``modes`` that changed, holding the replay lock only to copy.

        The inputs (the maps' snapshots, a copy of the log for the false links) are taken under
        the lock; the computation (some 30 ms per map) runs without it, so playback and rebuilds
        do not wait for it. The results are stored and the scene republished under the lock
        (a paused replay publishes nothing else); the views then refresh, each taking the lock
        for what it reads. Figures of a replay that was swapped for another bag meanwhile are
        dropped; those of a map that changed meanwhile are computed again next round.
        """
        replay = self.replay
        todo: list[tuple[MapMode, tuple[int, ...], FigureInputs]] = []
        with replay.lock:
            if replay is not self.replay:
                return
            log_ = replay.session.log
            judging = replay.session.evaluation
            false_key = (id(log_), log_.frames)
            false_inputs = false_link_inputs(log_) if false_key != self._false_key else None
            for mode in modes:
                cmap = replay.session.maps[mode]
                mkey = (id(cmap), cmap.num_vertices, cmap.num_edges, len(cmap.optimizations),
                        log_.frames)  # fmt: skip
                if self._figures_key.get(mode) != mkey or false_inputs is not None:
                    todo.append((mode, mkey, figure_inputs(log_, cmap)))
        links = self._links if false_inputs is None else judge_links(false_inputs, judging)
        computed = [
            (mode, mkey, compute_figures(inputs, judging, links)) for mode, mkey, inputs in todo
        ]
        if false_inputs is None and not computed:
            return
        with replay.lock, self.scene_lock:
            if replay is not self.replay:
                return
            if false_inputs is not None:
                self._false_key = false_key
                self._links = links
            for mode, mkey, figures in computed:
                self._figures_key[mode] = mkey
                self._figures[mode] = figures
                self.stats_version += 1
            self._publish_scene()  # the truth's alignment, the false loop closures
            self._update_counters()
        self._refresh_views()

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
            transforms = {
                mode: None if (f := self._figures.get(mode)) is None else f.truth_transform
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
            inputs = route_inputs(snapshots, transforms, truth, key)
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
            for mode, figures in self._figures.items()
        }
        odometry = self._dead_reckoning() if self.streamer.show_odometry else None
        self.streamer.publish(
            dict(session.maps.maps), truth, count, extras, odometry, self.replay.duration
        )

    def _status_content(self) -> str:
        r = getattr(self, "replay", None)
        if r is None:
            return '<div id="cogmap-status">starting…</div>'
        state = r.state
        color = {
            PlaybackState.LOADING: "#8a6d00",
            PlaybackState.PLAYING: "#1e8c3c",
            PlaybackState.PAUSED: "#555555",
            PlaybackState.ENDED: "#34659f",
            PlaybackState.ERROR: "#b00020",
        }[state]
        t = 0.0 if math.isnan(r.frame_time) else r.frame_time
        bag = html.escape(r.bag_path.name) if r.bag_path else "–"
        label = state.value
        if self._waiting_for_viewer and state is PlaybackState.PAUSED:
            label = "waiting for the first viewer"
        parts = [f'<b style="color:{color}">{label}</b>']
        if state is PlaybackState.PLAYING:
            parts.append("max speed" if math.isinf(r.speed) else f"{r.speed:g}×")
        if state is not PlaybackState.ERROR:
            parts.append(f"t = {t:.1f} / {r.duration:.1f} s · {bag}")
        text_ = " · ".join(parts)
        message = ""
        note = self.status_note
        if r.message or note:
            mcolor = "#b00020" if state is PlaybackState.ERROR or note else "#555"
            message = (
                f'<div id="cogmap-message" style="color:{mcolor};font-size:0.85em;'
                f'white-space:normal">{html.escape(self.scrubber.scrub(r.message or note))}</div>'
            )
        return (
            f'<div id="cogmap-status" data-state="{state.value}" '
            f'style="padding:0.3em 0.6em;font-size:0.9em">{text_}{message}</div>'
        )

    def _update_status(self, force: bool = False) -> None:
        self._state_shown = self.replay.state
        content = self._status_content()
        if self.status_html.content != content:
            self.status_html.content = content
        built = self._built_content()
        if self.built_html.content != built:
            self.built_html.content = built
        r = self.replay
        if r.duration > 0 and self.seek_slider.max != round(r.duration, 1):
            self.seek_slider.max = round(r.duration, 1)
        fraction = 0.0
        if r.duration > 0 and not math.isnan(r.frame_time):
            fraction = min(100.0, 100.0 * r.frame_time / r.duration)
        if r.at_end:
            fraction = 100.0
        if abs(self.progress.value - fraction) >= 0.1:
            self.progress.value = fraction
        if not math.isnan(r.frame_time) and r.state is not PlaybackState.LOADING:
            position = round(min(r.frame_time, self.seek_slider.max), 1)
            self._setting.seek = True  # (callbacks run on this thread)
            try:
                if abs(self.seek_slider.value - position) > 0.05:
                    self.seek_slider.value = position
                playing = r.state is PlaybackState.PLAYING
                if self._seek_box_limit.due(force or not playing):
                    self.seek_box.value = format_value(position)
            finally:
                self._setting.seek = False
        self._sync_play_button()

    def _built_content(self) -> str:
        """What the shown maps were built with, and which are being rebuilt (for what)."""
        r = self.replay
        rebuilding = r.rebuilding
        self._rebuild_shown = rebuilding
        maps = r.session.maps.maps
        groups: dict[MapParams, list[str]] = {}
        for mode in ALL_MODES:
            if mode in maps:
                groups.setdefault(maps[mode].params, []).append(mode.value.replace("_", " "))

        def described(params: MapParams) -> str:
            return " · ".join(
                f"{spec.label} {format_value(getattr(params, spec.name))}" for spec in ALL_SLIDERS
            )

        if len(groups) == 1:
            lines = [f"<b>maps built with</b> {html.escape(described(next(iter(groups))))}"]
        else:
            lines = [
                f"<b>{', '.join(names)} built with</b> {html.escape(described(params))}"
                for params, names in groups.items()
            ]
        content = '<div class="cogmap-note" id="cogmap-built">' + "<br>".join(lines) + "</div>"
        if rebuilding is not None:
            params, pending = rebuilding
            changes = []
            for spec in ALL_SLIDERS:
                olds = {getattr(maps[m].params, spec.name) for m in pending if m in maps}
                new = getattr(params, spec.name)
                if olds and olds != {new}:
                    was = ", ".join(format_value(v) for v in sorted(olds))
                    changes.append(f"{spec.label} = {format_value(new)} (was {was})")
            names = ", ".join(m.value.replace("_", " ") for m in pending)
            what = "; ".join(changes) or "the new parameters"
            content = (
                '<div class="cogmap-note cogmap-busy" id="cogmap-rebuild">rebuilding '
                f"{html.escape(names)} for {html.escape(what)} …</div>" + content
            )
        return content

    def restart(self) -> None:
        """Back to the first frame and play (the restart button; after the end as before it)."""
        self.replay.restart()
        self.replay.play()
        self._sync_play_button()
        self._update_status(force=True)

    def _loop_closures_detected(self) -> int:
        log_ = self.replay.session.log
        k = self.replay.cursor
        end = log_.frame_end[k - 1] if k else 0
        return int(np.count_nonzero(log_.columns(end)["kind"] == KIND_LINK))

    def map_figures(self, mode: MapMode, cmap: CognitiveMap) -> dict[str, str]:
        """A map's figures as the page writes them."""
        figures = self._figures.get(mode)
        fidelity = None if figures is None else figures.fidelity
        ate = None if figures is None else figures.ate
        false = None if figures is None else figures.false_count
        links = None if figures is None else figures.links
        c = cmap.counters

        def count(value: int | None) -> str:
            return "–" if value is None else str(value)

        return {
            "vertices": str(cmap.num_vertices),
            "edges": str(cmap.num_edges),
            "loops": str(cmap.num_loop_edges),
            "clusters": str(len(cmap.clusters)),
            "optimizations": str(len(cmap.optimizations)),
            "ate": "–" if ate is None else f"{ate:.3f}",
            "completeness": _share(None if fidelity is None else fidelity.completeness),
            "correctness": _share(None if fidelity is None else fidelity.correctness),
            "false": count(false),
            "links": count(None if links is None else links.links),
            "duplicates": count(None if links is None else links.duplicates),
            "refused_links": count(None if links is None else links.refused),
            "made": count(None if links is None else links.made),
            "removed": count(None if links is None else links.removed),
            "proposed": str(c.proposed),
            "declined": str(c.declined),
            "integrated": str(c.integrated),
            "short_edges": str(c.short_edges),
            "refused": str(c.refused_relocalisations),
        }

    def _update_counters(self) -> None:
        r = self.replay
        session = r.session
        t = 0.0 if math.isnan(r.frame_time) else r.frame_time
        detected = self._loop_closures_detected()
        false = self._links.false_before(detected)
        judged = false_link_label(session.evaluation)
        rows = [
            ("time", "time", f"{t:.1f} / {r.duration:.1f} s"),
            ("frames", "frames", f"{r.cursor} / {r.total_frames}"),
            ("loops-detected", "loop closures detected (links)", str(detected)),
            ("loops-false", "… of them false (ground truth)", "–" if false is None else str(false)),
        ]
        n = len(ALL_MODES)
        body = "".join(
            f'<tr><td>{label}</td><td colspan="{n}" id="cogmap-{key}">{value}</td></tr>'
            for key, label, value in rows
        )
        figures = {m: self.map_figures(m, session.maps[m]) for m in ALL_MODES}
        radius = layout_radius_label(session.evaluation)  # the input kind's
        sections = (
            (
                "size",
                (
                    ("vertices", "vertices"),
                    ("edges", "edges"),
                    ("loops", "loop-closure edges"),
                    ("clusters", "clusters"),
                    ("optimizations", "optimisations"),
                ),
            ),
            (
                "where the links went",
                (
                    ("links", "links received"),
                    ("duplicates", "duplicates (pair already joined)"),
                    ("refused_links", "refused by the relocalisation test"),
                    ("made", "loop-closure edges made"),
                    ("removed", "… of them merged or removed since"),
                ),
            ),
            (
                "accuracy",
                (
                    ("ate", "ATE (m)"),
                    ("completeness", f"completeness ({radius})"),
                    ("correctness", f"correctness ({radius})"),
                    ("false", "false loop closures in the map"),
                ),
            ),
            (
                "where the proposals went",
                (
                    ("proposed", "vertices proposed"),
                    ("declined", "declined by neighborhood fields"),
                    ("integrated", "merged by scene integration"),
                    ("short_edges", "removed as short edges"),
                    ("refused", "relocalisations refused"),
                ),
            ),
        )
        head = "".join(f"<th>{html.escape(m.value.replace('_', ' '))}</th>" for m in ALL_MODES)
        for title, keys in sections:
            body += f'<tr class="cogmap-section"><td colspan="{n + 1}">{title}</td></tr>'
            for key, label in keys:
                cells = "".join(
                    f'<td id="cogmap-{m.value}-{key}">{figures[m][key]}</td>' for m in ALL_MODES
                )
                body += f"<tr><td>{label}</td>{cells}</tr>"
        note = (
            '<div class="cogmap-note" id="cogmap-counters-note">A link is false when the ground '
            f"truth puts its two places apart ({html.escape(judged)}). <b>False loop closures "
            "in the map</b>: the map's loop-closure edges made from a link the ground truth "
            "calls false (as in summary.json). Links that join a pair already joined add no "
            "edge (duplicates): on the first lap most links are.</div>"
        )
        content = (
            f'<table class="cogmap-table" id="cogmap-counters"><thead><tr><th></th>{head}'
            f"</tr></thead><tbody>{body}</tbody></table>{note}"
        )
        if self.counters_html.content != content:
            self.counters_html.content = content

    def _update_chart(self) -> None:
        maps = dict(self.replay.session.maps.maps)
        data = chart_data(maps, self.replay.data_time)  # session time (bag time unless resuming)
        top = y_top(max(float(np.max(series)) for series in data[SIZE_SERIES]))
        end = x_end(float(data[0][-1]))
        with self.server.atomic():
            scales = chart_options(top, end)["scales"]
            if self.chart.scales != scales:
                self.chart.scales = scales  # type: ignore[assignment]
            self.chart.data = data
            series = chart_series(maps)
            if tuple(self.chart.series) != series:
                self.chart.series = series

    def cluster_log_html(self, mode: MapMode, cmap: CognitiveMap) -> str:
        """The cluster colour legend and the optimisation log of one map (a view's)."""
        clusters: list[int] = []
        if cmap.num_loop_edges:
            snap = cmap.snapshot()
            loops = snap.edge_cluster[snap.edge_kind == EdgeKind.LOOP_CLOSURE]
            clusters = sorted(set(loops.tolist()))
        swatches = "".join(
            f'<span style="display:inline-block;margin:1px 5px 1px 0">'
            f"{swatch(cluster_color(c))}{c}</span>"
            for c in clusters[-40:]
        )
        legend = (
            f'<div class="cogmap-note" id="cogmap-cluster-legend"><b>{mode.value}</b>: '
            f"loop-closure edges by cluster ({len(clusters)} cluster(s) with edges in the map)"
            f"<br>{swatches or 'none yet'}</div>"
        )
        total = sum(o.wall_s for o in cmap.optimizations)
        summary = (
            f'<div class="cogmap-note"><b>{len(cmap.clusters)}</b> clusters, '
            f"<b>{len(cmap.optimizations)}</b> optimisations ({total:.2f} s in total)</div>"
        )
        sizes = {c.cluster_id: c.edge_count for c in cmap.clusters}
        rows = "".join(
            f"<tr><td>{o.time:.1f}</td><td>{'end' if o.cluster_id < 0 else o.cluster_id}</td>"
            f"<td>{sizes.get(o.cluster_id, 0)}</td><td>{o.vertices}</td><td>{o.iterations}</td>"
            f"<td>{o.wall_s * 1000:.0f}</td><td>{o.integrated}</td>"
            f"<td>{o.short_edges_removed}</td></tr>"
            for o in reversed(cmap.optimizations[-12:])
        )
        table = ""
        if cmap.optimizations:
            table = (
                '<table class="cogmap-table" id="cogmap-optimizations"><thead><tr>'
                "<th>t (s)</th><th>cluster</th><th>links</th><th>V</th><th>iters</th>"
                "<th>ms</th><th>merged</th><th>short</th></tr></thead>"
                f"<tbody>{rows}</tbody></table>"
                '<div class="cogmap-note">links: the loop closures the front end detected in '
                "the cluster (the three maps share one schedule); the map keeps fewer "
                "loop-closure edges (duplicates, refused, merged: see <i>Live</i>).</div>"
            )
        latency = ""
        last = self.replay.last_completed_rebuild()
        if last is not None:
            shown = [
                f"{m.value} {last.latency(m) * 1000:.0f} ms ({last.how.get(m, '')})"
                for m in last.published
            ]
            latency = (
                '<div class="cogmap-note" id="cogmap-latency">last parameter change shown '
                f"after: {', '.join(shown)}</div>"
            )
        return legend + summary + table + latency

    # ------------------------------------------------------------------ export
    def _view_of(self, client: viser.ClientHandle | None) -> tuple[MapMode, ...]:
        view = self.views.get(getattr(client, "client_id", -1))
        if view is not None:
            return view.state.shown
        return self._default_modes

    def _download(self, client: viser.ClientHandle | None, what: str) -> None:
        try:
            inputs = None
            with self.replay.lock:
                mode = self._view_of(client)[0]
                if what == "g2o":
                    name, content = f"{mode.value}.g2o", g2o_bytes(self.replay.session.maps[mode])
                elif what == "summary":
                    inputs = summary_inputs(self.replay)  # a copy: its figures need no lock
                else:
                    name, content = "sizes.csv", sizes_csv_bytes(self.replay)
            if inputs is not None:  # (the bag named as the page names it, not by its server path)
                inputs = dataclasses.replace(inputs, dataset=self.data.shown(inputs.dataset))
                name, content = "summary.json", summary_bytes(inputs)
        except Exception as exc:
            traceback.print_exc()
            self.export_md.content = self._export_message(
                f"export failed: {self.scrubber.scrub(str(exc))}", error=True
            )
            return
        self.export_md.content = self._export_message(f"sent {name} ({len(content)} bytes)")
        targets = [client] if client is not None else list(self.server.get_clients().values())
        for c in targets:
            c.send_file_download(name, content, save_immediately=True)

    def _export_message(self, text_: str, error: bool = False) -> str:
        cls = "cogmap-note cogmap-error" if error else "cogmap-note"
        return f'<div class="{cls}" id="cogmap-export">{html.escape(text_)}</div>'

    def _save_replay(self, client: viser.ClientHandle | None) -> threading.Thread | None:
        """Save the HTML replay of ``client``'s view in the export folder and send it to ``client``.

        The name is the box's, made safe (:func:`~app.server.files.safe_name`); one replay is
        rendered at a time. Returns the thread rendering it (None when refused at once).
        """
        target = self.exports.target(self.replay_path.value)
        modes = self._view_of(client)
        with self._busy_lock:
            if self._saving is not None and self._saving.is_alive():
                self.export_md.content = self._export_message(
                    "a replay is being saved; try again when it is done", error=True
                )
                return None
            self.export_md.content = self._export_message(
                f"saving the HTML replay as {target.name} in the export folder …"
            )

            def send(page: bytes) -> None:
                if client is not None:
                    client.send_file_download(target.name, page, save_immediately=True)

            def work() -> None:
                try:
                    self.exports.prepare(target)
                    save_html_replay(
                        self.replay, modes, target, static_dir=self.static_dir, sent=send
                    )
                except CogmapError as exc:
                    self.export_md.content = self._export_message(
                        f"replay not saved: {self.scrubber.scrub(str(exc))}", True
                    )
                    return
                except Exception as exc:
                    traceback.print_exc()
                    self.export_md.content = self._export_message(
                        f"replay not saved: {type(exc).__name__}", True
                    )
                    return
                self.export_md.content = self._export_message(
                    f"saved the HTML replay as {target.name} in the export folder"
                    + (" and sent it to your browser" if client is not None else "")
                )

            thread = threading.Thread(target=work, name="cogmap-html-replay", daemon=True)
            thread.start()
            self._saving = thread
        return thread

    # ------------------------------------------------------------------ another bag
    def _open_message(self, text_: str, error: bool = False) -> None:
        cls = "cogmap-note cogmap-error" if error else "cogmap-note"
        self.open_md.content = f'<div class="{cls}" id="cogmap-open">{html.escape(text_)}</div>'

    def _list_bags(self) -> tuple[str, ...]:
        """List the bags of the data folders; the dropdown's options (never empty)."""
        self._bags = {f.name: f for f in self.data.listing()}
        return tuple(self._bags) or (NO_BAG,)

    def refresh_bags(self) -> list[str]:
        """List the bags of the data folders in the dropdown again; returns their names."""
        names = self._list_bags()
        if tuple(self.bag_dropdown.options) != names:
            self.bag_dropdown.options = names
        if self.bag_dropdown.value not in names:
            self.bag_dropdown.value = names[0]
        return list(self._bags)

    def _open_chosen(self) -> threading.Thread | None:
        """The open button: open the chosen bag on a thread of its own (one at a time)."""
        name = self.bag_dropdown.value
        with self._busy_lock:
            if self._opening is not None and self._opening.is_alive():
                self._open_message("another bag is being opened; wait for it", error=True)
                return None
            self._open_message(f"opening {name} …")
            thread = threading.Thread(
                target=self.open_bag, args=(name,), name="cogmap-open-bag", daemon=True
            )
            thread.start()
            self._opening = thread
        return thread

    def open_bag(self, name: str) -> bool:
        """Replay the input listed as ``name`` (in the data folders); errors go to the page.

        Only the names of :meth:`refresh_bags`' list are opened; anything else -- a path, a
        missing file, a folder not listed -- gets the same one line. The file is checked again
        (a regular file inside its folder, not too large; an image folder's images regular
        files) and opened by its resolved path, then checked (a bag, video or image folder with
        camera frames, or a log of odometry and place recognition read whole, as
        ``cogmap serve FILE`` reads it) before the current replay is replaced. A camera input
        after a log (or a log after one) starts from its kind's default parameters.
        """
        chosen = self._bags.get(name)
        if chosen is None:
            shown = name if len(name) <= 80 else name[:77] + "…"
            self._open_message(
                f"not opened: {shown!r} is not one of the bags in the data folders "
                "(refresh the list to see new ones)",
                error=True,
            )
            return False
        problem = None
        reader = None
        # opened once here, to refuse it before the running replay stops (the reader names what
        # is wrong: neither a ROS 1 bag nor a ROS 2 bag, ...), then handed over to the new replay
        options = self.input_options
        try:
            chosen = self.data.check(chosen)
            if chosen.kind == "bag":
                reader = open_bag(
                    chosen.path, topics=options.topics, image_scale=options.image_scale
                )
            elif KINDS[chosen.kind].has_camera:  # a video or image folder (serve's --fps)
                reader = open_source(
                    chosen.path, chosen.kind, camera=options.camera_for(chosen.path)
                )
            else:  # a log: read (and checked) whole, as cogmap serve FILE reads it
                reader = open_source(chosen.path, chosen.kind, log=LogOptions())
            frames = reader.info.frame_count
            if frames == 0:
                problem = (
                    f"{name} has no camera frames on the image topic"
                    if chosen.kind == "bag"
                    else f"{name} has no camera frames"
                    if KINDS[chosen.kind].has_camera
                    else f"{name} has no odometry to map"
                )
        except CogmapError as exc:
            problem = self.scrubber.scrub(str(exc))
        except Exception as exc:
            traceback.print_exc()
            problem = f"cannot open {name}: {type(exc).__name__}"
        if problem is not None:
            if reader is not None:
                reader.close()
            self._open_message(f"not opened: {problem}", error=True)
            return False
        assert reader is not None
        path = chosen.path
        kind = KINDS[chosen.kind]
        with self._switch_lock:
            old = self.replay
            params = old.params
            speed = old.speed
            switched = kind.map_params != self.defaults
            if switched:  # a log's (or a video's) map parameters are not a bag's: the kind's own
                params = self.defaults = kind.map_params
            old.stop()  # joins its worker, which may be waiting for the replay lock
            with self._replay_lock, self.scene_lock:
                self.streamer.reset()
                self._figures.clear()
                self._figures_key.clear()
                self._false_key = None
                self._links = NO_LINKS
                self._odometry_key = None
                options = dataclasses.replace(
                    self.input_options, format=chosen.kind, log=LogOptions()
                )
                self.replay = self._make_replay(  # (opened here: not sniffed again)
                    ReplayInput(path, options), params, speed, True, opened=reader
                )
                self.started_at = time.monotonic()
                self.links_html.content = ""  # (a log's latest links)
            self.views_changed()
            self.replay.start()
        for view in list(self.views.values()):  # what a tab picked was the old input's
            view.select(None)
            view.clear_route()
        if switched:
            self.reset_button.label = self._reset_label()
            self.reset_params()  # the sliders show the kind's defaults (no rebuild: in use)
        what = "frames" if kind.has_camera else "steps"
        self._open_message(f"opened {name} ({frames} {what}); replaying it for everyone")
        self._sync_play_button()
        return True


#: What the bag list shows when the data folders hold no bag.
NO_BAG = "(no bag in the data folders)"
