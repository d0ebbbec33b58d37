"""The map parameters' panel (shared): a slider and a box to type into per parameter, and reset.

A value is clamped into its slider's range (:mod:`app.server.params` reads what was typed); the
controls' values then become one :class:`~cogmap_core.config.MapParams`, which the replay worker
rebuilds the maps for (the latest request wins). The panel also says what the maps were built
with (:func:`built_content`, shown under *Live*).
"""

from __future__ import annotations

import html
import threading
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

import viser

from app.server.panels import note_html
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
from app.server.validation import (
    Adjusted,
    Adjustment,
    GuiGate,
    Refusal,
    Refused,
    click,
    number,
)
from cogmap_core.cognitive_map import CognitiveMap, MapMode
from cogmap_core.config import MapParams
from cogmap_core.errors import CogmapError
from cogmap_core.slam import ALL_MODES

if TYPE_CHECKING:
    from app.server.replay import Replay


@dataclass(frozen=True, slots=True)
class ParametersPanel:
    """The parameters panel's handles ("Map parameters — shared"), by parameter name."""

    param_sliders: dict[str, viser.GuiSliderHandle[float]]
    param_boxes: dict[str, viser.GuiTextHandle]
    reset_button: viser.GuiButtonHandle
    params_md: viser.GuiHtmlHandle


def defaults_name(defaults: MapParams) -> str:
    """What "reset" returns to: the paper's values, or the input kind's defaults."""
    return "paper values" if defaults == MapParams() else "defaults"


def reset_label(defaults: MapParams) -> str:
    """The reset button's label."""
    return f"reset to {defaults_name(defaults)}"


def params_message(text: str, error: bool = False) -> str:
    """The panel's message (``#cogmap-params-message``)."""
    return note_html("cogmap-params-message", text, error)


def build_parameters(gui: viser.GuiApi, params: MapParams, defaults: MapParams) -> ParametersPanel:
    """Add the parameters folder, the sliders showing ``params`` (advanced ones folded)."""
    for spec in ALL_SLIDERS:
        check_spec(spec)
    sliders: dict[str, viser.GuiSliderHandle[float]] = {}
    boxes: dict[str, viser.GuiTextHandle] = {}

    def add(spec: SliderSpec) -> None:
        value = clamp_to_slider(spec, getattr(params, spec.name))
        value = spec.low if value is None else value
        sliders[spec.name] = gui.add_slider(
            spec.label,
            min=spec.low,
            max=spec.high,
            step=spec.step,
            initial_value=value,
            hint=spec.hint,
        )
        boxes[spec.name] = gui.add_text(
            f"{spec.label} =", format_value(value), hint=f"type {spec.label}, then Enter"
        )

    with gui.add_folder("Map parameters — shared"):
        for spec in SLIDERS:
            add(spec)
        with gui.add_folder("Advanced", expand_by_default=False):
            for spec in ADVANCED_SLIDERS:
                add(spec)
        reset_button = gui.add_button(reset_label(defaults), icon=viser.Icon.RESTORE)
        message = gui.add_html(params_message(defaults_name(defaults)))
    return ParametersPanel(sliders, boxes, reset_button, message)


def built_content(
    maps: Mapping[MapMode, CognitiveMap],
    rebuilding: tuple[MapParams, tuple[MapMode, ...]] | None,
    previews: Mapping[MapMode, str] | None = None,
    differences: Mapping[MapMode, tuple[float, int]] | None = None,
) -> str:
    """What the maps were built with, and which are being rebuilt (for what).

    ``previews``: the maps drawn by a preview until their exact map arrives, with what the
    preview is (:mod:`app.server.preview`); ``differences``: per map of the latest parameter
    change whose exact map replaced a preview, how far the preview was from it (largest vertex
    shift in m, the preview's vertices minus the exact map's).
    """
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
    content = _preview_notes(previews or {}, differences or {}) + content
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


def _preview_notes(
    previews: Mapping[MapMode, str], differences: Mapping[MapMode, tuple[float, int]]
) -> str:
    """The maps shown as a preview, and how far the latest previews were from the exact maps."""
    lines = [
        f"<b>{html.escape(mode.value.replace('_', ' '))}: preview</b> "
        f"({html.escape(what)}) until the exact map arrives"
        for mode, what in previews.items()
    ]
    for mode in ALL_MODES:
        if mode in differences and mode not in previews:
            shift, count = differences[mode]
            lines.append(
                f"{html.escape(mode.value.replace('_', ' '))}: exact map shown; the preview "
                f"differed by {shift:.3f} m (largest vertex shift), {count:+d} vertices"
            )
    if not lines:
        return ""
    return '<div class="cogmap-note" id="cogmap-preview">' + "<br>".join(lines) + "</div>"


class ParametersHost(Protocol):
    """What the parameters panel uses of the page: the replay, and what "reset" returns to."""

    replay: Replay
    defaults: MapParams


class ParameterControls:
    """What the parameters panel's controls do (module doc); ``panel`` holds them."""

    def __init__(self, panel: ParametersPanel, host: ParametersHost) -> None:
        """Wire ``panel``'s controls to ``host``'s replay."""
        self.panel = panel
        self.host = host
        self._typed: dict[str, tuple[str, str]] = {}  # box -> (normal text, message)
        # set while the page itself sets a control (per thread: viser runs callbacks on a pool,
        # and another viewer's change must not be swallowed meanwhile)
        self._setting = threading.local()
        for spec in ALL_SLIDERS:
            panel.param_sliders[spec.name].on_update(lambda _, spec=spec: self._on_slider(spec))
            panel.param_boxes[spec.name].on_update(lambda _, spec=spec: self._on_box(spec))
        panel.reset_button.on_click(lambda _: self.reset_params())

    def guard(self, gate: GuiGate) -> None:
        """Check every value a client can send to the panel's controls."""
        p = self.panel
        gate.guard(p.reset_button, click())
        for spec in ALL_SLIDERS:
            gate.guard(
                p.param_sliders[spec.name], number(spec.low, spec.high), note=self._param_note
            )
            gate.guard(
                p.param_boxes[spec.name],
                self._box_check(spec),
                label=spec.label,
                note=self._param_note,
            )

    def _say(self, text: str, error: bool = False) -> None:
        self.panel.params_md.content = params_message(text, error)

    def _param_note(self, note: Refusal | Adjustment) -> None:
        """Show what the gate did with a parameter's value.

        A refusal reads ``refused δ: 'abc' is not a number; δ stays 3.746``.
        """
        if isinstance(note, Adjustment):
            self._say(note.message)
            return
        kept = note.kept if isinstance(note.kept, str) else repr(note.kept)
        self._say(f"refused {note.label}: {note.reason}; {note.label} stays {kept}", error=True)

    def _set_quietly(self, handle: Any, value: Any) -> None:
        self._setting.params = True
        try:
            handle.value = value
        finally:
            self._setting.params = False

    def _on_slider(self, spec: SliderSpec) -> None:
        if getattr(self._setting, "params", False):
            return
        slider = self.panel.param_sliders[spec.name]
        value = clamp_to_slider(spec, slider.value)
        if value is None:  # refuse: back to the value in use
            current = getattr(self.host.replay.params, spec.name)
            self._say(
                f"refused {spec.label} = {slider.value!r}: not a number; "
                f"{spec.label} stays {format_value(current)}",
                error=True,
            )
            self._set_quietly(slider, clamp_to_slider(spec, current) or spec.low)
            return
        if value != slider.value:
            self._say(
                f"{spec.label} = {slider.value!r} is outside [{format_value(spec.low)}, "
                f"{format_value(spec.high)}]: using {format_value(value)}"
            )
            self._set_quietly(slider, value)
        else:
            self._say(f"{spec.label} = {format_value(value)}")
        self._set_quietly(self.panel.param_boxes[spec.name], format_value(value))
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
        box = self.panel.param_boxes[spec.name]
        try:
            typed = parse_typed(spec, box.value)
        except Refused as exc:  # only a value set without the gate can get here
            current = getattr(self.host.replay.params, spec.name)
            self._param_note(Refusal(spec.label, str(exc), format_value(current)))
            self._set_quietly(box, format_value(current))
            return
        message = typed.message
        remembered = self._typed.pop(spec.name, None)
        if remembered is not None and remembered[0] == box.value:
            message = remembered[1]  # what was typed, before the gate normalised it
        self._say(message)
        self._set_quietly(box, format_value(typed.value))
        self._set_quietly(self.panel.param_sliders[spec.name], typed.value)
        self.request_params()

    def type_param(self, name: str, typed: str) -> None:
        """``typed`` entered into a parameter's box, as a browser sends it (scripts and tests)."""
        spec = SPECS[name]
        box = self.panel.param_boxes[name]
        try:
            value = self._box_check(spec)(typed)
        except Refused as exc:
            current = getattr(self.host.replay.params, spec.name)
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
        params = self.host.replay.params
        values: dict[str, float] = {}
        for spec in ALL_SLIDERS:
            value = clamp_to_slider(spec, self.panel.param_sliders[spec.name].value)
            values[spec.name] = getattr(params, spec.name) if value is None else value
        return params.with_changes(**values)

    def request_params(self) -> None:
        """Rebuild the maps for the controls' values (latest wins)."""
        try:
            params = self.current_slider_params()
        except CogmapError as exc:
            self._say(f"refused: {exc}", error=True)
            return
        if params != self.host.replay.params:
            self.host.replay.set_params(params)

    def reset_params(self) -> None:
        """Back to the default parameter values (the paper's, or the log's; one rebuild)."""
        defaults = self.host.defaults
        for name, slider in self.panel.param_sliders.items():
            self._set_quietly(slider, getattr(defaults, name))
            self._set_quietly(self.panel.param_boxes[name], format_value(getattr(defaults, name)))
        self._say(defaults_name(defaults))
        if self.host.replay.params != defaults:
            self.host.replay.set_params(defaults)

    def defaults_changed(self) -> None:
        """The defaults changed (another kind of input): relabel reset and show them."""
        self.panel.reset_button.label = reset_label(self.host.defaults)
        self.reset_params()  # the sliders show the kind's defaults (no rebuild: in use)
