"""Inspect (each viewer's): what a click on the map selected, a vertex or an edge, in a table.

:func:`nearest_pick` finds what lies under a click (a vertex's dot, or an edge away from its
ends); :func:`describe_vertex` and :func:`describe_edge` say what is known about it (an edge's
residual, its cluster, whether the ground truth calls it a false loop closure).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import viser
from numpy.typing import NDArray

from app.palette import cluster_color
from app.server.figures import FalseEdges
from app.server.panels import swatch
from app.server.scene_style import edge_error
from app.server.validation import GuiGate, click
from cogmap_core.cognitive_map import CognitiveMap, EdgeKind, MapMode
from cogmap_core.map_graph import MapSnapshot, nearest_vertex

#: What the panel says while nothing is selected.
INSPECT_HELP = (
    '<div class="cogmap-note" id="cogmap-inspect">Click a vertex or an edge of '
    "the map to see what it is.</div>"
)


@dataclass(frozen=True, slots=True)
class InspectPanel:
    """The handles of a viewer's "Inspect — yours" panel."""

    inspect_html: viser.GuiHtmlHandle
    clear_button: viser.GuiButtonHandle


def build_inspect(gui: viser.GuiApi, folder: viser.GuiFolderHandle) -> InspectPanel:
    """Add a viewer's inspection panel into ``folder`` (nothing selected)."""
    with folder:
        inspect_html = gui.add_html(INSPECT_HELP)
        clear_button = gui.add_button("clear selection", icon=viser.Icon.X)
    return InspectPanel(inspect_html, clear_button)


def guard_inspect(gate: GuiGate, panel: InspectPanel) -> None:
    """Check what a client can send to its inspection panel (a click)."""
    gate.guard(panel.clear_button, click())


@dataclass(frozen=True, slots=True)
class Pick:
    """What a click selected: a vertex or an edge of a shown map."""

    mode: MapMode
    kind: str  # "vertex" or "edge"
    index: int  # into the snapshot's vertices or edges
    html: str
    segment: NDArray[np.float64]  # (2, 2) the edge's ends, or the vertex twice
    summary: str = ""  # one line, written beside it in the scene


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
    residual = edge_error(snap, index, cmap.params.link_sigmas(), cmap.params.odometry_noise())
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
    nearest = nearest_vertex(snap.poses, point)
    if nearest is None:
        return None
    k, d_k = nearest
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
    if gap_e <= tolerance and gap_e < d_k:
        seg = np.array([a[e], b[e]])
        loop = snap.edge_kind[e] == EdgeKind.LOOP_CLOSURE
        false = (float(snap.edge_time[e]), int(snap.edge_to[e])) in false_edges
        summary = f"{name}: edge {int(snap.edge_from[e])} → {int(snap.edge_to[e])}" + (
            " (loop closure" + (", false)" if false else ")") if loop else ""
        )
        html_ = describe_edge(cmap, snap, e, false_edges)
        return gap_e, Pick(mode, "edge", e, html_, seg, summary)
    if d_k <= tolerance:
        seg = np.array([snap.poses[k, :2], snap.poses[k, :2]])
        summary = f"{name}: vertex {int(snap.vertex_ids[k])} ({snap.vertex_time[k]:.1f} s)"
        return d_k, Pick(mode, "vertex", k, describe_vertex(cmap, snap, k), seg, summary)
    return None
