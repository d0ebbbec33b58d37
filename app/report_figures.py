"""Report figures drawn with matplotlib, each saved as a PNG with an SVG beside it.

``map.png`` (each map over its aligned ground truth), ``size.png`` (the paper's size-over-time
figure), the sweep's ``pareto.png`` and the long-term benchmark's ``long_term.png`` are drawn
the way evo draws its plots: axes with units and ticks that suit any extent (matplotlib's
locator), a grid, a legend, maps at equal scale in metres. The colours are the page's
(:mod:`app.palette`): one per map everywhere, red only for false loop closures.

:func:`save_figure` writes the PNG (150 dpi) and an SVG of the same name for papers (text kept as
text, reproducible: no date, fixed ids), each atomically
(:func:`~cogmap_core.fileio.write_bytes_atomic`: a reader never sees half a file, a failed write
leaves the previous one). matplotlib is imported
only when a figure is drawn (the web app starts without it), and through its object API, not
``pyplot``: no global state, safe in any thread.
"""

from __future__ import annotations

import io
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from app.palette import (
    FALSE_LOOP_COLOR,
    GROUND_TRUTH_COLOR,
    INK,
    MAP_COLORS,
    PINNED_COLOR,
    hex_color,
)
from cogmap_core.cognitive_map import EdgeKind, MapMode
from cogmap_core.fileio import write_bytes_atomic
from cogmap_core.map_graph import MapSnapshot
from cogmap_core.map_modes import ALL_MODES

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

FloatArray = NDArray[np.float64]
Histories = Mapping[MapMode, tuple[FloatArray, NDArray[np.int64], NDArray[np.int64]]]

#: Resolution of the PNGs.
DPI = 150
#: Loop-closure edges that are not false (the map's own colour is its sequential edges').
LOOP_COLOR = "#555555"
_STYLE = {
    "svg.hashsalt": "cogmap",  # the same figure gives the same SVG
    "svg.fonttype": "none",  # text stays text (editable in a paper)
    "font.size": 9.0,
    "axes.titlesize": 9.5,
    "axes.labelsize": 9.0,
    "legend.fontsize": 8.0,
    "axes.grid": True,
    "grid.color": "#dddddd",
    "grid.linewidth": 0.6,
    "axes.edgecolor": hex_color(INK),
    "axes.axisbelow": True,
}


def map_color(mode: MapMode) -> str:
    """A map's colour in every figure (the page's)."""
    return hex_color(MAP_COLORS[mode])


def _figure(width: float, height: float) -> Figure:
    from matplotlib.figure import Figure

    return Figure(figsize=(width, height), dpi=DPI, layout="constrained")


def save_figure(figure: Figure, png: Path) -> list[Path]:
    """Write ``figure`` as ``png`` and as the SVG beside it (``.svg``); returns both paths.

    Each file is written atomically; the PNG first.

    Raises:
        OSError: a file cannot be written (e.g. a full disk), with the system's reason.

    """
    import matplotlib

    png = Path(png)
    svg = png.with_suffix(".svg")
    with matplotlib.rc_context(_STYLE):
        for path, kind in ((png, "png"), (svg, "svg")):
            buffer = io.BytesIO()
            metadata: dict[str, Any] = {"Software": None} if kind == "png" else {"Date": None}
            figure.savefig(buffer, format=kind, dpi=DPI, metadata=metadata)
            write_bytes_atomic(path, buffer.getvalue())
    return [png, svg]


def styled(draw: Any) -> Any:
    """Run ``draw`` with the figures' style (matplotlib reads it while drawing)."""
    import matplotlib

    with matplotlib.rc_context(_STYLE):
        return draw()


# --------------------------------------------------------------------------- size.png
def size_figure(histories: Histories, end_time: float) -> Figure:
    """The paper's size figure: vertices (left) and edges (right) over data time, per map."""

    def draw() -> Figure:
        figure = _figure(9.0, 3.6)
        axes = figure.subplots(1, 2)
        end = max(float(end_time), 1e-6)
        for k, (ax, title) in enumerate(zip(axes, ("vertices", "edges"), strict=True)):
            for mode, (times, vertices, edges) in histories.items():
                values = (vertices, edges)[k]
                # sizes hold until the next change, and until the end of the data
                t = np.r_[times, end] if times.size else np.array([0.0, end])
                v = np.r_[values, values[-1]] if values.size else np.zeros(2)
                ax.step(t, v, where="post", color=map_color(mode), lw=1.6, label=_name(mode))
            ax.set_xlim(0.0, end)
            ax.set_ylim(bottom=0.0)
            ax.set_xlabel("data time (s)")
            ax.set_ylabel(f"number of {title}")
            ax.set_title(f"{title} of each map")
        if histories:
            axes[0].legend(loc="upper left", frameon=False)
        return figure

    return styled(draw)


def _name(mode: MapMode) -> str:
    return mode.value.replace("_", " ")


# --------------------------------------------------------------------------- map.png
def map_figure(
    ground_truth: FloatArray | None,
    maps: Mapping[MapMode, MapSnapshot],
    aligned_poses: Mapping[MapMode, FloatArray] | None = None,
    notes: Mapping[MapMode, str] | None = None,
    false_edges: Mapping[MapMode, NDArray[np.bool_]] | None = None,
) -> Figure:
    """Each map over the ground truth, side by side at one scale (the paper's map figure).

    ``aligned_poses``: each map's vertex poses aligned onto the ground truth (the ATE's rigid
    alignment; default: as they are); ``notes``: a second title line per map (its ATE and
    fidelity); ``false_edges``: per map, which of its edges are false loop closures (red).
    Vertices are dots and sequential edges lines in the map's colour, loop closures grey, the
    ground truth a light grey band; axes in metres, equal scale.
    """

    def draw() -> Figure:
        panels = len(maps)
        poses = {m: (aligned_poses or {}).get(m, s.poses) for m, s in maps.items()}
        box = _bounds(
            [p for p in poses.values()] + ([ground_truth] if ground_truth is not None else [])
        )
        x0, x1, y0, y1 = box
        aspect = (y1 - y0) / max(x1 - x0, 1e-9)
        width = 3.6 * max(panels, 1)
        figure = _figure(width, min(max(3.6 * aspect + 1.1, 2.6), 9.0))
        axes = np.atleast_1d(figure.subplots(1, max(panels, 1), sharex=True, sharey=True))
        for ax, (mode, snap) in zip(axes, maps.items(), strict=False):
            _draw_map(ax, mode, snap, poses[mode], ground_truth, (false_edges or {}).get(mode))
            title = f"{_name(mode)}: V {snap.vertex_ids.shape[0]}, E {snap.edge_from.shape[0]}"
            if notes and mode in notes:
                title += "\n" + notes[mode]
            ax.set_title(title)
            ax.set_xlabel("x (m)")
            ax.set_aspect("equal", adjustable="box")
        axes[0].set_ylabel("y (m)")
        axes[0].set_xlim(x0, x1)
        axes[0].set_ylim(y0, y1)
        _map_legend(figure, ground_truth is not None, any(
            m is not None and m.any() for m in (false_edges or {}).values()
        ))  # fmt: skip
        return figure

    return styled(draw)


def _bounds(points: Sequence[FloatArray]) -> tuple[float, float, float, float]:
    stacked = np.vstack([p[:, :2] for p in points if len(p)] or [np.zeros((1, 2))])
    x0, y0 = stacked.min(0)
    x1, y1 = stacked.max(0)
    pad = 0.05 * max(x1 - x0, y1 - y0, 0.1)
    return float(x0 - pad), float(x1 + pad), float(y0 - pad), float(y1 + pad)


def _segments(snap: MapSnapshot, poses: FloatArray, which: NDArray[np.bool_]) -> FloatArray:
    first, second = snap.edge_ends()
    return np.stack([poses[first[which], :2], poses[second[which], :2]], axis=1)


def _draw_map(
    ax: Axes,
    mode: MapMode,
    snap: MapSnapshot,
    poses: FloatArray,
    truth: FloatArray | None,
    false: NDArray[np.bool_] | None,
) -> None:
    from matplotlib.collections import LineCollection

    if truth is not None and len(truth):
        ax.plot(truth[:, 0], truth[:, 1], color=hex_color(GROUND_TRUTH_COLOR), lw=3.0,
                solid_capstyle="round", zorder=1)  # fmt: skip
    color = map_color(mode)
    if snap.edge_from.shape[0]:
        loop = snap.edge_kind == EdgeKind.LOOP_CLOSURE
        bad = np.zeros_like(loop) if false is None else (loop & false)
        for which, c, lw, z in (
            (~loop, color, 1.0, 2),
            (loop & ~bad, LOOP_COLOR, 0.7, 3),
            (bad, hex_color(FALSE_LOOP_COLOR), 1.6, 5),
        ):
            if which.any():
                ax.add_collection(
                    LineCollection(_segments(snap, poses, which), colors=c, linewidths=lw, zorder=z)
                )
    if poses.shape[0]:
        size = 6.0 if poses.shape[0] < 400 else 3.0
        ax.scatter(poses[:, 0], poses[:, 1], s=size, color=color, linewidths=0, zorder=4)


def _map_legend(figure: Figure, truth: bool, false: bool) -> None:
    from matplotlib.lines import Line2D

    handles = [
        Line2D([], [], color=map_color(m), marker="o", ms=3, lw=1.0, label=f"{_name(m)} map")
        for m in ALL_MODES
    ]
    handles.append(Line2D([], [], color=LOOP_COLOR, lw=0.7, label="loop closures"))
    if false:
        handles.append(
            Line2D([], [], color=hex_color(FALSE_LOOP_COLOR), lw=1.6, label="false loop closures")
        )
    if truth:
        handles.append(
            Line2D([], [], color=hex_color(GROUND_TRUTH_COLOR), lw=3.0,
                   label="ground truth (maps aligned to it)")
        )  # fmt: skip
    figure.legend(handles=handles, loc="outside lower center", ncols=min(len(handles), 6),
                  frameon=False)  # fmt: skip


# --------------------------------------------------------------------------- pareto.png
def pareto_figure(
    best: Mapping[str, Any],
    vertices: Sequence[float],
    ate: Sequence[float],
    completeness: Sequence[float],
    title: str,
    min_completeness: float,
) -> Figure:
    """The sweep's Pareto fronts: vertices against ATE (left) and against completeness (right).

    Every setting is a grey dot, each front a staircase of dots in the swept map's colour, the
    paper's setting a diamond (ink), the smallest map with completeness >= ``min_completeness``
    ringed (sky blue), the completeness threshold dashed.
    """
    mode = MapMode(best.get("map", MapMode.COMPACT.value))

    def draw() -> Figure:
        figure = _figure(9.5, 4.2)
        axes = figure.subplots(1, 2)
        figure.suptitle(title[:160], fontsize=9.0)
        x_all = np.asarray(vertices, dtype=float)
        panels = (
            ("ate_m", np.asarray(ate, dtype=float), "ATE (m)", "vertices vs ATE (lower is better)",
             "front_ate"),
            ("completeness", np.asarray(completeness, dtype=float), "layout completeness",
             "vertices vs completeness (higher is better)", "front_completeness"),
        )  # fmt: skip
        for ax, (column, values, label, panel_title, front_name) in zip(axes, panels, strict=True):
            finite = np.isfinite(values) & np.isfinite(x_all)
            ax.scatter(x_all[finite], values[finite], s=12, color="#b0b0b0", linewidths=0,
                       label="setting", zorder=2)  # fmt: skip
            front = best.get(front_name) or []
            if front:
                fx = np.array([e["vertices"] for e in front], dtype=float)
                fy = np.array([_nan(e[column]) for e in front], dtype=float)
                ax.step(fx, fy, where="post", color=map_color(mode), lw=1.2, zorder=3)
                ax.scatter(fx, fy, s=22, color=map_color(mode), zorder=4, label="Pareto front")
            smallest = best.get("smallest_complete")
            if smallest:
                ax.scatter(
                    [smallest["vertices"]],
                    [_nan(smallest[column])],
                    s=140,
                    facecolors="none",
                    edgecolors=hex_color(PINNED_COLOR),
                    linewidths=2.0,
                    zorder=5,
                    label=f"smallest map, completeness ≥ {min_completeness:g}",
                )
            paper = best.get("paper")
            if paper:
                ax.scatter([paper["vertices"]], [_nan(paper[column])], s=60, marker="D",
                           color=hex_color(INK), zorder=6, label="paper's setting")  # fmt: skip
            if column == "completeness":
                ax.axhline(min_completeness, color=hex_color(PINNED_COLOR), lw=0.9, ls="--",
                           zorder=1)  # fmt: skip
            ax.set_xlabel("vertices")
            ax.set_ylabel(label)
            ax.set_title(panel_title)
        axes[0].legend(loc="best", frameon=False)
        return figure

    return styled(draw)


def _nan(value: Any) -> float:
    return math.nan if value is None else float(value)


# --------------------------------------------------------------------------- long_term.png
def long_term_figure(
    histories: Histories,
    end_time: float,
    laps: Sequence[int],
    stage_ms: Mapping[str, Sequence[float]],
    caption: str,
) -> Figure:
    """Long-term mapping: vertices per map over data time (hours, left) and per-lap cost (right).

    ``stage_ms``: per stage (reading, front end, event log, one per map), its milliseconds per
    frame in each lap; a stage named like a map takes the map's colour.
    """
    others = ("#7f7f7f", hex_color(INK), "#cc79a7", "#56b4e9")

    def draw() -> Figure:
        figure = _figure(10.0, 4.0)
        sizes, cost = figure.subplots(1, 2)
        end = max(float(end_time), 1e-6) / 3600.0
        for mode, (times, vertices, _) in histories.items():
            t = np.r_[times, end_time] / 3600.0 if times.size else np.array([0.0, end])
            v = np.r_[vertices, vertices[-1]] if vertices.size else np.zeros(2)
            sizes.step(t, v, where="post", color=map_color(mode), lw=1.5, label=_name(mode))
        sizes.set_xlim(0.0, end)
        sizes.set_ylim(bottom=0.0)
        sizes.set_xlabel("data time (h)")
        sizes.set_ylabel("vertices")
        sizes.set_title("vertices per map over time")
        sizes.legend(loc="upper left", frameon=False)
        spare = iter(others)
        modes = {m.value: m for m in MapMode}
        for stage, values in stage_ms.items():
            color = map_color(modes[stage]) if stage in modes else next(spare)
            cost.plot(list(laps), list(values), color=color, lw=1.3, marker="o", ms=2.5,
                      label=stage.replace("_", " "))  # fmt: skip
        cost.set_ylim(bottom=0.0)
        cost.set_xlabel("lap")
        cost.set_ylabel("ms per frame")
        cost.set_title("per-lap cost of each stage")
        cost.legend(loc="upper left", frameon=False, ncols=2)
        figure.supxlabel(caption, fontsize=8.0)
        return figure

    return styled(draw)
