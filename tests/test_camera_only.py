"""Camera-only input: RatSLAM's visual odometry, videos, image folders, bags without odometry."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from app.cli import main
from cogmap_core.datasets import MazeConfig
from cogmap_core.datasets.bag_writer import IratBagWriter
from cogmap_core.datasets.camera_writer import GENERATED_CAMERA_PROFILE, generate_camera_only
from cogmap_core.datasets.image_folder import open_image_folder
from cogmap_core.datasets.rosbag_reader import open_bag
from cogmap_core.datasets.video_reader import open_video
from cogmap_core.errors import InputFileError, ParameterError
from cogmap_core.frames import Frame
from cogmap_core.frontend import FrontEndConfig
from cogmap_core.frontend.visual_odometry import VisualOdometry, best_shift, with_visual_odometry
from cogmap_core.sources.detect import detect_format
from tests import test_server_support as server_support

LOOP = """\
; cell: 0.3
#########
#A.....B#
#.#####.#
#D.....C#
#########
"""
T0 = 1_700_000_000 * 10**9


def panorama(width: int = 600, seed: int = 3) -> np.ndarray:
    """A 240-row texture wider than a view: columns of random grey, smoothed."""
    rng = np.random.default_rng(seed)
    row = np.convolve(rng.random(width + 8), np.ones(5) / 5, mode="valid")[:width]
    row = (30 + 200 * (row - row.min()) / (row.max() - row.min())).astype(np.uint8)
    return np.repeat(row[None, :], 240, axis=0)


def view(pano: np.ndarray, start: int) -> np.ndarray:
    """The 416-column image from column ``start`` of the panorama."""
    return np.ascontiguousarray(pano[:, start : start + 416])


# ----------------------------------------------------------------------------- the odometry
def test_best_shift_finds_the_shift_both_ways_first_minimum_first() -> None:
    rng = np.random.default_rng(0)
    a = rng.random(460)
    assert best_shift(a[:416], a[5:421]) == (0.0, 5)  # the scene moved right: +5
    assert best_shift(a[5:421], a[:416]) == (0.0, -5)
    assert best_shift(a[:416], a[:416]) == (0.0, 0)
    flat = np.full(100, 0.5)
    assert best_shift(flat, flat) == (0.0, 0)  # every shift ties: the first, -0, wins
    difference, shift = best_shift(a[:416] + 0.01, a[:416])
    assert shift == 0 and difference == pytest.approx(0.01)


@pytest.mark.parametrize(("hz", "dt"), [(0.0, 0.1), (0.0, 0.37), (10.0, 0.1)])
def test_a_shifted_view_is_a_turn_of_shift_times_fov_over_width(hz: float, dt: float) -> None:
    config = FrontEndConfig(camera_fov_deg=52.0, camera_hz=hz, vtrans_scaling=100.0)
    vo = VisualOdometry(config)
    pano = panorama()
    assert vo.step(view(pano, 100), 0.0) == (0.0, 0.0)  # the first frame: no motion
    translation, rotation = vo.step(view(pano, 93), dt)  # the scene moved 7 columns right
    assert rotation == pytest.approx(7 * math.radians(52.0) / 416)
    assert translation == 0.0  # the same profile, shifted: no difference
    _, rotation = vo.step(view(pano, 103), dt)  # 10 columns left: clockwise
    assert rotation == pytest.approx(-10 * math.radians(52.0) / 416)


def test_speed_is_the_profile_difference_scaled_and_capped() -> None:
    vo = VisualOdometry(FrontEndConfig(vtrans_scaling=50.0, vtrans_max=20.0))
    image = np.full((240, 416), 100, dtype=np.uint8)
    vo.step(image, 0.0)
    translation, rotation = vo.step(image + 10, 0.2)  # every column 10/255 brighter
    assert rotation == 0.0
    assert translation == pytest.approx(10 / 255 * 50.0 * 0.2)
    vo = VisualOdometry(FrontEndConfig(vtrans_scaling=50.0, vtrans_max=1.5))
    vo.step(image, 0.0)
    assert vo.step(image + 10, 0.2)[0] == pytest.approx(1.5 * 0.2)


def test_the_strips_are_given_in_reference_pixels() -> None:
    config = FrontEndConfig(vrot_image_y_min=0, vrot_image_y_max=120, vtrans_image_x_max=208)
    vo = VisualOdometry(config)
    image = np.zeros((120, 208), dtype=np.uint8)  # decoded at half size
    image[:60, :] = 200  # the rotation strip (rows 0-59 at this size) is bright
    vtrans, vrot = vo.profiles(image)
    assert len(vtrans) == 104 and len(vrot) == 208
    assert np.allclose(vrot, 200 / 255) and np.allclose(vtrans, 100 / 255)
    with pytest.raises(InputFileError, match="too small for visual odometry"):
        vo.profiles(np.zeros((24, 60), dtype=np.uint8))
    with pytest.raises(ParameterError, match="vtrans_image_x_min"):
        FrontEndConfig(vtrans_image_x_min=300, vtrans_image_x_max=200)


def test_frames_get_the_cameras_motion_as_one_step() -> None:
    pano = panorama()
    frames = [Frame(k, 0.1 * k, view(pano, 100 - 4 * k), 9.0, 9.0) for k in range(4)]
    out = list(with_visual_odometry(frames, FrontEndConfig(camera_fov_deg=41.6)))
    assert [f.rotation for f in out] == pytest.approx([0.0] + [4 * math.radians(0.1)] * 3)
    assert out[0].odometry_steps.shape == (0, 2)  # the first frame starts the clock
    assert out[1].odometry_steps.tolist() == [[out[1].translation, out[1].rotation]]


# ----------------------------------------------------------------------------- image folders
def image_folder(tmp_path: Path, n: int = 6, times: bool = True, truth: bool = True) -> Path:
    folder = tmp_path / "cam"
    folder.mkdir()
    pano = panorama()
    for k in range(n):
        cv2.imwrite(str(folder / f"f{k:03d}.png"), view(pano, 100 - 3 * k))
    if times:
        (folder / "times.txt").write_text("".join(f"{5.0 + 0.2 * k}\n" for k in range(n)))
    if truth:
        rows = "".join(f"{5.0 + 0.5 * k} {0.1 * k} 0 {0.05 * k}\n" for k in range(n))
        (folder / "groundtruth.txt").write_text("# t x y th\n" + rows)
    return folder


def test_an_image_folder_streams_frames_with_times_truth_and_visual_odometry(
    tmp_path: Path,
) -> None:
    folder = image_folder(tmp_path)
    assert detect_format(folder) == "images"
    config = FrontEndConfig(camera_fov_deg=41.6)
    with open_image_folder(folder, frontend=config) as reader:
        assert (reader.info.frame_count, reader.info.width, reader.info.height) == (6, 416, 240)
        assert reader.info.duration == pytest.approx(1.0) and reader.info.has_ground_truth
        frames = list(reader.frames())
    assert [f.time for f in frames] == pytest.approx([0.2 * k for k in range(6)])
    # truth at 5.0 + 0.5 k: frame 1 (5.2 s) lies 0.4 of the way to the second pose
    assert frames[1].ground_truth == pytest.approx((0.04, 0.0, 0.02))
    assert [f.rotation for f in frames[1:]] == pytest.approx([3 * math.radians(0.1)] * 5)
    with open_image_folder(folder, fps=20.0) as reader:  # the times file wins over --fps
        assert reader.info.times_from == "times file"


def test_an_image_folder_takes_fps_without_a_times_file(tmp_path: Path) -> None:
    folder = image_folder(tmp_path, times=False, truth=False)
    with open_image_folder(folder, fps=4.0) as reader:
        assert [f.time for f in reader.frames()] == pytest.approx([0.25 * k for k in range(6)])
        assert reader.info.times_from == "--fps" and not reader.info.has_ground_truth


def test_an_undecodable_image_is_skipped_and_counted(tmp_path: Path) -> None:
    folder = image_folder(tmp_path)
    (folder / "f002.png").write_bytes(b"not an image")
    with open_image_folder(folder) as reader:
        frames = list(reader.frames())
        assert len(frames) == 5 and reader.counters.undecodable_images == 1
        assert reader.warnings == ["1 x image that does not decode skipped (first at 0.40 s)"]


# ----------------------------------------------------------------------------- bad input
def _run_error(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_bad_camera_inputs_are_one_line_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = str(tmp_path / "report")
    garbage = tmp_path / "garbage.mp4"
    garbage.write_bytes(b"\x00" * 1000)
    message = _run_error(["run", str(garbage), "--out", out], capsys)
    unreadable = "not a video OpenCV can read (damaged, or an unknown format)"
    assert message == f"cogmap run: error: {garbage}: {unreadable}"
    empty = tmp_path / "empty.avi"
    writer = cv2.VideoWriter(str(empty), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (416, 240), False)
    writer.release()
    message = _run_error(["run", str(empty), "--out", out], capsys)
    assert message == f"cogmap run: error: {empty}: the video has no frames; nothing to map"
    nothing = tmp_path / "nothing"
    nothing.mkdir()
    (nothing / "notes.txt").write_text("no images here")
    message = _run_error(["run", str(nothing), "--format", "images", "--out", out], capsys)
    suffixes = ".png, .jpg, .jpeg, .bmp, .pgm, .ppm, .tif, .tiff"
    assert message == f"cogmap run: error: {nothing}: no images in it ({suffixes}); nothing to map"
    folder = image_folder(tmp_path, times=False)
    message = _run_error(["run", str(folder), "--out", out], capsys)
    assert message == (
        f"cogmap run: error: {folder}: no frame times: give the camera's rate (--fps) or a "
        "times.txt in it (one time in s per image)"
    )
    (folder / "times.txt").write_text("0.0\n0.1\n")
    message = _run_error(["run", str(folder), "--out", out], capsys)
    assert "2 frame times for the 6 frames" in message
    (folder / "times.txt").write_text("0.0\n0.1\n0.05\n0.3\n0.4\n0.5\n")
    message = _run_error(["run", str(folder), "--out", out], capsys)
    assert (
        message
        == f"cogmap run: error: {folder / 'times.txt'}:3: time 0.05 is not finite or goes back"
    )
    message = _run_error(["run", str(folder), "--fps", "-3", "--out", out], capsys)
    assert "--fps -3" in message
    message = _run_error(["run", str(folder), "--odometry", "wheel", "--out", out], capsys)
    assert "camera only" in message
    assert not Path(out).exists()


# ----------------------------------------------------------------------------- bags
def test_a_bag_without_odometry_uses_the_cameras(tmp_path: Path) -> None:
    pano = panorama()
    path = tmp_path / "camera_only.bag"
    with IratBagWriter(path) as bag:
        for k in range(5):
            ok, buf = cv2.imencode(".jpg", view(pano, 100 - 2 * k), [cv2.IMWRITE_JPEG_QUALITY, 100])
            bag.write_image(T0 + k * 10**8, buf.tobytes())
    config = FrontEndConfig(camera_fov_deg=41.6)
    with open_bag(path, frontend=config) as reader:
        assert reader.visual_odometry
        frames = list(reader.frames())
    assert len(frames) == 5
    assert [f.rotation for f in frames[1:]] == pytest.approx([2 * math.radians(0.1)] * 4, abs=1e-4)
    with pytest.raises(Exception, match="no odometry topic"):
        open_bag(path, odometry="wheel")


def test_bag_frames_carry_each_odometry_message(tmp_path: Path) -> None:
    from tests.test_dataset_reader import simple_bag

    with open_bag(simple_bag(tmp_path / "b.bag"), odometry="wheel") as reader:
        frames = list(reader.frames())
    for frame in frames:
        steps = frame.odometry_steps
        assert steps is not None and steps.shape[1] == 2
        assert steps[:, 0].sum() == pytest.approx(frame.translation)
        assert steps[:, 1].sum() == pytest.approx(frame.rotation)
    assert [len(f.odometry_steps) for f in frames[:3]] == [1, 2, 2]  # every 0.1 s, frames 0.2 s


# ----------------------------------------------------------------------------- end to end
@pytest.fixture(scope="module")
def tiny_camera(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("camera")
    layout = folder / "loop.txt"
    layout.write_text(LOOP)
    return folder


@pytest.mark.parametrize("name", ["loop_images", "loop.avi"])
def test_make_maze_camera_only_then_run_it(
    tiny_camera: Path, name: str, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tiny_camera / name
    argv = ["make-maze", str(out), "--camera-only", "--layout", str(tiny_camera / "loop.txt")]
    assert main([*argv, "--laps", "1", "--fps", "5", "--quiet"]) == 0
    said = capsys.readouterr().out
    assert f"wrote {out} (camera only:" in said
    stem = out.stem if out.suffix else out.name
    profile = json.loads((tiny_camera / f"{stem}.frontend.json").read_text())
    assert profile["frontend"] == GENERATED_CAMERA_PROFILE
    times = out / "times.txt" if out.is_dir() else tiny_camera / f"{stem}.times.txt"
    truth = out / "groundtruth.txt" if out.is_dir() else tiny_camera / f"{stem}.groundtruth.txt"
    assert times.exists() and truth.exists()
    assert main(["make-maze", str(out), "--camera-only", "--quiet"]) == 2  # exists: not replaced
    report = tiny_camera / f"report_{stem}"
    assert main(["run", str(out), "--out", str(report)]) == 0
    summary = json.loads((report / "summary.json").read_text())
    assert summary["source"]["format"] == ("images" if out.is_dir() else "video")
    assert summary["source"]["odometry"] == "visual"
    assert summary["frames"] == len(times.read_text().split())
    assert summary["dead_reckoning_ate_m"] is not None  # the ground truth came with it
    for entry in summary["maps"].values():
        assert entry["vertices"] > 0


def test_generate_camera_only_refuses_an_unknown_video_suffix(tmp_path: Path) -> None:
    from cogmap_core.datasets.errors import BagError

    with pytest.raises(BagError, match="write a video as .mp4 or .avi"):
        generate_camera_only(tmp_path / "x.mkv", MazeConfig(laps=1))


def test_open_video_reads_frames_in_order(tmp_path: Path) -> None:
    pano = panorama()
    path = tmp_path / "v.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 8.0, (416, 240), False)
    for k in range(4):
        writer.write(view(pano, 100 - 5 * k))
    writer.release()
    with open_video(path, frontend=FrontEndConfig(camera_fov_deg=41.6)) as reader:
        assert reader.info.frame_count == 4 and reader.info.times_from == "the video"
        frames = list(reader.frames())
    assert [f.time for f in frames] == pytest.approx([0.0, 0.125, 0.25, 0.375])
    assert [f.rotation for f in frames[1:]] == pytest.approx([5 * math.radians(0.1)] * 3, abs=2e-3)


def test_serve_replays_an_image_folder_at_the_given_rate(tmp_path: Path) -> None:
    from app.inputs import InputOptions
    from app.server.replay import PlaybackState
    from cogmap_core.sources.detect import CameraOptions
    from tests.test_server_support import running_app, wait

    folder = image_folder(tmp_path, times=False, truth=False)
    options = CameraOptions(fps=4.0)
    read = InputOptions(format="images", camera=options)
    with running_app(folder, input_options=read, data_dirs=[tmp_path]) as app:
        wait(app)
        replay = app.replay
        assert replay.state is PlaybackState.ENDED, replay.message
        assert replay.session.log.frames == 6
        assert replay.session.log.frame_time[-1] == pytest.approx(1.25)


def test_camera_only_inputs_judge_loop_closures_past_a_metre() -> None:
    from cogmap_core.config import MapParams
    from cogmap_core.sources.detect import KINDS

    for kind in ("video", "images"):
        params = KINDS[kind].map_params
        assert params == MapParams(loop_scale=33.3)  # only the loop scale differs from a bag's
        model = params.loop_closure_model()
        assert model is not None and model.scale == pytest.approx(0.999, abs=1e-12)
    assert KINDS["bag"].map_params == MapParams()


def test_each_camera_input_gets_its_own_front_end_settings(tmp_path: Path) -> None:
    # the page opens other inputs with the settings of each, not the first input's
    from app.inputs import resolve_frontend
    from cogmap_core.datasets.profile import frontend_config_for

    given = FrontEndConfig(camera_fov_deg=33.0)
    folder = tmp_path / "run"
    assert resolve_frontend(given, folder) is given
    assert resolve_frontend(None, folder) == frontend_config_for(folder)
    made = resolve_frontend(lambda p: FrontEndConfig(camera_fov_deg=len(p.name)), folder)
    assert made.camera_fov_deg == 3


short_bag = server_support.short_bag  # the web-app tests' session fixture


def test_the_page_opens_a_bag_with_serve_s_odometry_choice(short_bag: Path) -> None:
    # a bag chosen on the page is read as serve's --odometry says, like the one served first
    from app.inputs import InputOptions
    from cogmap_core.sources.detect import CameraOptions
    from tests.test_server_support import running_app, wait

    read = InputOptions(camera=CameraOptions(odometry="visual"))
    with running_app(short_bag, input_options=read, data_dirs=[short_bag.parent]) as app:
        wait(app)
        assert app.replay.reader is not None and app.replay.reader.visual_odometry
        assert app.open_bag(short_bag.name), app.open_md.content
        wait(app)
        assert app.replay.reader is not None and app.replay.reader.visual_odometry
