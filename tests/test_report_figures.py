"""Issue 25: report figures drawn with matplotlib, an SVG beside each PNG, the page's colours."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import cv2
import numpy as np
import pytest

from app.cli import main
from app.palette import FALSE_LOOP_COLOR, MAP_COLORS
from app.report_figures import long_term_figure, map_figure, save_figure, size_figure
from cogmap_core.cognitive_map import CognitiveMap, MapMode
from tests import test_server_support as support
from tests.test_browser import colour_pixels
from tests.test_server_scene import circle_events

false_log = support.false_log


@pytest.fixture(scope="module")
def report(false_log: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("figures") / "run"
    assert main(["run", str(false_log), "--out", str(out)]) == 0
    return out


def _svg_text(path: Path) -> str:
    root = ET.fromstring(path.read_bytes())  # a well-formed SVG
    assert root.tag.endswith("svg")
    return " ".join(t.strip() for t in root.itertext() if t.strip())


def test_cogmap_run_writes_each_figure_as_png_and_svg(report: Path) -> None:
    for name in ("size", "map"):
        png = (report / f"{name}.png").read_bytes()
        assert png[:4] == b"\x89PNG"
        image = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
        assert image.shape[0] > 300 and image.shape[1] > 900
        for mode in MapMode:  # one colour per map, the page's
            assert colour_pixels(png, MAP_COLORS[mode], 12) > 200, (name, mode)
        text = _svg_text(report / f"{name}.svg")
        assert "standard" in text and "compact" in text
    assert colour_pixels((report / "map.png").read_bytes(), FALSE_LOOP_COLOR, 12) > 50
    assert colour_pixels((report / "size.png").read_bytes(), FALSE_LOOP_COLOR, 40) == 0
    size_text = _svg_text(report / "size.svg")
    assert "data time (s)" in size_text and "number of vertices" in size_text
    map_text = _svg_text(report / "map.svg")
    assert "x (m)" in map_text and "y (m)" in map_text and "false loop closures" in map_text
    assert "ATE" in map_text and "completeness" in map_text
    marker = (report / ".cogmap-report").read_text()
    assert all(f'"{n}"' in marker for n in ("size.png", "size.svg", "map.png", "map.svg"))


@pytest.mark.parametrize("radius", [0.3, 3.0, 40.0, 600.0])
def test_the_map_figure_has_a_readable_metric_scale_on_any_extent(radius: float) -> None:
    cmap = CognitiveMap(MapMode.STANDARD)
    cmap.apply_all(circle_events(200, laps=1))
    snap = cmap.snapshot()
    scale = radius / max(np.abs(snap.poses[:, :2]).max(), 1e-9)
    poses = snap.poses.copy()
    poses[:, :2] *= scale
    figure = map_figure(None, {MapMode.STANDARD: snap}, {MapMode.STANDARD: poses})
    figure.canvas.draw()  # (ticks are placed when drawn)
    ax = figure.axes[0]
    for ticks, (low, high) in ((ax.get_xticks(), ax.get_xlim()), (ax.get_yticks(), ax.get_ylim())):
        inside = [t for t in ticks if low <= t <= high]
        assert 3 <= len(inside) <= 11, (radius, inside)
    assert ax.get_xlabel() == "x (m)" and ax.get_aspect() == 1.0


def test_the_long_term_figure(tmp_path: Path) -> None:
    times = np.array([0.0, 1800.0, 3600.0])
    histories = {m: (times, np.array([1, 40, 41]), np.array([0, 45, 47])) for m in MapMode}
    figure = long_term_figure(
        histories,
        7200.0,
        [1, 2, 3],
        {"read": [0.1, 0.1, 0.1], "compact": [0.4, 0.5, 0.45]},
        "3 laps",
    )
    written = save_figure(figure, tmp_path / "long_term.png")
    assert [p.name for p in written] == ["long_term.png", "long_term.svg"]
    png = written[0].read_bytes()
    assert colour_pixels(png, MAP_COLORS[MapMode.COMPACT], 12) > 100
    assert "data time (h)" in _svg_text(written[1]) and "ms per frame" in _svg_text(written[1])


def test_the_same_figure_gives_the_same_svg(tmp_path: Path) -> None:
    histories = {MapMode.COMPACT: (np.array([0.0, 5.0]), np.array([1, 3]), np.array([0, 2]))}
    save_figure(size_figure(histories, 10.0), tmp_path / "a.png")
    save_figure(size_figure(histories, 10.0), tmp_path / "b.png")
    assert (tmp_path / "a.svg").read_bytes() == (tmp_path / "b.svg").read_bytes()
