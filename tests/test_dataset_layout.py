"""Maze layouts (parsing, validation, built-ins), route planning and rat-like motion."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from app.cli import main
from cogmap_core.datasets import LayoutError, builtin_layouts, load_layout
from cogmap_core.datasets.layout import DEFAULT_LAYOUT, parse_layout
from cogmap_core.datasets.motion import MotionParams, RoutePlanner, simulate_route
from cogmap_core.datasets.render import MazeRenderer, extract_faces
from cogmap_core.errors import ParameterError

LOOP = """\
; a small loop
#########
#A.....B#
#.#####.#
#D.....C#
#########
"""


def test_parse_a_layout() -> None:
    layout = parse_layout(LOOP, name="loop", cell=0.3)
    assert layout.name == "loop"
    assert layout.description == "a small loop"
    assert layout.walls.shape == (5, 9)
    assert int(layout.walls.sum()) == 45 - 16
    assert layout.waypoints == {"A": (1, 1), "B": (1, 7), "C": (3, 7), "D": (3, 1)}
    assert layout.cell == 0.3
    assert layout.size_m == pytest.approx((2.7, 1.5))
    assert layout.cell_center(1, 1) == pytest.approx((0.45, 1.05))
    assert layout.world_to_cell(0.45, 1.05) == (1, 1)
    assert layout.is_free(0.45, 1.05)
    assert not layout.is_free(0.1, 0.1)


def test_waypoints_are_sorted_and_spaces_are_floor() -> None:
    text = "#####\n#C B#\n# # #\n#A  #\n#####\n"
    layout = parse_layout(text, cell=0.3)
    assert list(layout.waypoints) == ["A", "B", "C"]
    assert not layout.walls[1, 2]


def test_short_lines_are_padded_with_floor() -> None:
    layout = parse_layout("####\n#AB\n####\n", cell=0.3)
    assert layout.walls.shape == (3, 4)
    assert not layout.walls[1, 3]


def test_cell_directive_and_automatic_cell() -> None:
    assert parse_layout("; cell: 0.25\n" + LOOP).cell == 0.25
    assert parse_layout("; cell = 0.25\n" + LOOP, cell=0.5).cell == 0.5  # override wins
    # corridors one cell wide -> cells of 0.3 m (iRat-scale corridors)
    assert parse_layout(LOOP).cell == pytest.approx(0.3)
    wide = "\n".join(
        ["#######", "#A....#", "#.....#", "#.....#", "#.###B#", "#.###.#", "#.....#", "#######"]
    )
    # median over floor cells of the shorter free run: 15 cells of the 3-row hall (3) against
    # 9 cells of 1-wide corridor, so the hall sets the scale: 3 cells = 0.3 m
    assert parse_layout(wide).cell == pytest.approx(0.1)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("#####\n#...#\n#####\n", "has no waypoints; mark at least two"),
        ("#####\n#A..#\n#####\n", "has only waypoint A"),
        ("#######\n#A.#.B#\n#######\n", r"waypoint B \(line 2 column 6\) cannot be reached"),
        ("#####\n#A.A#\n#B..#\n#####\n", "waypoint A appears twice"),
        ("#####\n#A.b#\n#####\n", "unexpected character 'b'; .*upper-case"),
        ("#####\n#A\t.B#\n#####\n", r"unexpected character '\\t'"),
        ("; just a comment\n\n", "is empty"),
        ("; cell: wide\n#AB#\n", "is not a number"),
        ("; cell: 50\n####\n#AB#\n####\n", "out of range"),
    ],
)
def test_bad_layouts(text: str, match: str) -> None:
    with pytest.raises(LayoutError, match=match):
        parse_layout(text, name="bad")


def test_builtin_layouts() -> None:
    names = builtin_layouts()
    assert DEFAULT_LAYOUT == "irat_australia"
    assert {"irat_australia", "figure_eight"} <= set(names)
    irat = load_layout("irat_australia")
    assert irat.cell == 0.1
    assert 3.0 <= irat.size_m[0] <= 4.5 and 2.0 <= irat.size_m[1] <= 3.0  # iRat scale
    assert len(irat.waypoints) >= 8
    assert load_layout("figure_eight.txt").name == "figure_eight"


def test_load_layout_from_file_and_unknown_name(tmp_path: Path) -> None:
    path = tmp_path / "mine.txt"
    path.write_text(LOOP)
    assert load_layout(path, cell=0.3).name == "mine"
    with pytest.raises(LayoutError, match="no layout file or built-in layout named 'nope'.*irat"):
        load_layout("nope")
    with pytest.raises(LayoutError, match="is not a file"):
        load_layout(tmp_path)


def test_cli_bad_layout_is_one_line_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "walled.txt"
    bad.write_text("#######\n#A.#.B#\n#######\n")
    assert main(["make-maze", str(tmp_path / "o.bag"), "--layout", str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "cannot be reached from waypoint A" in err
    assert not (tmp_path / "o.bag").exists()


# ------------------------------------------------------------------------------ faces, planning
def test_faces_close_the_free_space() -> None:
    layout = load_layout("irat_australia")
    faces = extract_faces(layout.walls, layout.cell)
    # each wall cell side that touches floor belongs to exactly one face: total lengths match
    free = ~np.pad(layout.walls, 1, constant_values=True)
    walls = ~free
    sides = 0
    for dr, dc in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        sides += int((walls & np.roll(np.roll(free, dr, 0), dc, 1)).sum())
    assert faces.length.sum() == pytest.approx(sides * layout.cell)
    # the normals point into free space
    mid = 0.5 * (faces.p0 + faces.p1) + 0.01 * faces.normal
    assert all(layout.is_free(x, y) for x, y in mid)
    # any ray from anywhere on the floor hits a wall
    renderer = MazeRenderer(layout)
    rng = np.random.default_rng(3)
    cells = np.argwhere(~layout.walls)
    for r, c in cells[rng.choice(len(cells), 30)]:
        x, y = layout.cell_center(r, c)
        depth, face, _ = renderer.cast(x, y, rng.uniform(-math.pi, math.pi))
        assert (face >= 0).all() and np.isfinite(depth).all()
        assert depth.max() < 5.0


def test_paths_keep_to_corridor_centres() -> None:
    layout = load_layout("irat_australia")
    planner = RoutePlanner(layout)
    path = planner.path(layout.waypoints["A"], layout.waypoints["B"])
    assert tuple(path[0]) == layout.waypoints["A"] and tuple(path[-1]) == layout.waypoints["B"]
    steps = np.abs(np.diff(path, axis=0))
    assert steps.max() <= 1  # 8-connected
    clearance = layout.clearance()[path[:, 0], path[:, 1]]
    assert np.median(clearance) == pytest.approx(1.5)  # the middle of 3-cell corridors


# -------------------------------------------------------------------------------------- motion
def test_motion_is_rat_like_and_stays_on_the_floor() -> None:
    layout = load_layout("irat_australia")
    traj = simulate_route(layout, MotionParams(laps=2), np.random.default_rng(7))
    assert len(traj.lap_times) == 3
    assert np.all(np.diff(traj.times) > 0)
    t = np.arange(0.0, traj.duration, 0.05)
    speed = np.diff(traj.distance_at(t)) / 0.05
    turn = np.abs(np.diff(traj.heading_at(t))) / 0.05
    moving = speed > 0.01
    assert 0.12 < speed[moving].mean() < 0.25  # rat-like ~0.1-0.3 m/s
    assert speed.max() <= 0.3 + 1e-9
    assert 0.05 < np.mean(speed < 0.005) < 0.5  # some pauses, mostly moving
    assert turn.max() < 2.5  # smooth turns
    # the robot body (radius 5 cm) never touches a wall
    clearance = layout.clearance() * layout.cell
    rc = np.array([layout.world_to_cell(x, y) for x, y in traj.xy[::5]])
    assert (clearance[rc[:, 0], rc[:, 1]] >= 0.05).all()
    # every waypoint is reached each lap, in order
    letters = [w for w, _ in traj.waypoint_times]
    tour = list(layout.waypoints)
    assert letters == tour[:1] + (tour[1:] + tour[:1]) * 2


def test_corridors_are_driven_in_both_directions() -> None:
    layout = load_layout("figure_eight")
    traj = simulate_route(
        layout, MotionParams(laps=1, detour_probability=0.0), np.random.default_rng(1)
    )
    # the shared middle corridor (x = 1.45 m): driven north and south within one lap
    on_middle = (np.abs(traj.xy[:, 0] - 1.45) < 0.03) & (np.abs(traj.xy[:, 1] - 0.65) < 0.2)
    headings = traj.heading[on_middle] % (2 * math.pi)
    north = np.abs(headings - math.pi / 2) < 0.3
    south = np.abs(headings - 3 * math.pi / 2) < 0.3
    assert north.any() and south.any()


def test_motion_is_deterministic_for_a_seed() -> None:
    layout = load_layout("figure_eight")
    a = simulate_route(layout, MotionParams(laps=1), np.random.default_rng(5))
    b = simulate_route(layout, MotionParams(laps=1), np.random.default_rng(5))
    c = simulate_route(layout, MotionParams(laps=1), np.random.default_rng(6))
    np.testing.assert_array_equal(a.xy, b.xy)
    np.testing.assert_array_equal(a.times, b.times)
    assert a.duration != c.duration


@pytest.mark.parametrize(("speed", "laps"), [(0.0, 1), (2.0, 1), (0.2, 0)])
def test_bad_motion_parameters(speed: float, laps: int) -> None:
    with pytest.raises(ParameterError, match="out of range"):
        MotionParams(speed=speed, laps=laps)
