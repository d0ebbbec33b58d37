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

Here: the streamer and the grid. One map's nodes are :class:`~app.server.map_layer.MapLayer`'s,
the chunks :mod:`app.server.scene_nodes`', sizes, heights and colour scales
:mod:`app.server.scene_style`'s.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np
import viser

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
from app.server.map_layer import MapExtras, MapLayer
from app.server.scene_nodes import ChunkedNodes, StreamStats
from app.server.scene_style import (
    GRID_Z,
    GROUND_TRUTH_Z,
    MIN_SPAN,
    ODOMETRY_Z,
    ROBOT_Z,
    VERTEX_FRACTION,
    Box,
    FloatArray,
    grid_spacing,
    nice,
    path_segments,
    span_of,
    union,
)
from cogmap_core.cognitive_map import CognitiveMap, MapMode
from cogmap_core.map_modes import ALL_MODES

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

    def __init__(self, server: viser.ViserServer, modes: Iterable[MapMode] = ALL_MODES) -> None:
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
        previewed: Iterable[MapMode] = (),
    ) -> None:
        """Send what changed in the maps viewers show (the others when they are shown).

        ``previewed``: the maps in ``maps`` that are previews (their names say so).
        """
        previewed = set(previewed)
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
                layer.set_previewed(mode in previewed)
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
