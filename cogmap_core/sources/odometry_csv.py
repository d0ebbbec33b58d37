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
``run1_loops.csv`` and ``run1_ground_truth.csv``. Lines are read by
:mod:`cogmap_core.sources.log_text` (fast, bounded memory; blanks around fields, blank lines, CRLF
line ends and a byte-order mark are fine); every malformed line is an error naming file and
line.
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
    make_odometry_log,
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


class CsvFormat(LineFormat):
    """CSV lines of one kind: numbers separated by commas, an optional header line.

    Args:
        kind: what the file holds (its ``widths``: the column counts a row may have).

    """

    expected = "CSV lines"
    commas = True

    def __init__(self, kind: LineKind) -> None:
        """A format of one kind of row."""
        self.kinds = (kind,)

    def classify(self, block: Block) -> tuple[IntArray, IntArray]:
        """Rows whose fields are one comma apart; odd: any other use of commas."""
        ntok = block.tstart.size
        has = block.counts > 0
        commas_before = np.zeros(ntok, np.int64)
        if block.commas is not None and block.commas.size:
            line = np.searchsorted(block.ends, block.commas)
            after = np.searchsorted(block.tstart, block.commas)  # the token after the comma
            nxt = np.minimum(after, max(ntok - 1, 0))
            between = (
                (after < ntok) & (block.line_of(nxt) == line) & (nxt != block.first[line])
                if ntok
                else np.zeros(line.size, bool)
            )
            block.odd[line[~between]] = True  # before the first field, after the last, alone
            commas_before = np.bincount(nxt[between], minlength=ntok)
        later = np.ones(ntok, bool)
        later[block.first[has]] = False
        block.odd[block.line_of(np.flatnonzero(later & (commas_before != 1)))] = True
        kind = np.where(has & (block.first_bytes() != ord("#")), 0, -1)
        return kind, np.zeros(block.lines, np.int64)

    def reference(self, text: str, where: str, first: bool) -> tuple[Parsed, bool]:
        """One line by the CSV rules (module doc)."""
        stripped = text.strip()
        if not stripped or stripped.startswith("#"):
            return None, False
        kind = self.kinds[0]
        fields = _split(stripped)
        expect = " or ".join(str(w) for w in kind.widths)
        names = ",".join(kind.columns)
        if first and not all(is_number(f) for f in fields):
            if len(fields) not in kind.widths:
                raise LogFormatError(
                    f"{where}: header has {len(fields)} columns; {kind.what} files have "
                    f"{expect} ({names})"
                )
            return None, True  # the header
        if len(fields) not in kind.widths:
            raise LogFormatError(
                f"{where}: {len(fields)} columns; {kind.what} files have {expect} ({names}) -- "
                "fix or drop the line"
            )
        try:
            values = [float(f) for f in fields]
        except ValueError:
            bad = next(f for f in fields if not is_number(f))
            raise LogFormatError(
                f"{where}: {bad!r} is not a number ({kind.what} columns {names})"
            ) from None
        return (0, self.kept(kind, values)), True


ODOMETRY_FORMAT = CsvFormat(LineKind("", "odometry", ODOMETRY_COLUMNS, (3,), (0, 1, 2)))
LOOP_FORMAT = CsvFormat(LineKind("", "loop", LOOP_COLUMNS, (3,), (0, 1, 2)))
# no heading: NaN, filled in from the direction of travel
TRUTH_FORMAT = CsvFormat(LineKind("", "ground truth", TRUTH_COLUMNS, (3, 4), (0, 1, 2, 3)))


def read_csv_rows(path: Path, fmt: CsvFormat) -> Rows:
    """The rows of a CSV file of ``fmt``'s kind (an optional header line).

    Raises:
        InputFileError: a missing or unreadable file.
        LogFormatError: a row of another width, or a field that is not a number.

    """
    (rows,) = read_rows(path, fmt)
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
    odometry = read_csv_rows(path, ODOMETRY_FORMAT)
    warnings = []
    loop_path = Path(loops) if loops is not None else companion(path, "loops")
    loop_rows = None
    if loop_path is None:
        beside = path.name.replace("odometry", "loops", 1) if "odometry" in path.name else None
        where = f"or put {beside} beside it" if beside else "or name the files *odometry*.csv"
        warnings.append(
            f"{path}: no loop file (give --loops FILE {where}); the maps are odometry only"
        )
    else:
        loop_rows = read_csv_rows(loop_path, LOOP_FORMAT)
    truth = None
    truth_path = None
    if use_ground_truth:
        truth_path = Path(ground_truth) if ground_truth is not None else None
        truth_path = truth_path or companion(path, "ground_truth")
        if truth_path is not None:
            truth = read_csv_rows(truth_path, TRUTH_FORMAT)
    return make_odometry_log(path, "csv", odometry, loop_rows, truth, truth_path, warnings)
