"""ASCII maze layouts: parsing, validation and the layouts shipped with cogmap.

A layout is a text grid, one character per cell:

- ``#`` a wall cell;
- ``.`` or a space: free floor;
- ``A``-``Z``: free floor holding a waypoint; the robot visits the waypoints in alphabetical order
  each lap and then returns to ``A``.

Lines starting with ``;`` are comments. A comment ``; cell: 0.1`` sets the cell size in metres
(``--cell`` overrides it); without one the cell size is chosen so that the typical corridor is
:data:`DEFAULT_CORRIDOR_WIDTH` metres wide (iRat scale). Everything outside the grid is wall and
short lines are padded with free floor. World coordinates: ``x`` east along columns, ``y`` north
(row 0 is the northern edge), headings counter-clockwise from ``+x``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from importlib import resources
from importlib.abc import Traversable
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from cogmap_core.datasets.errors import LayoutError

DEFAULT_LAYOUT = "irat_australia"
DEFAULT_CORRIDOR_WIDTH = 0.3  # metres: iRat-scale corridors are ~0.25-0.4 m wide
MIN_CELL, MAX_CELL = 0.01, 5.0  # metres
_CELL_DIRECTIVE = re.compile(r"^;\s*cell\s*[:=]\s*(\S+)\s*$", re.IGNORECASE)


@dataclass(frozen=True)
class Layout:
    """A parsed, validated maze.

    Attributes:
        name: short name (file stem or built-in name).
        walls: ``(rows, cols)`` boolean grid, ``True`` for wall cells.
        waypoints: letter -> ``(row, col)``, in alphabetical order.
        cell: cell size in metres.
        description: the first comment line of the file (may be empty).
        text: the layout text as read (for hashing and reproducibility).

    """

    name: str
    walls: NDArray[np.bool_]
    waypoints: dict[str, tuple[int, int]]
    cell: float
    description: str = ""
    text: str = field(default="", repr=False)

    @property
    def rows(self) -> int:
        """Number of grid rows."""
        return int(self.walls.shape[0])

    @property
    def cols(self) -> int:
        """Number of grid columns."""
        return int(self.walls.shape[1])

    @property
    def size_m(self) -> tuple[float, float]:
        """Extent of the grid in metres: ``(width, height)``."""
        return self.cols * self.cell, self.rows * self.cell

    def cell_center(self, row: int, col: int) -> tuple[float, float]:
        """World ``(x, y)`` of the centre of cell ``(row, col)``."""
        return (col + 0.5) * self.cell, (self.rows - row - 0.5) * self.cell

    def cell_centers(self, cells: NDArray[np.int64]) -> NDArray[np.float64]:
        """World ``(x, y)`` of the centres of an ``(n, 2)`` array of ``(row, col)`` cells."""
        cells = np.asarray(cells)
        x = (cells[:, 1] + 0.5) * self.cell
        y = (self.rows - cells[:, 0] - 0.5) * self.cell
        return np.stack([x, y], axis=1)

    def world_to_cell(self, x: float, y: float) -> tuple[int, int]:
        """Grid ``(row, col)`` containing the world point ``(x, y)`` (may lie outside the grid)."""
        return int(np.floor(self.rows - y / self.cell)), int(np.floor(x / self.cell))

    def is_free(self, x: float, y: float) -> bool:
        """Whether the world point lies on free floor inside the grid."""
        row, col = self.world_to_cell(x, y)
        return 0 <= row < self.rows and 0 <= col < self.cols and not self.walls[row, col]

    def clearance(self) -> NDArray[np.float64]:
        """Distance (in cells) from each free cell's centre to the nearest wall cell's edge.

        Wall cells get 0; the area outside the grid counts as wall.
        """
        padded = np.pad(~self.walls, 1, constant_values=False)
        dist = ndimage.distance_transform_edt(padded)[1:-1, 1:-1]
        return np.where(self.walls, 0.0, dist - 0.5)


def corridor_width_cells(walls: NDArray[np.bool_], reachable: NDArray[np.bool_]) -> float:
    """Typical corridor width in cells.

    The median, over reachable free cells, of the shorter of the horizontal and vertical runs of
    free cells through the cell.
    """
    free = ~walls
    h_run = _run_lengths(free)
    v_run = _run_lengths(free.T).T
    widths = np.minimum(h_run, v_run)[reachable]
    return float(np.median(widths)) if widths.size else 1.0


def _run_lengths(free: NDArray[np.bool_]) -> NDArray[np.int64]:
    """For each cell, the length of the horizontal run of free cells it belongs to (0 for walls)."""
    out = np.zeros(free.shape, dtype=np.int64)
    for r in range(free.shape[0]):
        row = free[r]
        c = 0
        n = row.size
        while c < n:
            if not row[c]:
                c += 1
                continue
            start = c
            while c < n and row[c]:
                c += 1
            out[r, start:c] = c - start
    return out


def parse_layout(text: str, name: str = "layout", cell: float | None = None) -> Layout:
    """Parse and validate a layout.

    Args:
        text: the layout text (see the module docstring for the format).
        name: name used in error messages and file names.
        cell: cell size in metres; overrides a ``; cell:`` comment and the automatic choice.

    Raises:
        LayoutError: unknown characters, duplicate / missing / unreachable waypoints, a bad
            cell size.

    """
    comments: list[str] = []
    grid_lines: list[tuple[int, str]] = []
    file_cell: float | None = None
    for lineno, raw in enumerate(text.splitlines(), start=1):
        line = raw.rstrip("\r\n")
        if line.startswith(";"):
            match = _CELL_DIRECTIVE.match(line)
            if match:
                try:
                    file_cell = float(match.group(1))
                except ValueError:
                    raise LayoutError(
                        f"layout {name}: line {lineno}: cell size {match.group(1)!r} is not a "
                        "number; write e.g. '; cell: 0.1'"
                    ) from None
            else:
                comments.append(line.lstrip("; ").strip())
            continue
        grid_lines.append((lineno, line))
    while grid_lines and not grid_lines[0][1].strip():
        grid_lines.pop(0)
    while grid_lines and not grid_lines[-1][1].strip():
        grid_lines.pop()
    if not grid_lines:
        raise LayoutError(f"layout {name} is empty; draw the maze with '#' walls and '.' floor")

    width = max(len(line) for _, line in grid_lines)
    walls = np.zeros((len(grid_lines), width), dtype=bool)
    waypoints: dict[str, tuple[int, int]] = {}
    waypoint_lines: dict[str, tuple[int, int]] = {}
    for r, (lineno, line) in enumerate(grid_lines):
        for c, ch in enumerate(line):
            if ch == "#":
                walls[r, c] = True
            elif ch in ". ":
                continue
            elif "A" <= ch <= "Z":
                if ch in waypoints:
                    first = waypoint_lines[ch]
                    raise LayoutError(
                        f"layout {name}: waypoint {ch} appears twice (line {first[0]} column "
                        f"{first[1]} and line {lineno} column {c + 1}); keep one of them"
                    )
                waypoints[ch] = (r, c)
                waypoint_lines[ch] = (lineno, c + 1)
            else:
                hint = "; waypoints are upper-case letters" if ch.isalpha() else ""
                raise LayoutError(
                    f"layout {name}: line {lineno} column {c + 1}: unexpected character {ch!r}; "
                    f"use '#' wall, '.' or space floor, A-Z waypoints{hint}"
                )
    if not waypoints:
        raise LayoutError(
            f"layout {name} has no waypoints; mark at least two floor cells with letters A, B, ..."
        )
    if len(waypoints) < 2:
        only = next(iter(waypoints))
        raise LayoutError(
            f"layout {name} has only waypoint {only}; add a second letter so the robot has "
            "somewhere to go"
        )
    waypoints = dict(sorted(waypoints.items()))

    labels, _ = ndimage.label(~walls)
    first_letter, first_rc = next(iter(waypoints.items()))
    home = labels[first_rc]
    for letter, rc in waypoints.items():
        if labels[rc] != home:
            lineno, col = waypoint_lines[letter]
            raise LayoutError(
                f"layout {name}: waypoint {letter} (line {lineno} column {col}) cannot be reached "
                f"from waypoint {first_letter}; open a passage between them or move it"
            )
    reachable = labels == home

    if cell is None:
        cell = file_cell
    if cell is None:
        cell = DEFAULT_CORRIDOR_WIDTH / corridor_width_cells(walls, reachable)
    if not (MIN_CELL <= cell <= MAX_CELL) or not np.isfinite(cell):
        raise LayoutError(
            f"layout {name}: cell size {cell} m is out of range; use {MIN_CELL}-{MAX_CELL} m"
        )
    description = comments[0] if comments else ""
    return Layout(
        name=name,
        walls=walls,
        waypoints=waypoints,
        cell=float(cell),
        description=description,
        text=text,
    )


def _layout_dir() -> Traversable:
    """The folder of built-in layouts inside the installed package."""
    return resources.files("cogmap_core.datasets").joinpath("layouts")


def builtin_layouts() -> list[str]:
    """Names of the layouts shipped with cogmap."""
    return sorted(p.name[:-4] for p in _layout_dir().iterdir() if p.name.endswith(".txt"))


def load_layout(name_or_file: str | Path, cell: float | None = None) -> Layout:
    """Load a layout from a file path or by built-in name (see :func:`builtin_layouts`).

    Raises:
        LayoutError: no such file or built-in layout, unreadable file, invalid layout.

    """
    path = Path(name_or_file)
    if path.is_file():
        try:
            text = path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise LayoutError(f"cannot read layout file {path}: {exc}; check the file") from None
        return parse_layout(text, name=path.stem, cell=cell)
    name = str(name_or_file)
    if name.endswith(".txt"):
        name = name[:-4]
    if name in builtin_layouts():
        text = _layout_dir().joinpath(f"{name}.txt").read_text("utf-8")
        return parse_layout(text, name=name, cell=cell)
    if path.exists():
        raise LayoutError(f"layout {path} is not a file; give a layout .txt file")
    raise LayoutError(
        f"no layout file or built-in layout named {str(name_or_file)!r}; built-in layouts: "
        f"{', '.join(builtin_layouts())}"
    )
