"""Pose cell network: attractor dynamics, path integration with wrap-around, peak decoding."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cogmap_core.frontend import FrontEndConfig, PoseCellExperiences, PoseCellNetwork

# Everything wraps around here; OpenRatSLAM's edge loss (the default) has its own test below.
CFG = FrontEndConfig(pc_edge_loss=0)
CELL = CFG.pc_cell_x_size  # 0.015 m
TH_CELL = 2 * math.pi / CFG.pc_dim_th  # 10 degrees


def delta_network(x: int, y: int, th: int) -> PoseCellNetwork:
    """A network whose whole activity is one cell."""
    net = PoseCellNetwork(CFG)
    net.cells[...] = 0.0
    net.cells[th, y, x] = 1.0
    net.find_best()
    return net


def test_starts_with_one_active_cell_in_the_centre() -> None:
    net = PoseCellNetwork(CFG)
    assert net.cells.shape == (36, 11, 11)
    assert net.cells.sum() == 1.0 and net.cells[18, 5, 5] == 1.0
    assert net.best == (5.0, 5.0, 18.0)


def test_attractor_keeps_a_normalised_packet_in_place() -> None:
    net = PoseCellNetwork(CFG)
    for _ in range(30):
        net.update(0.0, 0.0)
    assert net.cells.sum() == pytest.approx(1.0)
    assert net.cells.min() >= 0.0
    assert np.unravel_index(int(net.cells.argmax()), net.cells.shape) == (18, 5, 5)
    assert net.best == pytest.approx((5.0, 5.0, 18.0), abs=1e-9)
    # Global inhibition keeps the packet compact: most cells are exactly zero.
    assert np.count_nonzero(net.cells) < 0.2 * net.cells.size


@pytest.mark.parametrize(
    ("th", "cells", "expected_xy"),
    [
        # OpenRatSLAM's layout: heading theta moves (x, y) along (sin, cos)
        (0, 2.0, (5, 7)),  # heading 0: +y
        (9, 3.0, (8, 5)),  # heading 90 deg: +x
        (18, 1.0, (5, 4)),  # heading 180 deg: -y
        (27, 4.0, (1, 5)),  # heading 270 deg: -x
        (0, 8.0, (5, 2)),  # wraps around y: 5 + 8 = 13 = 2 (mod 11)
        (9, 17.0, (0, 5)),  # wraps around x: 5 + 17 = 22 = 0 (mod 11)
        (18, -3.0, (5, 8)),  # reversing along heading 180 deg moves +y
    ],
)
def test_translation_moves_each_heading_layer_along_its_heading(
    th: int, cells: float, expected_xy: tuple[int, int]
) -> None:
    net = delta_network(5, 5, th)
    net.path_integrate(cells * CELL, 0.0)
    ex, ey = expected_xy
    assert net.cells[th, ey, ex] == pytest.approx(1.0, abs=1e-9)
    assert net.cells.sum() == pytest.approx(1.0)


def test_fractional_translation_splits_activity_bilinearly() -> None:
    net = delta_network(5, 10, 0)
    net.path_integrate(0.25 * CELL, 0.0)
    assert net.cells[0, 10, 5] == pytest.approx(0.75)
    assert net.cells[0, 0, 5] == pytest.approx(0.25)  # wrapped
    # Heading 45 deg is not a layer (10 deg cells), take 40 deg: shift (sin, cos) * 1 cell.
    net = delta_network(5, 5, 4)
    net.path_integrate(CELL, 0.0)
    c, s = math.cos(math.radians(40)), math.sin(math.radians(40))
    expected = {
        (5, 5): (1 - s) * (1 - c),
        (5, 6): (1 - s) * c,
        (6, 5): s * (1 - c),
        (6, 6): s * c,
    }
    for (x, y), w in expected.items():
        assert net.cells[4, y, x] == pytest.approx(w, abs=1e-12)
    net.find_best()
    assert net.best[0] > 5.0 and net.best[1] > 5.0


@pytest.mark.parametrize(
    ("th", "rotation_cells", "expected_th"),
    [(0, 3.0, 3), (0, -1.0, 35), (30, 9.0, 3), (18, -18.0, 0), (5, 36.0, 5)],
)
def test_rotation_shifts_theta_with_wrap(th: int, rotation_cells: float, expected_th: int) -> None:
    net = delta_network(5, 5, th)
    net.path_integrate(0.0, rotation_cells * TH_CELL)
    assert net.cells[expected_th, 5, 5] == pytest.approx(1.0, abs=1e-9)


def test_fractional_rotation_splits_activity_linearly() -> None:
    net = delta_network(5, 5, 0)
    net.path_integrate(0.0, -0.3 * TH_CELL)
    assert net.cells[0, 5, 5] == pytest.approx(0.7)
    assert net.cells[35, 5, 5] == pytest.approx(0.3)


def test_peak_decoding_wraps_around() -> None:
    net = PoseCellNetwork(CFG)
    net.cells[...] = 0.0
    net.cells[7, 3, 10] = 0.5
    net.cells[7, 3, 0] = 0.5
    assert net.find_best() == pytest.approx((10.5, 3.0, 7.0), abs=1e-12)
    net.cells[...] = 0.0
    net.cells[35, 10, 4] = 0.3
    net.cells[1, 10, 4] = 0.3
    net.cells[0, 0, 4] = 0.4
    x, y, th = net.find_best()
    # OpenRatSLAM's decoding gives [0, dim]: theta cell 0 comes out as 36
    assert (x, th % 36) == pytest.approx((4.0, 0.0), abs=1e-12)
    assert y == pytest.approx(10.4, abs=0.01)  # 60% at y = 10, 40% at y = 0 = 11
    assert 0.0 <= y <= 11.0


@pytest.mark.parametrize("th", [0, 9, 18])
def test_odometry_moves_the_packet_by_the_expected_number_of_cells(th: int) -> None:
    """The full dynamics (attractor + path integration) over many steps."""
    net = PoseCellNetwork(CFG)
    net.update(0.0, (th - 18) * TH_CELL)  # turn the packet to heading layer th
    for _ in range(20):
        net.update(0.0, 0.0)
    x0, y0, th0 = net.best
    assert th0 % 36 == pytest.approx(th, abs=1e-6)
    steps, per_step = 33, 0.5  # 16.5 cells: wraps around the 11-cell torus
    for _ in range(steps):
        net.update(per_step * CELL, 0.0)
    x1, y1, th1 = net.best
    heading = th * TH_CELL
    # The packet spans a few heading layers whose mean direction is the centre layer's; its
    # off-centre layers move slightly less along the heading (cos of +-10..30 deg): about 1%.
    moved = steps * per_step
    ex = (x0 + moved * math.sin(heading)) % 11
    ey = (y0 + moved * math.cos(heading)) % 11
    assert net.distance((x1, y1, th1), (ex, ey, th)) < 0.02 * moved
    along = (x1 - x0) * math.sin(heading) + (y1 - y0) * math.cos(heading)
    assert math.remainder(along - moved, 11) == pytest.approx(-0.186, abs=0.01)
    # ... and the shortfall is small and along the heading: no drift sideways.
    side = (x1 - x0) * math.cos(heading) - (y1 - y0) * math.sin(heading)
    assert abs(math.remainder(side, 11)) < 1e-6


def test_a_full_turn_and_a_closed_square_return_to_the_start() -> None:
    net = PoseCellNetwork(CFG)
    for _ in range(10):
        net.update(0.0, 0.0)
    start = net.best
    for _ in range(4):
        for _ in range(7):
            net.update(CELL, 0.0)
        for _ in range(3):
            net.update(0.0, math.pi / 6)
    assert net.distance(net.best, start) < 0.05


def test_injected_energy_pulls_the_packet() -> None:
    net = PoseCellNetwork(CFG)
    for _ in range(10):
        net.update(0.0, 0.0)
    for _ in range(30):
        net.inject(1.0, 8.0, 3.0, 0.1)
        net.update(0.0, 0.0)
    assert net.distance(net.best, (1.0, 8.0, 3.0)) < 0.5


def _injected(pcx: PoseCellExperiences, vt: int, rad: float = 0.0) -> np.ndarray:
    before = pcx.network.cells.copy()
    pcx.on_view_template(vt, rad)
    return pcx.network.cells - before


def test_view_cells_inject_energy_as_openratslam() -> None:
    pcx = PoseCellExperiences(CFG)
    # Templates 0..11, each first seen at a different pose-cell position (moving +x then +y).
    for vt in range(12):
        assert not _injected(pcx, vt).any()  # a new template injects nothing
        pcx.on_odo(CELL if vt < 6 else 0.0, 0.0)
        pcx.get_action()
    cell0 = pcx.network.cells.copy()
    # Template 5 is among the 10 newest: no energy.
    assert not _injected(pcx, 5).any()
    # Template 0 is old enough: energy 0.1 / 30 * (30 - e^(1.2 * 1)) at its cells (5, 5, 18).
    diff = _injected(pcx, 0)
    expected = 0.1 / 30.0 * (30.0 - math.exp(1.2))
    assert diff[18, 5, 5] == pytest.approx(expected)
    assert np.count_nonzero(diff) == 1
    # Seen again the next frame: decay 1 - 0.05 restored to 1, + 1 active = 2: less energy.
    diff = _injected(pcx, 0)
    assert diff[18, 5, 5] == pytest.approx(0.1 / 30.0 * (30.0 - math.exp(1.2 * 2.0)))
    # A third time: decay 2 - 0.05 + 1 = 2.95, e^(3.54) > 30: nothing.
    assert not _injected(pcx, 0).any()
    assert pcx.view_decay(0) == pytest.approx(2.9)
    # Away for 20 frames the decay recovers by 0.05 a frame, down to 1.
    for _ in range(20):
        pcx.on_view_template(11, 0.0)
    assert pcx.view_decay(0) == pytest.approx(1.9)
    assert cell0.sum() == pytest.approx(1.0)


@pytest.mark.parametrize(("nearest", "cell"), [(0, 15), (1, 16)])
def test_injection_is_shifted_by_the_relative_angle(nearest: int, cell: int) -> None:
    pcx = PoseCellExperiences(CFG.with_changes(pc_inject_nearest=nearest))
    for vt in range(12):
        pcx.on_view_template(vt, 0.0)
    # Template 0 was seen at theta cell 18; the view is turned by -25 degrees: cell 15.5,
    # truncated to 15 (OpenRatSLAM) or rounded to 16.
    diff = _injected(pcx, 0, math.radians(-25.0))
    assert np.flatnonzero(diff.reshape(36, -1).any(axis=1)).tolist() == [cell]
    assert pcx.relative_rad == pytest.approx(math.radians(-25.0))


def test_the_first_templates_inject_through_openratslams_unsigned_difference() -> None:
    """``vt < size() - 10`` wraps around while there are fewer than 10 templates."""
    for nearest, injects in ((0, True), (1, False)):
        pcx = PoseCellExperiences(CFG.with_changes(pc_inject_nearest=nearest))
        for vt in range(3):
            pcx.on_view_template(vt, 0.0)
        assert bool(_injected(pcx, 0).any()) is injects
        pcx = PoseCellExperiences(CFG.with_changes(pc_inject_nearest=nearest))
        for vt in range(12):
            pcx.on_view_template(vt, 0.0)
        assert not _injected(pcx, 5).any()  # 5 < 12 - 10 is false either way


def test_openratslam_drops_what_wraps_at_the_first_cell_of_an_edge() -> None:
    """Values OpenRatSLAM's ``path_integration`` gives for one active cell moved 0.3 cells."""
    cases = [
        # (heading layer, active cell (y, x), cells the activity ends in (y, x): share)
        (0, (10, 0), {(10, 0): 0.7}),  # the wrap to (0, 0) is lost
        (0, (10, 5), {(10, 5): 0.7, (0, 5): 0.3}),
        (4, (10, 0), {(10, 0): 0.621667, (10, 1): 0.148520, (0, 1): 0.044316}),
        (4, (0, 10), {(0, 10): 0.621667, (1, 10): 0.185497, (1, 0): 0.044316}),
        (13, (0, 0), {(0, 0): 0.621667, (0, 1): 0.185497, (10, 1): 0.044316}),
        (22, (0, 0), {(0, 0): 0.621667, (0, 10): 0.148520, (10, 0): 0.185497, (10, 10): 0.044316}),
        (31, (10, 10), {(10, 10): 0.621667, (10, 9): 0.185497, (0, 9): 0.044316}),
        (9, (0, 10), {(0, 10): 0.7, (0, 0): 0.3}),  # 90 deg: the next quadrant's frame
    ]
    for th, (y, x), ends in cases:
        net = PoseCellNetwork(FrontEndConfig(pc_cell_x_size=1.0))
        net.cells[...] = 0.0
        net.cells[th, y, x] = 1.0
        net.path_integrate(0.3, 0.0)
        got = {
            (int(j), int(i)): v
            for j, i in zip(*np.nonzero(net.cells[th] > 1e-12), strict=True)
            for v in [float(net.cells[th, j, i])]
        }
        assert got.keys() == ends.keys(), (th, y, x)
        for key, share in ends.items():
            assert got[key] == pytest.approx(share, abs=1e-6)
