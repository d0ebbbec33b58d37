"""Reader of the TUC SLAM dataset's text format (Neubert, Schubert & Protzel, RA-L 2019).

One measurement per line, whitespace separated, the first word naming its type:

- ``odom2 time vx vy yaw_rate cov_vx cov_vy cov_yaw_rate`` -- 2-D wheel odometry;
- ``loop time matched_time score`` -- a place-recognition loop candidate, score in [0, 1];
- in the ground-truth file: ``point2 time x y c c c c`` (positions) and, where present,
  ``angle time theta c`` (headings).

``X_Input.txt`` comes with ``X_GT.txt`` beside it; that file is read as the ground truth unless
another one is given. Covariances and ``vy`` are read but not used (the map's motion model has
no lateral velocity). Lines are read by :mod:`cogmap_core.sources.log_text` (fast, bounded
memory; blank lines, ``#`` comments, CRLF line ends and a byte-order mark are fine); every
malformed line is an error naming file and line.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cogmap_core.sources.log_text import (
    Block,
    IntArray,
    LineFormat,
    LineKind,
    LogFormatError,
    Parsed,
    Rows,
    is_number,
    read_rows,
)
from cogmap_core.sources.odometry_log import (
    LOOP_COLUMNS,
    ODOMETRY_COLUMNS,
    TRUTH_COLUMNS,
    OdometryLog,
    check_finite,
    check_increasing,
    make_odometry_log,
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


class TucFormat(LineFormat):
    """TUC lines: a type word, then its numbers, separated by blanks.

    Args:
        kinds: the measurement types the file may hold.
        holds: which ones, for the message about a line of another type.

    """

    expected = "TUC measurement lines"

    def __init__(self, kinds: tuple[LineKind, ...], holds: str) -> None:
        """A format of these kinds."""
        self.kinds = kinds
        self.holds = holds
        self._index = {kind.name: k for k, kind in enumerate(kinds)}

    def classify(self, block: Block) -> tuple[IntArray, IntArray]:
        """Per line: the kind its first word names (-1: blank, comment or another word)."""
        kind = np.full(block.lines, -1, np.int64)
        lines = np.flatnonzero((block.counts > 0) & (block.first_bytes() != ord("#")))
        found = np.zeros(lines.size, bool)
        first = block.first[lines]
        for k, spec in enumerate(self.kinds):
            named = block.token_is(first, spec.name.encode())
            kind[lines[named]] = k
            found |= named
        block.odd[lines[~found]] = True  # the reference parser names the unknown type
        return kind, np.ones(block.lines, np.int64)

    def reference(self, text: str, where: str, first: bool) -> tuple[Parsed, bool]:
        """One line by the TUC rules (module doc)."""
        words = text.split()
        if not words or words[0].startswith("#"):
            return None, False
        kind = words[0]
        k = self._index.get(kind)
        if k is None:
            raise LogFormatError(f"{where}: unknown measurement type {kind!r}; a TUC {self.holds}")
        expected = self.kinds[k].widths[0]
        if len(words) - 1 != expected:
            raise LogFormatError(
                f"{where}: each '{kind}' line has {expected} numbers after the type, this one "
                f"{len(words) - 1}; fix or drop the line"
            )
        try:
            values = [float(w) for w in words[1:]]
        except ValueError:
            bad = next(w for w in words[1:] if not is_number(w))
            raise LogFormatError(
                f"{where}: {bad!r} in a '{kind}' line is not a number; fix or drop the line"
            ) from None
        return (k, self.kept(self.kinds[k], values)), True


INPUT_FORMAT = TucFormat(
    (
        # covariances and vy are read (and checked) but not kept
        LineKind("odom2", "odometry", ODOMETRY_COLUMNS, (7,), (0, 1, 3)),
        LineKind("loop", "loop", LOOP_COLUMNS, (3,), (0, 1, 2)),
    ),
    "input file has 'odom2' and 'loop' lines",
)
TRUTH_FORMAT = TucFormat(
    (
        LineKind("point2", "ground truth", TRUTH_COLUMNS[:3], (7,), (0, 1, 2)),
        LineKind("angle", "ground-truth angle", ("time", "theta"), (3,), (0, 1)),
    ),
    "ground-truth file has 'point2' (and 'angle') lines",
)


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
    odometry, loops = read_rows(path, INPUT_FORMAT)
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
    points, angles = read_rows(path, TRUTH_FORMAT)
    if not len(angles) or not len(points):
        return points
    angle = check_finite(angles)
    check_increasing(angles, angle, "sort the file by time")
    theta = np.interp(points.values[:, 0], angle[:, 0], np.unwrap(angle[:, 1]))
    return points.with_values(np.column_stack([points.values, theta]), TRUTH_COLUMNS)
