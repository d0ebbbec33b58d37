"""Reader of the TUC SLAM dataset's text format (Neubert, Schubert & Protzel, RA-L 2019).

One measurement per line, whitespace separated, the first word naming its type:

- ``odom2 time vx vy yaw_rate cov_vx cov_vy cov_yaw_rate`` -- 2-D wheel odometry;
- ``loop time matched_time score`` -- a place-recognition loop candidate, score in [0, 1];
- in the ground-truth file: ``point2 time x y c c c c`` (positions) and, where present,
  ``angle time theta c`` (headings).

``X_Input.txt`` comes with ``X_GT.txt`` beside it; that file is read as the ground truth unless
another one is given. Covariances and ``vy`` are read but not used (the map's motion model has
no lateral velocity). Every malformed line is an error naming file and line.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from cogmap_core.sources.odometry_log import (
    LOOP_COLUMNS,
    ODOMETRY_COLUMNS,
    TRUTH_COLUMNS,
    LogFormatError,
    OdometryLog,
    Rows,
    check_finite,
    check_increasing,
    is_number,
    make_odometry_log,
    read_log_text,
)

#: The first word of a line -> how many numbers follow it.
INPUT_FIELDS = {"odom2": 7, "loop": 3}
TRUTH_FIELDS = {"point2": 7, "angle": 3}


def looks_like_tuc(first_word: str) -> bool:
    """Whether ``first_word``, the first word of a file's first data line, is a TUC type.

    Only the first line decides: a later line with an unknown type is then reported by the
    reader with its line number, not as a file of no known format.
    """
    return first_word in INPUT_FIELDS or first_word in TRUTH_FIELDS


def ground_truth_companion(path: Path) -> Path | None:
    """``X_GT.txt`` beside ``X_Input.txt`` when it exists."""
    name = path.name
    if not name.endswith("_Input.txt"):
        return None
    candidate = path.with_name(name[: -len("_Input.txt")] + "_GT.txt")
    return candidate if candidate.is_file() else None


def _numbers(path: Path, line_no: int, words: list[str], expected: int) -> list[float]:
    kind = words[0]
    if len(words) - 1 != expected:
        raise LogFormatError(
            f"{path}:{line_no}: each '{kind}' line has {expected} numbers after the type, this one "
            f"{len(words) - 1}; fix or drop the line"
        )
    try:
        return [float(w) for w in words[1:]]
    except ValueError:
        bad = next(w for w in words[1:] if not is_number(w))
        raise LogFormatError(
            f"{path}:{line_no}: {bad!r} in a '{kind}' line is not a number; fix or drop the line"
        ) from None


def _measurements(
    path: Path, fields: dict[str, int], holds: str
) -> Iterator[tuple[str, str, list[float]]]:
    """``(kind, "file:line", numbers)`` of each measurement line of a TUC file.

    ``fields`` are the measurement types the file may hold; ``holds`` says which, for the
    message about a line of another type.
    """
    text = read_log_text(path, "TUC measurement lines")
    for line_no, line in enumerate(text.splitlines(), start=1):
        words = line.split()
        if not words or words[0].startswith("#"):
            continue
        kind = words[0]
        if kind not in fields:
            raise LogFormatError(
                f"{path}:{line_no}: unknown measurement type {kind!r}; a TUC {holds}"
            )
        yield kind, f"{path}:{line_no}", _numbers(path, line_no, words, fields[kind])


def read_tuc(
    path: str | Path, ground_truth: str | Path | None = None, use_ground_truth: bool = True
) -> OdometryLog:
    """Read a TUC input file (``odom2`` and ``loop`` lines) and its ground truth.

    Args:
        path: the input file.
        ground_truth: the ground-truth file (default: ``X_GT.txt`` beside ``X_Input.txt``).
        use_ground_truth: False reads no ground truth at all.

    Raises:
        LogFormatError: a malformed line, or values breaking the log's rules (file:line named).
        InputFileError: a missing or unreadable file.

    """
    path = Path(path)
    odometry = Rows("odometry", ODOMETRY_COLUMNS)
    loops = Rows("loop", LOOP_COLUMNS)
    holds = "input file has 'odom2' and 'loop' lines"
    for kind, where, values in _measurements(path, INPUT_FIELDS, holds):
        if kind == "odom2":
            odometry.add((values[0], values[1], values[3]), where)
        else:
            loops.add(values, where)
    truth_path = None
    truth = None
    if use_ground_truth:
        truth_path = Path(ground_truth) if ground_truth is not None else None
        truth_path = truth_path or ground_truth_companion(path)
        if truth_path is not None:
            truth = read_tuc_ground_truth(truth_path)
    return make_odometry_log(path, "tuc", odometry, loops, truth, truth_path)


def read_tuc_ground_truth(path: Path) -> Rows:
    """The ``point2`` positions of a TUC ground-truth file, with ``angle`` headings if present."""
    points = Rows("ground truth", TRUTH_COLUMNS[:3])
    angles = Rows("ground-truth angle", ("time", "theta"))
    holds = "ground-truth file has 'point2' (and 'angle') lines"
    for kind, where, values in _measurements(path, TRUTH_FIELDS, holds):
        if kind == "point2":
            points.add(values[:3], where)
        else:
            angles.add(values[:2], where)
    if not angles.values or not points.values:
        return points
    angle = check_finite(angles)
    check_increasing(angles, angle, "sort the file by time")
    times = np.asarray([v[0] for v in points.values], dtype=np.float64)
    theta = np.interp(times, angle[:, 0], np.unwrap(angle[:, 1]))
    full = Rows("ground truth", TRUTH_COLUMNS)
    for (values, where), th in zip(
        zip(points.values, points.where, strict=True), theta.tolist(), strict=True
    ):
        full.add((*values, th), where)
    return full
