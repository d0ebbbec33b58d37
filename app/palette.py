"""The colours of every cogmap output, checked for colour-blind readers.

One colour per map, red kept for false loop closures.

The page (:mod:`app.server.scene`, its legends and size chart) and the report figures
(:mod:`app.report_figures`: ``map.png``, ``size.png``, ``pareto.png``, ``long_term.png``) take
their colours from here, so a map has the same colour everywhere:

- the maps and the other things drawn beside them are Okabe & Ito's colour-blind-safe set
  ("Color Universal Design", 2008): standard **blue**, scene integration **orange**, compact
  **bluish green**; the pinned map sky blue, the dead-reckoned odometry reddish purple, the
  selection yellow, the robot black, the ground truth a light grey band;
- **red** means a false loop closure and nothing else (no cluster colour, no map, no chart line);
- loop-closure clusters take :data:`CLUSTER_PALETTE`, made here from the hue circle without
  its reds and far from every colour above.

"Checked" means measured: :func:`simulate` shows a colour as a protanope, a deuteranope and a
tritanope sees it (Machado, Oliveira & Fernandes 2009, full severity, in linear RGB), and
:func:`palette_problems` lists every pair of colours closer than a threshold in CIE L*a*b*
(ΔE*76) for normal vision or any of the three; the tests require none.
"""

from __future__ import annotations

import colorsys
import itertools
from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from cogmap_core.cognitive_map import MapMode

RGB = tuple[int, int, int]

#: One colour per map, in every output (Okabe-Ito blue, orange, bluish green).
MAP_COLORS: dict[MapMode, RGB] = {
    MapMode.STANDARD: (0, 114, 178),
    MapMode.SCENE_INTEGRATION: (230, 159, 0),
    MapMode.COMPACT: (0, 158, 115),
}
#: False loop closures: the only red of any output.
FALSE_LOOP_COLOR: RGB = (200, 20, 20)
GROUND_TRUTH_COLOR: RGB = (200, 200, 200)
ROBOT_COLOR: RGB = (0, 0, 0)
PINNED_COLOR: RGB = (86, 180, 233)
ODOMETRY_COLOR: RGB = (204, 121, 167)
SELECTION_COLOR: RGB = (240, 228, 66)
BACKGROUND: RGB = (255, 255, 255)
#: Text, axes, scale bars.
INK: RGB = (34, 34, 34)

#: The colours drawn side by side on the page and in the figures (besides the clusters').
NAMED_COLORS: dict[str, RGB] = {
    **{f"{mode.value} map": color for mode, color in MAP_COLORS.items()},
    "false loop closures": FALSE_LOOP_COLOR,
    "ground truth": GROUND_TRUTH_COLOR,
    "robot": ROBOT_COLOR,
    "pinned map": PINNED_COLOR,
    "dead-reckoned odometry": ODOMETRY_COLOR,
    "selection": SELECTION_COLOR,
    "background": BACKGROUND,
}

#: Smallest ΔE*76 between two named colours, for normal vision and each dichromacy.
MIN_DELTA_E = 15.0
#: Clusters: smallest ΔE*76 between any two palette colours (normal vision), between clusters
#: up to :data:`CLUSTER_NEIGHBOURS` ids apart (every vision), and from the named colours (every
#: vision); no cluster within :data:`RED_DELTA_E` of the false loop closures' red.
CLUSTER_MIN_DELTA_E = 18.0
CLUSTER_NEIGHBOURS = 2
RED_DELTA_E = 40.0
#: Hues (degrees) a cluster colour never takes: the reds.
RED_HUES = (330.0, 30.0)
PALETTE_SIZE = 32

#: Machado et al. (2009) simulation matrices, severity 1, for linear RGB.
CVD_MATRICES: dict[str, NDArray[np.float64]] = {
    "protanopia": np.array(
        [[0.152286, 1.052583, -0.204868], [0.114503, 0.786281, 0.099216],
         [-0.003882, -0.048116, 1.051998]]
    ),
    "deuteranopia": np.array(
        [[0.367322, 0.860646, -0.227968], [0.280085, 0.672501, 0.047413],
         [-0.011820, 0.042940, 0.968881]]
    ),
    "tritanopia": np.array(
        [[1.255528, -0.076749, -0.178779], [-0.078411, 0.930809, 0.147602],
         [0.004733, 0.691367, 0.303900]]
    ),
}  # fmt: skip
VISIONS: tuple[str, ...] = ("normal", *CVD_MATRICES)


def _linear(rgb: NDArray[np.float64]) -> NDArray[np.float64]:
    c = np.asarray(rgb, dtype=np.float64) / 255.0
    return np.where(c > 0.04045, ((c + 0.055) / 1.055) ** 2.4, c / 12.92)


def _lab_of_linear(linear: NDArray[np.float64]) -> NDArray[np.float64]:
    xyz = linear @ np.array(
        [[0.4124, 0.2126, 0.0193], [0.3576, 0.7152, 0.1192], [0.1805, 0.0722, 0.9505]]
    )
    xyz = xyz / np.array([0.95047, 1.0, 1.08883])
    f = np.where(xyz > 0.008856, np.cbrt(xyz), 7.787 * xyz + 16.0 / 116.0)
    return np.stack(
        [
            116.0 * f[..., 1] - 16.0,
            500.0 * (f[..., 0] - f[..., 1]),
            200.0 * (f[..., 1] - f[..., 2]),
        ],
        -1,
    )


def lab(rgb: NDArray[np.float64] | Sequence[RGB]) -> NDArray[np.float64]:
    """CIE L*a*b* (D65) of sRGB colours ``(n, 3)`` in 0..255."""
    return _lab_of_linear(_linear(np.asarray(rgb, dtype=np.float64)))


def simulate(rgb: NDArray[np.float64] | Sequence[RGB], vision: str) -> NDArray[np.float64]:
    """L*a*b* of sRGB colours ``(n, 3)`` as seen with ``vision`` (:data:`VISIONS`)."""
    linear = _linear(np.asarray(rgb, dtype=np.float64))
    if vision != "normal":
        linear = np.clip(linear @ CVD_MATRICES[vision].T, 0.0, 1.0)
    return _lab_of_linear(linear)


def delta_e(a: RGB, b: RGB, vision: str = "normal") -> float:
    """ΔE*76 between two colours as seen with ``vision``."""
    pair = simulate(np.array([a, b], dtype=np.float64), vision)
    return float(np.linalg.norm(pair[0] - pair[1]))


def palette_problems(colors: Mapping[str, RGB], threshold: float = MIN_DELTA_E) -> list[str]:
    """Every pair of ``colors`` closer than ``threshold`` for some vision (empty: all apart)."""
    problems = []
    for (name_a, a), (name_b, b) in itertools.combinations(colors.items(), 2):
        for vision in VISIONS:
            d = delta_e(a, b, vision)
            if d < threshold:
                problems.append(f"{name_a} / {name_b}: ΔE {d:.1f} ({vision})")
    return problems


def hue_degrees(rgb: RGB) -> float:
    """The hue of a colour in degrees (0 = red)."""
    h, _, _ = colorsys.rgb_to_hsv(*(c / 255.0 for c in rgb))
    return 360.0 * h


def is_red(rgb: RGB) -> bool:
    """Whether a saturated colour's hue is in :data:`RED_HUES`."""
    low, high = RED_HUES
    hue = hue_degrees(rgb)
    return hue >= low or hue <= high


def _build_cluster_palette(size: int) -> tuple[RGB, ...]:
    """Saturated colours of every hue but red, each chosen far from those before it.

    Candidates span the hue circle (reds left out) at several brightnesses and saturations, and
    only those at least :data:`MIN_DELTA_E` from every named colour for every vision (and
    :data:`RED_DELTA_E` from the false loop closures' red) are used. Each next colour is the
    candidate farthest from the palette so far for normal vision and, for every vision, from
    the :data:`CLUSTER_NEIGHBOURS` colours before it (its neighbours in cluster id; the last
    ones are also kept apart from the first ones, which follow them when ids cycle).
    """
    candidates = []
    for hue in np.arange(0.0, 360.0, 5.0):
        for value in (1.0, 0.85, 0.7, 0.55, 0.4):
            for saturation in (1.0, 0.75, 0.5):
                r, g, b = colorsys.hsv_to_rgb(hue / 360.0, saturation, value)
                rgb = (round(r * 255), round(g * 255), round(b * 255))
                if not is_red(rgb):
                    candidates.append(rgb)
    cand = np.array(candidates, dtype=np.float64)
    seen = np.stack([simulate(cand, v) for v in VISIONS])  # (visions, n, 3)
    named = np.array(list(NAMED_COLORS.values()), dtype=np.float64)
    named_seen = np.stack([simulate(named, v) for v in VISIONS])
    apart = np.linalg.norm(seen[:, :, None] - named_seen[:, None], axis=3).min(axis=(0, 2))
    red = np.linalg.norm(seen - simulate(np.array([FALSE_LOOP_COLOR], float), "normal")[0], axis=2)
    usable = (apart >= MIN_DELTA_E) & (red[0] >= RED_DELTA_E)
    nearest = np.full(cand.shape[0], np.inf)  # normal vision, to every colour chosen
    chosen: list[int] = []
    for index in range(size):
        score = nearest.copy()
        # its neighbours in id: the colours before it and, ids cycling, the first ones after it
        wrap = max(0, index + CLUSTER_NEIGHBOURS - size + 1)
        for k in chosen[-CLUSTER_NEIGHBOURS:] + chosen[:wrap]:
            score = np.minimum(score, np.linalg.norm(seen - seen[:, k][:, None], axis=2).min(0))
        score[~usable] = -np.inf
        k = int(np.argmax(score))
        chosen.append(k)
        nearest = np.minimum(nearest, np.linalg.norm(seen[0] - seen[0, k], axis=1))
    return tuple((int(cand[k, 0]), int(cand[k, 1]), int(cand[k, 2])) for k in chosen)


#: Colours of loop-closure clusters, by id modulo its size.
CLUSTER_PALETTE: tuple[RGB, ...] = _build_cluster_palette(PALETTE_SIZE)


def cluster_color(cluster_id: int) -> RGB:
    """The colour of loop-closure cluster ``cluster_id`` (:data:`CLUSTER_PALETTE`, cycled)."""
    return CLUSTER_PALETTE[int(cluster_id) % PALETTE_SIZE]


def hex_color(rgb: RGB) -> str:
    """``#rrggbb`` (matplotlib, CSS)."""
    return "#{:02x}{:02x}{:02x}".format(*rgb)


def css(rgb: RGB) -> str:
    """``rgb(r,g,b)`` (CSS)."""
    return f"rgb({rgb[0]},{rgb[1]},{rgb[2]})"
