"""Issue 25 (items 8, 16): colours a colour-blind reader can tell apart, red kept for false loop
closures, one colour per map in every output."""

from __future__ import annotations

import itertools

import numpy as np

from app import palette
from app.palette import (
    CLUSTER_MIN_DELTA_E,
    CLUSTER_NEIGHBOURS,
    MIN_DELTA_E,
    RED_DELTA_E,
    VISIONS,
    delta_e,
    is_red,
    palette_problems,
    simulate,
)
from app.server import chart, scene
from cogmap_core.cognitive_map import MapMode


def page_colours() -> dict[str, tuple[int, int, int]]:
    """The colours the page draws side by side (as the scene module has them)."""
    return {
        **{f"{mode.value} map": scene.MAP_COLORS[mode] for mode in MapMode},
        "false loop closures": scene.FALSE_LOOP_COLOR,
        "ground truth": scene.GROUND_TRUTH_COLOR,
        "robot": scene.ROBOT_COLOR,
        "pinned map": scene.PINNED_COLOR,
        "dead-reckoned odometry": scene.ODOMETRY_COLOR,
        "selection": scene.SELECTION_COLOR,
        "background": (255, 255, 255),
    }


def test_the_simulation_is_machados() -> None:
    # a pure red seen by a protanope is a dark olive, by a deuteranope a brighter one; white
    # stays white and grey stays grey for everyone (rows of the matrices sum to 1)
    for vision in VISIONS:
        np.testing.assert_allclose(
            simulate([(255, 255, 255)], vision), [[100.0, 0.0, 0.0]], atol=0.2
        )
        assert abs(simulate([(128, 128, 128)], vision)[0, 1:]).max() < 0.5
    red_p = simulate([(255, 0, 0)], "protanopia")[0]
    red_d = simulate([(255, 0, 0)], "deuteranopia")[0]
    assert red_p[0] < simulate([(255, 0, 0)], "normal")[0, 0] < red_d[0]
    assert abs(red_p[1]) < 10 and abs(red_d[1]) < 10  # no red left: a* near zero
    assert delta_e((255, 0, 0), (0, 255, 0)) > 80  # normal vision: very different
    assert delta_e((255, 0, 0), (0, 255, 0), "deuteranopia") < 40  # the classic confusion


def test_every_colour_the_page_draws_is_apart_for_every_vision() -> None:
    assert palette_problems(page_colours(), MIN_DELTA_E) == []
    assert MIN_DELTA_E >= 15.0


def test_red_means_false_loop_closure_and_nothing_else() -> None:
    assert is_red(scene.FALSE_LOOP_COLOR)
    others = {k: v for k, v in page_colours().items() if k != "false loop closures"}
    assert not any(is_red(c) for c in others.values() if max(c) - min(c) > 60)
    colours = [scene.cluster_color(c) for c in range(len(palette.CLUSTER_PALETTE))]
    assert not any(is_red(c) for c in colours)
    assert min(delta_e(c, scene.FALSE_LOOP_COLOR) for c in colours) >= RED_DELTA_E
    assert RED_DELTA_E >= 40.0


def test_cluster_colours_are_distinct_and_neighbours_apart_for_every_vision() -> None:
    n = len(palette.CLUSTER_PALETTE)
    colours = [scene.cluster_color(c) for c in range(n)]
    assert n >= 26 and len(set(colours)) == n  # the default dataset's 26 clusters all differ
    assert scene.cluster_color(n) == colours[0]  # then the palette cycles
    normal = min(delta_e(a, b) for a, b in itertools.combinations(colours, 2))
    assert normal >= CLUSTER_MIN_DELTA_E >= 18.0
    for k in range(n):  # clusters close in id (ids cycle) differ for every vision
        for step in range(1, CLUSTER_NEIGHBOURS + 1):
            for vision in VISIONS:
                d = delta_e(colours[k], colours[(k + step) % n], vision)
                assert d >= CLUSTER_MIN_DELTA_E, (k, step, vision)
    for colour in colours:  # and no cluster looks like a map, the truth, the robot, ...
        for name, other in page_colours().items():
            for vision in VISIONS:
                assert delta_e(colour, other, vision) >= MIN_DELTA_E, (colour, name, vision)
    assert all(max(c) - min(c) > 40 for c in colours)  # coloured: no grey


def test_one_colour_per_map_in_the_page_the_chart_and_the_figures() -> None:
    from app import report_figures

    for mode in MapMode:
        colour = palette.MAP_COLORS[mode]
        assert scene.MAP_COLORS[mode] == colour
        assert report_figures.map_color(mode) == palette.hex_color(colour)
        stroke = next(
            s["stroke"]
            for s in chart.chart_series()
            if s["label"].startswith(chart.SHORT[mode] + " V")
        )
        assert stroke == palette.css(colour)
