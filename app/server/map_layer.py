"""The scene nodes of one cognitive map under ``/map/<mode>`` (:class:`MapLayer`).

One frame per *layer* a viewer can show or hide (:data:`LAYERS`; :mod:`app.server.view` shadows
them per client), the edges once per colouring in use, the ground truth aligned to the map, the
false loop closures over the others, the robot and the map's name (see :mod:`app.server.scene`).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np
import viser
from numpy.typing import NDArray

from app.palette import (
    FALSE_LOOP_COLOR,
    GROUND_TRUTH_COLOR,
    MAP_COLORS,
    ODOMETRY_COLOR,
    ROBOT_COLOR,
)
from app.server.figures import FalseEdges, false_edge_mask
from app.server.scene_nodes import ChunkedNodes, NodeFactory, NodeUpdater, StreamStats
from app.server.scene_style import (
    COLOURINGS,
    ERROR_RAMP,
    ERROR_SCALE_MAX,
    FALSE_LOOP_Z,
    LOOP_Z,
    MIN_SPAN,
    ROBOT_VERTICES,
    ROBOT_Z,
    SEQUENTIAL_Z,
    TIME_RAMP,
    VERTEX_FRACTION,
    VERTEX_Z,
    Box,
    FloatArray,
    cluster_colors,
    edge_errors,
    edge_segments,
    ramp,
    robot_triangle,
    union,
    yaw_to_wxyz,
)
from cogmap_core.cognitive_map import CognitiveMap, EdgeKind, MapMode


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
        self.previewed = False  # the map drawn is a preview (:mod:`app.server.preview`)

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

    def set_previewed(self, previewed: bool) -> None:
        """Name the map a preview (its exact rebuild is on its way), or the map again."""
        if previewed != self.previewed:
            self.previewed = previewed
            name = self.mode.value.replace("_", " ")
            self.label.text = f"{name} · preview" if previewed else name

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
            colors = ramp(snap.edge_time / max(duration, 1e-9), TIME_RAMP)
        else:
            colors = ramp(edge_errors(cmap) / ERROR_SCALE_MAX, ERROR_RAMP)
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
