"""Layers and view (each viewer's): which map, side by side, edge colours, layers, the camera.

The controls say what one viewer looks at (:class:`ViewState`, read whole by
:func:`read_state`); :class:`~app.server.view.ClientView` shows it. The legend below them
explains the colours of what is shown (:func:`legend_html`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import viser

from app.palette import (
    FALSE_LOOP_COLOR,
    GROUND_TRUTH_COLOR,
    MAP_COLORS,
    ODOMETRY_COLOR,
    PINNED_COLOR,
)
from app.server.figures import false_link_label
from app.server.panels import swatch
from app.server.scene_style import ERROR_RAMP_CSS, ERROR_SCALE_MAX, TIME_RAMP_CSS
from app.server.validation import GuiGate, boolean, choice, click
from cogmap_core.cognitive_map import MapMode
from cogmap_core.evaluation import EvaluationSettings
from cogmap_core.map_modes import ALL_MODES

MODE_NAMES: tuple[str, ...] = tuple(m.value for m in ALL_MODES)
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


@dataclass(frozen=True, slots=True)
class LayersPanel:
    """The handles of a viewer's "View — yours" panel."""

    mode_dropdown: viser.GuiDropdownHandle[str]
    compare_checkbox: viser.GuiCheckboxHandle
    compare_dropdown: viser.GuiDropdownHandle[str]
    colouring_dropdown: viser.GuiDropdownHandle[str]
    layer_checkboxes: dict[str, viser.GuiCheckboxHandle]
    follow_checkbox: viser.GuiCheckboxHandle
    top_button: viser.GuiButtonHandle
    view3d_button: viser.GuiButtonHandle
    legend_html: viser.GuiHtmlHandle

    def inputs(self) -> tuple[viser.GuiInputHandle, ...]:
        """The controls whose values make up the :class:`ViewState` (see :func:`read_state`)."""
        return (
            self.mode_dropdown,
            self.compare_checkbox,
            self.compare_dropdown,
            self.colouring_dropdown,
            self.follow_checkbox,
            *self.layer_checkboxes.values(),
        )


def build_layers(gui: viser.GuiApi, folder: viser.GuiFolderHandle, s: ViewState) -> LayersPanel:
    """Add a viewer's view controls into ``folder``, showing ``s``."""
    with folder:
        mode_dropdown = gui.add_dropdown("map", MODE_NAMES, initial_value=s.mode.value)
        compare_checkbox = gui.add_checkbox("side by side", s.compare)
        compare_dropdown = gui.add_dropdown(
            "compare with", MODE_NAMES, initial_value=s.compare_mode.value
        )
        colouring_dropdown = gui.add_dropdown(
            "colour edges by",
            tuple(COLOURING_LABELS.values()),
            initial_value=COLOURING_LABELS["cluster"],
        )
        with gui.add_folder("Layers", expand_by_default=False):
            layer_checkboxes = {
                name: gui.add_checkbox(label, s.layers[name])
                for name, label in LAYER_LABELS.items()
            }
        follow_checkbox = gui.add_checkbox(
            "follow the map", s.follow, hint="re-frame the camera as the map grows"
        )
        top_button = gui.add_button("plan view", icon=viser.Icon.MAP_2)
        view3d_button = gui.add_button("3-D view", icon=viser.Icon.VIEW_360)
        legend_html = gui.add_html("")
    return LayersPanel(
        mode_dropdown, compare_checkbox, compare_dropdown, colouring_dropdown, layer_checkboxes,
        follow_checkbox, top_button, view3d_button, legend_html,
    )  # fmt: skip


def guard_layers(gate: GuiGate, panel: LayersPanel) -> None:
    """Check every value a client can send to its view controls."""
    gate.guard(panel.mode_dropdown, choice(MODE_NAMES))
    gate.guard(panel.compare_dropdown, choice(MODE_NAMES))
    gate.guard(panel.colouring_dropdown, choice(tuple(COLOURING_LABELS.values())))
    for handle in (panel.compare_checkbox, panel.follow_checkbox, *panel.layer_checkboxes.values()):
        gate.guard(handle, boolean())
    for button in (panel.top_button, panel.view3d_button):
        gate.guard(button, click())


def read_state(panel: LayersPanel, pin_display: str) -> ViewState:
    """What the controls say the viewer looks at (the pinned map drawn ``pin_display``)."""
    labels = {v: k for k, v in COLOURING_LABELS.items()}
    return ViewState(
        mode=MapMode(panel.mode_dropdown.value),
        compare=bool(panel.compare_checkbox.value),
        compare_mode=MapMode(panel.compare_dropdown.value),
        colouring=labels.get(panel.colouring_dropdown.value, "cluster"),
        layers={name: bool(box.value) for name, box in panel.layer_checkboxes.items()},
        follow=bool(panel.follow_checkbox.value),
        pin_display=pin_display,
    )


def legend_html(
    s: ViewState,
    judging: EvaluationSettings,
    grid: tuple[float, float],
    pinned: MapMode | None,
) -> str:
    """The legend of what ``s`` shows: colours, the grid's ``(cell, section)``, the pinned map."""
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
        f"({false_link_label(judging)})"
    )
    parts.append(
        f"{swatch(GROUND_TRUTH_COLOR)}ground truth, aligned to each map by the rigid "
        "transform of the ATE (least squares over the vertices)"
    )
    if s.layers["odometry"]:
        parts.append(f"{swatch(ODOMETRY_COLOR)}dead-reckoned odometry (the map's frame)")
    if s.layers["grid"]:
        cell, section = grid
        parts.append(
            f"grid: {cell:g} m cells, {section:g} m sections (scale bar: {section:g} m, "
            "bottom right); each map's name above it"
        )
    parts.append(f"{swatch((15, 15, 15))}robot")
    if pinned is not None:
        parts.append(f"{swatch(PINNED_COLOR)}pinned {pinned.value} map ({s.pin_display})")
    return '<div class="cogmap-note" id="cogmap-legend">' + "<br>".join(parts) + "</div>"
