"""Bad data that still decodes: clock jumps, corrupt-but-decodable JPEGs, tiny images, damage.

Each case is read by the reader (exact frames and counters) and run through ``cogmap run``
(exit code, the one line or the warning it prints, and what is written).
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from app.cli import main
from cogmap_core.datasets import open_bag
from cogmap_core.datasets.bag_writer import IratBagWriter
from cogmap_core.datasets.clock_jumps import plan_clock_jumps
from cogmap_core.datasets.jpeg import JpegDecoder
from cogmap_core.errors import ParameterError
from tests.test_dataset_reader import T0, S, jpeg, simple_bag, write_bag
from tests.test_faults import corrupt_mid_bag, one_line_error, snapshot

SHIFT = 3.05  # s the clock jumps back
JUMP_AT = 6.0  # s of true time at which it jumps


def frame_times(n: int = 60) -> list[float]:
    return [round(0.1 + 0.2 * k, 6) for k in range(n)]


def clock_jump_bag(path: Path, n: int = 60) -> Path:
    """Frames every 0.2 s, odometry and ground truth every 0.1 s; from ``JUMP_AT`` (true time)
    on, header and record stamps are ``SHIFT`` s earlier, written after everything before."""
    events: list[tuple[float, int, int]] = []
    events += [(round(0.1 * k, 6), 0, k) for k in range(2 * n + 1)]
    events += [(round(0.1 * k, 6), 1, k) for k in range(2 * n + 1)]
    events += [(t, 2, k) for k, t in enumerate(frame_times(n))]
    events.sort(key=lambda e: (e[0], e[1]))
    with IratBagWriter(path) as bag:
        for t, kind, k in events:  # written in true-time order: the recorder's order
            stamp = t - SHIFT if t >= JUMP_AT else t
            ns = T0 + round(stamp * S)
            if kind == 0:
                bag.write_odometry(ns, 0.1, 0.0)
            elif kind == 1:
                bag.write_ground_truth(ns, 0.1 * t, 0.0, 0.0)
            else:
                bag.write_image(ns, jpeg(k % 12))
    return path


def expected_after_jump(times: list[float], reached: float) -> tuple[list[float], int]:
    """Stamps kept and dropped by the "drop" policy for one topic with true ``times``."""
    kept, dropped = [], 0
    for t in times:
        stamp = round(t - SHIFT, 6) if t >= JUMP_AT else t
        if t >= JUMP_AT and stamp < reached:
            dropped += 1
        else:
            kept.append(stamp)
    return kept, dropped


# ---------------------------------------------------------------------------------- clock jumps
def test_clock_jump_back_drops_the_overlap(tmp_path: Path) -> None:
    path = clock_jump_bag(tmp_path / "jump.bag")
    frames = frame_times()
    kept_frames, dropped_frames = expected_after_jump(frames, reached=5.9)
    ticks = [round(0.1 * k, 6) for k in range(121)]
    _, dropped_ticks = expected_after_jump(ticks, reached=5.9)  # odometry, ground truth
    assert (len(kept_frames), dropped_frames, dropped_ticks) == (45, 15, 30)
    with open_bag(path) as reader:
        (jump,) = reader.clock_jumps
        got = list(reader.frames())
        counters = reader.counters
        warnings = reader.warnings
    assert jump.time == pytest.approx(5.9) and jump.back == pytest.approx(5.9 - (6.0 - SHIFT))
    assert jump.dropped == dropped_frames + 2 * dropped_ticks == 75
    assert [f.time for f in got] == pytest.approx(kept_frames)  # no interleaving
    assert counters.clock_jumps == 1 and counters.clock_jump_messages_dropped == 75
    assert counters.image_stamps_backwards == 0
    assert warnings == [
        "the bag's clock jumps back 2.95 s at t=5.90 s: 75 messages recorded again over the "
        "same time were dropped (each topic resumes when its clock passes the time it had "
        "reached)"
    ]
    # across the dropped stretch only the kept messages' intervals count (5.9 -> 5.95 -> 6.05 s)
    assert got[30].time == pytest.approx(6.05)
    assert got[30].translation == pytest.approx(0.1 * (6.05 - 5.9), abs=1e-9)


def test_clock_jump_back_can_stop_the_reading(tmp_path: Path) -> None:
    path = clock_jump_bag(tmp_path / "jump.bag")
    with open_bag(path, on_clock_jump="stop") as reader:
        got = list(reader.frames())
        (jump,) = reader.clock_jumps
        assert reader.warnings == [
            "the bag's clock jumps back 2.95 s at t=5.90 s: reading stops there (152 later "
            "messages not read)"
        ]
    assert [f.time for f in got] == pytest.approx(frame_times()[:30])
    assert jump.dropped == 30 + 2 * 61  # frames, odometry and ground truth from 6.0 s on


def test_topics_written_one_after_the_other_are_not_a_clock_jump(tmp_path: Path) -> None:
    """A converter may write all odometry, then all images: time order per topic is intact."""
    path = tmp_path / "by_topic.bag"
    with IratBagWriter(path) as bag:
        for k in range(21):
            bag.write_odometry(T0 + k * S // 10, 0.1, 0.0)
        for k in range(10):
            bag.write_image(T0 + (2 * k + 1) * S // 10, jpeg(k))
    with open_bag(path) as reader:
        assert reader.clock_jumps == []
        assert len(list(reader.frames())) == 10
        assert reader.warnings == []
    assert plan_clock_jumps([], "drop", T0) is None


def test_bad_clock_jump_policy(tmp_path: Path) -> None:
    with pytest.raises(ParameterError, match="'drop' or 'stop'"):
        open_bag(simple_bag(tmp_path / "s.bag", n=2), on_clock_jump="merge")


def test_cogmap_run_reports_the_clock_jump(tmp_path: Path, capsys) -> None:
    path = clock_jump_bag(tmp_path / "jump.bag")
    out = tmp_path / "out"
    assert main(["run", str(path), "--out", str(out)]) == 0
    stdout = capsys.readouterr().out
    assert "warning: the bag's clock jumps back 2.95 s at t=5.90 s: 75 messages" in stdout
    summary = json.loads((out / "summary.json").read_text())
    assert summary["frames"] == 45
    warnings = summary["read_warnings"]
    assert (warnings["clock_jumps"], warnings["clock_jump_messages_dropped"]) == (1, 75)
    assert warnings["first_seen"]["clock_jumps"] == pytest.approx(5.9)
    assert main(["run", str(path), "--out", str(out), "--force", "--on-clock-jump", "stop"]) == 0
    assert "reading stops there (152 later messages not read)" in capsys.readouterr().out
    assert json.loads((out / "summary.json").read_text())["frames"] == 30


# --------------------------------------------------------------------------- corrupt JPEGs
def damaged(data: bytes, how: str) -> bytes:
    """JPEG bytes that libjpeg still decodes, with a warning."""
    mid = (data.index(b"\xff\xda") + len(data)) // 2  # in the entropy-coded data
    if how == "cut":  # 300 bytes missing
        return data[:mid] + data[mid + 300 :]
    return data[:mid] + bytes(8) + data[mid + 8 :]  # 8 bytes overwritten


def frames_with_corrupt_jpegs(n: int) -> list[tuple[float, bytes]]:
    """``n`` frames at :func:`frame_times`; every 12th from the 6th (t = 1.1 s, ...) a cut JPEG."""
    return [
        (t, damaged(jpeg(k), "cut") if k % 12 == 5 else jpeg(k))
        for k, t in enumerate(frame_times(n))
    ]


@pytest.mark.parametrize(
    ("how", "warning"),
    [
        ("cut", "Corrupt JPEG data: premature end of data segment"),
        ("overwritten", "Corrupt JPEG data: 6 extraneous bytes before marker 0xd9"),
    ],
)
def test_jpeg_decoder_catches_libjpeg_warnings(how: str, warning: str) -> None:
    decoder = JpegDecoder(cv2.IMREAD_REDUCED_GRAYSCALE_4)
    assert decoder.checks
    good = np.frombuffer(jpeg(3), np.uint8)
    image, problem = decoder.decode(good)
    assert problem is None
    np.testing.assert_array_equal(image, cv2.imdecode(good, cv2.IMREAD_REDUCED_GRAYSCALE_4))
    bad = np.frombuffer(damaged(jpeg(3), how), np.uint8)
    image, problem = decoder.decode(bad)
    assert image is not None and image.shape == (60, 104)  # decodes, scrambled
    assert problem == warning
    decoder.close()


def test_corrupt_but_decodable_jpegs_are_skipped_and_counted(tmp_path: Path) -> None:
    n = 36
    frames = frames_with_corrupt_jpegs(n)
    odom = [(0.1 * k, 1.0, 0.0) for k in range(2 * n + 1)]
    with open_bag(write_bag(tmp_path / "cj.bag", frames, odom), image_scale=4) as reader:
        got = list(reader.frames())
        assert reader.counters.corrupt_images == 3
        assert reader.counters.undecodable_images == 0
        assert reader.warnings == [
            "3 x camera image with corrupt JPEG data (decoded scrambled) skipped (first at "
            "t=1.10 s)"
        ]
    assert len(got) == n - 3
    assert 1.1 not in [round(f.time, 6) for f in got]
    assert sum(f.translation for f in got) == pytest.approx(frame_times(n)[-1])  # carried over


def test_cogmap_run_skips_corrupt_jpegs_and_refuses_tiny_images(tmp_path: Path, capsys) -> None:
    n = 36
    frames = frames_with_corrupt_jpegs(n)
    odom = [(0.1 * k, 0.1, 0.0) for k in range(2 * n + 1)]
    path = write_bag(tmp_path / "cj.bag", frames, odom)
    assert main(["run", str(path), "--out", str(tmp_path / "out")]) == 0
    assert "warning: 3 x camera image with corrupt JPEG data" in capsys.readouterr().out
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["frames"] == n - 3 and summary["read_warnings"]["corrupt_images"] == 3

    tiny = [(t, jpeg(k, (8, 8))) for k, t in enumerate(frame_times(10))]
    path = write_bag(tmp_path / "tiny.bag", tiny, odom)
    out = tmp_path / "tiny-out"
    assert main(["run", str(path), "--out", str(out)]) == 2
    assert one_line_error(capsys.readouterr().err) == (
        f"cogmap run: error: {path}: camera images of about 8x8 px are too small for the 60x20 "
        "view template; use a camera topic with images of at least 60x32 px"  # decoded at full size
    )
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == [
        "cj.bag",
        "out",
        "tiny.bag",
    ]


# --------------------------------------------------------------------------- damaged bags
def test_until_error_maps_the_part_before_the_damage(tmp_path: Path, capsys) -> None:
    bag = simple_bag(tmp_path / "ok.bag", n=60)
    broken = corrupt_mid_bag(bag, tmp_path / "broken.bag")
    out = tmp_path / "out"
    assert main(["run", str(broken), "--out", str(out)]) == 2
    line = one_line_error(capsys.readouterr().err)
    assert f"bag {broken} is corrupt near t=" in line
    assert line.endswith("copy it again, or read up to there (cogmap run --until-error)")
    assert not out.exists()
    assert main(["run", str(broken), "--out", str(out), "--until-error"]) == 0
    printed = capsys.readouterr().out
    summary = json.loads((out / "summary.json").read_text())
    stopped = summary["read_warnings"]["first_seen"]["corrupt_chunks"]
    assert summary["read_warnings"]["corrupt_chunks"] == 1
    assert 0 < summary["frames"] < 60
    assert summary["data_duration_s"] <= stopped
    assert (
        f"warning: 1 x corrupt bag data: reading stopped there, the frames before it kept "
        f"(first at t={stopped:.2f} s)" in printed
    )
    assert set(snapshot(out)) >= {"summary.json", "map.png", "compact.g2o"}
    with open_bag(broken, on_corrupt="stop") as reader:
        assert len(list(reader.frames())) == summary["frames"]
