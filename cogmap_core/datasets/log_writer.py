"""Writers of generated logs: the TUC dataset's text format and plain CSV.

- **TUC**: ``PREFIX_Input.txt`` (all ``odom2 time vx vy yaw_rate cov_vx cov_vy cov_yaw_rate``
  lines, then the ``loop time matched_time score`` lines, as the dataset's files are laid out)
  and ``PREFIX_GT.txt`` (``point2 time x y 0 0 0 0`` lines, then ``angle time theta 0``);
  :func:`~cogmap_core.sources.tuc.read_tuc` finds the ground truth beside the input.
- **CSV**: ``PREFIX_odometry.csv`` (``time,v,omega``), ``PREFIX_loops.csv``
  (``time,matched_time,score``) and ``PREFIX_ground_truth.csv`` (``time,x,y,theta``), each with
  a header line; :func:`~cogmap_core.sources.odometry_csv.read_odometry_csv` finds the
  companions.

Numbers are written in the shortest form that reads back to the same float, so a reader
returns the generator's arrays exactly. Every file goes through a temporary name and is
renamed into place only when all of them are written; existing files are refused unless
``force``, which replaces only the files named here.
"""

from __future__ import annotations

import contextlib
from pathlib import Path

import numpy as np

from cogmap_core.datasets.log_generator import GeneratedLog
from cogmap_core.errors import OutputError, ParameterError
from cogmap_core.fileio import atomic_writer, check_writable, interrupts_deferred, output_error

LOG_FORMATS = ("tuc", "csv")
"""Formats :func:`write_log` writes."""

#: Each format's files: the name's ending after the prefix (the first is the one to read).
SUFFIXES = {
    "tuc": ("_Input.txt", "_GT.txt"),
    "csv": ("_odometry.csv", "_loops.csv", "_ground_truth.csv"),
}


def output_paths(prefix: str | Path, fmt: str) -> list[Path]:
    """The files :func:`write_log` writes for ``prefix`` in format ``fmt``, main file first.

    A prefix that already ends in the format's main suffix (``run1_Input.txt``) stands for
    its prefix (``run1``).

    Raises:
        ParameterError: an unknown format, or a prefix that names a folder.

    """
    if fmt not in SUFFIXES:
        raise ParameterError(f"unknown log format {fmt!r}; choose from {', '.join(LOG_FORMATS)}")
    text = str(prefix)
    main = SUFFIXES[fmt][0]
    if text.endswith(main):
        text = text[: -len(main)]
    base = Path(text)
    if not base.name or text.endswith(("/", "\\")) or base.is_dir():
        raise ParameterError(
            f"{prefix} is a folder; give a prefix for the files' names, e.g. {base / 'run1'}"
        )
    return [base.with_name(base.name + suffix) for suffix in SUFFIXES[fmt]]


def check_outputs(paths: list[Path], force: bool) -> None:
    """Refuse outputs that exist (unless ``force``), folders in the way and unwritable folders.

    Raises:
        OutputError: one line naming the files and what to do.

    """
    folders = [p for p in paths if p.is_dir()]
    if folders:
        raise OutputError(f"{folders[0]} is a folder; choose another prefix")
    existing = [str(p) for p in paths if p.exists() or p.is_symlink()]
    if existing and not force:
        raise OutputError(
            f"{', '.join(existing)} already exist{'s' if len(existing) == 1 else ''}; choose "
            "another prefix or pass --force to replace "
            f"{'it' if len(existing) == 1 else 'them'}"
        )
    folder = paths[0].parent
    if not folder.is_dir():
        raise OutputError(f"folder {folder} does not exist; create it first")
    check_writable(folder)


def _rows(kind: str, values: np.ndarray) -> str:
    """``kind`` lines (or CSV rows for ``kind`` ``""``) of float rows, shortest exact repr."""
    sep = " " if kind else ","
    head = kind + " " if kind else ""
    return "".join(head + sep.join(map(repr, row)) + "\n" for row in values.tolist())


def tuc_texts(log: GeneratedLog) -> list[str]:
    """The contents of ``_Input.txt`` and ``_GT.txt``."""
    odo = log.odometry
    odom2 = np.column_stack([odo[:, 0], odo[:, 1], log.lateral, odo[:, 2], log.covariance])
    gt = log.ground_truth
    zeros = np.zeros((gt.shape[0], 4))
    points = _rows("point2", np.column_stack([gt[:, :3], zeros]))
    angles = _rows("angle", np.column_stack([gt[:, 0], gt[:, 3], zeros[:, 0]]))
    return [_rows("odom2", odom2) + _rows("loop", log.loops), points + angles]


def csv_texts(log: GeneratedLog) -> list[str]:
    """The contents of ``_odometry.csv``, ``_loops.csv`` and ``_ground_truth.csv``."""
    return [
        "time,v,omega\n" + _rows("", log.odometry),
        "time,matched_time,score\n" + _rows("", log.loops),
        "time,x,y,theta\n" + _rows("", log.ground_truth),
    ]


def write_log(log: GeneratedLog, prefix: str | Path, fmt: str, force: bool = False) -> list[Path]:
    """Write ``log`` as ``fmt`` files named after ``prefix``; returns them, main file first.

    All files are written to temporary names first and renamed into place together (Ctrl-C
    held back meanwhile): an error leaves no partial file and replaces nothing.

    Raises:
        ParameterError: an unknown format or a folder as prefix.
        OutputError: a file exists (without ``force``), a folder is in the way, or the folder
            is missing or cannot be written.

    """
    paths = output_paths(prefix, fmt)
    check_outputs(paths, force)
    texts = tuc_texts(log) if fmt == "tuc" else csv_texts(log)
    current = paths[0]
    try:
        with interrupts_deferred(), contextlib.ExitStack() as stack:
            for path, text in zip(paths, texts, strict=True):
                current = path
                stack.enter_context(atomic_writer(path)).write(text)
            current = paths[0]
    except OSError as exc:
        raise output_error(current, exc) from None
    return paths
