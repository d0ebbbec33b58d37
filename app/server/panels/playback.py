"""The playback panel (shared): play or pause, speed, one frame, restart, seek; the status line.

Every control only asks the replay worker (:class:`~app.server.replay.Replay`) for something;
the worker does it on its own thread, and the page follows its state
(:meth:`PlaybackControls.follow`).
"""

from __future__ import annotations

import html
import math
import threading
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

import viser

from app.server.params import SliderSpec, format_value, parse_typed
from app.server.replay_state import PlaybackState
from app.server.timing import RateLimit
from app.server.validation import (
    Adjusted,
    Adjustment,
    GuiGate,
    Refusal,
    Refused,
    choice,
    click,
    number,
)

if TYPE_CHECKING:
    from app.server.files import Scrubber
    from app.server.replay import Replay

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
_STATE_COLORS: dict[PlaybackState, str] = {
    PlaybackState.LOADING: "#8a6d00",
    PlaybackState.PLAYING: "#1e8c3c",
    PlaybackState.PAUSED: "#555555",
    PlaybackState.ENDED: "#34659f",
    PlaybackState.ERROR: "#b00020",
}


@dataclass(frozen=True, slots=True)
class PlaybackPanel:
    """The playback panel's handles ("Playback — shared")."""

    play_button: viser.GuiButtonHandle
    speed_dropdown: viser.GuiDropdownHandle[str]
    step_button: viser.GuiButtonHandle
    restart_button: viser.GuiButtonHandle
    seek_slider: viser.GuiSliderHandle[float]
    seek_box: viser.GuiTextHandle
    progress: viser.GuiProgressBarHandle


def build_playback(gui: viser.GuiApi, speed: float, autoplay: bool) -> PlaybackPanel:
    """Add the playback folder: ``speed`` chosen, "pause" shown when ``autoplay``."""
    with gui.add_folder("Playback — shared"):
        play_button = gui.add_button(
            "pause" if autoplay else "play",
            icon=viser.Icon.PLAYER_PAUSE if autoplay else viser.Icon.PLAYER_PLAY,
        )
        speed_label = next((k for k, v in SPEEDS.items() if v == speed), "1x")
        speed_dropdown = gui.add_dropdown("speed", tuple(SPEEDS), initial_value=speed_label)
        step_button = gui.add_button("step one frame", icon=viser.Icon.PLAYER_TRACK_NEXT)
        restart_button = gui.add_button("restart", icon=viser.Icon.PLAYER_SKIP_BACK)
        seek_slider = gui.add_slider("seek (s)", 0.0, 1.0, 0.1, 0.0)
        seek_box = gui.add_text("go to (s)", "0", hint="type a data time, then Enter")
        progress = gui.add_progress_bar(0.0)
    return PlaybackPanel(
        play_button, speed_dropdown, step_button, restart_button, seek_slider, seek_box, progress
    )


def status_content(replay: Replay, waiting: bool, note: str, scrubber: Scrubber) -> str:
    """The status line: the replay's state, speed, position and input, and its message.

    ``waiting``: the replay waits for the first viewer; ``note``: what was done with the value
    typed last into "go to" (shown as an error).
    """
    r = replay
    state = r.state
    color = _STATE_COLORS[state]
    t = 0.0 if math.isnan(r.frame_time) else r.frame_time
    bag = html.escape(r.bag_path.name) if r.bag_path else "–"
    label = state.value
    if waiting and state is PlaybackState.PAUSED:
        label = "waiting for the first viewer"
    parts = [f'<b style="color:{color}">{label}</b>']
    if state is PlaybackState.PLAYING:
        parts.append("max speed" if math.isinf(r.speed) else f"{r.speed:g}×")
    if state is not PlaybackState.ERROR:
        parts.append(f"t = {t:.1f} / {r.duration:.1f} s · {bag}")
    text_ = " · ".join(parts)
    message = ""
    if r.message or note:
        mcolor = "#b00020" if state is PlaybackState.ERROR or note else "#555"
        message = (
            f'<div id="cogmap-message" style="color:{mcolor};font-size:0.85em;'
            f'white-space:normal">{html.escape(scrubber.scrub(r.message or note))}</div>'
        )
    return (
        f'<div id="cogmap-status" data-state="{state.value}" '
        f'style="padding:0.3em 0.6em;font-size:0.9em">{text_}{message}</div>'
    )


class PlaybackHost(Protocol):
    """What the playback panel uses of the page: the replay, and the status to show again."""

    replay: Replay

    def update_status(self, force: bool = False) -> None:
        """Show the replay's state on the page (``force``: now, not rate-limited)."""


class PlaybackControls:
    """What the playback panel's controls do (module doc); ``panel`` holds them."""

    def __init__(self, panel: PlaybackPanel, host: PlaybackHost) -> None:
        """Wire ``panel``'s controls to ``host``'s replay."""
        self.panel = panel
        self.host = host
        self.status_note = ""  # what the gate did with the value typed last into "go to"
        self._seek_box_limit = RateLimit(1.0)  # the "go to" box while playing
        # set while the page itself moves the seek controls (per thread: viser runs callbacks on
        # a pool, and another viewer's change must not be swallowed meanwhile)
        self._setting = threading.local()
        panel.play_button.on_click(lambda _: self.toggle_play())
        panel.speed_dropdown.on_update(lambda _: self._on_speed())
        panel.step_button.on_click(lambda _: self.host.replay.step())
        panel.restart_button.on_click(lambda _: self.restart())
        panel.seek_slider.on_update(lambda _: self._on_seek())
        panel.seek_box.on_update(lambda _: self._on_seek_box())

    def guard(self, gate: GuiGate) -> None:
        """Check every value a client can send to the panel's controls."""
        p = self.panel
        gate.guard(p.speed_dropdown, choice(tuple(SPEEDS)))
        for button in (p.play_button, p.step_button, p.restart_button):
            gate.guard(button, click())
        gate.guard(p.seek_slider, number(0.0, lambda: float(p.seek_slider.max)))
        gate.guard(p.seek_box, self._seek_check(), note=self._seek_note)

    # ------------------------------------------------------------------ what the controls do
    def toggle_play(self) -> None:
        """The play/pause button ("play" at the end plays again from the start)."""
        r = self.host.replay
        if r.state is PlaybackState.ENDED or r.at_end:
            r.restart()  # "play" at the end plays again from the start
            r.play()
        elif r.playing:
            r.pause()
        else:
            r.play()
        self.sync_play_button()
        self.host.update_status(force=True)

    def sync_play_button(self) -> None:
        """Label the play button for what a click does now."""
        replay = self.host.replay
        playing = replay.playing and replay.state is not PlaybackState.ENDED
        label = "pause" if playing else "play"
        button = self.panel.play_button
        if button.label != label:
            button.label = label
            button.icon = viser.Icon.PLAYER_PAUSE if playing else viser.Icon.PLAYER_PLAY

    def restart(self) -> None:
        """Back to the first frame and play (the restart button; after the end as before it)."""
        self.host.replay.restart()
        self.host.replay.play()
        self.sync_play_button()
        self.host.update_status(force=True)

    def _on_speed(self) -> None:
        dropdown = self.panel.speed_dropdown
        speed = SPEEDS.get(dropdown.value)
        if speed is None:  # a client sent an unknown option
            dropdown.value = "1x"
            return
        self.host.replay.set_speed(speed)
        self.host.update_status(force=True)

    def _on_seek(self) -> None:
        if getattr(self._setting, "seek", False):
            return  # the slider following playback, not a user
        slider = self.panel.seek_slider
        value = slider.value
        if not math.isfinite(value):
            return
        high = slider.max
        clamped = min(max(float(value), 0.0), float(high))
        if clamped != value:
            slider.value = clamped
            return
        self.host.replay.seek(clamped)

    def _seek_check(self) -> Any:
        def check(value: object) -> object:
            self.status_note = ""  # a note is about the value typed last (set again below)
            if not isinstance(value, str):
                raise Refused(f"{value!r} is not text")
            spec = SliderSpec("seek", "seek", 0.0, float(self.panel.seek_slider.max), 0.1, "")
            typed = parse_typed(spec, value)
            normal = format_value(round(typed.value, 1))
            return Adjusted(normal, typed.message) if normal != value else normal

        return check

    def _seek_note(self, note: Refusal | Adjustment) -> None:
        self.status_note = note.message
        self.host.update_status(force=True)

    def _on_seek_box(self) -> None:
        if getattr(self._setting, "seek", False):
            return
        try:
            value = float(self.panel.seek_box.value)
        except ValueError:
            return
        if math.isfinite(value):
            self.host.replay.seek(min(max(value, 0.0), float(self.panel.seek_slider.max)))

    # ------------------------------------------------------------------ following the replay
    def follow(self, force: bool = False) -> None:
        """Move the seek controls and the progress bar to the replay's position; label "play"."""
        r = self.host.replay
        p = self.panel
        if r.duration > 0 and p.seek_slider.max != round(r.duration, 1):
            p.seek_slider.max = round(r.duration, 1)
        fraction = 0.0
        if r.duration > 0 and not math.isnan(r.frame_time):
            fraction = min(100.0, 100.0 * r.frame_time / r.duration)
        if r.at_end:
            fraction = 100.0
        if abs(p.progress.value - fraction) >= 0.1:
            p.progress.value = fraction
        if not math.isnan(r.frame_time) and r.state is not PlaybackState.LOADING:
            position = round(min(r.frame_time, p.seek_slider.max), 1)
            self._setting.seek = True  # (callbacks run on this thread)
            try:
                if abs(p.seek_slider.value - position) > 0.05:
                    p.seek_slider.value = position
                playing = r.state is PlaybackState.PLAYING
                if self._seek_box_limit.due(force or not playing):
                    p.seek_box.value = format_value(position)
            finally:
                self._setting.seek = False
        self.sync_play_button()
