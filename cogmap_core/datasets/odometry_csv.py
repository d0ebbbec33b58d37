"""Reader of plain CSV logs: odometry, loop candidates and ground truth, one file each.

A user of any odometry and place recognition writes (comma separated, an optional header line,
``#`` comments):

- odometry: ``time,v,omega`` -- seconds, forward velocity (m/s), yaw rate (rad/s); the
  velocities hold over the interval that ends at ``time``;
- loops: ``time,matched_time,score`` -- "the view at ``time`` matches the one at
  ``matched_time``", score in [0, 1] with 1 the most similar;
- ground truth (optional): ``time,x,y`` or ``time,x,y,theta``.

The loop and ground-truth files are given explicitly or found beside the odometry file by
replacing the word ``odometry`` in its name: ``run1_odometry.csv`` comes with
``run1_loops.csv`` and ``run1_ground_truth.csv``. Every malformed line is an error naming file
and line.
"""

from __future__ import annotations

from pathlib import Path

from cogmap_core.sources.odometry_log import (
    LOOP_COLUMNS,
    ODOMETRY_COLUMNS,
    TRUTH_COLUMNS,
    LogFormatError,
    OdometryLog,
    Rows,
    is_number,
    make_odometry_log,
    read_log_text,
)


def companion(path: Path, kind: str) -> Path | None:
    """The ``loops`` or ``ground_truth`` file beside an ``..odometry..`` file, if it exists."""
    if "odometry" not in path.name:
        return None
    candidate = path.with_name(path.name.replace("odometry", kind, 1))
    return candidate if candidate.is_file() else None


def _split(line: str) -> list[str]:
    return [field.strip() for field in line.split(",")]


def looks_like_csv(first_line: str) -> bool:
    """Whether a file's first non-comment line is a 3- or 4-column CSV row or header."""
    fields = _split(first_line)
    return "," in first_line and len(fields) in (3, 4) and all(fields)


def read_rows(path: Path, rows: Rows, widths: tuple[int, ...]) -> Rows:
    """Read a CSV file of ``widths`` columns (an optional header line) into ``rows``.

    Raises:
        InputFileError: a missing or unreadable file.
        LogFormatError: a row of another width, or a field that is not a number.

    """
    text = read_log_text(path, "CSV lines")
    expect = " or ".join(str(w) for w in widths)
    names = ",".join(rows.columns)
    first = True
    for line_no, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        fields = _split(stripped)
        if first and not all(is_number(f) for f in fields):
            first = False
            if len(fields) not in widths:
                raise LogFormatError(
                    f"{path}:{line_no}: header has {len(fields)} columns; {rows.what} files have "
                    f"{expect} ({names})"
                )
            continue  # the header
        first = False
        if len(fields) not in widths:
            raise LogFormatError(
                f"{path}:{line_no}: {len(fields)} columns; {rows.what} files have {expect} "
                f"({names}) -- fix or drop the line"
            )
        try:
            values = [float(f) for f in fields]
        except ValueError:
            bad = next(f for f in fields if not is_number(f))
            raise LogFormatError(
                f"{path}:{line_no}: {bad!r} is not a number ({rows.what} columns {names})"
            ) from None
        if len(values) < len(rows.columns):
            values.append(float("nan"))  # no heading: filled in from the direction of travel
        rows.add(values, f"{path}:{line_no}")
    return rows


def read_odometry_csv(
    path: str | Path,
    loops: str | Path | None = None,
    ground_truth: str | Path | None = None,
    use_ground_truth: bool = True,
) -> OdometryLog:
    """Read an odometry CSV with its loop candidates and (optionally) ground truth.

    Args:
        path: the odometry file.
        loops: the loop file (default: the ``loops`` companion; without one, no loops and a
            warning).
        ground_truth: the ground-truth file (default: the ``ground_truth`` companion).
        use_ground_truth: False reads no ground truth at all.

    Raises:
        LogFormatError: a malformed line, or values breaking the log's rules (file:line named).
        InputFileError: a missing or unreadable file.

    """
    path = Path(path)
    odometry = read_rows(path, Rows("odometry", ODOMETRY_COLUMNS), (3,))
    warnings = []
    loop_path = Path(loops) if loops is not None else companion(path, "loops")
    loop_rows = Rows("loop", LOOP_COLUMNS)
    if loop_path is None:
        beside = path.name.replace("odometry", "loops", 1) if "odometry" in path.name else None
        where = f"or put {beside} beside it" if beside else "or name the files *odometry*.csv"
        warnings.append(
            f"{path}: no loop file (give --loops FILE {where}); the maps are odometry only"
        )
    else:
        read_rows(loop_path, loop_rows, (3,))
    truth = None
    truth_path = None
    if use_ground_truth:
        truth_path = Path(ground_truth) if ground_truth is not None else None
        truth_path = truth_path or companion(path, "ground_truth")
        if truth_path is not None:
            truth = read_rows(truth_path, Rows("ground truth", TRUTH_COLUMNS), (3, 4))
    return make_odometry_log(path, "csv", odometry, loop_rows, truth, truth_path, warnings)
