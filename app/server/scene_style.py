"""How the scene looks: sizes, heights and colour scales, and the maps' geometry as segments.

Sizes follow the extent of what is mapped (:func:`nice`, :func:`grid_spacing`); heights keep the
ground truth and odometry under the vertices and the edges on top (seen from above); edges are
coloured by cluster, by creation time or by their error (:func:`edge_errors`, the whitened
residual the optimiser sees). :mod:`app.server.map_layer` and :mod:`app.server.scene` draw with
these, :mod:`app.server.view` places and frames with them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from app.palette import cluster_color
from cogmap_core.cognitive_map import CognitiveMap
from cogmap_core.edge_noise import OdometryNoise, edge_information
from cogmap_core.edge_residuals import EdgeModel, edge_terms
from cogmap_core.map_graph import MapSnapshot

FloatArray = NDArray[np.float64]
UInt8Array = NDArray[np.uint8]

# The page's colours come from app.palette: one per map everywhere (sequential edges and
# vertices in their map's colour), red only for false loop closures, checked for colour-blind
# readers.

#: Ways to colour the edges: loop closures by cluster, every edge by time, or by its error.
COLOURINGS: tuple[str, ...] = ("cluster", "time", "error")
#: An edge whose whitened residual reaches this is drawn in the last colour of the error scale.
ERROR_SCALE_MAX = 3.0

#: Heights: the ground truth and odometry below, vertices, then edges on top (seen from above).
GROUND_TRUTH_Z = -0.006
ODOMETRY_Z = -0.004
GRID_Z = -0.008
VERTEX_Z = 0.0
SEQUENTIAL_Z = 0.003
LOOP_Z = 0.005
FALSE_LOOP_Z = 0.007
ROBOT_Z = 0.009

#: Vertices are drawn this fraction of the mapped extent wide (then rounded, :func:`nice`).
VERTEX_FRACTION = 1.0 / 260.0
#: The robot's arrow is this many vertices long.
ROBOT_VERTICES = 3.5
#: The smallest extent sizes are chosen for (m): a map of two vertices is not drawn huge.
MIN_SPAN = 3.2


def nice(value: float, steps: Sequence[float] = (1.0, 1.5, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0)) -> float:
    """The round number (``steps`` x 10^k) nearest to ``value`` in ratio (positive values)."""
    if not value > 0 or not math.isfinite(value):
        return 1.0
    exponent = math.floor(math.log10(value))
    candidates = [m * 10.0**e for e in (exponent - 1, exponent, exponent + 1) for m in steps]
    return min(candidates, key=lambda c: abs(math.log(c / value)))


def nice_ceil(value: float, steps: Sequence[float] = (1.0, 2.0, 5.0)) -> float:
    """The smallest round number (``steps`` x 10^k) at least ``value`` (positive values)."""
    if not value > 0 or not math.isfinite(value):
        return 1.0
    exponent = math.floor(math.log10(value))
    for e in (exponent, exponent + 1):
        for m in steps:
            if m * 10.0**e >= value * (1 - 1e-9):
                return m * 10.0**e
    return 10.0 ** (exponent + 1)


def grid_spacing(span: float) -> tuple[float, float]:
    """(section, cell) of a metric grid over ``span`` metres: 2-7 sections, 4-10 cells each."""
    section = nice_ceil(max(span, 1e-3) / 6.0)
    mantissa = round(section / 10.0 ** math.floor(math.log10(section)))
    return section, section / {1: 10.0, 2: 4.0, 5: 5.0}.get(mantissa, 5.0)


Box = tuple[float, float, float, float]


def union(a: Box | None, b: Box | None) -> Box | None:
    """The bounding box of two boxes (xmin, xmax, ymin, ymax); either may be None."""
    if a is None:
        return b
    if b is None:
        return a
    return (min(a[0], b[0]), max(a[1], b[1]), min(a[2], b[2]), max(a[3], b[3]))


def span_of(box: Box | None) -> float:
    """The larger side of a box (0 for None)."""
    return 0.0 if box is None else max(box[1] - box[0], box[3] - box[2])


def cluster_colors(cluster_ids: NDArray[np.int64]) -> UInt8Array:
    """``(n, 3)`` colours of cluster ids."""
    if cluster_ids.size == 0:
        return np.zeros((0, 3), dtype=np.uint8)
    unique, inverse = np.unique(cluster_ids, return_inverse=True)
    table = np.array([cluster_color(int(c)) for c in unique], dtype=np.uint8)
    return table[inverse.reshape(-1)]


#: Anchor colours of the time scale (dark blue, teal, green, yellow: a viridis-like ramp).
TIME_RAMP = np.array([(68, 1, 84), (59, 82, 139), (33, 145, 140), (94, 201, 98), (253, 231, 37)])
#: Anchor colours of the error scale (light grey to dark purple at ERROR_SCALE_MAX: no red, which
#: means a false loop closure).
ERROR_RAMP = np.array([(200, 200, 200), (140, 150, 205), (85, 60, 165), (40, 0, 75)])


def ramp(values: FloatArray, anchors: NDArray[np.int64]) -> UInt8Array:
    """Colours of ``values`` in ``[0, 1]`` (clipped) on a ramp through ``anchors``."""
    v = np.clip(np.nan_to_num(values, nan=0.0), 0.0, 1.0) * (len(anchors) - 1)
    lo = np.minimum(v.astype(np.int64), len(anchors) - 2)
    w = (v - lo)[:, None]
    return np.round(anchors[lo] * (1.0 - w) + anchors[lo + 1] * w).astype(np.uint8)


def ramp_css(anchors: NDArray[np.int64]) -> str:
    """The ramp as a CSS linear gradient (for legends)."""
    stops = ", ".join(f"rgb({r},{g},{b})" for r, g, b in anchors.tolist())
    return f"linear-gradient(to right, {stops})"


TIME_RAMP_CSS = ramp_css(TIME_RAMP)
ERROR_RAMP_CSS = ramp_css(ERROR_RAMP)


def yaw_to_wxyz(theta: float) -> tuple[float, float, float, float]:
    """Quaternion (w, x, y, z) of a rotation by ``theta`` about +z."""
    return math.cos(theta / 2.0), 0.0, 0.0, math.sin(theta / 2.0)


def edge_errors(cmap: CognitiveMap) -> FloatArray:
    """Per edge of the map's snapshot (in its order), its whitened residual's norm now.

    At the current poses. This is what the optimiser weighs (before the Huber loss): about 1
    for an edge off by one standard deviation of its noise model. (The evidence edges, which
    the snapshot leaves out, are left out here too.)
    """
    graph = cmap.to_pose_graph()
    if graph.num_edges == 0:
        return np.zeros(0)
    x = graph.poses
    norms = _whitened_norms(
        x[graph.edge_from], x[graph.edge_to], graph.measurements, graph.information
    )
    return norms[cmap.graph.path_rows()]


def edge_error(
    snap: MapSnapshot,
    index: int,
    link_sigmas: tuple[float, float] | None,
    odometry: OdometryNoise | None = None,
) -> float:
    """The norm of edge ``index``'s whitened residual: :func:`edge_errors` of that edge alone.

    Computed from the edge's two vertex poses, its measurement and its information (with the
    map's ``link_sigmas``, :meth:`~cogmap_core.config.MapParams.link_sigmas`, and its
    ``odometry``, :meth:`~cogmap_core.config.MapParams.odometry_noise`), not from the whole pose
    graph.
    """
    edge = slice(index, index + 1)
    first, second = np.searchsorted(snap.vertex_ids, (snap.edge_from[index], snap.edge_to[index]))
    measurement = snap.edge_rel[edge]
    information = edge_information(snap.edge_kind[edge], measurement, link_sigmas, odometry)
    norms = _whitened_norms(
        snap.poses[first : first + 1], snap.poses[second : second + 1], measurement, information
    )
    return float(norms[0])


def _whitened_norms(
    pose_from: FloatArray, pose_to: FloatArray, measurements: FloatArray, information: FloatArray
) -> FloatArray:
    """Per edge, ``‖S r‖``: the norm of the residual whitened by its information."""
    model = EdgeModel(measurements, information)
    res, _ = edge_terms(pose_from, pose_to, model, None, False)
    return np.sqrt(np.einsum("ka,ka->k", res, res))


def path_segments(poses: FloatArray, z: float) -> NDArray[np.float32]:
    """Consecutive points of a path as line segments ``(n - 1, 2, 3)``."""
    if poses.shape[0] < 2:
        return np.zeros((0, 2, 3), dtype=np.float32)
    seg = np.empty((poses.shape[0] - 1, 2, 3), dtype=np.float32)
    seg[:, 0, :2] = poses[:-1, :2]
    seg[:, 1, :2] = poses[1:, :2]
    seg[:, :, 2] = z
    return seg


def edge_segments(snap: MapSnapshot, heights: float | FloatArray = 0.0) -> NDArray[np.float32]:
    """The edges of ``snap`` as line segments ``(m, 2, 3)`` from the first vertex to the second.

    ``heights``: the segments' z, one for all or one per edge.
    """
    m = snap.edge_from.shape[0]
    segments = np.empty((m, 2, 3), dtype=np.float32)
    if m:
        first, second = snap.edge_ends()
        segments[:, 0, :2] = snap.poses[first, :2]
        segments[:, 1, :2] = snap.poses[second, :2]
    z = np.asarray(heights)
    segments[:, :, 2] = z[:, None] if z.ndim else z
    return segments


def robot_triangle(size: float) -> tuple[NDArray[np.float32], NDArray[np.int32]]:
    """A flat arrow-head pointing along +x (vertices, faces), both sides drawn."""
    v = np.array(
        [[size, 0.0, 0.0], [-0.6 * size, 0.55 * size, 0.0], [-0.3 * size, 0.0, 0.0],
         [-0.6 * size, -0.55 * size, 0.0]],
        dtype=np.float32,
    )  # fmt: skip
    f = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int32)
    return v, f
