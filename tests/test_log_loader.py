"""The log loader: real logs as they come (each case counted and warned once), in bounded memory.

Every case reads a tiny file written here and checks the exact counts, warning lines and the
mapped result. The tests use only the readers' public API, so that each fails on the code before
the loader took these cases (the array parser's own tests: ``test_log_text.py``).
"""

from __future__ import annotations

import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from cogmap_core.errors import InputFileError
from cogmap_core.events import LinkToVertex
from cogmap_core.sources.detect import detect_format, open_source
from cogmap_core.sources.log_reader import LogReader, log_steps
from cogmap_core.sources.odometry_csv import read_odometry_csv
from cogmap_core.sources.odometry_log import LogFormatError, LogSourceConfig
from cogmap_core.sources.tuc import read_tuc
from tests.test_odometry_log import LOOPS, events_of, odom_lines, write

BOM = b"\xef\xbb\xbf"
MIB = 1 << 20


def links_of(reader: LogReader) -> list[LinkToVertex]:
    return [e for e in events_of(reader.steps) if type(e) is LinkToVertex]


# ------------------------------------------------------------ 1. loops just outside the odometry
def test_loops_just_outside_the_odometry_are_moved_onto_it_further_out_dropped(
    tmp_path: Path,
) -> None:
    """Odometry 0-10 s; within max_odometry_gap (1 s) of its ends a loop's times are moved onto
    them, further out the candidate is dropped (today: refused, nothing mapped)."""
    path = write(
        tmp_path / "edge_Input.txt",
        odom_lines()
        + [
            "loop 10.2 1.1 0.9",  # 0.2 s after the last odometry: a link at 10 s
            "loop 11.5 2.6 0.9",  # 1.5 s after: dropped
            "loop 9 -0.5 0.9",  # matches 0.5 s before the data: a link to the first vertex
            "loop 9.5 -2 0.9",  # 2 s before: dropped
        ],
    )
    reader = LogReader(read_tuc(path))
    assert (reader.stats.loop_candidates, reader.stats.loops_clamped) == (4, 2)
    assert (reader.stats.loops_outside, reader.stats.links) == (2, 2)
    assert links_of(reader) == [LinkToVertex(9.0, 0, 0.0), LinkToVertex(10.0, 4, 0.0)]
    assert reader.warnings == [
        f"2 x loop candidate with a time up to 1 s outside the odometry (0.000-10.000 s): moved "
        f"onto it (first at {path}:82)",
        f"2 x loop candidate with a time more than 1 s outside the odometry (0.000-10.000 s): "
        f"dropped (first at {path}:83)",
    ]
    assert reader.log.loops.tolist() == [  # the log keeps the file's times, sorted
        [9.0, -0.5, 0.9],
        [9.5, -2.0, 0.9],
        [10.2, 1.1, 0.9],
        [11.5, 2.6, 0.9],
    ]
    description = reader.description()
    assert (description["loops_clamped"], description["loops_outside"]) == (2, 2)
    # the tolerance is the source's max_odometry_gap: at 2 s every candidate is used
    wide = LogReader(read_tuc(path), LogSourceConfig(max_odometry_gap=2.0))
    assert (wide.stats.loops_clamped, wide.stats.loops_outside, wide.stats.links) == (4, 0, 4)


def test_the_tolerance_edge_is_inclusive_and_steps_stay_on_the_odometry(tmp_path: Path) -> None:
    path = write(tmp_path / "e_Input.txt", odom_lines() + ["loop 11 1 0.9", "loop 11.001 1 0.9"])
    steps, stats = log_steps(read_tuc(path))
    assert (stats.loops_clamped, stats.loops_outside) == (1, 1)
    assert steps[-1].time == 10.0 and len(steps) == 81  # no step after the odometry ends


# ------------------------------------------------------------ 2. loops to themselves, later ones
def test_loops_matching_their_own_view_are_dropped_later_ones_swapped(tmp_path: Path) -> None:
    straight = write(tmp_path / "straight_Input.txt", odom_lines() + LOOPS)
    path = write(
        tmp_path / "odd_Input.txt",
        odom_lines()
        + [
            "loop 5 5 0.9",  # to itself
            "loop 5 4.2 0.9",  # 0.8 s apart: the same view
            "loop 1.1 8.0625 0.9",  # the later time matches the earlier: as 'loop 8.0625 1.1'
            *LOOPS[1:],
        ],
    )
    log = read_tuc(path)
    assert log.read_counts == {
        "odometry_repeated": 0,
        "odometry_conflicting": 0,
        "loops_same_view": 2,
        "loops_swapped": 1,
    }
    assert log.warnings == (
        f"2 x loop candidate matching a view less than 1 s from its own: dropped (first at "
        f"{path}:82)",
        f"1 x loop candidate matching a later time: the two swapped (the later view matches the "
        f"earlier place) (first at {path}:84)",
    )
    # the swapped candidate maps exactly as the file that says it the usual way round
    assert LogReader(log).steps == LogReader(read_tuc(straight)).steps
    assert log.loop_lines.tolist() == [84, 85, 86, 87, 88]


# ------------------------------------------------------------ 3. repeated odometry stamps
def test_repeated_odometry_lines_are_dropped_conflicting_ones_keep_the_first(
    tmp_path: Path,
) -> None:
    """Today a line repeating a time is silently ignored by log_steps (its union of times and
    searchsorted(side="left") take the first sample of a time); now it is counted."""
    lines = odom_lines()
    clean = write(tmp_path / "clean_Input.txt", lines + LOOPS)
    conflicting = lines[20].replace("odom2 2.5 1 0.5 0 ", "odom2 2.5 2 0.5 0.3 ")
    vy_only = lines[40].replace("odom2 5 1 0.5 ", "odom2 5 1 0.7 ")  # vy is not read
    path = write(
        tmp_path / "rep_Input.txt",
        lines[:11]
        + [lines[10], lines[10]]  # lines 12, 13
        + lines[11:21]
        + [conflicting]  # line 24
        + lines[21:41]
        + [vy_only]  # line 45
        + lines[41:]
        + LOOPS,
    )
    log = read_tuc(path)
    assert log.warnings == (
        f"3 x odometry line with the time and values of an earlier line: dropped (first at "
        f"{path}:12)",
        f"1 x odometry line with the time of an earlier line but other values: dropped, the "
        f"earlier line kept (first at {path}:24)",
    )
    reference = read_tuc(clean)
    np.testing.assert_array_equal(log.odometry, reference.odometry)
    assert LogReader(log).steps == LogReader(reference).steps
    assert log.read_counts["odometry_repeated"] == 3
    assert log.read_counts["odometry_conflicting"] == 1


def test_odometry_going_back_stays_an_error(tmp_path: Path) -> None:
    lines = odom_lines(9)
    path = write(tmp_path / "b_Input.txt", [*lines[:5], lines[3], *lines[5:]])
    with pytest.raises(LogFormatError, match=r"b_Input.txt:6: odometry time 0.375000 s is earl"):
        read_tuc(path)


# ------------------------------------------------------------ 4. formatting of real files
def messy(lines: list[str]) -> bytes:
    """A byte-order mark, CRLF line ends, trailing blanks and tabs, blank lines."""
    body = "\r\n".join(f"{line} \t " if k % 2 else f"{line}\t" for k, line in enumerate(lines))
    return BOM + ("\r\n  \r\n\t\r\n" + body + "\r\n\r\n").encode()


def test_bom_crlf_trailing_blanks_and_blank_lines_read_as_normal(tmp_path: Path) -> None:
    lines = odom_lines() + LOOPS
    plain = write(tmp_path / "plain_Input.txt", lines)
    path = tmp_path / "messy_Input.txt"
    path.write_bytes(messy(lines))
    assert detect_format(path) == "tuc"
    reader = open_source(path)
    assert reader.warnings == []
    reference = read_tuc(plain)
    np.testing.assert_array_equal(reader.log.odometry, reference.odometry)
    np.testing.assert_array_equal(reader.log.loops, reference.loops)
    assert reader.log.loop_lines.tolist() == [k + 4 for k in range(81, 86)]  # 3 lines before
    assert reader.steps == LogReader(reference).steps
    assert open_source(path, "tuc").steps == reader.steps


def test_a_csv_with_a_bom_and_no_header_keeps_its_first_row(tmp_path: Path) -> None:
    """Today the first row of such a file is taken for a header and silently lost."""
    rows = [f"{k * 0.125:g},1.0,0.0 " for k in range(81)]
    path = tmp_path / "bom_odometry.csv"
    path.write_bytes(BOM + "\r\n".join(rows).encode() + b"\r\n\r\n")
    write(tmp_path / "bom_loops.csv", ["time,matched_time,score", "8.0625,1.1,0.9"])
    log = read_odometry_csv(path)
    assert log.odometry.shape == (81, 3) and log.odometry[0].tolist() == [0.0, 1.0, 0.0]
    assert log.loops.tolist() == [[8.0625, 1.1, 0.9]] and log.warnings == ()
    assert detect_format(path) == "csv"


# ------------------------------------------------------------ 5. no odometry, no loops
def test_a_file_without_odometry_is_one_line(tmp_path: Path) -> None:
    comments = write(tmp_path / "c_Input.txt", ["# recorded 2024-05-01", "", "# nothing else"])
    with pytest.raises(InputFileError) as caught:
        detect_format(comments)
    assert str(caught.value) == (
        f"{comments}: the file holds only comments and blank lines; nothing to map"
    )
    with pytest.raises(LogFormatError) as caught:
        read_tuc(comments)
    assert str(caught.value) == (
        f"{comments}: no odometry in the file; a log needs odometry lines (time, v, omega)"
    )
    header = write(tmp_path / "h_odometry.csv", ["time,v,omega"])
    with pytest.raises(LogFormatError, match=r"h_odometry.csv: no odometry in the file"):
        read_odometry_csv(header)


def test_no_loop_candidates_is_a_warning_and_the_maps_are_built(tmp_path: Path) -> None:
    path = write(tmp_path / "n_Input.txt", odom_lines())
    reader = open_source(path)
    assert reader.warnings == [f"{path}: no loop candidates: the map is its odometry"]
    assert reader.stats.links == 0 and len(reader.steps) == 81
    # none left after dropping: said once more, after the reasons
    gone = write(tmp_path / "g_Input.txt", odom_lines() + ["loop 5 5 1", "loop 30 1 1"])
    reader = open_source(gone)
    assert reader.warnings[-1] == f"{gone}: no loop candidates left: the map is its odometry"
    assert len(reader.warnings) == 3
    # an empty loop file of a CSV log; no loop file at all keeps its own warning only
    odometry = write(tmp_path / "r_odometry.csv", [f"{k},0.5,0" for k in range(20)])
    loops = write(tmp_path / "r_loops.csv", ["time,matched_time,score"])
    assert open_source(odometry).warnings == [
        f"{loops}: no loop candidates: the map is its odometry"
    ]
    loops.unlink()
    (warning,) = open_source(odometry).warnings
    assert "no loop file" in warning


# ------------------------------------------------------------ 6. bounded memory, fast
def test_reading_keeps_only_arrays(tmp_path: Path) -> None:
    """200,000 loop lines: the reader's peak allocations stay near the arrays it keeps (32 bytes
    a line: 3 values, 1 line number), not a Python list and a string per line (~1 KB)."""
    n = 200_000
    path = tmp_path / "many_Input.txt"
    with path.open("w") as out:
        out.write("odom2 0 0.5 0 0 0 0 0\n")
        out.writelines(f"loop {10 + k * 1e-4:.4f} {k * 1e-5:.5f} 0.5\n" for k in range(n))
        out.write("odom2 40 0.5 0 0 0 0 0\n")
    tracemalloc.start()
    try:
        log = read_tuc(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 100 * n + 30 * MIB, peak / n  # (a read block is 1 MiB)
    assert log.loops.shape == (n, 3) and log.loop_lines[-1] == n + 1


def test_a_file_without_line_ends_is_refused_before_it_is_read_whole(tmp_path: Path) -> None:
    path = tmp_path / "one_Input.txt"
    path.write_bytes(b"odom2 0 0 0 0 0 0 0\n" + b"1" * (MIB + 10))
    with pytest.raises(LogFormatError) as caught:
        read_tuc(path)
    assert str(caught.value) == (
        f"{path}:2: a line longer than 1 MiB; expected TUC measurement lines"
    )
