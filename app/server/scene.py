"""Incremental streaming of the cognitive maps into the viser scene.

Every map lives under its own frame ``/map/<mode>`` (moved aside for the side-by-side comparison),
with children

- ``/map/<mode>/vertices/cNNNN`` -- point clouds of at most :data:`CHUNK` vertices each,
- ``/map/<mode>/edges/sequential/cNNNN`` and ``/map/<mode>/edges/loop/cNNNN`` -- line segments,
  loop closures coloured by cluster id (:func:`cluster_color`),
- ``/map/<mode>/robot`` -- the current (dead-reckoned) robot pose,

and the ground-truth path under ``/ground_truth/path/cNNNN``, expressed in the frame of the first
ground-truth pose (which is where the maps' first vertex sits).

Between two optimisations a map only grows at its end, so only the last chunk of each layer
changes: :class:`ChunkedNodes` compares every chunk with what it last sent and re-sends only the
chunks that differ. After an optimisation every vertex moves, so everything is sent once. A map
whose sizes did not change since the last update costs one robot-pose message. Each update is
grouped with ``server.atomic()`` so a browser never draws a half-updated map, and viser's message
buffer keeps the latest state of every node, which is what a client joining late receives.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

import numpy as np
import viser
from numpy.typing import NDArray

from cogmap_core.cognitive_map import CognitiveMap, EdgeKind, MapMode

FloatArray = NDArray[np.float64]
UInt8Array = NDArray[np.uint8]

#: Items (vertices, edges, ground-truth segments) per scene node.
CHUNK = 512

MAP_COLORS: dict[MapMode, tuple[int, int, int]] = {
    MapMode.STANDARD: (52, 101, 164),
    MapMode.SCENE_INTEGRATION: (206, 92, 0),
    MapMode.COMPACT: (30, 140, 60),
}
GROUND_TRUTH_COLOR = (150, 150, 150)
#: Colours of loop-closure clusters (cluster id modulo the length).
CLUSTER_PALETTE: tuple[tuple[int, int, int], ...] = (
    (31, 119, 180),
    (255, 127, 14),
    (44, 160, 44),
    (214, 39, 40),
    (148, 103, 189),
    (140, 86, 75),
    (227, 119, 194),
    (188, 189, 34),
    (23, 190, 207),
    (60, 60, 60),
)
_PALETTE = np.array(CLUSTER_PALETTE, dtype=np.uint8)

VERTEX_Z = 0.004
EDGE_Z = 0.0
GROUND_TRUTH_Z = -0.004


def cluster_color(cluster_id: int) -> tuple[int, int, int]:
    """The colour of loop-closure cluster ``cluster_id``."""
    return CLUSTER_PALETTE[cluster_id % len(CLUSTER_PALETTE)]


def lighter(color: tuple[int, int, int], amount: float = 0.45) -> tuple[int, int, int]:
    """``color`` blended towards white by ``amount`` (0..1)."""
    r, g, b = (int(round(c + (255 - c) * amount)) for c in color)
    return r, g, b


def yaw_to_wxyz(theta: float) -> tuple[float, float, float, float]:
    """Quaternion (w, x, y, z) of a rotation by ``theta`` about +z."""
    return math.cos(theta / 2.0), 0.0, 0.0, math.sin(theta / 2.0)


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


class ChunkedNodes:
    """A growing array of items shown as scene nodes of :data:`CHUNK` items each.

    :meth:`sync` sends only the chunks whose content differs from what was last sent, and removes
    chunks beyond the new length.
    """

    def __init__(
        self, name: str, factory: NodeFactory, stats: StreamStats, chunk: int = CHUNK
    ) -> None:
        """Manage nodes ``<name>/c0000``, ``<name>/c0001``, ... made by ``factory``."""
        self.name = name
        self.factory = factory
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

    def sync(self, items: np.ndarray, colors: np.ndarray | None = None) -> int:
        """Show ``items`` (with per-item ``colors`` or none); return the chunks sent."""
        n = items.shape[0]
        count = -(-n // self.chunk)
        sent = 0
        for c in range(count):
            lo, hi = c * self.chunk, min((c + 1) * self.chunk, n)
            part = items[lo:hi]
            cpart = None if colors is None else colors[lo:hi]
            if c < len(self._sent):
                old, old_colors = self._sent[c]
                if (
                    old.shape == part.shape
                    and np.array_equal(old, part)
                    and (cpart is None or np.array_equal(old_colors, cpart))
                ):
                    continue
            handle = self.factory(f"{self.name}/c{c:04d}", part, cpart)
            record = (part.copy(), None if cpart is None else cpart.copy())
            if c < len(self._handles):
                self._handles[c] = handle
                self._sent[c] = record
            else:
                self._handles.append(handle)
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


def _segments_from_poses(poses: FloatArray, z: float) -> NDArray[np.float32]:
    """Consecutive points of a path as line segments ``(n - 1, 2, 3)``."""
    if poses.shape[0] < 2:
        return np.zeros((0, 2, 3), dtype=np.float32)
    seg = np.empty((poses.shape[0] - 1, 2, 3), dtype=np.float32)
    seg[:, 0, :2] = poses[:-1, :2]
    seg[:, 1, :2] = poses[1:, :2]
    seg[:, :, 2] = z
    return seg


class MapLayer:
    """The scene nodes of one cognitive map under ``/map/<mode>``."""

    def __init__(
        self, server: viser.ViserServer, mode: MapMode, stats: StreamStats, root: str = "/map"
    ) -> None:
        """Create the (empty) frame of the map; nothing else is sent until :meth:`update`."""
        self.server = server
        self.mode = mode
        self.stats = stats
        self.name = f"{root}/{mode.value}"
        color = MAP_COLORS[mode]
        self.frame = server.scene.add_frame(self.name, show_axes=False)
        self._offset = 0.0
        scene = server.scene

        def vertices(name: str, part: np.ndarray, _: np.ndarray | None) -> viser.SceneNodeHandle:
            return scene.add_point_cloud(
                name,
                points=part,
                colors=color,
                point_size=0.03,
                point_shape="circle",
                precision="float32",
                point_shading="flat",
            )

        def sequential(name: str, part: np.ndarray, _: np.ndarray | None) -> viser.SceneNodeHandle:
            return scene.add_line_segments(
                name, part, colors=lighter(color), thickness=1.5, thickness_units="screen"
            )

        def loops(name: str, part: np.ndarray, cols: np.ndarray | None) -> viser.SceneNodeHandle:
            assert cols is not None
            return scene.add_line_segments(
                name, part, colors=cols, thickness=2.5, thickness_units="screen"
            )

        self.vertices = ChunkedNodes(f"{self.name}/vertices", vertices, stats)
        self.sequential = ChunkedNodes(f"{self.name}/edges/sequential", sequential, stats)
        self.loops = ChunkedNodes(f"{self.name}/edges/loop", loops, stats)
        self.robot = scene.add_frame(
            f"{self.name}/robot",
            axes_length=0.15,
            axes_radius=0.012,
            origin_radius=0.03,
            origin_color=color,
        )
        self._map: CognitiveMap | None = None
        self._key: tuple[int, int, int] | None = None
        self._robot_pose: tuple[float, float, float] | None = None
        self.extent: tuple[float, float, float, float] | None = None  # xmin, xmax, ymin, ymax

    # ------------------------------------------------------------------ layout
    @property
    def visible(self) -> bool:
        """Whether the map is shown."""
        return bool(self.frame.visible)

    @visible.setter
    def visible(self, value: bool) -> None:
        if bool(self.frame.visible) != value:
            self.frame.visible = value

    @property
    def offset(self) -> float:
        """Shift of the map along +x (m), for side-by-side comparison."""
        return self._offset

    @offset.setter
    def offset(self, value: float) -> None:
        if value != self._offset:
            self._offset = value
            self.frame.position = (value, 0.0, 0.0)

    # ------------------------------------------------------------------ content
    def update(self, cmap: CognitiveMap) -> bool:
        """Send what changed in ``cmap`` since the last update; True when the graph changed."""
        # Between optimisations a map only gains vertices and edges; merges and moves happen in
        # optimisations. So these three numbers change whenever the graph does.
        key = (cmap.num_vertices, cmap.num_edges, len(cmap.optimizations))
        changed = cmap is not self._map or key != self._key
        if changed:
            self._send_graph(cmap)
            self._map, self._key = cmap, key
        pose = cmap.current_pose()
        robot = (float(pose[0]), float(pose[1]), float(pose[2]))
        if robot != self._robot_pose:
            self.robot.position = (robot[0], robot[1], VERTEX_Z)
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
        self.vertices.sync(points)
        if n:
            self.extent = (
                float(points[:, 0].min()),
                float(points[:, 0].max()),
                float(points[:, 1].min()),
                float(points[:, 1].max()),
            )
        else:
            self.extent = None
        m = snap.edge_from.shape[0]
        segments = np.empty((m, 2, 3), dtype=np.float32)
        if m:
            segments[:, 0, :2] = snap.poses[np.searchsorted(snap.vertex_ids, snap.edge_from), :2]
            segments[:, 1, :2] = snap.poses[np.searchsorted(snap.vertex_ids, snap.edge_to), :2]
        segments[:, :, 2] = EDGE_Z
        is_loop = snap.edge_kind == EdgeKind.LOOP_CLOSURE
        self.sequential.sync(segments[~is_loop])
        loop_colors = _PALETTE[snap.edge_cluster[is_loop] % len(CLUSTER_PALETTE)]
        self.loops.sync(segments[is_loop], np.repeat(loop_colors[:, None, :], 2, axis=1))

    def reset(self) -> None:
        """Forget what was sent and remove the map's content (the frame stays)."""
        for layer in (self.vertices, self.sequential, self.loops):
            layer.clear()
        self._map = None
        self._key = None
        self.extent = None


class GroundTruthLayer:
    """The ground-truth path (``/ground_truth``), relative to the first ground-truth pose."""

    def __init__(self, server: viser.ViserServer, stats: StreamStats) -> None:
        """Create the (empty) layer."""
        scene = server.scene
        self.frame = scene.add_frame("/ground_truth", show_axes=False)

        def segments(name: str, part: np.ndarray, _: np.ndarray | None) -> viser.SceneNodeHandle:
            return scene.add_line_segments(
                name, part, colors=GROUND_TRUTH_COLOR, thickness=1.5, thickness_units="screen"
            )

        self.path = ChunkedNodes("/ground_truth/path", segments, stats)
        self._poses = np.zeros((0, 3))
        self._origin: tuple[float, float, float] | None = None

    def update(self, ground_truth: Sequence[tuple[float, float, float]], count: int) -> None:
        """Show the first ``count`` poses of ``ground_truth`` (a growing list)."""
        count = min(count, len(ground_truth))
        have = self._poses.shape[0]
        if count < have:
            self._poses = self._poses[:count]
        elif count > have:
            new = np.asarray(ground_truth[have:count], dtype=np.float64).reshape(-1, 3)
            if self._origin is None:
                self._origin = (float(new[0, 0]), float(new[0, 1]), float(new[0, 2]))
            x0, y0, t0 = self._origin
            c, s = math.cos(-t0), math.sin(-t0)
            dx, dy = new[:, 0] - x0, new[:, 1] - y0
            rel = np.stack([c * dx - s * dy, s * dx + c * dy, new[:, 2] - t0], axis=1)
            self._poses = np.concatenate([self._poses, rel])
        if count == 0:
            self._origin = None
        self.path.sync(_segments_from_poses(self._poses, GROUND_TRUTH_Z))

    @property
    def visible(self) -> bool:
        """Whether the path is shown."""
        return bool(self.frame.visible)

    @visible.setter
    def visible(self, value: bool) -> None:
        if bool(self.frame.visible) != value:
            self.frame.visible = value


class SceneStreamer:
    """All map layers and the ground truth; :meth:`publish` sends one incremental update."""

    def __init__(
        self, server: viser.ViserServer, modes: Iterable[MapMode] = tuple(MapMode)
    ) -> None:
        """Create the scene's layers (empty) for ``modes``."""
        self.server = server
        self.stats = StreamStats()
        self.layers: dict[MapMode, MapLayer] = {m: MapLayer(server, m, self.stats) for m in modes}
        self.ground_truth = GroundTruthLayer(server, self.stats)
        self.shown: tuple[MapMode, ...] = ()
        self.show((MapMode.COMPACT,))

    def show(self, modes: Sequence[MapMode], show_ground_truth: bool = True) -> None:
        """Show ``modes`` (the first at the origin, a second one beside it); hide the rest."""
        self.shown = tuple(modes)
        with self.server.atomic():
            for mode, layer in self.layers.items():
                layer.visible = mode in self.shown
            self.ground_truth.visible = show_ground_truth
            self._place()

    def _place(self) -> None:
        if not self.shown:
            return
        first = self.layers[self.shown[0]]
        first.offset = 0.0
        if len(self.shown) > 1:
            extents = [e for e in (self.layers[m].extent for m in self.shown) if e is not None]
            width = max((e[1] - e[0] for e in extents), default=1.0)
            step = math.ceil((width + 0.5) * 2.0) / 2.0  # in 0.5 m steps: few re-placements
            for k, mode in enumerate(self.shown[1:], start=1):
                self.layers[mode].offset = step * k

    def publish(
        self,
        maps: dict[MapMode, CognitiveMap],
        ground_truth: Sequence[tuple[float, float, float]] | None = None,
        ground_truth_count: int = 0,
    ) -> None:
        """Send what changed in the shown maps (hidden maps are brought up to date when shown)."""
        started = time.perf_counter()
        with self.server.atomic():
            for mode in self.shown:
                if mode in maps:
                    self.layers[mode].update(maps[mode])
            if ground_truth is not None:
                self.ground_truth.update(ground_truth, ground_truth_count)
            self._place()
        self.stats.updates += 1
        self.stats.seconds += time.perf_counter() - started

    def reset(self) -> None:
        """Remove all map content (on restart)."""
        with self.server.atomic():
            for layer in self.layers.values():
                layer.reset()
            self.ground_truth.update([], 0)

    def extent(self) -> tuple[float, float, float, float] | None:
        """Bounding box (xmin, xmax, ymin, ymax) of what is shown, offsets included."""
        boxes = []
        for mode in self.shown:
            layer = self.layers[mode]
            if layer.extent is not None:
                x0, x1, y0, y1 = layer.extent
                boxes.append((x0 + layer.offset, x1 + layer.offset, y0, y1))
        if not boxes:
            return None
        return (
            min(b[0] for b in boxes),
            max(b[1] for b in boxes),
            min(b[2] for b in boxes),
            max(b[3] for b in boxes),
        )
