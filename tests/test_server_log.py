"""The web app on a log of odometry and place recognition: same maps, link scores, no camera."""

from __future__ import annotations

import bisect
import re
from pathlib import Path

import pytest

from app.cli import main
from app.server import export
from app.server.export import summary_dict, summary_inputs
from app.server.figures import LinkJudgement, false_link_label, layout_radius_label
from app.server.panels.live_figures import recent_links
from app.server.replay import PlaybackState
from cogmap_core.cognitive_map import MapMode
from cogmap_core.config import MapParams
from cogmap_core.evaluation import EvaluationSettings
from cogmap_core.event_log import EventLog
from cogmap_core.session_file import SessionMeta
from cogmap_core.slam import SlamSession
from cogmap_core.sources import detect
from cogmap_core.sources.detect import open_source
from cogmap_core.sources.odometry_log import LOG_MAP_PARAMS
from tests import test_server_support as support
from tests.test_log_cli import square_run
from tests.test_server_support import assert_same_map, counter, running_app, until, wait

short_bag = support.short_bag


@pytest.fixture(scope="module")
def square_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("server-log")
    lines, truth, _ = square_run(laps=2)
    (folder / "square_Input.txt").write_text("\n".join(lines) + "\n")
    (folder / "square_GT.txt").write_text("\n".join(truth) + "\n")
    return folder / "square_Input.txt"


@pytest.fixture(scope="module")
def reference(square_log: Path) -> SlamSession:
    reader = open_source(square_log)
    session = SlamSession(LOG_MAP_PARAMS, evaluation=reader.evaluation)
    session.run(reader.frames())
    return session


def test_a_log_replays_with_link_scores_and_no_camera(
    square_log: Path, reference: SlamSession
) -> None:
    with running_app(square_log, params=LOG_MAP_PARAMS, defaults=LOG_MAP_PARAMS) as app:
        wait(app)
        r = app.replay
        assert r.state is PlaybackState.ENDED and r.message == "" and not r.has_camera
        assert r.cursor == reference.log.frames == r.total_frames
        for mode in MapMode:
            assert_same_map(r.session.maps[mode], reference.maps[mode])
        compact = reference.maps[MapMode.COMPACT]
        assert counter(app, "compact-ate") == f"{reference.ate(compact):.3f}"
        assert not app.camera_image.visible
        links = reference.log.link_table()
        shown = re.findall(
            r"<tr><td>([\d.]+)</td><td>(\d+)</td><td>([\d.]+)</td></tr>", app.links_html.content
        )
        expected = recent_links(reference.log, reference.log.frames, 8)
        assert len(shown) == 8 and expected[-1][:2] == links[-1][:2]
        assert [(float(t), int(v), float(s)) for t, v, s in shown] == [
            (round(t, 1), v, round(s, 3)) for t, v, s in reversed(expected)
        ]
        assert {s for _, _, s in expected} <= {0.9, 0.95}  # the place recognition's scores
        with r.lock:
            summary = summary_dict(summary_inputs(r))
        assert summary["source"]["format"] == "tuc"
        assert summary["maps"]["compact"]["vertices"] == compact.num_vertices
        assert summary["loop_closures"]["tolerance_deg"] is None
        assert [f["score"] for f in summary["loop_closures"]["false_links"]] == [0.95]
        # a slider and "reset to defaults" rebuild from the cached events
        app.param_sliders["alpha"].value = 10.0
        wait(app)
        expected_maps = reference.rebuild(LOG_MAP_PARAMS.with_changes(alpha=10.0))
        assert_same_map(r.session.maps[MapMode.COMPACT], expected_maps[MapMode.COMPACT])
        assert app.reset_button.label == "reset to defaults"
        app.reset_params()
        wait(app)
        assert r.params == LOG_MAP_PARAMS
        assert_same_map(r.session.maps[MapMode.COMPACT], compact)
        # seeking replays the steps from the cache
        r.pause()  # (a seek while playing plays on from there)
        app.seek_slider.value = 100.0
        wait(app)
        k = bisect.bisect_right(reference.log.frame_time, 100.0)
        assert r.cursor == k
        partial = reference.rebuild(LOG_MAP_PARAMS, frames=k, finish=False)
        for mode in MapMode:
            assert_same_map(r.session.maps[mode], partial[mode])


def test_serve_refuses_a_bad_log_before_starting(tmp_path: Path, capsys) -> None:
    empty = tmp_path / "empty_Input.txt"
    empty.write_text("")
    assert main(["serve", str(empty), "--port", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"cogmap serve: error: {empty}: the file is empty; nothing to map"]
    odometry = tmp_path / "run_odometry.csv"
    odometry.write_text("0,1,0\n")
    assert main(["serve", str(odometry), "--frontend", "score_threshold=2"]) == 2
    assert "score_threshold=2.0 is out of range" in capsys.readouterr().err


def test_a_session_is_refused_on_a_log_with_one_message(
    square_log: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    said = (
        f"--resume: sessions are for bags; {square_log} is a log of odometry and place "
        "recognition (tuc): serve it without --resume"
    )
    session = tmp_path / "s.npz"
    session.write_bytes(b"not read: refused first")
    assert main(["serve", str(square_log), "--resume", str(session), "--port", "1"]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [f"cogmap serve: error: {said}"]
    # the app, given a session by a script, refuses it the same way when it opens the log
    resumed = (SlamSession(LOG_MAP_PARAMS), SessionMeta())
    with running_app(square_log, params=LOG_MAP_PARAMS, resume=resumed) as app:
        until(lambda: app.replay.state is PlaybackState.ERROR)
        assert app.replay.message == said


def test_the_page_and_the_replay_judge_a_log_with_its_own_tolerances(
    square_log: Path, reference: SlamSession, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    assert layout_radius_label(reference.evaluation) == "50 cm"
    assert false_link_label(reference.evaluation) == "position 1 m"
    assert layout_radius_label(EvaluationSettings()) == "8 cm"
    assert false_link_label(EvaluationSettings()) == "position 0.1 m, heading 10°"
    judged: list[EvaluationSettings | None] = []
    real = export.judge_links

    def spy(log: EventLog, judging: EvaluationSettings | None = None) -> LinkJudgement:
        judged.append(judging)
        return real(log, judging)

    monkeypatch.setattr(export, "judge_links", spy)
    with running_app(square_log, params=LOG_MAP_PARAMS, defaults=LOG_MAP_PARAMS) as app:
        wait(app)
        export.save_html_replay(app.replay, (MapMode.COMPACT,), tmp_path / "r.html", 3, 0.1)
    assert judged == [reference.evaluation]


def test_opening_a_bag_after_a_log_shows_the_camera_and_the_bag_defaults(
    square_log: Path, short_bag: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    folders = [square_log.parent, short_bag.parent]  # the bag is one of the data folders'
    with running_app(
        square_log, params=LOG_MAP_PARAMS, defaults=LOG_MAP_PARAMS, data_dirs=folders
    ) as app:
        wait(app)
        assert not app.camera_image.visible and "cogmap-links" in app.links_html.content

        def sniffed(path: object) -> str:
            raise AssertionError(f"{path} sniffed again")

        # open_bag opened it as a bag: the new replay is told so, not left to sniff the file
        monkeypatch.setattr(detect, "detect_format", sniffed)
        listed = f"{short_bag.parent.name}/{short_bag.name}"  # (two folders: named by folder)
        assert listed in app.refresh_bags()
        assert app.open_bag(listed)
        wait(app)
        assert app.replay.format == "bag" and app.replay.message == ""
        assert app.replay.has_camera and app.camera_image.visible
        assert app.links_html.content == ""
        # the log's parameters (alpha 2.746, link sigma 0.5 m, ...) are not carried to a bag
        assert app.replay.params == MapParams() == app.defaults
        assert app.param_sliders["alpha"].value == MapParams().alpha
        assert app.reset_button.label == "reset to paper values"
