"""Report figures drawn with OpenCV (no plotting library needed): map size over time, maps."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from cogmap_core.cognitive_map import EdgeKind, MapSnapshot
from cogmap_core.fileio import write_bytes_atomic

Color = tuple[int, int, int]  # BGR
WHITE: Color = (255, 255, 255)
BLACK: Color = (0, 0, 0)
GREY: Color = (200, 200, 200)
MAP_COLORS: dict[str, Color] = {
    "standard": (40, 40, 40),
    "scene_integration": (200, 110, 30),
    "compact": (40, 40, 220),
}
FONT = cv2.FONT_HERSHEY_SIMPLEX


def nice_ticks(low: float, high: float, count: int = 5) -> list[float]:
    """Round tick values covering ``[low, high]``."""
    if not math.isfinite(low) or not math.isfinite(high) or high <= low:
        return [low]
    raw = (high - low) / max(count, 1)
    magnitude = 10 ** math.floor(math.log10(raw))
    step = next(m * magnitude for m in (1, 2, 2.5, 5, 10) if m * magnitude >= raw)
    first = math.ceil(low / step) * step
    ticks = []
    value = first
    while value <= high + 1e-9 * step:
        ticks.append(round(value, 10))
        value += step
    return ticks


@dataclass
class Panel:
    """A rectangular plotting area mapping data coordinates to pixels."""

    image: NDArray[np.uint8]
    left: int
    top: int
    width: int
    height: int
    x_range: tuple[float, float]
    y_range: tuple[float, float]

    def to_px(self, x: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.int32]:
        """Pixel coordinates of data points."""
        x0, x1 = self.x_range
        y0, y1 = self.y_range
        px = self.left + (np.asarray(x) - x0) / max(x1 - x0, 1e-12) * self.width
        py = self.top + self.height - (np.asarray(y) - y0) / max(y1 - y0, 1e-12) * self.height
        return np.stack([px, py], axis=-1).round().astype(np.int32)

    def axes(self, x_label: str, y_label: str, title: str) -> None:
        """Frame, ticks, tick labels, axis labels and title."""
        img = self.image
        cv2.rectangle(
            img, (self.left, self.top), (self.left + self.width, self.top + self.height), BLACK, 1
        )
        for x in nice_ticks(*self.x_range):
            px = int(self.to_px(np.array([x]), np.array([self.y_range[0]]))[0, 0])
            cv2.line(img, (px, self.top + self.height), (px, self.top + self.height + 5), BLACK, 1)
            cv2.putText(img, f"{x:g}", (px - 12, self.top + self.height + 20), FONT, 0.4, BLACK, 1)
        for y in nice_ticks(*self.y_range):
            py = int(self.to_px(np.array([self.x_range[0]]), np.array([y]))[0, 1])
            cv2.line(img, (self.left - 5, py), (self.left, py), BLACK, 1)
            cv2.line(img, (self.left, py), (self.left + self.width, py), GREY, 1)
            cv2.putText(img, f"{y:g}", (self.left - 48, py + 4), FONT, 0.4, BLACK, 1)
        cv2.putText(
            img,
            x_label,
            (self.left + self.width // 2 - 30, self.top + self.height + 40),
            FONT,
            0.45,
            BLACK,
            1,
        )
        cv2.putText(img, y_label, (self.left - 48, self.top - 8), FONT, 0.45, BLACK, 1)
        cv2.putText(img, title, (self.left + 5, self.top - 10), FONT, 0.55, BLACK, 1)

    def polyline(
        self, x: NDArray[np.float64], y: NDArray[np.float64], color: Color, thickness: int = 2
    ) -> None:
        """Connected line through the points."""
        if len(x) == 0:
            return
        pts = self.to_px(x, y).reshape(-1, 1, 2)
        cv2.polylines(self.image, [pts], False, color, thickness, cv2.LINE_AA)


def size_figure(
    histories: Mapping[str, tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.int64]]],
    end_time: float,
) -> NDArray[np.uint8]:
    """The paper's size figure: vertices (left) and edges (right) over time, one line per map."""
    width, height = 1200, 480
    img = np.full((height, width, 3), 255, np.uint8)
    max_v = max([int(v.max()) if len(v) else 1 for _, v, _ in histories.values()] + [1])
    max_e = max([int(e.max()) if len(e) else 1 for _, _, e in histories.values()] + [1])
    panels = []
    for k, (label, top_value) in enumerate((("vertices", max_v), ("edges", max_e))):
        panel = Panel(
            img, 80 + k * 590, 50, 480, 340, (0.0, max(end_time, 1e-6)), (0.0, top_value * 1.05)
        )
        panel.axes("time (s)", label, f"number of {label}")
        panels.append(panel)
    for name, (times, vertices, edges) in histories.items():
        color = MAP_COLORS.get(name, BLACK)
        # step plot: sizes hold until the next change, and until the end of the data
        t = np.r_[np.repeat(times, 2)[1:], end_time] if len(times) else times
        for panel, values in zip(panels, (vertices, edges), strict=True):
            panels_values = np.repeat(values, 2).astype(float)
            panel.polyline(t, panels_values, color)
    for k, name in enumerate(histories):
        color = MAP_COLORS.get(name, BLACK)
        y = height - 30
        x = 100 + k * 300
        cv2.line(img, (x, y), (x + 40, y), color, 3)
        cv2.putText(img, name, (x + 48, y + 5), FONT, 0.5, BLACK, 1)
    return img


def _bounds(points: Sequence[NDArray[np.float64]]) -> tuple[float, float, float, float]:
    stacked = np.vstack([p[:, :2] for p in points if len(p)] or [np.zeros((1, 2))])
    x0, y0 = stacked.min(0)
    x1, y1 = stacked.max(0)
    pad = 0.05 * max(x1 - x0, y1 - y0, 0.1)
    return float(x0 - pad), float(x1 + pad), float(y0 - pad), float(y1 + pad)


def map_figure(
    ground_truth: NDArray[np.float64] | None,
    maps: Mapping[str, MapSnapshot],
    aligned_poses: Mapping[str, NDArray[np.float64]] | None = None,
    notes: Mapping[str, str] | None = None,
) -> NDArray[np.uint8]:
    """Ground-truth path beside each map (vertices as dots, sequential edges blue, loops red).

    The paper's "Cognitive Map" figure: each map titled with its vertices and edges.
    ``aligned_poses`` optionally gives each map's vertex poses aligned to the ground truth;
    ``notes`` a second title line per map (e.g. its layout fidelity).
    """
    panels_spec: list[tuple[str, NDArray[np.float64], MapSnapshot | None]] = []
    if ground_truth is not None and len(ground_truth):
        panels_spec.append(("ground truth", ground_truth, None))
    for name, snap in maps.items():
        poses = aligned_poses[name] if aligned_poses and name in aligned_poses else snap.poses
        panels_spec.append((name, poses, snap))
    x0, x1, y0, y1 = _bounds([p for _, p, _ in panels_spec])
    side = 420
    scale = min(side / (x1 - x0), side / (y1 - y0))
    pw, ph = int((x1 - x0) * scale), int((y1 - y0) * scale)
    width = 40 + len(panels_spec) * (pw + 40)
    height = max(ph, 200) + 130
    img = np.full((height, width, 3), 255, np.uint8)
    for k, (title, poses, snap) in enumerate(panels_spec):
        panel = Panel(img, 40 + k * (pw + 40), 70, pw, ph, (x0, x1), (y0, y1))
        cv2.rectangle(img, (panel.left, panel.top), (panel.left + pw, panel.top + ph), GREY, 1)
        label = title
        if snap is None:
            panel.polyline(poses[:, 0], poses[:, 1], (60, 160, 60), 1)
        else:
            label = f"{title}: V {len(snap.vertex_ids)}, E {len(snap.edge_from)}"
            index = {v: i for i, v in enumerate(snap.vertex_ids.tolist())}
            a = np.array([index[v] for v in snap.edge_from.tolist()], dtype=np.int64)
            b = np.array([index[v] for v in snap.edge_to.tolist()], dtype=np.int64)
            pa = panel.to_px(poses[a, 0], poses[a, 1]) if len(a) else np.zeros((0, 2), np.int32)
            pb = panel.to_px(poses[b, 0], poses[b, 1]) if len(b) else np.zeros((0, 2), np.int32)
            for (u, v), kind in zip(zip(pa, pb, strict=True), snap.edge_kind.tolist(), strict=True):
                color = (60, 60, 230) if kind == EdgeKind.LOOP_CLOSURE else (200, 120, 40)
                cv2.line(
                    img, tuple(int(c) for c in u), tuple(int(c) for c in v), color, 1, cv2.LINE_AA
                )
            for p in panel.to_px(poses[:, 0], poses[:, 1]):
                cv2.circle(img, (int(p[0]), int(p[1])), 2, (40, 150, 40), -1, cv2.LINE_AA)
        cv2.putText(img, label, (panel.left, 35), FONT, 0.45, BLACK, 1)
        if notes and title in notes:
            cv2.putText(img, notes[title], (panel.left, 57), FONT, 0.42, (90, 90, 90), 1)
    cv2.putText(img, "1 m", (20, height - 20), FONT, 0.45, BLACK, 1)
    cv2.line(img, (60, height - 25), (60 + int(scale), height - 25), BLACK, 2)
    return img


def save_png(image: NDArray[np.uint8], path: Path) -> None:
    """Write a PNG atomically (:func:`~cogmap_core.fileio.write_bytes_atomic`).

    A reader never sees a half-written file, and a failed write leaves an existing ``path`` as
    it was.

    Raises:
        OSError: the file cannot be written (e.g. a full disk), with the system's reason.
        ValueError: OpenCV cannot encode the image.

    """
    path = Path(path)
    ok, data = cv2.imencode(".png", image)
    if not ok:
        raise ValueError(f"could not encode {path.name} as PNG")
    write_bytes_atomic(path, data.tobytes())
