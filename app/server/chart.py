"""The map-size chart (the paper's size-over-time figure) for the page's uPlot element.

x is data time in seconds (uPlot's default x scale is wall-clock time, which showed times of day
of 1 January 1970); vertices (solid) and edges (dashed) of the three maps; a marker at every
batch optimisation of each map, at the map's size right after it. uPlot's legend shows values
only under the mouse (and "--" otherwise), so the legend's labels carry the current values.

Every series has a value at every x. uPlot takes NaN for a number (one NaN and the axis range
is lost), so a marker series is far below the chart where it has no marker, and the y range is
fixed -- a round number above the largest size, changed only when the maps outgrow it.

The x range is set too (:func:`x_end`: a round number just above the data time), not left to the
browser: viser's chart keeps an open tab's x range *relative to the data's range when the tab
opened*, so a tab open during the replay showed 0-3.7 s at 37 s, and 0-1 s after another bag was
opened. A new range makes the browser draw the chart anew, once per round number passed.
"""

from __future__ import annotations

import math

import numpy as np
import viser.uplot
from numpy.typing import NDArray

from app.server.scene import MAP_COLORS
from cogmap_core.cognitive_map import CognitiveMap, MapMode
from cogmap_core.slam import ALL_MODES

SHORT = {MapMode.STANDARD: "std", MapMode.SCENE_INTEGRATION: "s.i.", MapMode.COMPACT: "compact"}
#: Samples of the size curves over the data so far.
CHART_POINTS = 400
#: Series: x, then per map vertices and edges (these), then per map its optimisation markers.
SIZE_SERIES = slice(1, 1 + 2 * len(ALL_MODES))
#: A marker series' value where it has no marker (outside the y range: not drawn).
OFF_CHART = -1e9


def _rgb(mode: MapMode) -> str:
    r, g, b = MAP_COLORS[mode]
    return f"rgb({r},{g},{b})"


def chart_series(maps: dict[MapMode, CognitiveMap] | None = None) -> tuple[viser.uplot.Series, ...]:
    """The series (labels with the maps' current sizes and optimisation counts)."""
    series: list[viser.uplot.Series] = [{"label": "data time (s)"}]
    for mode in ALL_MODES:
        cmap = None if maps is None else maps.get(mode)
        v = "–" if cmap is None else str(cmap.num_vertices)
        e = "–" if cmap is None else str(cmap.num_edges)
        series.append({"label": f"{SHORT[mode]} V {v}", "stroke": _rgb(mode), "width": 2})
        series.append(
            {"label": f"{SHORT[mode]} E {e}", "stroke": _rgb(mode), "width": 1, "dash": (5.0, 4.0)}
        )
    for mode in ALL_MODES:
        cmap = None if maps is None else maps.get(mode)
        n = "–" if cmap is None else str(len(cmap.optimizations))
        series.append(
            {
                "label": f"{SHORT[mode]} optimisations {n}",
                "stroke": _rgb(mode),
                "width": 0,
                "points": {"show": True, "size": 7, "fill": "#ffffff", "width": 2},
            }
        )
    return tuple(series)


def y_top(largest: float) -> float:
    """A round top of the y axis (1, 1.5, 2, 3, 4, 5, 6, 8 x 10^k) above 1.05 x ``largest``."""
    target = max(float(largest) * 1.05, 10.0)
    exponent = math.floor(math.log10(target))
    for step in (1.0, 1.5, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0):
        top = step * 10.0**exponent
        if top >= target:
            return top
    return 10.0 ** (exponent + 1)


#: Round ends of the x axis (x 10^k).
X_STEPS = (1.0, 1.5, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0)


def x_end(data_time: float) -> float:
    """The end of the x axis: the smallest round number (:data:`X_STEPS`) at least ``data_time``.

    At least 1 s (before any data).
    """
    t = max(float(data_time), 1.0) if math.isfinite(data_time) else 1.0
    exponent = math.floor(math.log10(t))
    for e in (exponent, exponent + 1):
        for step in X_STEPS:
            end = step * 10.0**e
            if end >= t * (1 - 1e-12):
                return float(round(end, 9))
    return 10.0 ** (exponent + 1)


def chart_options(top: float = 10.0, end: float = 1.0) -> dict[str, object]:
    """Scales, axes, legend and padding (x in data seconds up to ``end``, y up to ``top``).

    The y axis is wide enough for "30,000" and the plot starts below the top of the chart, so
    the top tick's label is never cut.
    """
    return {
        "scales": {"x": {"time": False, "range": (0.0, end)}, "y": {"range": (0.0, top)}},
        "axes": (
            {"label": "data time (s)", "size": 40},
            {"label": "vertices / edges", "size": 64},
        ),
        "legend": {"live": False},
        "padding": (14, 24, 0, 0),
    }


def chart_data(
    maps: dict[MapMode, CognitiveMap], end_time: float, points: int = CHART_POINTS
) -> tuple[NDArray[np.float64], ...]:
    """The x values (data seconds), vertices and edges of each map, and the optimisation markers."""
    end = 0.0 if math.isnan(end_time) else max(end_time, 0.0)
    optimisations = {
        mode: np.array([o.time for o in maps[mode].optimizations if o.time <= end])
        if mode in maps
        else np.zeros(0)
        for mode in ALL_MODES
    }
    times = np.unique(
        np.concatenate([np.linspace(0.0, max(end, 1e-3), points), *optimisations.values()])
    )
    data: list[NDArray[np.float64]] = [times]
    sizes: dict[MapMode, NDArray[np.float64]] = {}
    for mode in ALL_MODES:
        if mode not in maps:
            data += [np.zeros_like(times), np.zeros_like(times)]
            sizes[mode] = np.zeros_like(times)
            continue
        t, v, e = maps[mode].size_history()
        idx = np.searchsorted(t, times, side="right") - 1
        ok = idx >= 0
        safe = np.maximum(idx, 0)
        vertices = np.where(ok, v[safe] if v.size else 0, 0).astype(float)
        edges = np.where(ok, e[safe] if e.size else 0, 0).astype(float)
        data += [vertices, edges]
        sizes[mode] = vertices
    for mode in ALL_MODES:
        marker = np.full_like(times, OFF_CHART)
        at = np.isin(times, optimisations[mode])
        marker[at] = sizes[mode][at]
        data.append(marker)
    return tuple(data)
