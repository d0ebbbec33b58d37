"""A sweep's results: the table of finished cells (``results.csv``) and the Pareto figure.

``results.csv`` is appended a row at a time, each flushed to disk the moment its cell finishes,
so an interrupted sweep keeps every finished cell and is resumed by reading the table back.
"""

from __future__ import annotations

import csv
import io
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from app.report_figures import pareto_figure as draw_pareto
from app.sweep.errors import SweepError
from cogmap_core.fileio import write_bytes_atomic
from cogmap_core.sweep import (
    FIGURE_COLUMNS,
    MIN_COMPLETENESS,
    PARAMETER_NAMES,
    TIMING_COLUMNS,
    SettingFigures,
)

ID_COLUMNS: tuple[str, ...] = ("key", "run", "bag", "bag_key", "map", "status", "error")
RESULT_COLUMNS: tuple[str, ...] = (
    ID_COLUMNS + PARAMETER_NAMES + FIGURE_COLUMNS + TIMING_COLUMNS + ("worker",)
)
_INT_COLUMNS = frozenset(
    ("run", "vertices", "edges", "loop_edges", "clusters", "optimizations", "exploration_vertices")
)
_STR_COLUMNS = frozenset(("key", "bag", "bag_key", "map", "status", "error", "worker"))


def _format(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return repr(value)
    return str(value)


def _parse(column: str, text: str) -> Any:
    if column in _STR_COLUMNS:
        return text
    if text == "":
        return None
    if column in _INT_COLUMNS:
        return int(text)
    return float(text)


class ResultsTable:
    """``results.csv``: one row per finished cell, appended and flushed as each cell finishes.

    A row is written with one ``write`` of a whole line and then ``fsync``: a kill can at worst
    cut the last line short, and that line is dropped (the file rewritten atomically) when the
    table is opened again. A cell may have several rows (a failed attempt, then a good one);
    the last one counts.
    """

    def __init__(self, path: Path) -> None:
        """Open (or create) the table at ``path``; repair a cut-short last line."""
        self.path = path
        self.rows: list[dict[str, Any]] = []
        if not path.exists():
            write_bytes_atomic(path, (",".join(RESULT_COLUMNS) + "\n").encode())
            return
        with path.open(newline="") as handle:
            text = handle.read()
        if text and not text.endswith("\n"):
            text = text[: text.rfind("\n") + 1]  # the last line was cut short by a kill
            write_bytes_atomic(path, text.encode())
        reader = csv.reader(io.StringIO(text, newline=""))
        header = next(reader, None)
        if header is None:
            write_bytes_atomic(path, (",".join(RESULT_COLUMNS) + "\n").encode())
            return
        if tuple(header) != RESULT_COLUMNS:
            raise SweepError(
                f"{path}: its columns are not this cogmap's sweep table; choose another --out"
            )
        for number, fields_ in enumerate(reader, start=2):
            if len(fields_) != len(RESULT_COLUMNS):
                raise SweepError(
                    f"{path}: line {number} is malformed; fix or remove that line, or choose "
                    "another --out"
                )
            try:
                self.rows.append(
                    {c: _parse(c, v) for c, v in zip(RESULT_COLUMNS, fields_, strict=True)}
                )
            except ValueError:
                raise SweepError(
                    f"{path}: line {number} holds a value that is not a number; fix or remove "
                    "that line"
                ) from None

    def latest(self) -> dict[str, dict[str, Any]]:
        """The last row of every cell, by cell key."""
        return {row["key"]: row for row in self.rows}

    def append(self, row: Mapping[str, Any]) -> None:
        """Append one row and flush it to disk before returning."""
        buffer = io.StringIO()
        csv.writer(buffer, lineterminator="\n").writerow(
            [_format(row.get(c)) for c in RESULT_COLUMNS]
        )
        with self.path.open("a", newline="") as handle:
            handle.write(buffer.getvalue())
            handle.flush()
            os.fsync(handle.fileno())
        self.rows.append({c: row.get(c) for c in RESULT_COLUMNS})


def pareto_figure(best: Mapping[str, Any], settings: Sequence[SettingFigures], title: str) -> Any:
    """``pareto.png``: vertices against ATE (left) and completeness (right).

    Every setting is a grey dot, the Pareto fronts staircases in the swept map's colour, the
    paper's setting a diamond, the smallest complete map ringed
    (:func:`app.report_figures.pareto_figure`, a matplotlib figure).
    """
    return draw_pareto(
        best,
        [s.vertices for s in settings],
        [_nan(s.ate_m) for s in settings],
        [_nan(s.completeness) for s in settings],
        title,
        float(best.get("min_completeness", MIN_COMPLETENESS)),
    )


def _nan(value: Any) -> float:
    return float("nan") if value is None else float(value)
