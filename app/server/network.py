"""The network behind the map, as OpenRatSLAM shows it: pose cells and view templates.

Two pictures for the page's *Network behind the map* panel, drawn from what the front end
exposes (:class:`~cogmap_core.frontend.FrontEnd`: its pose-cell activity and peak, its view
templates, the last view's match):

- :func:`pose_cell_image` -- the 3-D pose-cell network (x, y, theta) as a point cloud in an
  oblique projection: every cell above :data:`ACTIVITY_FLOOR` of the peak activity is a dot, its
  colour and size its activity (a viridis ramp, no red), the box of the network drawn around
  them, the peak marked with a black ring and cross;
- :func:`template_image` -- the current view (the camera image as the local view cells see it:
  cropped, resampled to the template's size and normalised) beside the template it matched,
  enlarged, a gap between them.

:func:`match_text` says which template matched and the match error against the threshold
(``0.021 <= 0.025``), or that the view became a new template. Nothing here touches the front
end's state: the pictures are made from read-only views and copies.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from numpy.typing import NDArray

from app.palette import INK

UInt8Image = NDArray[np.uint8]

#: Cells below this fraction of the peak activity are not drawn.
ACTIVITY_FLOOR = 0.05
#: Size of the pose-cell picture (px).
POSE_CELL_SIZE = (420, 300)
#: Width of the template picture (px); its height follows the templates' aspect.
TEMPLATE_WIDTH = 420

_VIRIDIS = np.array(
    [(68, 1, 84), (59, 82, 139), (33, 145, 140), (94, 201, 98), (253, 231, 37)], dtype=np.float64
)


def _ramp(values: NDArray[np.float64]) -> NDArray[np.uint8]:
    v = np.clip(values, 0.0, 1.0) * (len(_VIRIDIS) - 1)
    lo = np.minimum(v.astype(np.int64), len(_VIRIDIS) - 2)
    w = (v - lo)[:, None]
    return np.round(_VIRIDIS[lo] * (1.0 - w) + _VIRIDIS[lo + 1] * w).astype(np.uint8)


def _projector(
    n_xy: int, n_th: int, size: tuple[int, int]
) -> tuple[float, float, float, float, float]:
    """Scale and origin of the oblique projection fitting the network's box into ``size``."""
    width, height = size
    depth = 0.55  # y goes back and up at 35 degrees, shortened
    dx, dy = depth * math.cos(math.radians(35.0)), depth * math.sin(math.radians(35.0))
    # the box's extent in projected units: x + dx y across, theta + dy y up
    th_scale = n_xy / n_th * 1.1  # theta drawn about as tall as x is wide
    across = n_xy + dx * n_xy
    up = n_th * th_scale + dy * n_xy
    scale = min((width - 64) / across, (height - 40) / up)
    ox = 44.0
    oy = height - 22.0
    return scale, ox, oy, th_scale, dx


def project(
    x: NDArray[np.float64] | float,
    y: NDArray[np.float64] | float,
    th: NDArray[np.float64] | float,
    n_xy: int,
    n_th: int,
    size: tuple[int, int] = POSE_CELL_SIZE,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Pixel coordinates (u, v) of pose cells (x, y, theta in cell units) in the picture."""
    scale, ox, oy, th_scale, dx = _projector(n_xy, n_th, size)
    dy = dx * math.tan(math.radians(35.0))
    x, y, th = np.asarray(x, float), np.asarray(y, float), np.asarray(th, float)
    u = ox + scale * (x + dx * y)
    v = oy - scale * (th * th_scale + dy * y)
    return u, v


def pose_cell_image(
    activity: NDArray[np.float64],
    peak: tuple[float, float, float],
    size: tuple[int, int] = POSE_CELL_SIZE,
) -> UInt8Image:
    """The pose-cell network's activity as a point cloud, the peak marked (RGB, module doc).

    ``activity`` is indexed ``[theta, y, x]`` (:attr:`~cogmap_core.frontend.FrontEnd.
    pose_cell_activity`); ``peak`` is ``(x, y, theta)`` in cell units.
    """
    n_th, n_xy, _ = activity.shape
    width, height = size
    image = np.full((height, width, 3), 255, np.uint8)
    # the network's box: its 12 edges, back ones lighter
    corners = np.array(
        [(x, y, t) for t in (0, n_th) for y in (0, n_xy) for x in (0, n_xy)], dtype=float
    )
    u, v = project(corners[:, 0], corners[:, 1], corners[:, 2], n_xy, n_th, size)
    edges = [(0, 1), (2, 3), (4, 5), (6, 7), (0, 2), (1, 3), (4, 6), (5, 7), (0, 4), (1, 5),
             (2, 6), (3, 7)]  # fmt: skip
    for a, b in edges:
        cv2.line(image, (round(u[a]), round(v[a])), (round(u[b]), round(v[b])), (200, 200, 200), 1,
                 cv2.LINE_AA)  # fmt: skip
    axis_names = (
        ("x", (n_xy / 2, -1.2, 0.0)),
        ("y", (n_xy + 0.6, n_xy / 2, 0.0)),
        ("theta", (-0.6, -0.5, n_th / 2)),
    )
    for text, (x, y, t) in axis_names:
        pu, pv = project(x, y, t, n_xy, n_th, size)
        at = (max(2, round(float(pu)) - (38 if text == "theta" else 4)), round(float(pv)) + 4)
        cv2.putText(image, text, at, cv2.FONT_HERSHEY_SIMPLEX, 0.4, INK, 1, cv2.LINE_AA)
    top = float(activity.max()) if activity.size else 0.0
    if top > 0:
        th, y, x = np.nonzero(activity >= ACTIVITY_FLOOR * top)
        level = activity[th, y, x] / top
        order = np.argsort(level)  # the strongest drawn last
        th, y, x, level = th[order], y[order], x[order], level[order]
        pu, pv = project(x + 0.5, y + 0.5, th + 0.5, n_xy, n_th, size)
        colours = _ramp(level)
        for k in range(level.size):
            radius = 1 + round(3 * level[k])
            c = colours[k]
            cv2.circle(image, (round(float(pu[k])), round(float(pv[k]))), radius,
                       (int(c[0]), int(c[1]), int(c[2])), -1, cv2.LINE_AA)  # fmt: skip
    px, py, pth = peak
    if all(math.isfinite(value) for value in peak):
        pu, pv = project(px + 0.5, py + 0.5, pth + 0.5, n_xy, n_th, size)
        centre = (round(float(pu)), round(float(pv)))
        cv2.circle(image, centre, 9, INK, 2, cv2.LINE_AA)
        cv2.line(image, (centre[0] - 14, centre[1]), (centre[0] + 14, centre[1]), INK, 1)
        cv2.line(image, (centre[0], centre[1] - 14), (centre[0], centre[1] + 14), INK, 1)
    return image


def peak_pixel(
    activity: NDArray[np.float64],
    peak: tuple[float, float, float],
    size: tuple[int, int] = POSE_CELL_SIZE,
) -> tuple[int, int]:
    """Where :func:`pose_cell_image` marks the peak (for tests and legends)."""
    n_th, n_xy, _ = activity.shape
    u, v = project(peak[0] + 0.5, peak[1] + 0.5, peak[2] + 0.5, n_xy, n_th, size)
    return round(float(u)), round(float(v))


def template_image(
    current: UInt8Image, matched: UInt8Image | None, width: int = TEMPLATE_WIDTH
) -> UInt8Image:
    """The current view beside the template it matched, enlarged (RGB; blank: no template)."""
    h, w = current.shape
    half = (width - 12) // 2
    scale = max(1, half // w)
    tile_w, tile_h = w * scale, h * scale
    image = np.full((tile_h + 8, 2 * tile_w + 12 + 8, 3), 255, np.uint8)
    for k, tile in enumerate((current, matched)):
        x = 4 + k * (tile_w + 12)
        if tile is None:
            cv2.rectangle(image, (x, 4), (x + tile_w - 1, 4 + tile_h - 1), (200, 200, 200), 1)
            continue
        big = cv2.resize(tile, (tile_w, tile_h), interpolation=cv2.INTER_NEAREST)
        image[4 : 4 + tile_h, x : x + tile_w] = big[:, :, None]
    return image


def match_text(template: int | None, error: float | None, threshold: float, new: bool) -> str:
    """What the view template panel says about the last view's match (HTML, no markup needed)."""
    if template is None:
        return "no view yet"
    if new or error is None or not math.isfinite(error):
        return (
            f"no template within the match threshold {threshold:.3g}: the view became new "
            f"template #{template}"
        )
    relation = "≤" if error <= threshold else ">"
    return (
        f"matched template #{template}: match error {error:.4f} {relation} threshold "
        f"{threshold:.3g}"
    )
