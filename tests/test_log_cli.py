"""``cogmap run`` on logs of odometry and place recognition: report, settings, bad input."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from app.cli import main
from cogmap_core.cognitive_map import MapMode
from cogmap_core.event_file import load_event_file
from cogmap_core.slam import SlamSession
from cogmap_core.sources.detect import open_source
from cogmap_core.sources.odometry_log import LOG_MAP_PARAMS
from tests.test_faults import snapshot

DT = 0.1
SIDE_SAMPLES = 160  # 8 m at 0.5 m/s
TURN_SAMPLES = 20  # 90 degrees in 2 s
LAP = 4 * (SIDE_SAMPLES + TURN_SAMPLES)  # 72 s
YAW_BIAS = 0.01  # rad/s of gyro bias: dead reckoning drifts metres in three laps


def square_run(laps: int = 3) -> tuple[list[str], list[str], int]:
    """A robot lapping an 8 m square: TUC input lines, ground-truth lines, false loops."""
    x = y = th = 0.0
    odometry, truth = [], []
    n = laps * LAP
    for k in range(n + 1):
        t = k * DT
        v = w = 0.0
        if k > 0:
            phase = (k - 1) % (SIDE_SAMPLES + TURN_SAMPLES)
            if phase < SIDE_SAMPLES:
                v = 0.5
            else:
                w = (math.pi / 2) / (TURN_SAMPLES * DT)
            th += w * DT
            x += v * DT * math.cos(th)
            y += v * DT * math.sin(th)
        odometry.append(f"odom2 {t:.1f} {v:g} 0 {w + YAW_BIAS if k else 0:.9f} 0 0 0")
        if k % 2 == 0:
            truth.append(f"point2 {t:.1f} {x:.9f} {y:.9f} 0 0 0 0")
            truth.append(f"angle {t:.1f} {th:.9f} 0")
    loops = []
    for k in range(LAP + 25, n + 1, 25):  # a place-recognition query every 2.5 s
        loops.append(f"loop {k * DT:.1f} {(k - LAP) * DT:.1f} 0.9")  # the previous lap
    false = [f"loop {n * DT - 20:.1f} {LAP * DT / 2:.1f} 0.95"]  # across the square
    return odometry + loops + false, truth, len(false)


@pytest.fixture(scope="module")
def square_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("logs")
    lines, truth, _ = square_run()
    (folder / "square_Input.txt").write_text("\n".join(lines) + "\n")
    (folder / "square_GT.txt").write_text("\n".join(truth) + "\n")
    return folder / "square_Input.txt"


@pytest.fixture(scope="module")
def report(square_log: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("runs") / "report"
    assert main(["run", str(square_log), "--out", str(out)]) == 0
    return out


def test_report_of_a_log(report: Path, square_log: Path) -> None:
    summary = json.loads((report / "summary.json").read_text())
    reference = SlamSession(LOG_MAP_PARAMS, evaluation=open_source(square_log).evaluation)
    reference.run(open_source(square_log).frames())
    assert summary["source"]["format"] == "tuc"
    assert summary["source"]["ground_truth"] == str(square_log.with_name("square_GT.txt"))
    assert summary["source"]["links"] == reference.maps[MapMode.STANDARD].counters.links
    assert summary["frames"] == reference.log.frames == 3 * LAP + 1
    assert summary["params"]["alpha"] == LOG_MAP_PARAMS.alpha
    assert summary["layout_radius_m"] == 0.5
    assert summary["read_warnings"] == {}
    loops = summary["loop_closures"]
    # every query of laps 2 and 3 (one link each) and the false match across the square
    assert loops["total"] == (2 * LAP) // 25 + 1
    assert (loops["false"], loops["tolerance_m"], loops["tolerance_deg"]) == (1, 1.0, None)
    (false,) = loops["false_links"]
    assert false["score"] == 0.95 and false["position_error_m"] > 5.0
    dr = summary["dead_reckoning_ate_m"]
    assert dr == pytest.approx(reference.log.dead_reckoning_ate()) and dr > 1.0
    for mode in MapMode:
        entry = summary["maps"][mode.value]
        cmap = reference.maps[mode]
        assert (entry["vertices"], entry["edges"]) == (cmap.num_vertices, cmap.num_edges)
        assert entry["ate_m"] == pytest.approx(reference.ate(cmap), abs=1e-6)
        assert entry["ate_m"] < 0.25 * dr  # the Huber loss absorbs the false match
        assert entry["completeness"] >= 0.9 and entry["correctness"] >= 0.95  # corners cut
    standard, compact = summary["maps"]["standard"], summary["maps"]["compact"]
    assert compact["vertices"] < 0.25 * standard["vertices"]
    assert summary["maps"]["scene_integration"]["integrated"] > 0  # laps 2, 3 merged
    config = json.loads((report / "config.json").read_text())
    assert config["format"] == "tuc" and config["frontend"]["score_threshold"] == 0.8
    assert config["map"] == LOG_MAP_PARAMS.to_dict()
    gt = np.loadtxt(report / "groundtruth_tum.txt")
    assert gt.shape == (standard["vertices"], 8)


def test_a_logs_events_can_be_saved(square_log: Path, tmp_path: Path) -> None:
    events = tmp_path / "square.events.npz"
    assert (
        main(["run", str(square_log), "--out", str(tmp_path / "r"), "--save-events", str(events)])
        == 0
    )
    reference = SlamSession(LOG_MAP_PARAMS, evaluation=open_source(square_log).evaluation)
    reference.run(open_source(square_log).frames())
    saved = load_event_file(events)
    assert saved.events == list(reference.log.events)
    assert saved.frames == reference.log.frames and saved.frontend == {}
    assert saved.meta["input_format"] == "tuc"


def test_a_sweep_refuses_a_logs_events(square_log: Path, tmp_path: Path, capsys) -> None:
    """A log's saved events would be swept with a bag's settings and radius: refused."""
    events = tmp_path / "square.events.npz"
    assert (
        main(["run", str(square_log), "--out", str(tmp_path / "r"), "--save-events", str(events)])
        == 0
    )
    capsys.readouterr()
    assert main(["sweep", str(events), "--out", str(tmp_path / "s"), "--delta", "3,6"]) != 0
    assert capsys.readouterr().err.strip() == (
        f"cogmap sweep: error: {events}: these events were recorded from a tuc odometry log, "
        "whose maps are set and judged differently; a sweep takes bags and their event files"
    )


def test_settings_from_the_command_line(square_log: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "run"
    args = ["run", str(square_log), "--out", str(out), "--frontend", "score_threshold=0.92"]
    assert main([*args, "--alpha", "5", "--no-ground-truth"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["source"]["links"] == 1  # only the false match scores above 0.92
    assert summary["params"]["alpha"] == 5.0 and summary["params"]["t_interval"] == 5.0
    assert summary["dead_reckoning_ate_m"] is None and summary["loop_closures"]["true"] is None
    capsys.readouterr()


def test_param_options_override_the_log_defaults(square_log: Path, tmp_path: Path) -> None:
    """--param NAME=VALUE and the paper's flags change the log's defaults, nothing else."""
    out = tmp_path / "run"
    args = ["run", str(square_log), "--out", str(out), "--param", "integration_radius=0.3"]
    assert main([*args, "--beta", "12"]) == 0
    config = json.loads((out / "config.json").read_text())
    expected = LOG_MAP_PARAMS.with_changes(integration_radius=0.3, beta=12.0)
    assert config["map"] == expected.to_dict()
    assert config["map"]["alpha"] == LOG_MAP_PARAMS.alpha  # still the log's default
    # a --params table: the parameters it names, the log's defaults for the others
    table = tmp_path / "p.json"
    table.write_text('{"delta": 4.5, "t_total": 80}')
    again = tmp_path / "again"
    assert main(["run", str(square_log), "--out", str(again), "--params", str(table)]) == 0
    config = json.loads((again / "config.json").read_text())
    assert config["map"] == LOG_MAP_PARAMS.with_changes(delta=4.5, t_total=80.0).to_dict()


def test_a_log_report_is_staged_like_a_bag_report(square_log: Path, tmp_path: Path) -> None:
    """The report marker is written; --force replaces only the report's own files."""
    out = tmp_path / "run"
    assert main(["run", str(square_log), "--out", str(out)]) == 0
    assert (out / ".cogmap-report").is_file()
    mine = out / "notes.txt"
    mine.write_text("keep me")
    before = snapshot(out)
    assert main(["run", str(square_log), "--out", str(out)]) == 2  # not empty: needs --force
    assert snapshot(out) == before
    # another delta, so that the rewritten summary.json must differ from the old one
    assert main(["run", str(square_log), "--out", str(out), "--force", "--delta", "5"]) == 0
    assert mine.read_text() == "keep me" and (out / "summary.json").is_file()
    after = snapshot(out)
    assert set(after) == set(before)
    assert after["summary.json"] != before["summary.json"]
    assert json.loads(after["summary.json"])["params"]["delta"] == 5.0  # type: ignore[arg-type]


def test_an_empty_ground_truth_file_is_a_warning(tmp_path: Path, capsys) -> None:
    log = write(tmp_path / "e_Input.txt", ODOM)
    write(tmp_path / "e_GT.txt", ["# no positions"])
    out = tmp_path / "run"
    assert main(["run", str(log), "--out", str(out)]) == 0
    said = f"warning: {tmp_path / 'e_GT.txt'}: no ground truth in the file; the report has no"
    assert any(line.startswith(said) for line in capsys.readouterr().out.splitlines())
    assert json.loads((out / "summary.json").read_text())["dead_reckoning_ate_m"] is None


def test_sessions_are_refused_for_logs(square_log: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "run"
    session = tmp_path / "s.npz"
    for flag in ("--save-session", "--resume"):
        if flag == "--resume":
            assert not session.exists()  # --save-session wrote nothing
            session.write_bytes(b"anything")
        code = main(["run", str(square_log), "--out", str(out), flag, str(session)])
        lines = capsys.readouterr().err.splitlines()
        assert code == 2 and len(lines) == 1, lines
        assert f"{flag}: sessions are for bags" in lines[0]
        assert not out.exists()
    assert session.read_bytes() == b"anything"
    assert main(["serve", str(square_log), "--resume", str(session), "--port", "1"]) == 2
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln]
    assert len(lines) == 1 and "--resume: sessions are for bags" in lines[0], lines


def write(path: Path, lines: list[str]) -> Path:
    path.write_text("".join(line + "\n" for line in lines))
    return path


ODOM = [f"odom2 {k / 10:.1f} 0.5 0 0 0 0 0" for k in range(50)]


def _fake_bag(path: Path) -> Path:
    """A file that a bag's first line makes a bag (never read further in these tests)."""
    path.write_bytes(b"#ROSBAG V2.0\n" + bytes(100))
    return path


def _binary(path: Path) -> Path:
    """A file that starts like a TUC log and then holds bytes that are not UTF-8."""
    path.write_bytes(b"odom2 0 0 0 0 0.1 0.1 0.1\n\xff\xfe\x00 binary\n")
    return path


def bad_inputs(tmp: Path, square_log: Path) -> list[tuple[str, list[str], str]]:
    """(case, arguments after 'run FILE --out DIR' prefix, expected message part)."""
    partial = write(tmp / "partial_GT.txt", [f"point2 {k} 0 0 0 0 0 0" for k in range(3)])
    other = write(tmp / "other_GT.txt", [f"point2 {k} 0 0 0 0 0 0" for k in range(90, 99)])
    return [
        (
            "malformed line",
            [str(write(tmp / "a.txt", [*ODOM[:3], "odom2 0.3 0.5 0 0"]))],
            "a.txt:4: each 'odom2' line has 7 numbers after the type, this one 4",
        ),
        (
            "odometry going backwards",
            [str(write(tmp / "b.txt", [ODOM[0], ODOM[2], ODOM[1]]))],
            "b.txt:3: odometry time 0.100000 s is earlier than the previous (0.200000 s)",
        ),
        (
            "loop with a score out of range",
            [str(write(tmp / "c.txt", [*ODOM, "loop 4 1 1.2"]))],
            "c.txt:51: loop score 1.2 is outside [0, 1] (1 = most similar)",
        ),
        (
            "only comments",
            [str(write(tmp / "n.txt", ["# odometry to follow", ""]))],
            "n.txt: the file holds only comments and blank lines; nothing to map",
        ),
        (
            "NaN value",
            [str(write(tmp / "d.txt", [*ODOM[:5], "odom2 0.5 nan 0 0 0 0 0"]))],
            "d.txt:6: odometry v is nan",
        ),
        ("empty file", [str(write(tmp / "e.txt", []))], "e.txt: the file is empty"),
        (
            "ground truth of another run",
            [str(write(tmp / "f.txt", ODOM)), "--ground-truth", str(other)],
            "other_GT.txt: ground truth covers 90.000-98.000 s, the odometry 0.000-4.900 s",
        ),
        (
            "CSV with a broken row",
            [str(write(tmp / "g_odometry.csv", ["time,v,omega", "0,1,0", "1,1"]))],
            "g_odometry.csv:3: 2 columns; odometry files have 3 (time,v,omega)",
        ),
        (
            "--loops with a TUC file",
            [str(square_log), "--loops", str(tmp / "x.csv")],
            "--loops belongs to CSV logs",
        ),
        (
            "typo in a measurement type after the sniffed lines' first",
            [str(write(tmp / "i.txt", [*ODOM[:2], "odm2 0.2 0.5 0 0 0 0 0", *ODOM[3:]]))],
            "i.txt:3: unknown measurement type 'odm2'",
        ),
        (
            "relocalise that is not 0 or 1",
            [str(square_log), "--frontend", "relocalise=nan"],
            "log source setting relocalise=nan must be 0 or 1",
        ),
        (
            "unknown log setting",
            [str(square_log), "--frontend", "threshold=0.5"],
            "unknown log source setting(s) ['threshold']",
        ),
        (
            "--ground-truth with a bag",
            [str(_fake_bag(tmp / "m.bag")), "--ground-truth", str(partial)],
            "--loops and --ground-truth belong to logs; a bag's ground truth is a topic",
        ),
        (
            "a binary file read with --format",
            [str(_binary(tmp / "j.txt")), "--format", "tuc"],
            "j.txt: not a text file; expected TUC measurement lines",
        ),
        (
            "a --loops file that does not exist",
            [str(write(tmp / "k_odometry.csv", ["time,v,omega", "0,0,0", "1,0.1,0"]))]
            + ["--loops", str(tmp / "missing_loops.csv")],
            "missing_loops.csv: no such file",
        ),
        (
            "a --params file that is not JSON",
            [str(write(tmp / "l.txt", ODOM)), "--params", str(write(tmp / "p.json", ["{bad"]))],
            "p.json: not a readable JSON file",
        ),
        (
            "partial ground truth is only a warning",
            [str(write(tmp / "h.txt", ODOM)), "--ground-truth", str(partial)],
            "warning: " + str(partial) + ": ground truth covers 0.0-2.0 s of the 0.0-4.9 s run",
        ),
    ]


def test_bad_input_is_one_line_and_exit_2(tmp_path: Path, square_log: Path, capsys) -> None:
    for case, args, message in bad_inputs(tmp_path, square_log):
        out = tmp_path / f"out-{case.replace(' ', '-')}"
        code = main(["run", *args[:1], "--out", str(out), *args[1:]])
        captured = capsys.readouterr()
        err = captured.err
        lines = err.splitlines()
        if case.startswith("partial"):
            assert code == 0, case
            # printed after the table like a bag's reader warnings
            assert any(line.startswith(message) for line in captured.out.splitlines()), case
            summary = json.loads((out / "summary.json").read_text())
            assert summary["dead_reckoning_ate_m"] is None
            continue
        assert code == 2, (case, err)
        assert len(lines) == 1 and message in lines[0], (case, err)
        assert lines[0].startswith("cogmap run: error: ")
        assert not out.exists(), case


def run_log(tmp: Path, name: str, data: bytes, capsys) -> tuple[int, list[str], dict]:
    """``cogmap run`` on a log written as ``data``: exit code, warning lines, summary."""
    path = tmp / name
    path.write_bytes(data)
    out = tmp / f"out-{name}"
    code = main(["run", str(path), "--out", str(out)])
    printed = capsys.readouterr().out.splitlines()
    warnings = [line.removeprefix("warning: ") for line in printed if line.startswith("warning:")]
    summary = json.loads((out / "summary.json").read_text()) if code == 0 else {}
    return code, warnings, summary


LONG = [f"odom2 {k / 10:.1f} 0.5 0 0 0 0 0" for k in range(300)]  # 15 m straight in 29.9 s


def test_a_log_with_loops_at_its_edges_is_mapped(tmp_path: Path, capsys) -> None:
    """Real logs end with loop candidates just after the last odometry line, match their own
    view, or state the later time second: all refused today; now used or dropped and counted."""
    loops = [
        "loop 30.1 2 0.9",  # 0.2 s after the last odometry: moved onto it, linked
        "loop 40 2 0.9",  # 10 s after: dropped
        "loop 20 -0.5 0.9",  # matches 0.5 s before the data: moved onto it, linked
        "loop 10 10 0.9",  # matches its own view: dropped
        "loop 5 25 0.9",  # the later time second: swapped, linked
    ]
    path = tmp_path / "edges_Input.txt"
    code, warnings, summary = run_log(
        tmp_path, path.name, ("\n".join(LONG + loops) + "\n").encode(), capsys
    )
    assert code == 0
    assert warnings == [
        f"1 x loop candidate matching a view less than 1 s from its own: dropped (first at "
        f"{path}:304)",
        f"1 x loop candidate matching a later time: the two swapped (the later view matches the "
        f"earlier place) (first at {path}:305)",
        f"2 x loop candidate with a time up to 1 s outside the odometry (0.000-29.900 s): moved "
        f"onto it (first at {path}:301)",
        f"1 x loop candidate with a time more than 1 s outside the odometry (0.000-29.900 s): "
        f"dropped (first at {path}:302)",
    ]
    assert summary["read_warnings"] == {"warnings": warnings}
    source = summary["source"]
    assert (source["loops_same_view"], source["loops_swapped"]) == (1, 1)
    assert (source["loops_clamped"], source["loops_outside"]) == (2, 1)
    assert (source["loop_candidates"], source["links"]) == (4, 3)
    assert summary["loop_closures"]["total"] == 3


def test_a_log_with_a_bom_and_crlf_is_detected_and_mapped(tmp_path: Path, capsys) -> None:
    body = "\r\n".join(line + " \t" for line in [*LONG, "loop 25 5 0.9"])
    code, warnings, summary = run_log(
        tmp_path, "bom_Input.txt", b"\xef\xbb\xbf" + body.encode() + b"\r\n", capsys
    )
    assert (code, warnings) == (0, [])
    assert summary["frames"] == 300 and summary["source"]["links"] == 1


def test_a_log_without_loops_is_mapped_with_a_warning(tmp_path: Path, capsys) -> None:
    code, warnings, summary = run_log(
        tmp_path, "solo_Input.txt", ("\n".join(LONG) + "\n").encode(), capsys
    )
    assert code == 0
    assert warnings == [
        f"{tmp_path / 'solo_Input.txt'}: no loop candidates: the map is its odometry"
    ]
    assert summary["maps"]["standard"]["vertices"] > 1 and summary["source"]["links"] == 0
