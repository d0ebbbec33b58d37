"""``cogmap make-log`` and the log generator: determinism, formats, patterns, labels, drift."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from app.cli import main
from cogmap_core.datasets.log_candidates import NEAR, STRUCTURED, TRUE
from cogmap_core.datasets.log_generator import (
    DRIFT_LEVELS,
    GeneratedLog,
    LogGeneratorConfig,
    generate_log,
)
from cogmap_core.datasets.log_routes import PATTERNS
from cogmap_core.datasets.log_writer import write_log
from cogmap_core.errors import ParameterError
from cogmap_core.evaluation import absolute_trajectory_error, dead_reckoning, interpolate_poses
from cogmap_core.sources.log_reader import log_steps
from cogmap_core.sources.odometry_csv import read_odometry_csv
from cogmap_core.sources.odometry_log import OdometryLog, label_loop_candidates
from cogmap_core.sources.tuc import read_tuc

SHORT = LogGeneratorConfig(duration=120.0)  # for the file tests: a tenth of a second's work


@pytest.fixture(scope="module")
def logs() -> dict[str, GeneratedLog]:
    """Every pattern at the default settings (20 min, seed 1): about 0.5 s each."""
    return {p: generate_log(LogGeneratorConfig(pattern=p)) for p in PATTERNS}


def measured_ate(log: OdometryLog) -> float:
    """Dead-reckoning ATE of a log read back, at its odometry stamps."""
    odo, truth = log.odometry, log.ground_truth
    assert truth is not None
    dt = np.diff(odo[:, 0], prepend=odo[0, 0])
    poses = dead_reckoning(odo[:, 1] * dt, odo[:, 2] * dt)
    return absolute_trajectory_error(poses, interpolate_poses(truth[:, 0], truth[:, 1:], odo[:, 0]))


def usable_counts(log: GeneratedLog) -> tuple[int, int, int, int]:
    """Usable true, false, structured and near-miss candidates, counted from the labels."""
    usable = (log.loops[:, 2] >= log.config.score_threshold) & ~log.recent
    return (
        int((usable & log.true_match).sum()),
        int((usable & ~log.true_match).sum()),
        int((usable & log.structured).sum()),
        int((usable & (log.kind == NEAR)).sum()),
    )


def keyframe_poses(log: GeneratedLog, times: np.ndarray) -> np.ndarray:
    return interpolate_poses(log.ground_truth[:, 0], log.ground_truth[:, 1:], times)


def revisiting(log: GeneratedLog) -> np.ndarray:
    """Per keyframe: is it within 1 m of an earlier one, at least 10 m of driving before?"""
    poses = keyframe_poses(log, log.keyframe_times)
    step = np.hypot(*np.diff(log.ground_truth[:, 1:3], axis=0).T)
    driven = np.interp(log.keyframe_times, log.ground_truth[:, 0], np.r_[0.0, np.cumsum(step)])
    out = np.zeros(poses.shape[0], dtype=bool)
    for i in range(poses.shape[0]):
        near = np.hypot(*(poses[:i, :2] - poses[i, :2]).T) <= 1.0
        out[i] = bool(np.any(near & (driven[i] - driven[:i] >= 10.0)))
    return out


# ---------------------------------------------------------------------------------- library
@pytest.mark.parametrize("fmt", ["tuc", "csv"])
def test_the_same_seed_gives_identical_files_and_another_seed_other_ones(
    tmp_path: Path, fmt: str
) -> None:
    for name in ("a", "b", "c"):
        (tmp_path / name).mkdir()
    first = write_log(generate_log(SHORT), tmp_path / "a" / "run", fmt)
    again = write_log(generate_log(SHORT), tmp_path / "b" / "run", fmt)
    other = write_log(
        generate_log(LogGeneratorConfig(duration=120.0, seed=2)), tmp_path / "c" / "run", fmt
    )
    if fmt == "tuc":
        names = ["run_Input.txt", "run_GT.txt"]
    else:
        names = ["run_odometry.csv", "run_loops.csv", "run_ground_truth.csv"]
    assert [p.name for p in first] == [p.name for p in again] == [p.name for p in other] == names
    for a, b, c in zip(first, again, other, strict=True):
        assert a.read_bytes() == b.read_bytes()
        assert a.read_bytes() != c.read_bytes()


def test_both_formats_read_back_as_the_generated_arrays(tmp_path: Path) -> None:
    log = generate_log(LogGeneratorConfig(pattern="figure_eight", duration=600.0, seed=3))
    tuc_input, tuc_truth = write_log(log, tmp_path / "f8", "tuc")
    write_log(log, tmp_path / "f8", "csv")
    from_tuc = read_tuc(tuc_input)
    from_csv = read_odometry_csv(tmp_path / "f8_odometry.csv")
    assert from_tuc.ground_truth_path == tuc_truth and from_tuc.warnings == ()
    assert from_csv.ground_truth_path == tmp_path / "f8_ground_truth.csv"
    for read in (from_tuc, from_csv):
        assert np.array_equal(read.odometry, log.odometry)
        assert np.array_equal(read.loops, log.loops)
        assert np.array_equal(read.ground_truth, log.ground_truth)
        assert read.heading_known
        assert np.array_equal(label_loop_candidates(read), log.true_match)
        assert measured_ate(read) == pytest.approx(log.dead_reckoning_ate, rel=1e-12)
    # the odom2 lines carry vy and the covariances as generated, like TUC's
    odom2 = [line.split() for line in tuc_input.read_text().splitlines() if line[0] == "o"]
    assert np.array_equal([float(w[3]) for w in odom2], log.lateral)
    assert np.array_equal([[float(x) for x in w[5:]] for w in odom2], log.covariance)
    x, y = (float(v) for v in log.ground_truth[0, 1:3])
    assert tuc_truth.read_text().splitlines()[0] == f"point2 0.0 {x!r} {y!r} 0.0 0.0 0.0 0.0"


def test_odometry_and_ground_truth_look_like_tuc(logs: dict[str, GeneratedLog]) -> None:
    log = logs["loop"]
    t = log.odometry[:, 0]
    assert t[0] == 0.0 and log.odometry[0, 1] == log.odometry[0, 2] == 0.0
    assert np.abs(np.diff(t) - 0.1).max() <= 1e-4 + 1e-12 and t[-1] == pytest.approx(
        1200.0, abs=1e-4
    )
    gt_t = log.ground_truth[:, 0]
    assert np.array_equal(gt_t, np.round(np.arange(gt_t.size) * 0.2, 9))
    assert gt_t[-1] >= t[-1] > gt_t[-2]
    dt = np.diff(t, prepend=0.0)
    assert np.array_equal(log.lateral, log.odometry[:, 1] * np.sin(log.odometry[:, 2] * dt))
    e = log.errors
    assert np.array_equal(log.covariance[:, 1], np.full(t.size, float(f"{e.sigma_v**2:.2g}")))
    assert np.array_equal(
        log.covariance[:, 2], np.full(t.size, float(f"{e.sigma_w**2 + e.bias**2:.2g}"))
    )
    # wheel odometry reads exactly zero while the robot stands (0.6 s without moving or turning)
    speed = np.hypot(*np.diff(log.ground_truth[:, 1:3], axis=0).T) / 0.2
    still = (speed == 0.0) & (np.diff(log.ground_truth[:, 3]) == 0.0)
    start = gt_t[:-3][still[:-2] & still[1:-1] & still[2:]]
    run = np.searchsorted(start, t) - 1
    at_rest = (run >= 0) & (t > start[run] + 0.11) & (t < start[run] + 0.59)
    assert at_rest.sum() > 50 and not log.odometry[at_rest, 1:].any()
    assert np.count_nonzero(log.odometry[:, 1]) > 0.9 * t.size
    assert 0.3 <= np.median(speed) <= 1.5 and speed.max() <= 1.5
    heading_rate = np.abs(np.diff(log.ground_truth[:, 3])) / 0.2
    assert heading_rate.max() <= 0.8 + 1e-9  # smooth turns: the turn-rate limit


@pytest.mark.parametrize("pattern", PATTERNS)
def test_every_pattern_revisits_places_and_yields_true_matches(
    logs: dict[str, GeneratedLog], pattern: str
) -> None:
    log = logs[pattern]
    cfg = log.config
    kf = log.keyframe_times
    revisit = revisiting(log)
    true_usable, false_usable, _, _ = usable_counts(log)
    assert true_usable >= 10 and false_usable >= 1
    if pattern == "long_exploration":  # mostly new ground, a few returns late in the run
        assert 0.05 < revisit.mean() < 0.25 and kf[revisit][0] > 0.6 * cfg.duration
    else:
        assert revisit.mean() > (0.35 if pattern == "campus" else 0.7)
        assert kf[revisit][0] < 0.35 * cfg.duration
    # queries are keyframes every ~2.5 s; a candidate matches an earlier keyframe
    assert np.isin(log.loops[:, :2], kf).all() and (log.loops[:, 1] < log.loops[:, 0]).all()
    assert 2.0 < np.median(np.diff(kf)) < 3.0
    assert log.loops[:, 0].max() <= log.odometry[-1, 0]
    # labels: true matches within the radius from about the same (or the opposite) direction
    a = keyframe_poses(log, log.loops[:, 0])
    b = keyframe_poses(log, log.loops[:, 1])
    gap = np.hypot(*(a[:, :2] - b[:, :2]).T)
    assert np.array_equal(log.true_match, gap <= cfg.match_radius)
    assert np.array_equal(log.kind == TRUE, log.true_match & ~log.recent)
    turn = np.degrees(np.abs((a[:, 2] - b[:, 2] + np.pi) % (2 * np.pi) - np.pi))
    true = log.kind == TRUE
    assert ((turn[true] <= cfg.view_angle) | (turn[true] >= 180 - cfg.view_angle)).all()
    # true matches score higher on average, but overlap the false ones
    false = ~log.true_match & ~log.recent
    assert np.mean(log.loops[true, 2]) > np.mean(log.loops[false, 2]) + 0.2
    assert np.mean(log.loops[true, 2] < cfg.score_threshold) > 0.5


@pytest.mark.parametrize("opposite", [0.0, 1.0])
def test_places_seen_the_other_way_are_recognised_only_as_asked(opposite: float) -> None:
    log = generate_log(
        LogGeneratorConfig(pattern="back_and_forth", duration=600.0, opposite_probability=opposite)
    )
    true = log.loops[log.kind == TRUE]
    a, b = keyframe_poses(log, true[:, 0]), keyframe_poses(log, true[:, 1])
    turn = np.degrees(np.abs((a[:, 2] - b[:, 2] + np.pi) % (2 * np.pi) - np.pi))
    reverse = int((turn > 90).sum())
    if opposite:
        assert reverse > 100 and (turn[turn > 90] >= 150).all()
    else:
        assert reverse == 0 and true.shape[0] > 100


@pytest.mark.parametrize(
    ("pattern", "fraction", "structured", "near"),
    [
        ("loop", 0.05, 0.3, 0.6),
        ("parallel_corridors", 0.25, 0.5, 0.0),
        ("back_and_forth", 0.5, 0.2, 1.0),
    ],
)
def test_false_matches_are_the_configured_share_of_the_usable_candidates(
    pattern: str, fraction: float, structured: float, near: float
) -> None:
    cfg = LogGeneratorConfig(
        pattern=pattern,
        duration=900.0,
        false_fraction=fraction,
        structured_fraction=structured,
        near_fraction=near,
    )
    log = generate_log(cfg)
    n_true, n_false, n_structured, n_near = usable_counts(log)
    assert n_true >= 50
    assert n_false == round(fraction * n_true / (1 - fraction))
    assert abs(n_false / (n_true + n_false) - fraction) <= 1 / (n_true + n_false)
    assert n_structured == round(structured * n_false) > 0
    assert n_near == round(near * (n_false - n_structured))
    assert log.counts() == {
        "candidates": log.loops.shape[0],
        "queries": np.unique(log.loops[:, 0]).size,
        "usable": n_true + n_false,
        "true": n_true,
        "false": n_false,
        "structured": n_structured,
        "near": n_near,
    }


def test_structured_matches_in_parallel_corridors_see_the_other_corridor() -> None:
    cfg = LogGeneratorConfig(pattern="parallel_corridors", false_fraction=0.3)
    log = generate_log(cfg)
    pairs = log.loops[log.kind == STRUCTURED]
    assert pairs.shape[0] == usable_counts(log)[2] > 20
    a = keyframe_poses(log, pairs[:, 0])
    b = keyframe_poses(log, pairs[:, 1])
    # the same offset along the corridors, facing the same way, in another corridor (8-15 m)
    assert np.abs(a[:, 0] - b[:, 0]).max() <= 1.0
    assert np.abs(a[:, 1] - b[:, 1]).min() > 6.0
    assert np.degrees(np.abs((a[:, 2] - b[:, 2] + np.pi) % (2 * np.pi) - np.pi)).max() <= 30
    # in sequences over consecutive queries (at most 3 keyframes apart), not one-offs
    kf = list(log.keyframe_times)
    queries = sorted({kf.index(t) for t in pairs[:, 0]})
    runs = 1 + sum(1 for a, b in zip(queries, queries[1:], strict=False) if b - a > 3)
    assert runs <= len(queries) / 3


def test_recent_candidates_are_the_ones_the_reader_drops(logs: dict[str, GeneratedLog]) -> None:
    log = logs["back_and_forth"]
    read = OdometryLog(Path("generated"), "tuc", log.odometry, log.loops, log.ground_truth)
    _, stats = log_steps(read)
    high = log.loops[:, 2] >= 0.8
    assert stats.loop_candidates == log.loops.shape[0]
    assert stats.below_threshold == int((~high).sum())
    assert stats.too_close == int((high & log.recent).sum()) > 0
    assert stats.links + stats.duplicates == int(log.usable.sum())


def test_dead_reckoning_error_grows_with_the_drift_level() -> None:
    ates = []
    for level, (low, high) in DRIFT_LEVELS.items():
        log = generate_log(LogGeneratorConfig(drift=level))
        ates.append(log.dead_reckoning_ate)
        assert low <= log.errors.target_ate <= high
        if level != "extreme":  # (beyond some routes' reach: their error curls back)
            assert log.dead_reckoning_ate == pytest.approx(log.errors.target_ate, rel=1e-3)
    assert ates == sorted(ates)
    assert 2.0 <= ates[0] <= 4.0 and ates[-1] >= 30.0
    metres = generate_log(LogGeneratorConfig(pattern="campus", drift=20.0, duration=600.0))
    assert metres.errors.target_ate == 20.0
    assert metres.dead_reckoning_ate == pytest.approx(20.0, rel=1e-3)
    assert metres.errors.bias != 0 and metres.errors.scale != 0


def test_trailing_loops_lie_after_the_odometry_only_when_asked() -> None:
    plain = generate_log(SHORT)
    assert plain.loops[:, 0].max() <= plain.odometry[-1, 0]
    late = generate_log(LogGeneratorConfig(duration=120.0, trailing_loops=0.2))
    over = late.loops[:, 0].max() - late.odometry[-1, 0]
    assert 0.05 <= over <= 0.2
    assert late.ground_truth[-1, 0] >= late.loops[:, 0].max()
    assert np.array_equal(late.odometry, plain.odometry)


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"pattern": "spiral"}, "unknown pattern 'spiral'; choose from loop, back_and_forth"),
        ({"duration": 10.0}, "duration 10 s is out of range; use 60-14400 s"),
        ({"drift": 0.0}, "drift 0.0 m is out of range; use 0-500 m"),
        ({"drift": "wobbly"}, "drift 'wobbly' is neither a level (low, medium, high, extreme)"),
        ({"seed": True}, "seed True must be a whole number >= 0"),
        ({"false_fraction": math.nan}, "false_fraction nan is not a number"),
        ({"speed": 2.0}, "speed 2 m/s is out of range; use 0.3-1.5 m/s"),
    ],
)
def test_settings_are_validated(changes: dict[str, object], message: str) -> None:
    with pytest.raises(ParameterError) as caught:
        LogGeneratorConfig(**changes)  # type: ignore[arg-type]
    assert str(caught.value).startswith(message)


# ---------------------------------------------------------------------------------- command
def test_make_log_writes_a_log_that_cogmap_run_maps(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    args = ["--speed", "1.5", "--duration", "300", "--false-fraction", "0.25", "--seed", "4"]
    assert main(["make-log", str(tmp_path / "lap"), *args]) == 0
    out = capsys.readouterr().out.splitlines()
    log = generate_log(LogGeneratorConfig(speed=1.5, duration=300.0, false_fraction=0.25, seed=4))
    c = log.counts()
    assert out[0] == f"wrote {tmp_path / 'lap_Input.txt'}, {tmp_path / 'lap_GT.txt'} (tuc)"
    assert f"dead-reckoning ATE {log.dead_reckoning_ate:.2f} m" in out[2]
    assert out[3] == (
        f"  loop candidates: {c['candidates']} from {c['queries']} queries; usable (score >= 0.8, "
        f"not recent) {c['usable']}: {c['true']} true, {c['false']} false "
        f"({100 * c['false'] / c['usable']:.1f} %: {c['structured']} structured, {c['near']} near "
        f"misses, {c['false'] - c['structured'] - c['near']} far)"
    )
    assert len(out) == 4 and c["false"] > 0
    report = tmp_path / "report"
    assert main(["run", str(tmp_path / "lap_Input.txt"), "--out", str(report)]) == 0
    summary = json.loads((report / "summary.json").read_text())
    assert summary["dead_reckoning_ate_m"] == pytest.approx(log.dead_reckoning_ate, rel=0.01)
    source = summary["source"]
    assert source["loop_candidates"] == c["candidates"]
    assert source["links"] + source["duplicates"] == c["usable"]


def test_make_log_refuses_existing_files_and_force_replaces_only_its_own(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    prefix = str(tmp_path / "run")
    short = ["--duration", "60"]
    assert main(["make-log", prefix, *short]) == 0
    mine = {name: (tmp_path / name).read_bytes() for name in ("run_Input.txt", "run_GT.txt")}
    others = {"run_notes.txt": b"notes", "run_odometry.csv": b"time,v,omega\n0,0,0\n"}
    for name, data in others.items():
        (tmp_path / name).write_bytes(data)
    capsys.readouterr()

    assert main(["make-log", prefix, *short, "--seed", "2"]) == 2
    err = capsys.readouterr().err
    assert err == (
        f"cogmap make-log: error: {prefix}_Input.txt, {prefix}_GT.txt already exist; choose "
        "another prefix or pass --force to replace them\n"
    )
    assert {n: (tmp_path / n).read_bytes() for n in mine} == mine

    assert main(["make-log", prefix, *short, "--seed", "2", "--force"]) == 0
    assert all((tmp_path / n).read_bytes() != data for n, data in mine.items())
    assert {n: (tmp_path / n).read_bytes() for n in others} == others
    # CSV: its odometry file is in the way; --force replaces the CSV files only
    assert main(["make-log", prefix, *short, "--format", "csv"]) == 2
    assert "run_odometry.csv already exists" in capsys.readouterr().err
    replaced = {n: (tmp_path / n).read_bytes() for n in ("run_Input.txt", "run_GT.txt")}
    assert main(["make-log", prefix, *short, "--format", "csv", "--force"]) == 0
    assert (tmp_path / "run_odometry.csv").read_text().startswith("time,v,omega\n0.0,0.0,0.0\n0.")
    assert {n: (tmp_path / n).read_bytes() for n in replaced} == replaced
    assert (tmp_path / "run_notes.txt").read_bytes() == b"notes"
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "run_GT.txt",
        "run_Input.txt",
        "run_ground_truth.csv",
        "run_loops.csv",
        "run_notes.txt",
        "run_odometry.csv",
    ]  # no temporary files left


def test_a_prefix_naming_the_main_file_stands_for_its_prefix(tmp_path: Path) -> None:
    assert main(["make-log", str(tmp_path / "hall_Input.txt"), "--duration", "60"]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["hall_GT.txt", "hall_Input.txt"]


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--pattern", "spiral"], "argument --pattern: invalid choice: 'spiral'"),
        (["--format", "xml"], "argument --format: invalid choice: 'xml'"),
        (["--duration", "10"], "duration 10 s is out of range; use 60-14400 s"),
        (["--false-fraction", "0.95"], "false_fraction 0.95 is out of range; use 0-0.9"),
        (["--drift", "wobbly"], "drift 'wobbly' is neither a level"),
        (["--drift", "-3"], "drift -3.0 m is out of range; use 0-500 m"),
        (["--speed", "3"], "speed 3 m/s is out of range; use 0.3-1.5 m/s"),
        (["--seed", "-1"], "seed -1 must be a whole number >= 0"),
        (["--trailing-loops", "1"], "trailing_loops 1 s is out of range; use 0-0.5 s"),
        (["--seed", "x"], "argument --seed: invalid int value: 'x'"),
    ],
)
def test_bad_arguments_are_one_line_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: list[str], message: str
) -> None:
    try:
        code = main(["make-log", str(tmp_path / "run"), *extra])
    except SystemExit as stop:  # argparse's own errors exit
        code = stop.code
    assert code == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith("cogmap make-log: error: ")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("where", ["missing", "folder"])
def test_bad_output_places_are_one_line_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], where: str
) -> None:
    (tmp_path / "logs").mkdir()
    target = tmp_path / "nowhere" / "run" if where == "missing" else tmp_path / "logs"
    assert main(["make-log", str(target), "--duration", "60"]) == 2
    err = capsys.readouterr().err
    expected = (
        f"folder {tmp_path / 'nowhere'} does not exist; create it first"
        if where == "missing"
        else f"{target} is a folder; give a prefix for the files' names, e.g. {target / 'run1'}"
    )
    assert err == f"cogmap make-log: error: {expected}\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["logs"]
    assert list((tmp_path / "logs").iterdir()) == []
