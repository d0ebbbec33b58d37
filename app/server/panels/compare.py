"""Pin and compare (each viewer's): keep a copy of the shown map, change the parameters, compare.

The pinned map (:class:`PinnedMap`: its snapshot, parameters and figures) is drawn in the
viewer's scene beside or under the live one (:func:`send_pinned`), and a table compares the two
(:func:`compare_table`).
"""

from __future__ import annotations

import html
import math
from dataclasses import dataclass

import numpy as np
import viser

from app.palette import PINNED_COLOR
from app.server.figures import layout_radius_label
from app.server.params import ALL_SLIDERS, format_value
from app.server.scene_style import edge_segments
from app.server.validation import GuiGate, choice, click
from cogmap_core.cognitive_map import EdgeKind, MapMode
from cogmap_core.config import MapParams
from cogmap_core.evaluation import EvaluationSettings
from cogmap_core.map_graph import MapSnapshot

#: Where the pinned map is drawn: beside the shown maps, or under the first.
PIN_DISPLAYS: tuple[str, ...] = ("beside", "under")
#: What the panel says while nothing is pinned.
COMPARE_HELP = (
    '<div class="cogmap-note" id="cogmap-compare">Pin the shown map, change the '
    "parameters, and compare the two here and in the scene.</div>"
)


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
class ComparePanel:
    """The handles of a viewer's "Compare with a pinned map — yours" panel."""

    pin_button: viser.GuiButtonHandle
    pin_dropdown: viser.GuiDropdownHandle[str]
    unpin_button: viser.GuiButtonHandle
    compare_html: viser.GuiHtmlHandle


def build_compare(
    gui: viser.GuiApi, folder: viser.GuiFolderHandle, pin_display: str
) -> ComparePanel:
    """Add a viewer's pin-and-compare panel into ``folder`` (the pinned map ``pin_display``)."""
    with folder:
        pin_button = gui.add_button("pin the shown map", icon=viser.Icon.PIN)
        pin_dropdown = gui.add_dropdown("pinned map", PIN_DISPLAYS, initial_value=pin_display)
        unpin_button = gui.add_button("unpin", icon=viser.Icon.PINNED_OFF)
        compare_html = gui.add_html(COMPARE_HELP)
    return ComparePanel(pin_button, pin_dropdown, unpin_button, compare_html)


def guard_compare(gate: GuiGate, panel: ComparePanel) -> None:
    """Check every value a client can send to its pin-and-compare panel."""
    gate.guard(panel.pin_dropdown, choice(PIN_DISPLAYS))
    for button in (panel.pin_button, panel.unpin_button):
        gate.guard(button, click())


def send_pinned(
    scene: viser.SceneApi, pinned: PinnedMap, marker: float, section: float
) -> tuple[viser.FrameHandle, list[viser.SceneNodeHandle]]:
    """Draw ``pinned`` under ``/pinned`` of a viewer's scene: its frame and its nodes.

    Vertices ``marker`` metres wide, the map's name above it (``section``: the grid's).
    """
    snap = pinned.snapshot
    nodes: list[viser.SceneNodeHandle] = []
    frame = scene.add_frame("/pinned", show_axes=False)
    n = snap.vertex_ids.shape[0]
    points = np.zeros((n, 3), dtype=np.float32)
    points[:, :2] = snap.poses[:, :2]
    if n:
        nodes.append(
            scene.add_point_cloud(
                "/pinned/vertices",
                points,
                colors=PINNED_COLOR,
                point_size=marker,
                point_shape="circle",
                point_shading="flat",
            )
        )
        top_left = (float(points[:, 0].min()), float(points[:, 1].max()))
        nodes.append(
            scene.add_label(
                "/pinned/name",
                f"pinned {pinned.mode.value.replace('_', ' ')}",
                position=(top_left[0], top_left[1] + 0.06 * section * 4, 0.009),
                anchor="bottom-left",
                font_screen_scale=1.25,
            )
        )
    if snap.edge_from.shape[0]:
        loop = snap.edge_kind == EdgeKind.LOOP_CLOSURE
        colors = np.where(loop[:, None], (40, 90, 130), PINNED_COLOR).astype(np.uint8)
        nodes.append(
            scene.add_line_segments(
                "/pinned/edges",
                edge_segments(snap),
                colors=np.repeat(colors[:, None, :], 2, axis=1),
                thickness=2.0,
                thickness_units="screen",
            )
        )
    return frame, nodes


def compare_table(
    pinned: PinnedMap,
    mode: MapMode,
    live_params: MapParams,
    live: dict[str, str],
    judging: EvaluationSettings,
) -> str:
    """The table comparing the live map ``mode`` (its figures ``live``) with ``pinned``."""
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
    radius = layout_radius_label(judging)
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
        f"<thead><tr><th></th><th>live {mode.value}</th>"
        f"<th>pinned {pinned.mode.value}</th></tr></thead><tbody>"
        + "".join(rows)
        + "</tbody></table>"
        f'<div class="cogmap-note">pinned at {when} of {html.escape(pinned.bag)} '
        f"({pinned.frames} frames); differing parameters in bold</div>"
    )
