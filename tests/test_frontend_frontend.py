"""FrontEnd: the event stream -- new places, loop closures, determinism, bad frames."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from cogmap_core.errors import InputFileError
from cogmap_core.events import CreateVertex, LinkToVertex, Odometry, SetCurrentVertex
from cogmap_core.frames import Frame
from cogmap_core.frontend import FrontEnd, FrontEndConfig
from cogmap_core.frontend.config import COGMAP_ARITHMETIC

CELL = 0.015
# Most tests here follow one frame's action in that frame's events: cogmap's former order (one
# pose-cell update per frame, decided at once). OpenRatSLAM's order (the default) is tested at
# the end: the same decisions, one frame later.
CONFIG = FrontEndConfig(
    reference_image_width=420,
    image_crop_x_max=420,
    image_crop_y_max=140,
    camera_hfov_deg=60.0,
    **COGMAP_ARITHMETIC,
)
ORS = CONFIG.with_changes(
    vt_whole_crop=0, vt_mean_skip=1, pc_update_per_odometry=1, pc_inject_nearest=0, pc_edge_loss=1
)


def place(seed: int, shift: int = 0) -> np.ndarray:
    """A 420x240 camera image of 'place' ``seed``, the view turned by ``shift`` columns."""
    rng = np.random.default_rng(seed)
    cells = cv2.GaussianBlur(rng.random((20, 80)), (0, 0), 1.2)
    cells = (cells - cells.min()) / (cells.max() - cells.min())
    cells = (40 + 170 * cells).astype(np.uint8)[:, 10 + shift : 70 + shift]
    top = np.kron(cells, np.ones((7, 7), dtype=np.uint8))
    return np.vstack([top, np.full((100, 420), 17, dtype=np.uint8)])


class Drive:
    """Feeds frames to a front end at 17.5 Hz and collects the events."""

    def __init__(self, config: FrontEndConfig = CONFIG) -> None:
        self.fe = FrontEnd(config)
        self.index = 0
        self.events: list[list[object]] = []

    def frame(self, image: np.ndarray, translation: float = 0.0, rotation: float = 0.0) -> list:
        f = Frame(self.index, self.index / 17.5, image, translation, rotation, (9.0, 9.0, 9.0))
        self.index += 1
        out = self.fe.process(f)
        self.events.append(out)
        assert isinstance(out[0], Odometry)
        assert (out[0].translation, out[0].rotation) == (translation, rotation)
        assert all(e.time == f.time for e in out)
        return out[1:]


def square_loop(drive: Drive, side: int, first_seed: int) -> int:
    """Drive a closed square (``side`` cells a side) seeing a new place each frame."""
    seed = first_seed
    for _ in range(4):
        for _ in range(side):
            actions = drive.frame(place(seed), translation=CELL)
            assert actions == [CreateVertex(actions[0].time, drive.fe.vertex_count - 1, seed)]
            seed += 1
        actions = drive.frame(place(seed), rotation=math.pi / 2)
        assert isinstance(actions[0], CreateVertex)
        seed += 1
    return seed


def test_first_frame_creates_experience_zero() -> None:
    drive = Drive()
    assert drive.fe.current_vertex is None and drive.fe.current_template is None
    actions = drive.frame(place(0))
    assert actions == [CreateVertex(0.0, 0, 0)]
    assert drive.fe.current_vertex == 0 and drive.fe.vertex_count == 1
    assert drive.fe.current_template == 0 and drive.fe.template_count == 1


def test_staying_put_with_the_same_view_does_nothing() -> None:
    drive = Drive()
    drive.frame(place(0))
    for _ in range(20):
        assert drive.frame(place(0)) == []
    assert drive.fe.vertex_count == 1 and drive.fe.template_count == 1


def test_moving_far_with_the_same_view_creates_new_experiences() -> None:
    drive = Drive()
    drive.frame(place(0))
    created = []
    for step in range(1, 10):  # along the heading; the peak moves about one cell a step
        actions = drive.frame(place(0), translation=CELL)
        created += [(step, a) for a in actions]
    # Every 3 cells the packet is more than 2 cells from the current experience: a new one.
    assert [(step, a.vertex, a.view_template) for step, a in created] == [
        (3, 1, 0),
        (6, 2, 0),
        (9, 3, 0),
    ]
    assert all(isinstance(a, CreateVertex) for _, a in created)
    # Three more cells and the packet is again 2 cells past experience 3 -- but the 11-cell torus
    # has wrapped, and experience 0 (same view) is within 1 cell: RatSLAM's aliasing closes a
    # loop there instead of creating an experience.
    assert drive.frame(place(0), translation=CELL) == []
    assert drive.frame(place(0), translation=CELL) == []
    actions = drive.frame(place(0), translation=CELL)
    assert [(type(a), a.target) for a in actions] == [(LinkToVertex, 0), (SetCurrentVertex, 0)]


def test_new_places_create_vertices_in_order() -> None:
    drive = Drive()
    drive.frame(place(0))
    end = square_loop(drive, 5, 1)
    assert drive.fe.vertex_count == end
    assert drive.fe.template_count == end


def test_returning_to_the_start_closes_the_loop() -> None:
    drive = Drive()
    drive.frame(place(0))
    square_loop(drive, 6, 1)  # back at the start, facing the start heading again
    n = drive.fe.vertex_count
    actions = drive.frame(place(0))
    assert actions == [LinkToVertex(actions[0].time, 0, 0.0), SetCurrentVertex(actions[0].time, 0)]
    assert drive.fe.current_vertex == 0 and drive.fe.current_template == 0
    assert drive.fe.vertex_count == n  # no new vertex
    # Continuing along the first leg re-visits the vertices of the first lap, in order.
    seen = []
    for seed in range(1, 4):
        seen += drive.frame(place(seed), translation=CELL)
    assert [(type(a), a.target) for a in seen] == [
        (LinkToVertex, 1),
        (SetCurrentVertex, 1),
        (LinkToVertex, 2),
        (SetCurrentVertex, 2),
        (LinkToVertex, 3),
        (SetCurrentVertex, 3),
    ]


def test_loop_closure_carries_the_relative_angle() -> None:
    drive = Drive()
    drive.frame(place(0))
    square_loop(drive, 6, 1)
    actions = drive.frame(place(0, shift=2))  # back, the view turned 2 columns = 2 degrees
    rel = -math.radians(2)
    assert actions == [
        LinkToVertex(actions[0].time, 0, pytest.approx(rel)),
        SetCurrentVertex(actions[0].time, 0, pytest.approx(rel)),
    ]


def test_a_familiar_view_far_from_its_pose_cells_is_a_new_place() -> None:
    # Few templates, so the familiar view injects no energy (the 10 newest never do): only the
    # pose cells decide, and they are 5 cells away from experience 0.
    drive = Drive()
    drive.frame(place(0))
    for seed in range(1, 6):
        drive.frame(place(seed), translation=CELL)
    actions = drive.frame(place(0))
    assert actions == [CreateVertex(actions[0].time, 6, 0)]


def test_the_front_end_is_deterministic() -> None:
    def run() -> list:
        drive = Drive(FrontEndConfig())
        rng = np.random.default_rng(5)
        for i in range(120):
            image = cv2.resize(place(i % 17), (104, 60), interpolation=cv2.INTER_AREA)
            noisy = np.clip(image + rng.normal(0, 2, image.shape), 0, 255).astype(np.uint8)
            drive.frame(noisy, float(rng.uniform(0, 0.02)), float(rng.uniform(-0.1, 0.1)))
        return drive.events

    first, second = run(), run()
    assert first == second
    kinds = {type(e) for frame in first for e in frame}
    assert {Odometry, CreateVertex, LinkToVertex, SetCurrentVertex} <= kinds


def test_ground_truth_is_not_used() -> None:
    a, b = FrontEnd(CONFIG), FrontEnd(CONFIG)
    for i in range(30):
        image = place(i % 7)
        fa = Frame(i, i * 0.1, image, 0.01, 0.05, None)
        fb = Frame(i, i * 0.1, image, 0.01, 0.05, (float(i), -1.0, 2.0))
        assert a.process(fa) == b.process(fb)


def test_gui_state_is_exposed() -> None:
    drive = Drive()
    drive.frame(place(0), translation=CELL)
    x, y, th = drive.fe.pose_cell_peak
    assert 0 <= x < 11 and 0 <= y < 11 and 0 <= th < 36
    activity = drive.fe.pose_cell_activity
    assert activity.shape == (36, 11, 11) and not activity.flags.writeable
    assert activity.sum() == pytest.approx(1.0)


@pytest.mark.parametrize(
    ("time", "translation", "rotation"),
    [(float("nan"), 0.0, 0.0), (1.0, float("inf"), 0.0), (1.0, 0.0, float("nan"))],
)
def test_bad_frames_are_rejected(time: float, translation: float, rotation: float) -> None:
    fe = FrontEnd(CONFIG)
    with pytest.raises(InputFileError):
        fe.process(Frame(0, time, place(0), translation, rotation))


def test_time_going_backwards_is_rejected() -> None:
    fe = FrontEnd(CONFIG)
    fe.process(Frame(0, 2.0, place(0), 0.0, 0.0))
    with pytest.raises(InputFileError, match="backwards"):
        fe.process(Frame(1, 1.0, place(0), 0.0, 0.0))


# ------------------------------------------------------------------ OpenRatSLAM's order
def test_openratslam_order_decides_at_the_first_odometry_after_a_frame() -> None:
    fe = FrontEnd(ORS)
    steps = np.array([[0.004, 0.0], [0.005, 0.01], [0.006, 0.02]])
    first = fe.process(Frame(0, 0.0, place(0), 0.0, 0.0, odometry_steps=np.zeros((0, 2))))
    assert first == [Odometry(0.0, 0.0, 0.0)]  # the view is in, nothing decided yet
    assert fe.vertex_count == 0 and fe.current_template == 0
    events = fe.process(Frame(1, 0.1, place(1), 0.015, 0.03, odometry_steps=steps))
    # Frame 0's experience at the first message, then the rest of the motion.
    assert events == [
        Odometry(0.1, 0.004, 0.0),
        CreateVertex(0.1, 0, 0),
        Odometry(0.1, pytest.approx(0.011), pytest.approx(0.03)),
    ]
    assert fe.current_template == 1 and fe.vertex_count == 1
    events = fe.process(Frame(2, 0.2, place(2), 0.01, 0.0))  # no steps given: one step
    assert events == [Odometry(0.2, 0.01, 0.0), CreateVertex(0.2, 1, 1)]


def test_both_orders_take_the_same_decisions_one_frame_apart() -> None:
    """Frames with one odometry message each: OpenRatSLAM's order decides frame k's action at
    frame k + 1 with the pose cells moved by frame k + 1's message first."""
    ors, former = FrontEnd(ORS), FrontEnd(ORS.with_changes(pc_update_per_odometry=0))
    ors.decisions, former.decisions = [], []
    for i in range(40):
        image = place(i % 9)
        frame = Frame(i, i * 0.1, image, 0.01, 0.05, odometry_steps=np.array([[0.01, 0.05]]))
        ors.process(frame)
        former.process(frame)
    assert 10 < len(ors.decisions) <= len(former.decisions)
    assert [d[0] for d in ors.decisions] == [d[0] for d in former.decisions][: len(ors.decisions)]


def test_a_bad_odometry_step_is_rejected() -> None:
    fe = FrontEnd(ORS)
    steps = np.array([[0.01, 0.0], [float("nan"), 0.0]])
    with pytest.raises(InputFileError, match="odometry step"):
        fe.process(Frame(0, 0.0, place(0), 0.01, 0.0, odometry_steps=steps))
