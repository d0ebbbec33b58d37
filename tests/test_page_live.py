"""Issue 25: the live panels -- the camera after a seek, a rebuild you can see, restart plays,
and the network behind the map (view templates, pose cells) as OpenRatSLAM shows it."""

from __future__ import annotations

import bisect
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from app.server.network import peak_pixel, pose_cell_image, template_image
from app.server.replay import PlaybackState
from cogmap_core.datasets import open_bag
from cogmap_core.slam import SlamSession
from cogmap_core.sources.odometry_log import LOG_MAP_PARAMS
from tests import test_server_support as support
from tests.test_server_support import running_app, until, wait

short_bag = support.short_bag
reference = support.reference
false_log = support.false_log


def _frame_image(bag: Path, index: int) -> np.ndarray:
    with open_bag(bag, image_scale=1) as reader:  # the full-size decode the app uses
        for k, frame in enumerate(reader.frames()):
            if k == index:
                return frame.image
    raise AssertionError(f"no frame {index}")


def test_a_seek_while_paused_shows_its_frame_at_once(
    short_bag: Path, reference: SlamSession
) -> None:
    with running_app(short_bag) as app:
        wait(app)  # (played to the end: every frame cached)
        app.replay.pause()
        for t in (30.0, 12.0, 50.0):
            app.replay.seek(t)
            wait(app)
            k = bisect.bisect_right(reference.log.frame_time, t)
            assert app.replay.cursor == k and not app.replay.playing
            image = app.camera_image.image
            assert image is not None
            np.testing.assert_array_equal(image[:, :, 0], _frame_image(short_bag, k - 1))
            assert f"frame {k} / {app.replay.total_frames}" in app.template_md.content
        # stepping on from there shows the next frame, as before
        app.replay.step()
        wait(app)
        np.testing.assert_array_equal(app.camera_image.image[:, :, 0], _frame_image(short_bag, k))


class _Slow:
    """A builder that takes its time (a long rebuild) before each map."""

    def __init__(self, builder: object, seconds: float) -> None:
        self.builder = builder
        self.seconds = seconds

    def build(self, *args: object, **kwargs: object) -> Iterator[object]:
        for built in self.builder.build(*args, **kwargs):  # type: ignore[attr-defined]
            time.sleep(self.seconds)
            yield built

    def __getattr__(self, name: str) -> object:
        return getattr(self.builder, name)


def test_a_rebuild_in_progress_is_shown_and_what_the_maps_were_built_with(
    short_bag: Path,
) -> None:
    with running_app(short_bag) as app:
        wait(app)
        assert "maps built with</b> α 10 · β 10 · δ 3.746 · T_interval 2 · T_total 100" in (
            app.built_html.content
        )
        app.replay.builder = _Slow(app.replay.builder, 1.5)  # type: ignore[assignment]
        app.type_param("delta", "8")
        until(lambda: "cogmap-rebuild" in app.built_html.content, 5, "the rebuild shown")
        assert "rebuilding compact for δ = 8 (was 3.746) …" in app.built_html.content
        wait(app)
        content = app.built_html.content
        assert "cogmap-rebuild" not in content and "δ 8" in content
        app.type_param("t_interval", "4")  # every map rebuilt: the shown one first
        until(lambda: "cogmap-rebuild" in app.built_html.content, 5, "the second rebuild")
        assert "T_interval = 4 (was 2)" in app.built_html.content
        until(
            lambda: (
                "compact built with" in app.built_html.content
                or "cogmap-rebuild" not in app.built_html.content
            ),
            10,
            "one map built with the new value while the others are rebuilt",
        )
        wait(app)
        assert "maps built with</b> α 10 · β 10 · δ 8 · T_interval 4" in app.built_html.content


def test_restart_after_the_end_plays_from_the_start(short_bag: Path) -> None:
    with running_app(short_bag, speed=20.0) as app:
        app.replay.set_speed(float("inf"))
        wait(app)
        assert app.replay.state is PlaybackState.ENDED
        app.replay.set_speed(5.0)
        app.restart_button.value = True  # a click
        until(lambda: app.replay.state is PlaybackState.PLAYING, 10, "playing again")
        assert app.replay.cursor < 60
        until(lambda: app.play_button.label == "pause", 5, "the button saying pause")


def test_the_network_behind_the_map(short_bag: Path, reference: SlamSession) -> None:
    with running_app(short_bag, autoplay=False) as app:
        wait(app)
        app.replay.step(40)
        wait(app)
        frontend = app.replay.session.frontend
        k = app.replay.cursor
        # the view template panel: the current view beside the template it matched
        matched = app.replay.view_templates[k - 1]
        current = frontend.local_view.make_template(_frame_image(short_bag, k - 1))
        expected = template_image(current, frontend.local_view.template(matched))
        np.testing.assert_array_equal(app.template_image.image, expected)
        error = app.replay.view_errors[k - 1]
        threshold = frontend.config.vt_match_threshold
        text = app.match_html.content
        if np.isnan(error):
            assert f"the view became new template #{matched}" in text
        else:
            said = f"matched template #{matched}: match error {error:.4f} ≤ threshold "
            said += f"{threshold:.3g}"
            assert said in text
        # the pose cells: the network's activity, the peak marked
        activity, peak = frontend.pose_cell_activity, frontend.pose_cell_peak
        shown = app.pose_cells_image.image
        assert app.pose_cells_image.visible
        np.testing.assert_array_equal(shown, pose_cell_image(activity, peak))
        u, v = peak_pixel(activity, peak)
        ring = shown[v - 12 : v + 13, u - 12 : u + 13]
        assert (ring.max(axis=2) < 60).sum() > 40  # black ring and cross at the peak
        n_th, n_xy, _ = activity.shape
        assert f"{n_xy} × {n_xy} × {n_th} pose-cell network at frame {k}" in (
            app.pose_cells_html.content
        )
        assert f"peak (ring) at x {peak[0]:.1f}, y {peak[1]:.1f}" in app.pose_cells_html.content
        # replaying cached frames: the pose cells are the front end's, further on: said so
        app.replay.seek(1.0)
        wait(app)
        assert not app.pose_cells_image.visible
        assert f"the front end last ran at frame {k}" in app.pose_cells_html.content


def test_a_log_has_no_camera_and_says_so(false_log: Path) -> None:
    with running_app(false_log, params=LOG_MAP_PARAMS, defaults=LOG_MAP_PARAMS) as app:
        wait(app)
        for handle in (app.camera_image, app.template_image, app.pose_cells_image):
            assert not handle.visible
        assert "No camera: this input is a log of odometry and place recognition" in (
            app.network_html.content
        )
        assert "no view templates, no pose cells" in app.network_html.content


@pytest.mark.parametrize("size", [(420, 300), (200, 150)])
def test_pose_cell_pictures_fit_any_network(size: tuple[int, int]) -> None:
    rng = np.random.default_rng(1)
    for shape in ((36, 11, 11), (36, 21, 21), (8, 5, 5)):
        activity = np.zeros(shape)
        activity[tuple(rng.integers(0, n) for n in shape)] = 1.0
        peak = (shape[2] - 1.0, shape[1] - 1.0, shape[0] - 1.0)  # a far corner: still inside
        image = pose_cell_image(activity, peak, size)
        assert image.shape == (size[1], size[0], 3)
        u, v = peak_pixel(activity, peak, size)
        assert 10 <= u < size[0] - 10 and 10 <= v < size[1] - 10
