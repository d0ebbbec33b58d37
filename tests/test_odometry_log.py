"""Logs of odometry and place recognition: TUC and CSV readers, events, bad input, detection."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from cogmap_core.errors import InputFileError, ParameterError
from cogmap_core.events import CreateVertex, LinkToVertex, Odometry, SetCurrentVertex
from cogmap_core.sources.detect import LogOptions, detect_format, open_source
from cogmap_core.sources.log_reader import LogReader, log_steps
from cogmap_core.sources.odometry_csv import read_odometry_csv
from cogmap_core.sources.odometry_log import (
    LogFormatError,
    LogSourceConfig,
    label_loop_candidates,
)
from cogmap_core.sources.tuc import looks_like_tuc, read_tuc

DT = 0.125  # s between odometry samples (exact in binary, so step sums are exact)


def odom_lines(n: int = 81, v: float = 1.0, yaw: float = 0.0, t0: float = 0.0) -> list[str]:
    return [f"odom2 {t0 + k * DT:g} {v:g} 0.5 {yaw:g} 0.0025 0.0025 0.0001" for k in range(n)]


def write(path: Path, lines: list[str]) -> Path:
    path.write_text("\n".join(lines) + "\n")
    return path


# the loop candidates of the straight 10 s run below (1 m/s)
LOOPS = [
    "loop 8.0625 1.1 0.9",  # -> the vertex made at 1.0 s (nearest in time)
    "loop 8.0625 1.05 0.85",  # same vertex, lower score: one link
    "loop 8.0625 3.0 0.5",  # below the threshold
    "loop 8.0625 5.0 0.95",  # only 3.06 m of odometry ago: too close
    "loop 9 2.6 1",  # -> the vertex made at 2.5 s
]


@pytest.fixture
def straight(tmp_path: Path) -> Path:
    return write(tmp_path / "straight_Input.txt", odom_lines() + LOOPS)


def events_of(steps):
    return [e for s in steps for e in s.events]


def test_tuc_log_becomes_odometry_vertices_and_links(straight: Path) -> None:
    log = read_tuc(straight)
    assert log.format == "tuc" and log.ground_truth is None
    np.testing.assert_array_equal(log.odometry[:3], [[0, 1, 0], [DT, 1, 0], [2 * DT, 1, 0]])
    steps, stats = log_steps(log)
    # every odometry stamp and the one loop query between two stamps
    assert [s.time for s in steps][63:67] == [7.875, 8.0, 8.0625, 8.125]
    assert len(steps) == 81 + 1 and [s.index for s in steps] == list(range(82))
    events = events_of(steps)
    odometry = [e for e in events if type(e) is Odometry]
    assert odometry[0] == Odometry(0.0, 0.0, 0.0)  # the first sample only starts the clock
    assert math.fsum(e.translation for e in odometry) == 10.0  # vy is not part of the motion
    assert [e.translation for e in odometry if e.time in (8.0625, 8.125)] == [0.0625, 0.0625]
    created = [e for e in events if type(e) is CreateVertex]
    assert [e.vertex for e in created] == list(range(len(created)))
    # a vertex every 0.2 m driven: every second sample up to the split step at 8.0625 s
    assert [e.time for e in created[:33]] == [0.25 * k for k in range(33)]
    links = [e for e in events if type(e) is LinkToVertex]
    assert links == [LinkToVertex(8.0625, 4, 0.0), LinkToVertex(9.0, 10, 0.0)]
    assert not any(type(e) is SetCurrentVertex for e in events)
    linked = [s for s in steps if s.link_scores]
    assert [(s.time, s.link_scores) for s in linked] == [(8.0625, (0.9,)), (9.0, (1.0,))]
    assert (stats.loop_candidates, stats.below_threshold, stats.too_close) == (5, 1, 1)
    assert (stats.duplicates, stats.links, stats.frames) == (1, 2, 82)


def test_a_candidate_below_the_threshold_changes_no_step(straight: Path, tmp_path: Path) -> None:
    log = read_tuc(straight)
    steps, stats = log_steps(log)
    # the same log with two more candidates below the threshold, queried between two stamps
    weak = ["loop 4.0625 1.0 0.3", "loop 6.1 2.0 0.79"]
    more = write(tmp_path / "weak_Input.txt", odom_lines() + LOOPS + weak)
    more_steps, more_stats = log_steps(read_tuc(more))
    assert more_steps == steps
    assert (more_stats.below_threshold, stats.below_threshold) == (3, 1)
    assert (more_stats.frames, more_stats.links) == (stats.frames, stats.links) == (82, 2)
    # at a lower threshold the same query becomes a step, and a link
    config = LogSourceConfig(score_threshold=0.25, min_loop_travel=0.0)
    times = [s.time for s in log_steps(read_tuc(more), config)[0]]
    assert 4.0625 in times and 6.1 in times and len(times) == 84


def test_settings_change_the_events(straight: Path) -> None:
    log = read_tuc(straight)
    config = LogSourceConfig(score_threshold=0.5, min_loop_travel=0.0, relocalise=True)
    events = events_of(log_steps(log, config)[0])
    links = [(e.time, e.target) for e in events if type(e) is LinkToVertex]
    sets = [(e.time, e.target) for e in events if type(e) is SetCurrentVertex]
    # best score first at a query; each link followed by its set-current event
    assert links == [(8.0625, 20), (8.0625, 4), (8.0625, 12), (9.0, 10)]
    assert sets == links
    turning = write(straight.with_name("spin_Input.txt"), odom_lines(9, v=0.0, yaw=1.0))
    created = [e for e in events_of(log_steps(read_tuc(turning))[0]) if type(e) is CreateVertex]
    assert [e.time for e in created] == [0.0, 0.25, 0.5, 0.75, 1.0]  # every 0.2 rad turned


def test_ground_truth_is_interpolated_at_every_step(tmp_path: Path) -> None:
    path = write(tmp_path / "run_Input.txt", odom_lines(17, v=1.0) + ["loop 1.9 0.1 0.9"])
    truth = [f"point2 {0.2 * k:g} {0.2 * k:g} 1 0 0 0 0" for k in range(11)]
    truth += [f"angle {0.2 * k:g} 0.5 0" for k in range(11)]
    write(tmp_path / "run_GT.txt", truth)
    reader = open_source(path)
    assert isinstance(reader, LogReader) and reader.info.has_ground_truth
    assert reader.log.heading_known
    for step in reader.frames():
        np.testing.assert_allclose(step.ground_truth, (step.time, 1.0, 0.5), atol=1e-12)
    assert reader.counters.warnings == []
    no_truth = open_source(path, log=LogOptions(use_ground_truth=False))
    assert all(s.ground_truth is None for s in no_truth.frames())


def test_loop_candidates_are_labelled_by_the_true_distance_of_their_two_times(
    tmp_path: Path,
) -> None:
    # true path: out along x (1 m/s) until 5 s, then back, 0.5 m to the side after 7 s
    loops = [
        "loop 6.0 3.0 0.2",  # x 4 and 3: 1 m apart, true at the default radius
        "loop 6.0 2.9 0.95",  # x 4 and 2.9: 1.1 m apart, false
        "loop 8.0 1.0 1.0",  # x 2 and 1, y 0.5 and 0: 1.118 m apart, false
        "loop 9.5 0.5 0.9",  # x 0.5 and 0.5, y 0.5 and 0: 0.5 m apart, true
    ]
    path = write(tmp_path / "back_Input.txt", odom_lines() + loops)
    truth = [f"point2 {t:g} {min(t, 10 - t):g} {0.5 if t > 7 else 0:g} 0 0 0 0" for t in range(11)]
    write(tmp_path / "back_GT.txt", truth)
    log = read_tuc(path)
    assert label_loop_candidates(log).tolist() == [True, False, False, True]
    assert label_loop_candidates(log, radius=1.11).tolist() == [True, True, False, True]
    assert label_loop_candidates(log, radius=0.5).tolist() == [False, False, False, True]
    with pytest.raises(ParameterError, match="radius 0 m is out of range"):
        label_loop_candidates(log, radius=0)
    with pytest.raises(ParameterError, match="has no ground truth"):
        label_loop_candidates(read_tuc(path, use_ground_truth=False))


def test_ground_truth_covering_part_of_the_run_is_dropped_with_a_warning(tmp_path: Path) -> None:
    path = write(tmp_path / "run_Input.txt", odom_lines(81))
    write(tmp_path / "run_GT.txt", [f"point2 {k:g} {k:g} 0 0 0 0 0" for k in range(6)])
    reader = open_source(path)
    assert not reader.info.has_ground_truth
    warning, no_loops = reader.counters.warnings
    assert "covers 0.0-5.0 s of the 0.0-10.0 s run" in warning
    assert no_loops == f"{path}: no loop candidates: the map is its odometry"
    write(tmp_path / "run_GT.txt", [f"point2 {k:g} {k:g} 0 0 0 0 0" for k in range(50, 60)])
    with pytest.raises(LogFormatError, match="do not overlap"):
        open_source(path)


def test_csv_log_with_header_comments_and_companions(tmp_path: Path) -> None:
    odometry = ["# my robot", "time,v,omega"] + [f"{100 + k * DT:g},1.0,0.0" for k in range(81)]
    path = write(tmp_path / "lap_odometry.csv", odometry)
    write(tmp_path / "lap_loops.csv", ["time,matched_time,score", "108.0625,101.1,0.9"])
    write(tmp_path / "lap_ground_truth.csv", [f"{100 + k},{k},2" for k in range(11)])
    assert detect_format(path) == "csv"
    reader = open_source(path)
    assert reader.info.format == "csv" and reader.info.duration == 10.0
    steps = list(reader.frames())
    assert steps[0].time == 0.0  # data time counts from the first odometry sample
    links = [e for e in events_of(steps) if type(e) is LinkToVertex]
    assert links == [LinkToVertex(8.0625, 4, 0.0)]
    assert not reader.log.heading_known  # no theta column: heading = direction of travel
    np.testing.assert_allclose(steps[40].ground_truth, (5.0, 2.0, 0.0), atol=1e-12)
    alone = write(tmp_path / "solo.csv", odometry)
    (warning,) = open_source(alone).counters.warnings
    assert "no loop file" in warning and "odometry only" in warning
    log = read_odometry_csv(alone, loops=tmp_path / "lap_loops.csv")
    assert log.loops.tolist() == [[108.0625, 101.1, 0.9]]


def test_later_frames_start_where_asked(straight: Path) -> None:
    reader = open_source(straight)
    assert [s.time for s in reader.frames(8.0)][:3] == [8.0, 8.0625, 8.125]
    with pytest.raises(ParameterError, match="outside the log"):
        reader.frames(-1.0)


BAD_TUC = [
    (["odom2 0 1 0 0 0 0"], ":1: each 'odom2' line has 7 numbers after the type, this one 6"),
    (["odom2 0 1 0 x 0 0 0"], ":1: 'x' in a 'odom2' line is not a number"),
    (["odom2 0 1 0 0 0 0 0", "range 1 2"], ":2: unknown measurement type 'range'"),
    (["odom2 1 1 0 0 0 0 0", "odom2 0.5 1 0 0 0 0 0"], ":2: odometry time 0.500000 s is earlier"),
    (["odom2 0 1 0 0 0 0 0", "odom2 1 nan 0 0 0 0 0"], ":2: odometry v is nan"),
    (odom_lines(9) + ["loop 0.5 0.25 1.5"], ":10: loop score 1.5 is outside [0, 1]"),
    (odom_lines(9) + ["loop 0.5 0.25 inf"], ":10: loop score is inf"),
    (["loop 0.5 0.25 0.9"], ": no odometry in the file"),
]


def assert_one_line_error(read: Callable[[], object], path: Path, message: str) -> None:
    """``read()`` raises a one-line LogFormatError starting with ``path`` and saying ``message``."""
    with pytest.raises(LogFormatError) as caught:
        read()
    text = str(caught.value)
    assert "\n" not in text
    assert text.startswith(str(path)) and message in text, text


@pytest.mark.parametrize(("lines", "message"), BAD_TUC)
def test_bad_tuc_lines_name_file_and_line(tmp_path: Path, lines: list[str], message: str) -> None:
    path = write(tmp_path / "bad_Input.txt", lines)
    assert_one_line_error(lambda: read_tuc(path), path, message)


BAD_TRUTH = [
    (["angle 0 0.5 0", "angle 1 nan 0"], ":3: ground-truth angle theta is nan"),
    (["angle 1 0.5 0", "angle 0.5 0.5 0"], ":3: ground-truth angle time 0.500000 s is earlier"),
    (["point2 0 0 0 0 0 0 0", "point2 1 0 0 0 0 0"], ":3: each 'point2' line has 7 numbers"),
    (["point2 1 nan 0 0 0 0 0"], ":2: ground truth x is nan; every value must be a finite number"),
    (
        ["point2 2 0 0 0 0 0 0", "point2 1 0 0 0 0 0 0"],
        ":3: ground truth time 1.000000 s is earlier",
    ),
]


@pytest.mark.parametrize(("lines", "message"), BAD_TRUTH)
def test_bad_ground_truth_lines_name_file_and_line(
    tmp_path: Path, lines: list[str], message: str
) -> None:
    path = write(tmp_path / "run_Input.txt", odom_lines(9))
    truth = write(tmp_path / "run_GT.txt", ["point2 0 0 0 0 0 0 0", *lines])
    assert_one_line_error(lambda: read_tuc(path), truth, message)


BAD_CSV = [
    (["time,v,omega", "0,1"], ":2: 2 columns; odometry files have 3 (time,v,omega)"),
    (["0,1,0", "1,one,0"], ":2: 'one' is not a number"),
    (["0,1,0", "1,1,inf"], ":2: odometry omega is inf"),
    (["a,b"], ":1: header has 2 columns"),
]


@pytest.mark.parametrize(("lines", "message"), BAD_CSV)
def test_bad_csv_lines_name_file_and_line(tmp_path: Path, lines: list[str], message: str) -> None:
    path = write(tmp_path / "bad_odometry.csv", lines)
    assert_one_line_error(lambda: read_odometry_csv(path), path, message)


def test_detection_from_the_content(tmp_path: Path, straight: Path) -> None:
    assert detect_format(straight) == "tuc"
    bag = tmp_path / "x.data"
    bag.write_bytes(b"#ROSBAG V2.0\n" + bytes(100))
    assert detect_format(bag) == "bag"
    empty = tmp_path / "empty.txt"
    empty.write_text("\n  \n")
    with pytest.raises(InputFileError, match="the file is empty"):
        detect_format(empty)
    other = write(tmp_path / "notes.txt", ["hello world"])
    with pytest.raises(InputFileError, match="not a bag, a TUC log or a CSV log"):
        detect_format(other)
    with pytest.raises(InputFileError, match="no such file"):
        detect_format(tmp_path / "missing.txt")
    # --format overrides detection; a TUC file read as CSV fails on its first line
    with pytest.raises(LogFormatError, match=r":1: header has 1 columns; odometry files"):
        open_source(straight, "csv")


def test_the_first_data_line_decides_tuc(tmp_path: Path) -> None:
    assert looks_like_tuc("odom2") and looks_like_tuc("loop")
    assert looks_like_tuc("point2") and looks_like_tuc("angle")
    assert not looks_like_tuc("hello") and not looks_like_tuc("")
    # comments and blank lines are skipped; a later unknown type is the reader's business
    tuc = write(tmp_path / "commented.txt", ["# a comment", "", "odom2 0 0 0 0 0 0 0", "x 1"])
    assert detect_format(tuc) == "tuc"
    other = write(tmp_path / "later.txt", ["hello world", "odom2 0 0 0 0 0 0 0"])
    with pytest.raises(InputFileError, match="not a bag, a TUC log or a CSV log"):
        detect_format(other)


def test_log_settings_are_validated() -> None:
    with pytest.raises(ParameterError, match="score_threshold=1.5 is out of range"):
        LogSourceConfig(score_threshold=1.5)
    with pytest.raises(ParameterError, match="unknown log source setting"):
        LogSourceConfig().with_changes(threshold=0.5)
