"""The event log keeps events and frames as columns and gives them back exactly."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from cogmap_core.errors import InputFileError
from cogmap_core.event_file import load_event_file, save_event_file
from cogmap_core.event_log import EventLog
from cogmap_core.events import CreateVertex, LinkToVertex, MapEvent, Odometry, SetCurrentVertex

FRAMES: list[tuple[list[MapEvent], float, tuple[float, float, float] | None]] = [
    ([Odometry(0.0, 0.0, 0.0), CreateVertex(0.0, 0, 0)], 0.0, (0.0, 0.0, 0.0)),
    ([Odometry(0.1, 0.5, 0.25), CreateVertex(0.1, 1, 1)], 0.1, (0.5, 0.0, 0.25)),
    ([Odometry(0.2, 0.25, -math.pi / 2)], 0.2, None),
    (
        [Odometry(0.3, 0.0, 0.125), LinkToVertex(0.3, 0, 0.5), SetCurrentVertex(0.3, 0, 0.5)],
        0.3,
        (0.0, 0.1, 3.0),
    ),
    ([Odometry(0.4, 0.1, 0.0), LinkToVertex(0.4, 1, -0.25)], 0.4, None),
]


def build() -> EventLog:
    log = EventLog()
    for events, time, truth in FRAMES:
        log.append_frame(events, time, truth)
    return log


def all_events() -> list[MapEvent]:
    return [e for events, _, _ in FRAMES for e in events]


def truth_at_links(log: EventLog) -> list[tuple[float, ...] | None]:
    """Per link of ``link_table``, the true pose of its frame (None: that frame has none)."""
    truth = iter(log.ground_truth.tolist())
    per_frame = [tuple(next(truth)) if known else None for known in log.has_truth.tolist()]
    frame_at = {t: k for k, t in enumerate(log.frame_time.tolist())}
    return [per_frame[frame_at[t]] for t, _, _ in log.link_table()]


def test_events_come_back_as_given() -> None:
    log = build()
    events = all_events()
    assert log.frames == 5 and log.event_count == len(events) == len(log.events)
    assert list(log.events) == events
    assert log.events[3] == events[3] and log.events[-1] == events[-1]
    assert log.events[2:6] == events[2:6] and log.events[::3] == events[::3]
    assert log.events_until(2) == events[:4] and log.events_until() == events
    assert log.events_until(0) == []
    with pytest.raises(IndexError):
        log.events[len(events)]
    assert log.frame_end.tolist() == [2, 4, 5, 8, 10]
    assert log.frame_time.tolist() == [0.0, 0.1, 0.2, 0.3, 0.4]


def test_ground_truth_per_frame_and_per_link() -> None:
    log = build()
    assert log.ground_truth.tolist() == [[0.0, 0.0, 0.0], [0.5, 0.0, 0.25], [0.0, 0.1, 3.0]]
    assert log.has_truth.tolist() == [True, True, False, True, False]
    assert not log.has_ground_truth()
    assert truth_at_links(log) == [(0.0, 0.1, 3.0), None]
    assert log.link_table() == [(0.3, 0, 0.5), (0.4, 1, -0.25)]


def test_views_are_read_only() -> None:
    log = build()
    with pytest.raises(ValueError, match="^assignment destination is read-only$"):
        log.frame_time[0] = 1.0
    with pytest.raises(ValueError, match="^assignment destination is read-only$"):
        log.columns()["time"][0] = 1.0


def test_growing_past_the_initial_capacity_keeps_everything() -> None:
    log = EventLog()
    for k in range(3000):
        log.append_frame([Odometry(k * 0.1, 0.01 * k, 0.0), CreateVertex(k * 0.1, k, k)], k * 0.1)
    assert log.event_count == 6000 and log.frames == 3000
    assert log.events[5999] == CreateVertex(2999 * 0.1, 2999, 2999)
    assert log.events[4000] == Odometry(2000 * 0.1, 20.0, 0.0)
    assert log.frame_end[-1] == 6000 and len(log.ground_truth) == 0


def test_truncated_and_recording_round_trip() -> None:
    log = build()
    part = log.truncated(4)
    assert list(part.events) == all_events()[:8] and part.frames == 4
    assert truth_at_links(part) == [(0.0, 0.1, 3.0)]
    full = EventLog()
    for events, time, truth in FRAMES:
        full.append_frame(events, time, truth or (1.0, 2.0, 3.0))
    again = EventLog.from_recording(full.recording("x"))
    assert list(again.events) == list(full.events)
    assert np.array_equal(again.ground_truth, full.ground_truth)
    assert np.array_equal(again.frame_end, full.frame_end)


def test_dead_reckoning_per_frame() -> None:
    log = build()
    poses = log.dead_reckoning()
    # rotate first, then translate: (0.5 at 0.25), (0.25 at 0.25 - pi/2), (0 at ...), (0.1 ...)
    h1 = 0.25
    h2 = h1 - math.pi / 2
    h3 = h2 + 0.125
    x = [0.0, 0.5 * math.cos(h1)]
    y = [0.0, 0.5 * math.sin(h1)]
    x.append(x[-1] + 0.25 * math.cos(h2))
    y.append(y[-1] + 0.25 * math.sin(h2))
    x.append(x[-1])
    y.append(y[-1])
    x.append(x[-1] + 0.1 * math.cos(h3))
    y.append(y[-1] + 0.1 * math.sin(h3))
    assert poses[:, 0] == pytest.approx(x, abs=1e-12)
    assert poses[:, 1] == pytest.approx(y, abs=1e-12)
    assert poses[-1, 2] == pytest.approx(h3, abs=1e-12)


def test_link_scores_are_a_column() -> None:
    log = EventLog()
    log.append_frame([Odometry(0.0, 0.0, 0.0), CreateVertex(0.0, 0, 0)], 0.0)
    log.append_frame([Odometry(0.1, 0.5, 0.0), CreateVertex(0.1, 1, 1)], 0.1)
    links = [LinkToVertex(0.2, 0, 0.0), LinkToVertex(0.2, 1, 0.0)]
    log.append_frame([Odometry(0.2, 0.1, 0.0), *links], 0.2, link_scores=(0.9, 0.85))
    log.append_frame([LinkToVertex(0.3, 0, 0.0)], 0.3)  # a camera front end's: no score
    assert log.link_scores == [0.9, 0.85, None]
    links = [(0.2, 0, 0.0), (0.2, 1, 0.0), (0.3, 0, 0.0)]  # link_table's order, no fourth link
    assert list(zip(log.link_table(), log.link_scores, strict=True)) == list(
        zip(links, [0.9, 0.85, None], strict=True)
    )
    assert log.truncated(3).link_scores == [0.9, 0.85]
    score = log.columns()["score"]
    assert np.isnan(score[:5]).all()  # NaN for events other than links ...
    assert score[5:7].tolist() == [0.9, 0.85] and np.isnan(score[7])  # ... and links without
    again = EventLog.from_columns(log.columns(), log.frame_end, log.frame_time)
    assert again.link_scores == log.link_scores
    # columns without scores (an event file's) give links without scores
    columns = {k: v for k, v in log.columns().items() if k != "score"}
    assert EventLog.from_columns(columns, log.frame_end, log.frame_time).link_scores == [None] * 3


def test_links_beyond_the_first_capacity_have_no_score_without_a_score_column() -> None:
    """Columns grown past the log's first capacity keep "no score" (NaN), not a score of 0."""
    log = EventLog()
    log.append_frame([Odometry(0.0, 0.0, 0.0), CreateVertex(0.0, 0, 0)], 0.0)
    for k in range(1, 1500):
        log.append_frame([LinkToVertex(0.1 * k, 0, 0.0)], 0.1 * k)
    columns = {k: v for k, v in log.columns().items() if k != "score"}
    again = EventLog.from_columns(columns, log.frame_end, log.frame_time)
    assert again.link_scores == [None] * 1499


# ------------------------------------------------------------------------------ event files
def rewrite_npz(path: Path, target: Path, **changes: object) -> Path:
    """A copy of the ``.npz`` file ``path`` (an event or session file) with arrays replaced."""
    with np.load(path) as data:
        arrays = {name: data[name] for name in data.files}
    for name, value in changes.items():
        arrays[name] = np.asarray(value)
    np.savez(target, **arrays)
    return target


@pytest.fixture
def event_file(tmp_path: Path) -> Path:
    return save_event_file(tmp_path / "run.events.npz", build().recording("run.bag"))


def test_event_file_round_trip(event_file: Path) -> None:
    recording = load_event_file(event_file)
    assert recording.events == all_events() and recording.source == "run.bag"


@pytest.mark.parametrize(
    ("damage", "message"),
    [
        ("missing", "no such event file"),
        ("truncated", "not a readable cogmap event file (BadZipFile: "),
        ("header [1]", "not a cogmap event file (format None)"),
        ("header not JSON", "the event file's header is not valid JSON; it is corrupt"),
        ("version 99", "event format version 99 is not supported (this cogmap reads version 1)"),
        ("no frames", "not a cogmap event file (missing frame_end)"),
    ],
)
def test_a_damaged_event_file_is_one_line_naming_the_problem(
    event_file: Path, tmp_path: Path, damage: str, message: str
) -> None:
    bad = tmp_path / "bad.npz"
    header = json.loads(str(np.load(event_file)["header"]))
    if damage == "missing":
        bad = tmp_path / "nothing.npz"
    elif damage == "truncated":
        bad.write_bytes(event_file.read_bytes()[:100])
    elif damage == "header [1]":
        rewrite_npz(event_file, bad, header="[1]")
    elif damage == "header not JSON":
        rewrite_npz(event_file, bad, header="{not json")
    elif damage == "version 99":
        rewrite_npz(event_file, bad, header=json.dumps({**header, "version": 99}))
    else:
        with np.load(event_file) as data:
            np.savez(bad, **{n: data[n] for n in data.files if n != "frame_end"})
    with pytest.raises(InputFileError) as caught:
        load_event_file(bad)
    assert str(caught.value).startswith(f"{bad}: {message}")
    assert "\n" not in str(caught.value)
