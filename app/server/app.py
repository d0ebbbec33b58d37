"""The live web app: a viser GUI around the replay worker and the scene streamer.

:class:`CogmapApp` builds the page (folders: status, view, playback, live, map parameters,
map size, clusters and optimisations, export), implements the worker's
:class:`~app.server.replay.ReplayListener` and rate-limits what it sends: the map at most
``scene_hz`` times per second during playback (always at once after a rebuild, a seek, a step or
the end), counters and the camera image likewise, the size chart once per second.

All state is global (``server.gui``/``server.scene``): every client sees the same page, and a
client joining late is sent the current state by viser.
"""

from __future__ import annotations

import html
import logging
import math
import threading
import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import viser
import viser.uplot

from app.server.export import (
    default_replay_path,
    g2o_bytes,
    save_html_replay,
    sizes_csv_bytes,
    summary_bytes,
)
from app.server.replay import BagSource, FrontEndSource, PlaybackState, Replay
from app.server.scene import (
    MAP_COLORS,
    SceneStreamer,
    cluster_color,
)
from app.server.validation import GuiGate, boolean, choice, click, number, text
from cogmap_core.cognitive_map import CognitiveMap, EdgeKind, MapMode
from cogmap_core.config import MapParams, parameter_range
from cogmap_core.datasets import BagTopics
from cogmap_core.errors import CogmapError, ParameterError
from cogmap_core.evaluation import LayoutFidelity
from cogmap_core.event_file import KIND_LINK
from cogmap_core.events import LinkToVertex
from cogmap_core.frames import EventStep, Frame
from cogmap_core.session_file import SessionMeta
from cogmap_core.slam import EventLog, SlamSession
from cogmap_core.sources.detect import LogOptions

log = logging.getLogger(__name__)

MODE_LABELS: dict[str, MapMode] = {m.value: m for m in MapMode}
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
CHART_POINTS = 400
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


@dataclass(frozen=True, slots=True)
class SliderSpec:
    """A map-parameter slider: label, parameter name, range and step."""

    label: str
    name: str
    low: float
    high: float
    step: float
    hint: str


#: The tuning sliders (ranges inside the valid parameter ranges of :class:`MapParams`).
SLIDERS: tuple[SliderSpec, ...] = (
    SliderSpec("α", "alpha", 0.0, 50.0, 0.1, "translation weight of the neighborhood field (1/m)"),
    SliderSpec("β", "beta", 0.0, 50.0, 0.1, "rotation weight of the neighborhood field (1/rad)"),
    SliderSpec("δ", "delta", 1.05, 30.0, 0.001, "add a vertex only when g(d, θ) > δ"),
    SliderSpec("T_interval", "t_interval", 0.1, 20.0, 0.1, "cluster interval threshold (s)"),
    SliderSpec("T_total", "t_total", 1.0, 500.0, 1.0, "cluster total-time threshold (s)"),
)
ADVANCED_SLIDERS: tuple[SliderSpec, ...] = (
    SliderSpec("Huber scale", "huber_scale", 0.01, 2.0, 0.01, "Huber loss scale (m, rad)"),
    SliderSpec(
        "short edge (m)", "short_edge_threshold", 0.0, 0.5, 0.005, "edges shorter are removed"
    ),
)


def _check_spec(spec: SliderSpec) -> None:
    low, inclusive, high = parameter_range(spec.name)
    ok_low = spec.low >= low if inclusive else spec.low > low
    if not (ok_low and spec.high <= high):
        raise ParameterError(f"slider {spec.name} range [{spec.low}, {spec.high}] is invalid")


def clamp_to_slider(spec: SliderSpec, value: float) -> float | None:
    """``value`` clamped into the slider's range; None when it is not a finite number."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        return None
    if not math.isfinite(v):
        return None
    return min(max(v, spec.low), spec.high)


def _log_refusal(message: str) -> None:
    log.warning("GUI value from a client %s", message)


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


class CogmapApp:
    """The page and its behaviour for one replay.

    Args:
        server: the viser server to build the page on.
        bag: the bag (or a function generating the built-in one).
        params: initial map parameters (the paper's by default).
        frontend: front-end configuration or a function of the bag choosing it (default: the
            bag's profile, as ``cogmap run``).
        speed: initial playback speed.
        autoplay: start playing as soon as the bag is open.
        static_dir: default folder for saved HTML replays.
        scene_hz: maximum map updates per second during playback.
        image_scale: JPEG decode reduction (1, 2, 4, 8).
        topics: the bag's topic names.
        fmt: the input's kind (``bag``, ``tuc``, ``csv``; None: detected from the content).
        log: how to read a log (ignored for bags).
        defaults: what "reset" returns to (default: the paper's values; for logs, the
            defaults of that kind of input).
        resume: a loaded session to show and continue on the bag (see :class:`Replay`); its
            parameters are the sliders' initial values.

    """

    def __init__(
        self,
        server: viser.ViserServer,
        bag: BagSource,
        params: MapParams | None = None,
        frontend: FrontEndSource = None,
        speed: float = 1.0,
        autoplay: bool = True,
        static_dir: Path | None = None,
        scene_hz: float = 10.0,
        image_scale: int = 4,
        topics: BagTopics | None = None,
        fmt: str | None = None,
        log: LogOptions | None = None,
        defaults: MapParams | None = None,
        resume: tuple[SlamSession, SessionMeta] | None = None,
    ) -> None:
        """Build the page; call :meth:`start` to begin the replay."""
        self.defaults = defaults or MapParams()
        for spec in SLIDERS + ADVANCED_SLIDERS:
            _check_spec(spec)
        self.server = server
        self.static_dir = static_dir
        self.started_at = time.monotonic()
        self._scene_lock = threading.RLock()
        self._scene_limit = _RateLimit(scene_hz)
        self._status_limit = _RateLimit(4.0)
        self._image_limit = _RateLimit(scene_hz)
        self._chart_limit = _RateLimit(1.0)
        self._ate_limit = _RateLimit(1.0)
        self._ate: dict[MapMode, float | None] = {}
        self._fidelity: dict[MapMode, LayoutFidelity | None] = {}
        self._log_key: tuple[Any, ...] | None = None
        self._links_counted = (0, 0)  # (events counted, LinkToVertex among them)
        self._suppress_param_events = False
        self._camera_extent: tuple[float, float, float, float] | None = None
        self._pending_frame: tuple[Frame, int | None] | None = None
        self._local = threading.local()
        self.exports: list[Path] = []
        self.replay = Replay(
            bag,
            self,
            params=params,
            frontend=frontend,
            speed=speed,
            autoplay=autoplay,
            image_scale=image_scale,
            topics=topics,
            fmt=fmt,
            log=log,
            resume=resume,
        )
        if resume is not None:
            params = resume[0].params
        self.streamer = SceneStreamer(server)
        self._build_gui(params or MapParams(), speed, autoplay)
        self._guard_inputs()
        self._apply_view()

    # ================================================================== lifecycle
    def start(self) -> None:
        """Start replaying."""
        self.replay.start()

    def stop(self) -> None:
        """Stop the replay worker (the server is stopped by its owner)."""
        self.replay.stop()

    # ================================================================== GUI
    def _build_gui(self, params: MapParams, speed: float, autoplay: bool) -> None:
        gui = self.server.gui
        gui.configure_theme(
            control_width="large",
            show_share_button=False,
            brand_color=(30, 140, 60),
        )
        gui.set_panel_label("cogmap · compact cognitive map")
        self.status_html = gui.add_html(self._status_content())

        with gui.add_folder("View"):
            self.mode_dropdown = gui.add_dropdown(
                "map", tuple(MODE_LABELS), initial_value=MapMode.COMPACT.value
            )
            self.compare_checkbox = gui.add_checkbox("side by side", False)
            self.compare_dropdown = gui.add_dropdown(
                "compare with", tuple(MODE_LABELS), initial_value=MapMode.STANDARD.value
            )
            self.truth_checkbox = gui.add_checkbox("ground truth", True)
            self.top_button = gui.add_button("top view", icon=viser.Icon.MAP_2)
            self.view3d_button = gui.add_button("3-D view", icon=viser.Icon.VIEW_360)
        for handle in (
            self.mode_dropdown,
            self.compare_checkbox,
            self.compare_dropdown,
            self.truth_checkbox,
        ):
            handle.on_update(lambda _: self._apply_view())
        self.top_button.on_click(lambda event: self._set_camera(event.client, top=True))
        self.view3d_button.on_click(lambda event: self._set_camera(event.client, top=False))

        with gui.add_folder("Playback"):
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
            self.progress = gui.add_progress_bar(0.0)
        self.play_button.on_click(lambda _: self._toggle_play())
        self.speed_dropdown.on_update(lambda _: self._on_speed())
        self.step_button.on_click(lambda _: self.replay.step())
        self.restart_button.on_click(lambda _: self.replay.restart())
        self.seek_slider.on_update(lambda _: self._on_seek())

        with gui.add_folder("Live"):
            self.camera_image = gui.add_image(
                np.zeros((60, 104, 3), dtype=np.uint8), label="camera", format="jpeg"
            )
            self.template_md = gui.add_markdown("view template: –")
            self.links_html = gui.add_html("")  # logs: the latest links and their scores
            self.counters_html = gui.add_html("")

        with gui.add_folder("Map parameters"):
            self.param_sliders: dict[str, viser.GuiSliderHandle[float]] = {}
            for spec in SLIDERS:
                self._add_param_slider(spec, params)
            with gui.add_folder("Advanced", expand_by_default=False):
                for spec in ADVANCED_SLIDERS:
                    self._add_param_slider(spec, params)
            label = "reset to paper values" if self.defaults == MapParams() else "reset to defaults"
            self.reset_button = gui.add_button(label, icon=viser.Icon.RESTORE)
            self.params_md = gui.add_markdown("")
        self.reset_button.on_click(lambda _: self.reset_params())

        with gui.add_folder("Map size"):
            series: list[viser.uplot.Series] = [{"label": "t (s)"}]
            for mode in (MapMode.STANDARD, MapMode.SCENE_INTEGRATION, MapMode.COMPACT):
                r, g, b = MAP_COLORS[mode]
                series.append(
                    {"label": f"{mode.value} V", "stroke": f"rgb({r},{g},{b})", "width": 2}
                )
                series.append(
                    {
                        "label": f"{mode.value} E",
                        "stroke": f"rgb({r},{g},{b})",
                        "width": 1,
                        "dash": (5.0, 4.0),
                    }
                )
            self.chart = gui.add_uplot(
                tuple(np.zeros(1) for _ in range(7)),
                tuple(series),
                title="vertices (solid) and edges (dashed)",
                aspect=1.4,
            )

        with gui.add_folder("Clusters & optimisations"):
            self.legend_html = gui.add_html("")
            self.log_md = gui.add_markdown("no optimisation yet")

        with gui.add_folder("Export"):
            self.g2o_button = gui.add_button("download map (.g2o)", icon=viser.Icon.DOWNLOAD)
            self.summary_button = gui.add_button("download summary.json", icon=viser.Icon.DOWNLOAD)
            self.sizes_button = gui.add_button("download sizes.csv", icon=viser.Icon.DOWNLOAD)
            self.replay_path = gui.add_text(
                "replay file", str(default_replay_path(self.static_dir, MapMode.COMPACT))
            )
            self.replay_button = gui.add_button("save HTML replay", icon=viser.Icon.DEVICE_FLOPPY)
            self.export_md = gui.add_markdown("")
        self.g2o_button.on_click(lambda event: self._download(event.client, "g2o"))
        self.summary_button.on_click(lambda event: self._download(event.client, "summary"))
        self.sizes_button.on_click(lambda event: self._download(event.client, "sizes"))
        self.replay_button.on_click(lambda event: self._save_replay(event.client))

    def _guard_inputs(self) -> None:
        """Check every value a client can send before viser applies it (see validation.py)."""
        gate = self.gate = GuiGate(self.server, note=_log_refusal)
        maps = tuple(MODE_LABELS)
        gate.guard(self.mode_dropdown, choice(maps))
        gate.guard(self.compare_dropdown, choice(maps))
        gate.guard(self.speed_dropdown, choice(tuple(SPEEDS)))
        gate.guard(self.compare_checkbox, boolean())
        gate.guard(self.truth_checkbox, boolean())
        for button in (
            self.top_button,
            self.view3d_button,
            self.play_button,
            self.step_button,
            self.restart_button,
            self.reset_button,
            self.g2o_button,
            self.summary_button,
            self.sizes_button,
            self.replay_button,
        ):
            gate.guard(button, click())
        gate.guard(self.seek_slider, number(0.0, lambda: float(self.seek_slider.max)))
        for spec in SLIDERS + ADVANCED_SLIDERS:
            gate.guard(
                self.param_sliders[spec.name], number(spec.low, spec.high), note=self._param_note
            )
        gate.guard(self.replay_path, text())

    def _param_note(self, message: str) -> None:
        self.params_md.content = message

    def _add_param_slider(self, spec: SliderSpec, params: MapParams) -> None:
        value = clamp_to_slider(spec, getattr(params, spec.name))
        slider = self.server.gui.add_slider(
            spec.label,
            min=spec.low,
            max=spec.high,
            step=spec.step,
            initial_value=spec.low if value is None else value,
            hint=spec.hint,
        )
        slider.on_update(lambda _: self._on_param(spec))
        self.param_sliders[spec.name] = slider

    # ------------------------------------------------------------------ view
    @property
    def shown_modes(self) -> tuple[MapMode, ...]:
        """The displayed map and, side by side, the compared one."""
        first = MODE_LABELS.get(self.mode_dropdown.value, MapMode.COMPACT)
        if self.compare_checkbox.value:
            second = MODE_LABELS.get(self.compare_dropdown.value, MapMode.STANDARD)
            if second is not first:
                return (first, second)
        return (first,)

    def _apply_view(self) -> None:
        modes = self.shown_modes
        self.replay.set_priority(modes)
        with self.replay.lock, self._scene_lock:
            self.streamer.show(modes, self.truth_checkbox.value)
            self._publish_scene()
            self._update_counters()
            self._update_log(force=True)
        defaults = {str(default_replay_path(self.static_dir, m)) for m in MapMode}
        if self.replay_path.value in defaults:  # keep a path the user typed
            self.replay_path.value = str(default_replay_path(self.static_dir, modes[0]))

    def _set_camera(self, client: viser.ClientHandle | None, top: bool) -> None:
        position, look_at = self._camera_pose(top)
        clients = [client] if client is not None else list(self.server.get_clients().values())
        for c in clients:
            with c.atomic():
                c.camera.position = position
                c.camera.look_at = look_at

    def _camera_pose(self, top: bool) -> tuple[tuple[float, float, float], tuple[float, ...]]:
        extent = self.streamer.extent() or (-0.5, 3.5, -0.5, 2.5)
        cx, cy = (extent[0] + extent[1]) / 2, (extent[2] + extent[3]) / 2
        span = max(extent[1] - extent[0], extent[3] - extent[2], 1.0)
        if top:
            return (cx, cy - 0.05 * span, 0.9 * span + 0.4), (cx, cy, 0.0)
        return (cx + 0.5 * span, cy - 0.9 * span, 0.8 * span), (cx, cy, 0.0)

    def _update_initial_camera(self) -> None:
        extent = self.streamer.extent()
        if extent is None:
            return
        old = self._camera_extent
        if old is not None and all(abs(a - b) < 0.5 for a, b in zip(old, extent, strict=True)):
            return
        self._camera_extent = extent
        position, look_at = self._camera_pose(top=True)
        self.server.initial_camera.position = position
        self.server.initial_camera.look_at = look_at

    # ------------------------------------------------------------------ playback
    def _toggle_play(self) -> None:
        if self.replay.playing:
            self.replay.pause()
        else:
            self.replay.play()
        self._sync_play_button()

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

    def _on_seek(self) -> None:
        if getattr(self._local, "setting_seek", False):
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

    # ------------------------------------------------------------------ parameters
    def _on_param(self, spec: SliderSpec) -> None:
        if self._suppress_param_events:
            return
        slider = self.param_sliders[spec.name]
        value = clamp_to_slider(spec, slider.value)
        if value is None:  # refuse: back to the value in use
            current = getattr(self.replay.params, spec.name)
            self.params_md.content = f"refused {spec.name} = {slider.value!r}: not a number"
            slider.value = clamp_to_slider(spec, current) or spec.low
            return
        if value != slider.value:
            self.params_md.content = (
                f"{spec.name} = {slider.value!r} is outside [{spec.low:g}, {spec.high:g}]: "
                f"clamped to {value:g}"
            )
            slider.value = value  # calls this again with the clamped value
            return
        self.request_params()

    def current_slider_params(self) -> MapParams:
        """The parameters the sliders show, each clamped into its slider's range.

        A value that is not a finite number keeps the parameter in use. (A client can set a
        slider's value without its callback running, so every slider is checked here.)
        """
        params = self.replay.params
        values: dict[str, float] = {}
        for spec in SLIDERS + ADVANCED_SLIDERS:
            value = clamp_to_slider(spec, self.param_sliders[spec.name].value)
            values[spec.name] = getattr(params, spec.name) if value is None else value
        return params.with_changes(**values)

    def request_params(self) -> None:
        """Rebuild the maps for the sliders' values (latest wins)."""
        try:
            params = self.current_slider_params()
        except CogmapError as exc:
            self.params_md.content = f"refused: {exc}"
            return
        if params != self.replay.params:
            self.replay.set_params(params)

    def reset_params(self) -> None:
        """Back to the default parameter values (the paper's, or the log's; one rebuild)."""
        defaults = self.defaults
        self._suppress_param_events = True
        try:
            for name, slider in self.param_sliders.items():
                slider.value = getattr(defaults, name)
        finally:
            self._suppress_param_events = False
        self.params_md.content = "paper values" if defaults == MapParams() else "defaults"
        if self.replay.params != defaults:
            self.replay.set_params(defaults)

    # ================================================================== listener (worker thread)
    def on_status(self, replay: Replay) -> None:
        """Playback state changed (rate-limited except for state changes)."""
        if self._status_limit.due(forced=replay.state is not PlaybackState.PLAYING):
            self._update_status()

    def on_frame(self, replay: Replay, frame: Frame | EventStep, view_template: int | None) -> None:
        """Show the camera image (rate-limited; the latest one is shown when playback stops)."""
        self._pending_frame = (frame, view_template)
        if self._image_limit.due(not replay.playing):
            self._show_frame()

    def _show_frame(self) -> None:
        pending = self._pending_frame
        if pending is None:
            return
        self._pending_frame = None
        frame, view_template = pending
        if isinstance(frame, EventStep):  # a log: no camera; the latest links' scores instead
            self._show_links(frame)
            return
        self.camera_image.image = np.repeat(frame.image[:, :, None], 3, axis=2)  # RGB
        template = "–" if view_template is None else f"#{view_template}"
        self.template_md.content = (
            f"view template **{template}** · frame {frame.index} · t = {frame.time:.2f} s"
        )

    def _show_links(self, step: EventStep) -> None:
        """Hide the camera panel; list the latest place-recognition links with their scores."""
        if self.camera_image.visible:
            self.camera_image.visible = False
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
        with self._scene_lock:
            self._publish_scene()
            self._update_counters(forced)
            self._update_log()
            if self._chart_limit.due(forced):
                self._update_chart()
        self._update_status()
        self._update_initial_camera()

    # ------------------------------------------------------------------ page content
    def _publish_scene(self) -> None:
        session = self.replay.session
        log = session.log
        truth = log.ground_truth if len(log.ground_truth) else None
        count = min(self.replay.cursor, len(log.ground_truth))
        self.streamer.publish(dict(session.maps.maps), truth, count)

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
        speed = "max" if math.isinf(r.speed) else f"{r.speed:g}×"
        t = 0.0 if math.isnan(r.frame_time) else r.frame_time
        bag = html.escape(r.bag_path.name) if r.bag_path else "–"
        parts = [f'<b style="color:{color}">{state.value}</b>']
        if state is not PlaybackState.ERROR:
            parts.append(f"{speed} · t = {t:.1f} / {r.duration:.1f} s · {bag}")
        text = " · ".join(parts)
        message = ""
        if r.message:
            color = "#b00020" if state is PlaybackState.ERROR else "#555"
            message = (
                f'<div id="cogmap-message" style="color:{color};font-size:0.85em;'
                f'white-space:normal">{html.escape(r.message)}</div>'
            )
        return (
            f'<div id="cogmap-status" data-state="{state.value}" '
            f'style="padding:0.3em 0.6em;font-size:0.9em">{text}{message}</div>'
        )

    def _update_status(self) -> None:
        content = self._status_content()
        if self.status_html.content != content:
            self.status_html.content = content
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
        if r.state in (PlaybackState.PAUSED, PlaybackState.ENDED) and not math.isnan(r.frame_time):
            position = round(min(r.frame_time, self.seek_slider.max), 1)
            if abs(self.seek_slider.value - position) > 0.05:
                self._local.setting_seek = True  # (callbacks run on this thread)
                try:
                    self.seek_slider.value = position
                finally:
                    self._local.setting_seek = False
        self._sync_play_button()

    def _loop_closures_detected(self) -> int:
        log = self.replay.session.log
        k = self.replay.cursor
        end = log.frame_end[k - 1] if k else 0
        counted, links = self._links_counted
        if end < counted:
            counted, links = 0, 0
        links += sum(1 for e in log.events[counted:end] if isinstance(e, LinkToVertex))
        self._links_counted = (end, links)
        return links

    def _update_counters(self, forced: bool = True) -> None:
        r = self.replay
        session = r.session
        modes = self.streamer.shown
        if self._ate_limit.due(forced):
            self._ate = {m: session.ate(session.maps[m]) for m in modes}
            radius = session.evaluation.layout_radius  # the input kind's (8 cm for bags)
            self._fidelity = {m: session.layout_fidelity(session.maps[m], radius) for m in modes}
        t = 0.0 if math.isnan(r.frame_time) else r.frame_time
        rows = [
            ("time", "time", f"{t:.1f} / {r.duration:.1f} s"),
            ("frames", "frames", f"{r.cursor} / {r.total_frames}"),
            ("loops-detected", "loop closures detected", str(self._loop_closures_detected())),
        ]
        head = "".join(f"<th>{html.escape(m.value)}</th>" for m in modes)
        body = "".join(
            f'<tr><td>{label}</td><td colspan="{len(modes)}" id="cogmap-{key}">{value}</td></tr>'
            for key, label, value in rows
        )
        per_map: list[tuple[str, str, list[str]]] = []
        stats = [
            self._map_counts(session.maps[m], self._ate.get(m), self._fidelity.get(m))
            for m in modes
        ]
        radius = f"{session.evaluation.layout_radius * 100:g} cm"
        for key, label in (
            ("vertices", "vertices"),
            ("edges", "edges"),
            ("loops", "loop-closure edges"),
            ("clusters", "clusters"),
            ("optimizations", "optimizations"),
            ("ate", "ATE (m)"),
            ("completeness", f"completeness ({radius})"),
            ("correctness", f"correctness ({radius})"),
        ):
            per_map.append((key, label, [s[key] for s in stats]))
        body += f"<tr><td></td>{head}</tr>"
        for key, label, values in per_map:
            cells = "".join(
                f'<td id="cogmap-{m.value}-{key}">{v}</td>'
                for m, v in zip(modes, values, strict=True)
            )
            primary = f'<span id="cogmap-{key}" hidden>{values[0]}</span>'
            body += f"<tr><td>{label}{primary}</td>{cells}</tr>"
        content = (
            '<table id="cogmap-counters" style="width:100%;font-size:0.85em;'
            'font-variant-numeric:tabular-nums">' + body + "</table>"
        )
        if self.counters_html.content != content:
            self.counters_html.content = content

    @staticmethod
    def _map_counts(
        cmap: CognitiveMap, ate: float | None, fidelity: LayoutFidelity | None
    ) -> dict[str, str]:
        def share(value: float | None) -> str:
            return "–" if value is None or math.isnan(value) else f"{value:.3f}"

        return {
            "vertices": str(cmap.num_vertices),
            "edges": str(cmap.num_edges),
            "loops": str(cmap.num_loop_edges),
            "clusters": str(len(cmap.clusters)),
            "optimizations": str(len(cmap.optimizations)),
            "ate": "–" if ate is None else f"{ate:.3f}",
            "completeness": share(None if fidelity is None else fidelity.completeness),
            "correctness": share(None if fidelity is None else fidelity.correctness),
        }

    def _update_chart(self) -> None:
        session = self.replay.session
        order = (MapMode.STANDARD, MapMode.SCENE_INTEGRATION, MapMode.COMPACT)
        histories = [session.maps[m].size_history() for m in order]
        end = self.replay.data_time  # session data time (the bag's time when not resuming)
        end = 0.0 if math.isnan(end) else end
        times = np.linspace(0.0, max(end, 1e-3), CHART_POINTS)
        data: list[np.ndarray] = [times]
        for t, v, e in histories:
            idx = np.searchsorted(t, times, side="right") - 1
            ok = idx >= 0
            data.append(np.where(ok, v[np.maximum(idx, 0)] if v.size else 0, 0).astype(float))
            data.append(np.where(ok, e[np.maximum(idx, 0)] if e.size else 0, 0).astype(float))
        self.chart.data = tuple(data)

    def _update_log(self, force: bool = False) -> None:
        mode = self.streamer.shown[0] if self.streamer.shown else MapMode.COMPACT
        cmap = self.replay.session.maps[mode]
        key = (id(cmap), mode, len(cmap.optimizations), len(cmap.clusters), cmap.num_loop_edges)
        if key == self._log_key and not force:
            return
        self._log_key = key
        snap_clusters: list[int] = []
        if cmap.num_loop_edges:
            snap = cmap.snapshot()
            loops = snap.edge_cluster[snap.edge_kind == EdgeKind.LOOP_CLOSURE]
            snap_clusters = sorted(set(loops.tolist()))
        swatches = []
        for cid in snap_clusters[-24:]:
            r, g, b = cluster_color(cid)
            swatches.append(
                f'<span style="display:inline-block;margin:1px 4px 1px 0">'
                f'<span style="display:inline-block;width:10px;height:10px;'
                f'background:rgb({r},{g},{b});margin-right:2px"></span>{cid}</span>'
            )
        legend = (
            f'<div id="cogmap-legend" style="font-size:0.8em">'
            f"<b>{mode.value}</b>: loop-closure edges by cluster id "
            f"({len(snap_clusters)} cluster(s) with edges in the map)<br>"
            + ("".join(swatches) or "none yet")
            + "</div>"
        )
        self.legend_html.content = legend
        lines = [
            f"**{len(cmap.clusters)}** clusters, **{len(cmap.optimizations)}** optimisations "
            f"({sum(o.wall_s for o in cmap.optimizations):.2f} s in total)",
            "",
            "| t (s) | cluster | edges in cluster | V | iters | ms | merged | short |",
            "|---:|---:|---:|---:|---:|---:|---:|---:|",
        ]
        sizes = {c.cluster_id: c.edge_count for c in cmap.clusters}
        for o in reversed(cmap.optimizations[-12:]):
            cluster = "end" if o.cluster_id < 0 else str(o.cluster_id)
            lines.append(
                f"| {o.time:.1f} | {cluster} | {sizes.get(o.cluster_id, 0)} | {o.vertices} | "
                f"{o.iterations} | {o.wall_s * 1000:.0f} | {o.integrated} | "
                f"{o.short_edges_removed} |"
            )
        rebuilds = [b for b in self.replay.rebuilds if b.completed]
        if rebuilds:
            last = rebuilds[-1]
            shown = [f"{m.value} {last.latency(m) * 1000:.0f} ms" for m in last.published]
            lines.append("")
            lines.append("last parameter change shown after: " + ", ".join(shown))
        self.log_md.content = "\n".join(lines) if cmap.optimizations else lines[0]

    # ------------------------------------------------------------------ export
    def _download(self, client: viser.ClientHandle | None, what: str) -> None:
        try:
            with self.replay.lock:
                mode = self.shown_modes[0]
                if what == "g2o":
                    name, content = f"{mode.value}.g2o", g2o_bytes(self.replay.session.maps[mode])
                elif what == "summary":
                    name, content = "summary.json", summary_bytes(self.replay)
                else:
                    name, content = "sizes.csv", sizes_csv_bytes(self.replay)
        except Exception as exc:
            traceback.print_exc()
            self.export_md.content = f"export failed: {html.escape(str(exc))}"
            return
        self.export_md.content = f"sent {name} ({len(content)} bytes)"
        targets = [client] if client is not None else list(self.server.get_clients().values())
        for c in targets:
            c.send_file_download(name, content, save_immediately=True)

    def _save_replay(self, client: viser.ClientHandle | None) -> None:
        path = Path(self.replay_path.value).expanduser()
        self.export_md.content = f"saving the HTML replay to {path} …"

        def work() -> None:
            try:
                saved = save_html_replay(self.replay, self.shown_modes, path)
            except CogmapError as exc:
                self.export_md.content = f"replay not saved: {exc}"
                return
            except Exception as exc:
                traceback.print_exc()
                self.export_md.content = f"replay not saved: {type(exc).__name__}: {exc}"
                return
            self.exports.append(saved)
            self.export_md.content = f"saved the HTML replay to `{saved}`"

        threading.Thread(target=work, name="cogmap-html-replay", daemon=True).start()
