"""The synthetic maze generator: bag contents, odometry drift model, camera realism."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from cogmap_core.datasets import (
    BagError,
    MazeConfig,
    OdometryModel,
    generate_maze_bag,
    generator,
    load_layout,
    open_bag,
)
from cogmap_core.datasets.generator import (
    START_STAMP_NS,
    light_levels,
    plan_dataset,
    render_frames,
)
from cogmap_core.datasets.render import MazeRenderer, encode_jpeg
from cogmap_core.errors import ParameterError

LOOP = """\
; a small loop with a spur
; cell: 0.3
#########
#A.....B#
#.#####.#
#D.....C#
###.#####
###E#####
#########
"""


@pytest.fixture(scope="module")
def loop_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("layouts") / "loop.txt"
    path.write_text(LOOP)
    return path


@pytest.fixture(scope="module")
def small_bag(
    tmp_path_factory: pytest.TempPathFactory, loop_file: Path
) -> tuple[Path, MazeConfig, object]:
    config = MazeConfig(layout=str(loop_file), laps=1, seed=3)
    out = tmp_path_factory.mktemp("bags") / "loop.bag"
    result = generate_maze_bag(out, config, preview=True, workers=1)
    return out, config, result


def test_generated_bag_has_the_irat_layout(small_bag: tuple[Path, MazeConfig, object]) -> None:
    path, config, result = small_bag
    plan = plan_dataset(config)
    with open_bag(path) as reader:
        info = reader.info
        assert info.topics == {
            "/irat_red/camera/image/compressed": "sensor_msgs/msg/CompressedImage",
            "/irat_red/odom": "nav_msgs/msg/Odometry",
            "/overhead/pose": "geometry_msgs/msg/PoseStamped",
        }
        assert info.frame_count == len(plan.frame_times) == result.frames
        assert info.frame_rate == pytest.approx(17.5, rel=0.01)
        assert info.odometry_count == len(plan.odom_times)
        assert info.ground_truth_count == len(plan.gt_times)
        frames = list(reader.frames())
        assert reader.warnings == []
        assert reader.start_stamp == START_STAMP_NS / 1e9
    assert len(frames) == info.frame_count
    assert frames[0].image.shape == (240, 416)
    # frame times are the planned camera times (ns-rounded stamps)
    times = np.array([f.time for f in frames])
    np.testing.assert_allclose(times, plan.frame_times, atol=1e-9)
    # odometry: what the frames integrate is exactly what was published (v dt over stamps)
    dt = np.diff(plan.odom_times)
    published = plan.odom_v[1:] * dt
    upto = np.searchsorted(plan.odom_times[1:], times[-1], side="right")
    total = sum(f.translation for f in frames)
    assert total == pytest.approx(published[:upto].sum(), abs=1e-6)
    assert sum(f.rotation for f in frames) == pytest.approx(
        (plan.odom_w[1:] * dt)[:upto].sum(), abs=1e-6
    )
    # ground truth: the true pose at each frame, interpolated from the 10 Hz overhead poses
    truth = plan.trajectory.pose_at(times)
    gt = np.array([f.ground_truth for f in frames])
    assert np.abs(gt[:, :2] - truth[:, :2]).max() < 0.003
    dth = (gt[:, 2] - truth[:, 2] + math.pi) % (2 * math.pi) - math.pi
    assert np.abs(dth).max() < 0.01


def test_images_round_trip_exactly(small_bag: tuple[Path, MazeConfig, object]) -> None:
    path, config, _ = small_bag
    plan = plan_dataset(config)
    renderer = MazeRenderer(plan.layout)
    with open_bag(path) as reader:
        frames = [f for f, _ in zip(reader.frames(), range(3), strict=False)]
    for frame in frames:
        i = frame.index
        rng = np.random.default_rng((config.seed, 0xCA3E7A, i))
        image = renderer.render(*plan.frame_poses[i], plan.frame_light[i], rng, config.noise_sigma)
        jpeg = encode_jpeg(image, config.jpeg_quality)
        np.testing.assert_array_equal(
            frame.image, cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_GRAYSCALE)
        )


def test_previews(small_bag: tuple[Path, MazeConfig, object]) -> None:
    path, config, result = small_bag
    camera, maze = result.previews
    assert camera == path.with_name("loop_camera.png")
    assert maze == path.with_name("loop_maze.png")
    cam = cv2.imread(str(camera), cv2.IMREAD_UNCHANGED)
    assert cam.shape == (240, 416)
    assert cam[:150].std() > 10  # walls with texture, not a blank picture
    picture = cv2.imread(str(maze))
    layout = load_layout(config.layout)
    assert picture.shape == (
        round(layout.size_m[1] * 160) + 20,
        round(layout.size_m[0] * 160) + 20,
        3,
    )


def test_same_config_same_bag_and_seed_matters(tmp_path: Path, loop_file: Path) -> None:
    config = MazeConfig(layout=str(loop_file), laps=1, seed=11, fps=4.0)
    a = generate_maze_bag(tmp_path / "a.bag", config, workers=1)
    b = generate_maze_bag(tmp_path / "b.bag", config, workers=1)
    c = generate_maze_bag(
        tmp_path / "c.bag", MazeConfig(layout=str(loop_file), laps=1, seed=12, fps=4.0), workers=1
    )
    assert a.path.read_bytes() == b.path.read_bytes()
    assert a.path.read_bytes() != c.path.read_bytes()


def test_parallel_rendering_gives_the_same_frames(
    loop_file: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    plan = plan_dataset(MazeConfig(layout=str(loop_file), laps=1, seed=2, fps=2.0))
    used, serial = render_frames(plan, workers=1)
    assert used == 1
    expected = list(serial)
    monkeypatch.setattr(generator, "_CHUNK", 2)  # many chunks, to see the window move
    submitted: list[int] = []

    class Counting(generator.ProcessPoolExecutor):  # type: ignore[misc]
        def submit(self, *args: Any, **kwargs: Any) -> Any:
            submitted.append(1)
            return super().submit(*args, **kwargs)

    monkeypatch.setattr(generator, "ProcessPoolExecutor", Counting)
    used, parallel = render_frames(plan, workers=2, min_frames_per_worker=1)
    assert used == 2
    frames = []
    for k, jpeg in enumerate(parallel):
        frames.append(jpeg)
        # never more than _IN_FLIGHT chunks per worker ahead of the consumer (flat memory)
        assert len(submitted) <= k // 2 + 1 + generator._IN_FLIGHT * used
    assert len(expected) > 2 * 2 * generator._IN_FLIGHT * used  # the window did move
    assert frames == expected


def test_existing_output_and_interrupted_generation(tmp_path: Path, loop_file: Path) -> None:
    config = MazeConfig(layout=str(loop_file), laps=1, fps=2.0)
    out = tmp_path / "x.bag"
    out.write_bytes(b"keep me")
    with pytest.raises(BagError, match="already exists"):
        generate_maze_bag(out, config, workers=1)
    assert out.read_bytes() == b"keep me"

    def stop(done: int, total: int) -> None:
        if done > 10:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        generate_maze_bag(tmp_path / "y.bag", config, workers=1, progress=stop)
    with pytest.raises(ParameterError, match="workers 0 must be at least 1"):
        generate_maze_bag(tmp_path / "z.bag", config, workers=0)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.bag"]  # no bag, no partial file


@pytest.mark.parametrize(
    ("changes", "match"),
    [
        ({"fps": 0.0}, "fps 0.0 is out of range"),
        ({"speed": 3.0}, "speed 3.0 m/s is out of range"),
        ({"laps": 0}, "laps 0 is out of range"),
        ({"jpeg_quality": 101}, "jpeg_quality 101 is out of range"),
        ({"odometry": None}, None),
    ],
)
def test_bad_settings(changes: dict, match: str | None) -> None:
    if match is None:
        with pytest.raises(ParameterError, match="odometry noise sigma_v=-1"):
            OdometryModel(sigma_v=-1.0)
        with pytest.raises(ParameterError, match="drift_w=2"):
            OdometryModel(drift_w=2.0)
        return
    with pytest.raises(ParameterError, match=match):
        MazeConfig(**changes)


# ------------------------------------------------------------------------------- odometry drift
def _totals(plan: object) -> tuple[float, float, float, float, float]:
    """(measured distance, true distance, measured turn, true turn, sum of moving dt^2)."""
    dt = np.diff(plan.odom_times)
    t = plan.odom_times
    true_d = np.diff(plan.trajectory.distance_at(t))
    true_h = np.diff(plan.trajectory.heading_at(t))
    moving = (np.abs(true_d) > 1e-12) | (np.abs(true_h) > 1e-12)
    return (
        float((plan.odom_v[1:] * dt).sum()),
        float(true_d.sum()),
        float((plan.odom_w[1:] * dt).sum()),
        float(true_h.sum()),
        float((dt[moving] ** 2).sum()),
    )


def test_noise_free_odometry_is_exact() -> None:
    model = OdometryModel(sigma_v=0.0, sigma_w=0.0, bias_v=0.0, bias_w=0.0, drift_w=0.0)
    plan = plan_dataset(MazeConfig(layout="figure_eight", laps=1, odometry=model))
    d_meas, d_true, h_meas, h_true, _ = _totals(plan)
    assert d_meas == pytest.approx(d_true, abs=1e-9)
    assert h_meas == pytest.approx(h_true, abs=1e-9)
    truth = plan.trajectory.pose_at(plan.odom_times)
    start = truth[0]
    c, s = math.cos(start[2]), math.sin(start[2])
    odo = plan.odom_pose
    x = start[0] + c * odo[:, 0] - s * odo[:, 1]
    y = start[1] + s * odo[:, 0] + c * odo[:, 1]
    assert np.hypot(x - truth[:, 0], y - truth[:, 1]).max() < 0.002  # integration error only


@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_drift_stays_within_the_noise_model(seed: int) -> None:
    model = OdometryModel()
    plan = plan_dataset(MazeConfig(layout="irat_australia", laps=1, seed=seed, odometry=model))
    d_meas, d_true, h_meas, h_true, dt2 = _totals(plan)
    # distance: scale bias plus white noise
    sigma_d = model.sigma_v * math.sqrt(dt2)
    assert abs(d_meas - (1 + model.bias_v) * d_true) < 4 * sigma_d
    # heading: turn scale bias, drift per metre, white noise
    sigma_h = model.sigma_w * math.sqrt(dt2)
    expected = model.bias_w * h_true + model.drift_w * d_true
    assert abs(h_meas - h_true - expected) < 4 * sigma_h
    # and the drift is real: metres of error would be a bug, centimetres too little to see
    start = plan.trajectory.pose_at(0.0)
    end = plan.trajectory.pose_at(plan.odom_times[-1])
    c, s = math.cos(start[2]), math.sin(start[2])
    ox, oy = plan.odom_pose[-1, :2]
    error = math.hypot(start[0] + c * ox - s * oy - end[0], start[1] + s * ox + c * oy - end[1])
    assert 0.05 < error < 1.5


def test_heading_drift_grows_lap_after_lap() -> None:
    model = OdometryModel(sigma_v=0.005, sigma_w=0.02, bias_v=0.0, bias_w=0.0, drift_w=0.01)
    plan = plan_dataset(MazeConfig(layout="figure_eight", laps=4, odometry=model))
    dt = np.concatenate([[0.0], np.diff(plan.odom_times)])
    measured = np.cumsum(plan.odom_w * dt)
    true = plan.trajectory.heading_at(plan.odom_times) - plan.trajectory.heading[0]
    errors = []
    for lap_end in plan.trajectory.lap_times[1:]:
        k = min(int(np.searchsorted(plan.odom_times, lap_end)), len(plan.odom_times) - 1)
        errors.append(measured[k] - true[k])
        d = plan.trajectory.distance_at(plan.odom_times[k])
        sigma = model.sigma_w * math.sqrt((dt[: k + 1] ** 2).sum())
        assert abs(errors[-1] - model.drift_w * d) < 4 * sigma
    assert all(b > a for a, b in zip(errors, errors[1:], strict=False))
    assert errors[-1] > 0.2  # over 10 degrees after four laps: visible on a map


# ----------------------------------------------------------------------------------- the camera
def _template(image: np.ndarray) -> np.ndarray:
    """The front end's view: rows 0-150 reduced to 60 x 20, normalised to unit mean."""
    t = cv2.resize(image[:150].astype(np.float32), (60, 20), interpolation=cv2.INTER_AREA)
    return t / t.mean()


def test_same_pose_matches_better_than_other_places() -> None:
    plan = plan_dataset(MazeConfig(laps=1, seed=4))
    renderer = MazeRenderer(plan.layout)
    rng = np.random.default_rng(0)
    poses = plan.frame_poses[rng.choice(len(plan.frame_poses), 30, replace=False)]

    def shot(pose: np.ndarray, light: float, seed: int) -> np.ndarray:
        image = renderer.render(*pose, light, np.random.default_rng(seed), 3.0)
        jpeg = encode_jpeg(image, 80)
        return _template(cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_GRAYSCALE))

    first = [shot(p, 1.0, i) for i, p in enumerate(poses)]
    again = [shot(p, 0.8, 100 + i) for i, p in enumerate(poses)]  # dimmer light, new noise
    for i, pose in enumerate(poses):
        same = np.abs(first[i] - again[i]).mean()
        others = []
        for j, other in enumerate(poses):
            far = math.hypot(*(pose[:2] - other[:2])) > 0.3
            turned = abs((pose[2] - other[2] + math.pi) % (2 * math.pi) - math.pi) > 0.8
            if j != i and (far or turned):
                others.append(np.abs(first[i] - again[j]).mean())
        assert same < 0.5 * min(others)


def test_light_levels_vary_within_bounds() -> None:
    t = np.arange(0.0, 900.0, 0.5)
    level = light_levels(t, np.random.default_rng(1))
    assert 0.65 < level.min() < 0.95 and 1.0 < level.max() < 1.3
    assert np.abs(np.diff(level)).max() < 0.1  # smooth: no flicker between frames
    assert (light_levels(t, np.random.default_rng(1), enabled=False) == 1.0).all()
