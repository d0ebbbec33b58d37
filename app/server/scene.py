"""Incremental streaming of the cognitive maps into the viser scene.

Every map lives under its own frame ``/map/<mode>``, with one frame per *layer* under it so that
each viewer can show or hide it (:mod:`app.server.view` shadows these frames per client):

- ``vertices/cNNNN`` -- point clouds of at most :data:`CHUNK` vertices, in the map's colour;
- ``sequential/<colouring>/cNNNN`` and ``loop/<colouring>/cNNNN`` -- line segments of the
  sequential and loop-closure edges, once per edge colouring in use (:data:`COLOURINGS`: loop
  closures by cluster id over neutral sequential edges, every edge by creation time, or by its
  error -- the whitened residual the optimiser sees);
- ``false_loops`` -- the loop-closure edges made from links the ground truth calls false
  (:meth:`~cogmap_core.event_log.EventLog.loop_closure_score`), drawn over the others;
- ``truth/aligned/cNNNN`` -- the ground-truth path, placed by the frame ``truth/aligned`` with the
  rigid transform that aligns the truth to the map (the one the ATE uses): a good map lies on it;
- ``odometry/cNNNN`` -- the dead-reckoned path (odometry alone), in the map's own frame;
- ``robot`` -- a triangle at the robot's current (dead-reckoned) pose.

- ``name`` -- the map's name, above its top-left corner (side by side: which map is which).

Sizes follow the extent of what is mapped (:meth:`SceneStreamer.marker`): vertices, the robot and
the grid's spacing are chosen from the ground truth's and the maps' extent, never from the map
parameters, so a 4 m maze and a 40 m hall read alike. The metric grid with its scale bar is one
for everything a view shows (:class:`Grid`: the default view's here, each viewer's own in
:mod:`app.server.view`), its spacing a round number that suits the extent.

Between two optimisations a map only grows at its end, so only the last chunk of each layer
changes: :class:`ChunkedNodes` compares every chunk with what it last sent and re-sends only the
chunks that differ. After an optimisation every vertex moves, so everything is sent once. Maps
and colourings no viewer shows are not streamed. Each update is grouped with
``server.atomic()`` so a browser never draws a half-updated map, and viser's message buffer keeps
the latest state of every node, which is what a client joining late receives.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import viser
from numpy.typing import NDArray

from app.palette import (
    CLUSTER_PALETTE,
    FALSE_LOOP_COLOR,
    GROUND_TRUTH_COLOR,
    INK,
    MAP_COLORS,
    ODOMETRY_COLOR,
    PALETTE_SIZE,
    PINNED_COLOR,
    ROBOT_COLOR,
    SELECTION_COLOR,
    cluster_color,
)
from app.server.figures import FalseEdges, false_edge_mask
from cogmap_core.cognitive_map import CognitiveMap, EdgeKind, MapMode
from cogmap_core.edge_noise import edge_information
from cogmap_core.map_graph import MapSnapshot
from cogmap_core.optimizer import EdgeModel, edge_terms

FloatArray = NDArray[np.float64]
UInt8Array = NDArray[np.uint8]

#: Items (vertices, edges, path segments) per scene node.
CHUNK = 512

__all__ = [  # (with the page's colours, from app.palette)
    "CLUSTER_PALETTE",
    "FALSE_LOOP_COLOR",
    "GROUND_TRUTH_COLOR",
    "MAP_COLORS",
    "ODOMETRY_COLOR",
    "PALETTE_SIZE",
    "PINNED_COLOR",
    "ROBOT_COLOR",
    "SELECTION_COLOR",
    "ChunkedNodes",
    "MapExtras",
    "MapLayer",
    "SceneStreamer",
    "cluster_color",
]

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
_TIME_RAMP = np.array([(68, 1, 84), (59, 82, 139), (33, 145, 140), (94, 201, 98), (253, 231, 37)])
#: Anchor colours of the error scale (light grey to dark purple at ERROR_SCALE_MAX: no red, which
#: means a false loop closure).
_ERROR_RAMP = np.array([(200, 200, 200), (140, 150, 205), (85, 60, 165), (40, 0, 75)])


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


TIME_RAMP_CSS = ramp_css(_TIME_RAMP)
ERROR_RAMP_CSS = ramp_css(_ERROR_RAMP)


def yaw_to_wxyz(theta: float) -> tuple[float, float, float, float]:
    """Quaternion (w, x, y, z) of a rotation by ``theta`` about +z."""
    return math.cos(theta / 2.0), 0.0, 0.0, math.sin(theta / 2.0)


def edge_errors(cmap: CognitiveMap) -> FloatArray:
    """Per live edge (snapshot order), the norm of its whitened residual at the current poses.

    This is what the optimiser weighs (before the Huber loss): about 1 for an edge off by one
    standard deviation of its noise model.
    """
    graph = cmap.to_pose_graph()
    if graph.num_edges == 0:
        return np.zeros(0)
    x = graph.poses
    return _whitened_norms(
        x[graph.edge_from], x[graph.edge_to], graph.measurements, graph.information
    )


def edge_error(snap: MapSnapshot, index: int, link_sigmas: tuple[float, float] | None) -> float:
    """The norm of edge ``index``'s whitened residual: :func:`edge_errors` of that edge alone.

    Computed from the edge's two vertex poses, its measurement and its information (with the
    map's ``link_sigmas``, :meth:`~cogmap_core.config.MapParams.link_sigmas`), not from the
    whole pose graph.
    """
    edge = slice(index, index + 1)
    first, second = np.searchsorted(snap.vertex_ids, (snap.edge_from[index], snap.edge_to[index]))
    measurement = snap.edge_rel[edge]
    information = edge_information(snap.edge_kind[edge], measurement, link_sigmas)
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


@dataclass
class StreamStats:
    """What the streamer sent so far (for tests and benchmarks)."""

    updates: int = 0
    chunks_sent: int = 0
    chunks_removed: int = 0
    items_sent: int = 0
    bytes_sent: int = 0
    robot_updates: int = 0
    seconds: float = 0.0

    def copy(self) -> StreamStats:
        """A copy (to take differences)."""
        return StreamStats(**vars(self))


NodeFactory = Callable[[str, np.ndarray, np.ndarray | None], viser.SceneNodeHandle]
#: Puts new content (items, colours) into an existing node, in place.
NodeUpdater = Callable[[viser.SceneNodeHandle, np.ndarray, np.ndarray | None], None]


class ChunkedNodes:
    """A growing array of items shown as scene nodes of :data:`CHUNK` items each.

    :meth:`sync` sends only the chunks whose content differs from what was last sent, and removes
    chunks beyond the new length. A changed chunk is updated in place when ``updater`` is given
    (its points and colours replaced): a browser then keeps the node and its material, which is
    much cheaper than making a new one (a new line material is compiled, slowly without a GPU).
    """

    def __init__(
        self,
        name: str,
        factory: NodeFactory,
        stats: StreamStats,
        chunk: int = CHUNK,
        updater: NodeUpdater | None = None,
    ) -> None:
        """Manage nodes ``<name>/c0000``, ``<name>/c0001``, ... made by ``factory``."""
        self.name = name
        self.factory = factory
        self.updater = updater
        self.stats = stats
        self.chunk = chunk
        self._handles: list[viser.SceneNodeHandle] = []
        self._sent: list[tuple[np.ndarray, np.ndarray | None]] = []

    @property
    def num_chunks(self) -> int:
        """Chunks currently shown."""
        return len(self._handles)

    @property
    def num_items(self) -> int:
        """Items currently shown."""
        return sum(part.shape[0] for part, _ in self._sent)

    def items(self) -> np.ndarray | None:
        """All items currently shown, concatenated (None when empty)."""
        return np.concatenate([part for part, _ in self._sent]) if self._sent else None

    def colors(self) -> np.ndarray | None:
        """Their colours (None when empty or uncoloured)."""
        if not self._sent or self._sent[0][1] is None:
            return None
        return np.concatenate([c for _, c in self._sent if c is not None])

    def sync(self, items: np.ndarray, colors: np.ndarray | None = None, force: bool = False) -> int:
        """Show ``items`` (with per-item ``colors`` or none); return the chunks sent.

        ``force`` re-sends every chunk (the nodes' look changed).
        """
        n = items.shape[0]
        count = -(-n // self.chunk)
        sent = 0
        for c in range(count):
            lo, hi = c * self.chunk, min((c + 1) * self.chunk, n)
            part = items[lo:hi]
            cpart = None if colors is None else colors[lo:hi]
            if c < len(self._sent) and not force:
                old, old_colors = self._sent[c]
                if (
                    old.shape == part.shape
                    and np.array_equal(old, part)
                    and (cpart is None or np.array_equal(old_colors, cpart))
                ):
                    continue
            record = (part.copy(), None if cpart is None else cpart.copy())
            if c < len(self._handles):
                if self.updater is None:
                    self._handles[c] = self.factory(f"{self.name}/c{c:04d}", part, cpart)
                else:
                    self.updater(self._handles[c], part, cpart)
                self._sent[c] = record
            else:
                self._handles.append(self.factory(f"{self.name}/c{c:04d}", part, cpart))
                self._sent.append(record)
            sent += 1
            self.stats.items_sent += part.shape[0]
            self.stats.bytes_sent += part.nbytes + (0 if cpart is None else cpart.nbytes)
        for handle in self._handles[count:]:
            handle.remove()
            self.stats.chunks_removed += 1
        del self._handles[count:]
        del self._sent[count:]
        self.stats.chunks_sent += sent
        return sent

    def clear(self) -> None:
        """Remove every chunk."""
        for handle in self._handles:
            handle.remove()
        self.stats.chunks_removed += len(self._handles)
        self._handles.clear()
        self._sent.clear()


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


@dataclass
class MapExtras:
    """What the scene shows with a map besides its graph.

    Attributes:
        truth_transform: (theta, tx, ty) taking the ground truth onto the map (None: no truth).
        false_edges: the map's loop-closure edges made from links the ground truth calls false,
            as ``(time, end vertex)`` pairs (:attr:`~app.server.figures.MapFigures.false_edges`).

    """

    truth_transform: tuple[float, float, float] | None = None
    false_edges: FalseEdges = frozenset()


#: The layers of a map a viewer can switch on and off (frame names under ``/map/<mode>``).
LAYERS: tuple[str, ...] = (
    "vertices",
    "sequential",
    "loop",
    "false_loops",
    "truth",
    "odometry",
)


class MapLayer:
    """The scene nodes of one cognitive map under ``/map/<mode>``."""

    def __init__(
        self, server: viser.ViserServer, mode: MapMode, stats: StreamStats, root: str = "/map"
    ) -> None:
        """Create the (empty) frames of the map; nothing else is sent until :meth:`update`."""
        self.server = server
        self.mode = mode
        self.stats = stats
        self.name = f"{root}/{mode.value}"
        self.color = MAP_COLORS[mode]
        scene = server.scene
        self.frame = scene.add_frame(self.name, show_axes=False)
        self.groups: dict[str, viser.FrameHandle] = {
            layer: scene.add_frame(f"{self.name}/{layer}", show_axes=False) for layer in LAYERS
        }
        self.coloured: dict[str, viser.FrameHandle] = {}
        for kind in ("sequential", "loop"):
            for colouring in COLOURINGS:
                self.coloured[f"{kind}/{colouring}"] = scene.add_frame(
                    f"{self.name}/{kind}/{colouring}",
                    show_axes=False,
                    visible=colouring == COLOURINGS[0],
                )
        self.groups["odometry"].visible = False
        self.truth_frame = scene.add_frame(f"{self.name}/truth/aligned", show_axes=False)
        self._offset = 0.0
        self.point_size = MIN_SPAN * VERTEX_FRACTION
        self.label = scene.add_label(
            f"{self.name}/name",
            mode.value.replace("_", " "),
            position=(0.0, 0.0, ROBOT_Z),
            anchor="bottom-left",
            font_screen_scale=1.25,
            visible=False,
        )
        self._label_at: tuple[float, float] | None = None

        def vertices(name: str, part: np.ndarray, _: np.ndarray | None) -> viser.SceneNodeHandle:
            return scene.add_point_cloud(
                name,
                points=part,
                colors=self.color,
                point_size=self.point_size,
                point_shape="circle",
                precision="float32",
                point_shading="flat",
            )

        def segments(thickness: float) -> NodeFactory:
            def make(name: str, part: np.ndarray, cols: np.ndarray | None) -> viser.SceneNodeHandle:
                assert cols is not None
                return scene.add_line_segments(
                    name, part, colors=cols, thickness=thickness, thickness_units="screen"
                )

            return make

        def plain(color: tuple[int, int, int], thickness: float) -> NodeFactory:
            def make(name: str, part: np.ndarray, _: np.ndarray | None) -> viser.SceneNodeHandle:
                return scene.add_line_segments(
                    name, part, colors=color, thickness=thickness, thickness_units="screen"
                )

            return make

        # A node made with one colour keeps it: only its points are replaced. (viser's browser
        # side does not switch a line material from one colour to per-vertex colours: red false
        # loop closures updated that way were drawn white.)
        def move_points(handle: Any, part: np.ndarray, _: np.ndarray | None) -> None:
            with server.atomic():
                handle.points = part
                if handle.point_size != self.point_size:
                    handle.point_size = self.point_size

        def move_segments(color: tuple[int, int, int] | None) -> NodeUpdater:
            def update(handle: Any, part: np.ndarray, cols: np.ndarray | None) -> None:
                with server.atomic():
                    handle.points = part
                    if color is None:  # (made with per-vertex colours: replaced alike)
                        assert cols is not None
                        handle.colors = cols

            return update

        self.vertices = ChunkedNodes(f"{self.name}/vertices", vertices, stats, updater=move_points)
        self.edges: dict[str, ChunkedNodes] = {}
        for colouring in COLOURINGS:
            self.edges[f"sequential/{colouring}"] = ChunkedNodes(
                f"{self.name}/sequential/{colouring}",
                segments(1.5),
                stats,
                updater=move_segments(None),
            )
            self.edges[f"loop/{colouring}"] = ChunkedNodes(
                f"{self.name}/loop/{colouring}", segments(3.0), stats, updater=move_segments(None)
            )
        self.false_loops = ChunkedNodes(
            f"{self.name}/false_loops",
            plain(FALSE_LOOP_COLOR, 6.0),
            stats,
            updater=move_segments(FALSE_LOOP_COLOR),
        )
        self.truth = ChunkedNodes(
            f"{self.name}/truth/aligned",
            plain(GROUND_TRUTH_COLOR, 5.0),  # a light band under the map
            stats,
            updater=move_segments(GROUND_TRUTH_COLOR),
        )
        self.odometry = ChunkedNodes(
            f"{self.name}/odometry",
            plain(ODOMETRY_COLOR, 1.5),
            stats,
            updater=move_segments(ODOMETRY_COLOR),
        )
        self.robot = self._make_robot()
        self._map: CognitiveMap | None = None
        self._key: tuple[int, int, int] | None = None
        self._coloured_key: dict[str, tuple[int, tuple[int, int, int]]] = {}
        self._robot_pose: tuple[float, float, float] | None = None
        self._truth_sent: tuple[float, float, float] | None = None
        self._false_key: tuple[FalseEdges, int] | None = None
        self.false_count = 0
        self.extent: Box | None = None  # xmin, xmax, ymin, ymax of the vertices
        self.truth_extent: Box | None = None  # of the ground truth as aligned to the map
        self._truth_key: tuple[int, tuple[float, float, float] | None] | None = None
        self._segments = np.zeros((0, 2, 3), dtype=np.float32)

    def _make_robot(self) -> viser.MeshHandle:
        tri_v, tri_f = robot_triangle(ROBOT_VERTICES * self.point_size)
        return self.server.scene.add_mesh_simple(
            f"{self.name}/robot",
            tri_v,
            tri_f,
            color=ROBOT_COLOR,
            side="double",
            flat_shading=True,
            cast_shadow=False,
            receive_shadow=False,
        )

    # ------------------------------------------------------------------ layout
    @property
    def view_extent(self) -> Box | None:
        """What the map shows: its vertices and the ground truth aligned to it."""
        return union(self.extent, self.truth_extent)

    def set_marker(self, size: float) -> None:
        """Draw vertices ``size`` metres wide (and the robot to match); re-sent when it changes."""
        if size == self.point_size:
            return
        self.point_size = size
        if self.vertices.num_chunks:
            items = self.vertices.items()
            assert items is not None
            self.vertices.sync(items, force=True)
        pose = self._robot_pose
        self.robot = self._make_robot()
        if pose is not None:
            self.robot.position = (pose[0], pose[1], ROBOT_Z)
            self.robot.wxyz = yaw_to_wxyz(pose[2])

    def place_label(self, unit: float) -> None:
        """Put the map's name above the top-left corner of what it shows (``unit``: a margin)."""
        box = self.view_extent
        if box is None:
            if self._label_at is not None:
                self.label.visible = False
                self._label_at = None
            return
        at = (round(box[0] / unit) * unit, round((box[3] + unit) / unit) * unit)
        if at != self._label_at:
            self.label.position = (at[0], at[1], ROBOT_Z)
            if not self.label.visible:
                self.label.visible = True
            self._label_at = at

    @property
    def visible(self) -> bool:
        """Whether the map is shown (to viewers without a view of their own)."""
        return bool(self.frame.visible)

    @visible.setter
    def visible(self, value: bool) -> None:
        if bool(self.frame.visible) != value:
            self.frame.visible = value

    @property
    def offset(self) -> float:
        """Shift of the map along +x (m), for side-by-side comparison (default view)."""
        return self._offset

    @offset.setter
    def offset(self, value: float) -> None:
        if value != self._offset:
            self._offset = value
            self.frame.position = (value, 0.0, 0.0)

    # compatibility: the layers of the default (cluster) colouring
    @property
    def sequential(self) -> ChunkedNodes:
        """Sequential edges (cluster colouring)."""
        return self.edges["sequential/cluster"]

    @property
    def loops(self) -> ChunkedNodes:
        """Loop-closure edges (cluster colouring)."""
        return self.edges["loop/cluster"]

    # ------------------------------------------------------------------ content
    def update(
        self,
        cmap: CognitiveMap,
        colourings: Iterable[str] = ("cluster",),
        extras: MapExtras | None = None,
        duration: float = 0.0,
    ) -> bool:
        """Send what changed in ``cmap`` since the last update; True when the graph changed.

        ``colourings``: the edge colourings viewers use (the others are not sent);
        ``duration``: the data's length (s), the end of the time colour scale.
        """
        # Between optimisations a map only gains vertices and edges; merges and moves happen in
        # optimisations. So these three numbers change whenever the graph does.
        key = (cmap.num_vertices, cmap.num_edges, len(cmap.optimizations))
        changed = cmap is not self._map or key != self._key
        if changed:
            self._send_graph(cmap)
            self._map, self._key = cmap, key
            self._coloured_key.clear()
        for colouring in colourings:
            scale = int(duration) if colouring == "time" else 0
            ckey = (scale, key)
            if self._coloured_key.get(colouring) != ckey:
                self._send_edges(cmap, colouring, duration)
                self._coloured_key[colouring] = ckey
        if extras is not None:
            self._send_extras(cmap, extras, changed)
        pose = cmap.current_pose()
        robot = (float(pose[0]), float(pose[1]), float(pose[2]))
        if robot != self._robot_pose:
            self.robot.position = (robot[0], robot[1], ROBOT_Z)
            self.robot.wxyz = yaw_to_wxyz(robot[2])
            self._robot_pose = robot
            self.stats.robot_updates += 1
        return changed

    def _send_graph(self, cmap: CognitiveMap) -> None:
        snap = cmap.snapshot()
        n = snap.vertex_ids.shape[0]
        points = np.empty((n, 3), dtype=np.float32)
        points[:, :2] = snap.poses[:, :2]
        points[:, 2] = VERTEX_Z
        is_loop = snap.edge_kind == EdgeKind.LOOP_CLOSURE
        segments = edge_segments(snap, np.where(is_loop, LOOP_Z, SEQUENTIAL_Z))
        self.vertices.sync(points)
        self.extent = (
            (
                float(points[:, 0].min()),
                float(points[:, 0].max()),
                float(points[:, 1].min()),
                float(points[:, 1].max()),
            )
            if n
            else None
        )
        self._segments = segments
        self._snapshot = snap

    def _send_edges(self, cmap: CognitiveMap, colouring: str, duration: float) -> None:
        snap = self._snapshot
        segments = self._segments
        is_loop = snap.edge_kind == EdgeKind.LOOP_CLOSURE
        m = segments.shape[0]
        if colouring == "cluster":
            colors = np.empty((m, 3), dtype=np.uint8)
            colors[~is_loop] = self.color
            colors[is_loop] = cluster_colors(snap.edge_cluster[is_loop])
        elif colouring == "time":
            colors = ramp(snap.edge_time / max(duration, 1e-9), _TIME_RAMP)
        else:
            colors = ramp(edge_errors(cmap) / ERROR_SCALE_MAX, _ERROR_RAMP)
        pair = np.repeat(colors[:, None, :], 2, axis=1)
        self.edges[f"sequential/{colouring}"].sync(segments[~is_loop], pair[~is_loop])
        self.edges[f"loop/{colouring}"].sync(segments[is_loop], pair[is_loop])

    def _send_extras(self, cmap: CognitiveMap, extras: MapExtras, changed: bool) -> None:
        transform = extras.truth_transform
        self._truth_transform = transform
        if transform is not None and transform != self._truth_sent:
            theta, tx, ty = transform
            with self.server.atomic():
                self.truth_frame.position = (tx, ty, 0.0)
                self.truth_frame.wxyz = yaw_to_wxyz(theta)
            self._truth_sent = transform
        false_key = (extras.false_edges, len(cmap.optimizations))
        if changed or false_key != self._false_key:
            false = false_edge_mask(self._snapshot, extras.false_edges)
            segments = self._segments[false].copy()
            segments[:, :, 2] = FALSE_LOOP_Z
            self.false_loops.sync(segments)
            self.false_count = int(false.sum())
            self._false_key = false_key

    def update_paths(
        self,
        truth: NDArray[np.float32] | None,
        odometry: NDArray[np.float32] | None,
        truth_poses: FloatArray | None = None,
    ) -> None:
        """Show the true path (raw frame) and the dead-reckoned one (map frame).

        Both come as segments (:func:`path_segments`), made once per publish for every map;
        ``truth_poses`` (the truth's poses) give the truth's extent as aligned to the map.
        """
        if truth is not None:
            self.truth.sync(truth)
        if truth_poses is not None:
            transform = getattr(self, "_truth_transform", None)
            key = (truth_poses.shape[0], transform)
            if key != self._truth_key:
                self._truth_key = key
                self.truth_extent = _aligned_box(truth_poses, transform)
        if odometry is not None:
            self.odometry.sync(odometry)

    def reset(self) -> None:
        """Forget what was sent and remove the map's content (the frames stay)."""
        for layer in (self.vertices, self.false_loops, self.truth, self.odometry):
            layer.clear()
        for layer in self.edges.values():
            layer.clear()
        self._map = None
        self._key = None
        self._coloured_key.clear()
        self._truth_sent = None
        self._false_key = None
        self.extent = None
        self.truth_extent = None
        self._truth_key = None
        self._truth_transform = None
        if self._label_at is not None:
            self.label.visible = False
            self._label_at = None


def _aligned_box(poses: FloatArray, transform: tuple[float, float, float] | None) -> Box | None:
    """Bounding box of ``poses`` (x, y) moved by ``transform`` (theta, tx, ty)."""
    if poses.shape[0] == 0 or transform is None:
        return None
    theta, tx, ty = transform
    c, s = math.cos(theta), math.sin(theta)
    x = c * poses[:, 0] - s * poses[:, 1] + tx
    y = s * poses[:, 0] + c * poses[:, 1] + ty
    return (float(x.min()), float(x.max()), float(y.min()), float(y.max()))


class Grid:
    """One metric grid under everything a view shows, with a scale bar at its bottom right.

    The spacing suits the extent (:func:`grid_spacing`: 0.1 m cells and 1 m sections for a 4 m
    maze, 2 m and 10 m for a 40 m hall); the scale bar is one section long, under the content's
    bottom-right corner (clear of the axes gizmo at the screen's bottom left), its length
    written above it. ``scene`` is the server's (the default view) or a client's (a viewer's).
    """

    def __init__(self, scene: Any, name: str) -> None:
        """Create the (empty) grid under the frame ``name`` of ``scene``."""
        self.scene = scene
        self.name = name
        self.frame = scene.add_frame(name, show_axes=False)
        self._sent: tuple[Box, float, float, tuple[float, float]] | None = None
        self.section = 1.0
        self.cell = 0.1
        self.bar: tuple[float, float, float] | None = None  # x0, x1, y of the scale bar

    def cover(self, content: Box | None, span: float | None = None) -> Box | None:
        """Lie under ``content`` (spacing for ``span``, default its own); returns what to frame.

        What to frame: ``content`` with the scale bar below it and a margin for the maps'
        names above it. The grid is sent again only when its box, spacing or bar change.
        """
        if content is None:
            return None
        x0, x1, y0, y1 = content
        section, cell = grid_spacing(max(span or 0.0, span_of(content), 1e-3))
        self.section, self.cell = section, cell
        # beyond the content by most of its size: the canvas is filled whatever its shape
        pad = max(section, 0.8 * span_of(content))
        gx0 = math.floor((x0 - pad) / section) * section
        gx1 = math.ceil((x1 + pad) / section) * section
        gy0 = math.floor((y0 - pad) / section) * section
        gy1 = math.ceil((y1 + pad) / section) * section
        bar_y = y0 - 0.6 * section
        bar = (x1 - section, bar_y)
        box = (gx0, gx1, gy0, gy1)
        key = (box, section, cell, (round(bar[0] / cell) * cell, round(bar[1] / cell) * cell))
        bx, by = key[3]
        self.bar = (bx, bx + section, by)
        if key != self._sent:
            self._sent = key
            self.scene.add_grid(
                f"{self.name}/plane",
                width=gx1 - gx0,
                height=gy1 - gy0,
                plane="xy",
                cell_size=cell,
                section_size=section,
                cell_color=(228, 228, 228),
                section_color=(180, 180, 180),
                cell_thickness=1.0,
                section_thickness=1.4,
                shadow_opacity=0.0,
                fade_strength=0.0,  # (the plan view's camera is far: no fading with distance)
                fade_distance=1e9,
                position=((gx0 + gx1) / 2, (gy0 + gy1) / 2, GRID_Z),
            )
            line = np.array([[[bx, by, 0.0], [bx + section, by, 0.0]]], np.float32)
            self.scene.add_line_segments(
                f"{self.name}/scale", line, colors=INK, thickness=4.0, thickness_units="screen"
            )
            self.scene.add_label(
                f"{self.name}/scale/label",
                f"{section:g} m",
                position=(bx + section / 2, by + 0.05 * section, ROBOT_Z),
                anchor="bottom-center",
                font_screen_scale=1.15,
            )
        return (x0, x1, bar_y - 0.25 * section, y1 + 0.8 * section)


class SceneStreamer:
    """All map layers and the grid; :meth:`publish` sends one incremental update.

    ``needed`` are the maps and ``colourings`` the edge colourings some viewer shows (only
    those are streamed). :meth:`show` sets the view of viewers without a view of their own (an
    exported replay, a client that has not been set up yet).
    """

    def __init__(
        self, server: viser.ViserServer, modes: Iterable[MapMode] = tuple(MapMode)
    ) -> None:
        """Create the scene's layers (empty) for ``modes``."""
        self.server = server
        # Flat 2-D maps cast no useful shadows; without them a moving robot does not make the
        # browser redraw shadow maps (slow without a GPU: a third of a second per update).
        server.scene.configure_default_lights(True, cast_shadow=False)
        self.stats = StreamStats()
        self.layers: dict[MapMode, MapLayer] = {m: MapLayer(server, m, self.stats) for m in modes}
        self.shown: tuple[MapMode, ...] = ()
        self.needed: set[MapMode] = set()
        self.colourings: set[str] = {"cluster"}
        self.show_odometry = False
        self._truth = np.zeros((0, 3))
        #: sizes are chosen for at least this extent (m; the app sets it by the input's kind)
        self.min_span = MIN_SPAN
        self.marker = MIN_SPAN * VERTEX_FRACTION
        self.grid = Grid(server.scene, "/grid")  # the default view's (replays, a new tab)
        self.show((MapMode.COMPACT,))

    def show(self, modes: Sequence[MapMode], show_ground_truth: bool = True) -> None:
        """Default view: ``modes`` (the first at the origin, a second one beside it)."""
        self.shown = tuple(modes)
        self.needed |= set(self.shown)
        with self.server.atomic():
            for mode, layer in self.layers.items():
                layer.visible = mode in self.shown
                if layer.groups["truth"].visible != show_ground_truth:
                    layer.groups["truth"].visible = show_ground_truth
            self._place()

    def set_needed(
        self, modes: Iterable[MapMode], colourings: Iterable[str], odometry: bool
    ) -> None:
        """The maps, colourings and layers some viewer shows (what :meth:`publish` streams)."""
        self.needed = set(modes) | set(self.shown)
        self.colourings = set(colourings) | {"cluster"}
        self.show_odometry = odometry

    def _place(self) -> None:
        if not self.shown:
            return
        self.layers[self.shown[0]].offset = 0.0
        step = self.side_by_side_step(self.shown)
        for k, mode in enumerate(self.shown[1:], start=1):
            self.layers[mode].offset = step * k
        self.grid.cover(self.extent(), self.span())

    def side_by_side_step(self, modes: Sequence[MapMode]) -> float:
        """Shift (m) between maps shown side by side: the widest map (with its truth) and a gap.

        In steps of a grid section (the maps then sit alike on the one grid under them, and are
        placed again only when they outgrow a step).
        """
        boxes = [b for b in (self.layers[m].view_extent for m in modes) if b is not None]
        width = max((b[1] - b[0] for b in boxes), default=1.0)
        section, _ = grid_spacing(self.span())
        return math.ceil((width + 0.5 * section) / section) * section

    def span(self) -> float:
        """The extent sizes are chosen for: every map's and the truth's, at least ``min_span``."""
        box = None
        for layer in self.layers.values():
            if layer.extent is not None:
                box = union(box, layer.view_extent)
        if self._truth.shape[0]:
            t = self._truth
            box = union(box, (t[:, 0].min(), t[:, 0].max(), t[:, 1].min(), t[:, 1].max()))
        return max(span_of(box), self.min_span)

    def _resize(self) -> None:
        """Size the vertices and robots for the extent (:data:`VERTEX_FRACTION`, rounded)."""
        marker = nice(self.span() * VERTEX_FRACTION)
        if marker != self.marker:
            self.marker = marker
        for layer in self.layers.values():
            layer.set_marker(self.marker)

    def publish(
        self,
        maps: dict[MapMode, CognitiveMap],
        ground_truth: Sequence[tuple[float, float, float]] | None = None,
        ground_truth_count: int = 0,
        extras: dict[MapMode, MapExtras] | None = None,
        odometry: FloatArray | None = None,
        duration: float = 0.0,
    ) -> None:
        """Send what changed in the maps viewers show (the others when they are shown)."""
        started = time.perf_counter()
        truth = self._truth_poses(ground_truth, ground_truth_count)
        truth_segments = None if truth is None else path_segments(truth, GROUND_TRUTH_Z)
        odometry_segments = None
        if odometry is not None and self.show_odometry:
            odometry_segments = path_segments(odometry, ODOMETRY_Z)
        with self.server.atomic():
            for mode in sorted(self.needed & set(maps), key=lambda m: m.value):
                layer = self.layers[mode]
                layer.update(
                    maps[mode],
                    sorted(self.colourings),
                    None if extras is None else extras.get(mode),
                    duration,
                )
                layer.update_paths(truth_segments, odometry_segments, truth)
            self._resize()
            section, _ = grid_spacing(self.span())
            for mode in self.needed & set(maps):
                self.layers[mode].place_label(0.25 * section)
            self._place()
        self.stats.updates += 1
        self.stats.seconds += time.perf_counter() - started

    def _truth_poses(
        self, ground_truth: Sequence[tuple[float, float, float]] | None, count: int
    ) -> FloatArray | None:
        if ground_truth is None:
            return None
        count = min(count, len(ground_truth))
        have = self._truth.shape[0]
        if count < have:
            self._truth = self._truth[:count]
        elif count > have:
            new = np.asarray(ground_truth[have:count], dtype=np.float64).reshape(-1, 3)
            self._truth = np.concatenate([self._truth, new])
        return self._truth

    def reset(self) -> None:
        """Remove all map content (a new bag)."""
        with self.server.atomic():
            for layer in self.layers.values():
                layer.reset()
        self._truth = np.zeros((0, 3))

    def extent(
        self, modes: Sequence[MapMode] | None = None, offsets: Sequence[float] | None = None
    ) -> tuple[float, float, float, float] | None:
        """Bounding box (xmin, xmax, ymin, ymax) of ``modes`` (default: the shown ones).

        Each map's vertices and its aligned ground truth (what it shows).

        ``offsets``: their shifts along x (default: the default view's).
        """
        modes = self.shown if modes is None else tuple(modes)
        boxes = []
        for k, mode in enumerate(modes):
            layer = self.layers[mode]
            box = layer.view_extent
            if box is not None:
                shift = layer.offset if offsets is None else offsets[k]
                x0, x1, y0, y1 = box
                boxes.append((x0 + shift, x1 + shift, y0, y1))
        if not boxes:
            return None
        return (
            min(b[0] for b in boxes),
            max(b[1] for b in boxes),
            min(b[2] for b in boxes),
            max(b[3] for b in boxes),
        )
